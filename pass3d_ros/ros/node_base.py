"""What both PASS3D nodes share: parameters declared from their table, QoS names checked at start-up, one
latest-frame worker fed by the input subscription (or in memory by the node before it), counters on
`/diagnostics` at 1 Hz, frame errors logged (throttled), the worker stopped on destroy. An `auto` input QoS follows
the publishers (re-checked every second), and an input that stays silent or loses scans is reported, as is input
that comes in while no output goes out (skipped frames count as skipped, not processed)."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from sensor_msgs.msg import PointCloud2

from pass3d_ros.core.stage1.config import closest
from pass3d_ros.msgs.pointcloud2 import header_stamp_ns
from pass3d_ros.ros.dds_profile import shipped_profile
from pass3d_ros.ros.diagnostics import (
    DIAGNOSTICS_PERIOD_S,
    DIAGNOSTICS_TOPIC,
    NodeStats,
    OutputWatch,
    RecentTrouble,
    StepClock,
    to_status,
)
from pass3d_ros.ros.input_watch import InputWatch, OverlapFilter
from pass3d_ros.ros.latest_frame import SKIPPED, FrameCounters, LatestFrameWorker, Outcome
from pass3d_ros.ros.params import NodeParameters
from pass3d_ros.ros.qos import (
    AUTO,
    INPUT_QOS_NAMES,
    QOS_NAMES,
    RELIABILITY_WORDS,
    endpoint_qos,
    offered_qos,
    qos_profile,
)

LOG_PERIOD_S = 5.0
QOS_PARAMETERS = {"input_qos": INPUT_QOS_NAMES, "output_qos": QOS_NAMES}
INPUT_CHECK_PERIOD_S = 1.0  # auto QoS and the silent-input watch look at the input's publishers this often
INPUT_WARNING_PERIOD_S = 30.0  # the input warning repeats at most this often
RESUBSCRIBE_OVERLAP_S = 2.0  # an auto resubscription keeps the old subscription this long (duplicates dropped)
FRAME_BACKLOG = 2  # frames that may wait for a busy worker: one slow frame (a stream's first scans, a CPU hiccup)
# costs no frame when the stage keeps up on average; a stage that does not still drops (and counts) stale frames


class PointCloudNode(Node):
    """A node that processes the newest PointCloud2 of `input_topic` on a worker thread.

    Its parameter table must hold `input_topic`, `input_qos` and `output_qos`; a QoS name QOS_PARAMETERS does
    not allow ends start-up with a ValueError.
    """

    # Each hop counts the scans missing between consecutive header stamps of its input (the sensor's, or the node
    # before it: there they are the frames lost on the way or dropped upstream).
    COUNTS_INPUT_GAPS = True

    def __init__(self, parameters: NodeParameters, **kwargs: Any) -> None:
        super().__init__(parameters.node_name, **kwargs)
        parameters.declare(self)
        self.add_pre_set_parameters_callback(self._refuse_undeclared)
        for name, allowed in QOS_PARAMETERS.items():
            if self.get_parameter(name).value not in allowed:
                raise ValueError(f"parameter {name} must be one of {allowed}")
        self.stats = NodeStats(count_gaps=self.COUNTS_INPUT_GAPS)
        self.skip_reasons: Counter[str] = Counter()  # skipped frames by reason ("malformed", "empty")
        self.output_watch = OutputWatch()
        self.recent_trouble = RecentTrouble()  # WARN for loss only while it grows (diagnostics.TROUBLE_WINDOW_S)
        self._warned: set[str] = set()  # the keys of the once-only warnings given (warn_once)
        self._frame_id: str | None = None  # the input's frame_id the stream's state was learned in (follow_frame)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def _refuse_undeclared(self, changed: list[Parameter]) -> list[Parameter]:
        """Refuse a change of a parameter this node does not declare, naming it and the nearest declared one (rclpy
        7.1.6's own refusal names none: `ros2 param set` said "Invalid access to undeclared parameter(s): []")."""
        unknown = [p.name for p in changed if not self.has_parameter(p.name)]
        if unknown:
            near = {name: closest(name, self._parameters) for name in unknown}
            raise ParameterNotDeclaredException(", ".join(
                f"{name!r}" + (f" (did you mean {near[name]!r}?)" if near[name] else "") for name in unknown))
        return changed

    def warn_once(self, key: str, text: str) -> None:
        """Log `text` as a warning the first time `key` comes up (a setting that stays wrong, said once)."""
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def follow_frame(self, frame_id: str, starts_over: str | None) -> bool:
        """Note the input's frame_id; True when it differs from the one before (another sensor, or one mounted
        again), for the caller to start its stream's state over, with a throttled warning that says `starts_over`
        (what does; None: no warning, nothing held)."""
        changed = self._frame_id is not None and frame_id != self._frame_id
        if changed and starts_over is not None:
            self.get_logger().warning(f"input frame_id changed from {self._frame_id!r} to {frame_id!r}: {starts_over}",
                                      throttle_duration_sec=LOG_PERIOD_S)
        self._frame_id = frame_id
        return changed

    def output_publisher(self, msg_type: type, topic_parameter: str) -> Publisher:
        """A publisher on the topic the parameter `topic_parameter` names, with the `output_qos` profile."""
        qos = qos_profile(self.get_parameter("output_qos").value)
        return self.create_publisher(msg_type, self.get_parameter(topic_parameter).value, qos)

    def start_worker(self, process: Callable[[Any], object], name: str, subscribe: bool = True) -> None:
        """Hand the newest input to `process` on a thread; inputs come from `input_topic` (with `input_qos`),
        or only through `submit` when `subscribe` is False (an in-memory hand-off in one process). `process`
        returns `self.skipped(reason)` for a frame it skips, DROPPED for one it gives up."""
        self.worker: LatestFrameWorker[Any] = LatestFrameWorker(process, self._on_error, name,
                                                                         backlog=FRAME_BACKLOG)
        self.subscription = None
        self.input_watch: InputWatch | None = None
        self._retiring: tuple[Any, float] | None = None  # the subscription an auto switch replaced, and until when
        self._source = 0  # which of two overlapping subscriptions is the current one
        self._overlap = OverlapFilter()  # drops what both reach during a switch
        if not subscribe:
            return
        topic = self.get_parameter("input_topic").value
        self.input_qos = self.get_parameter("input_qos").value
        self.subscribed_qos = self.input_qos
        if self.input_qos == AUTO:
            self.subscribed_qos = offered_qos(self.get_publishers_info_by_topic(topic))
        self.subscription = self._subscribe(topic, self.subscribed_qos)
        self.input_watch = InputWatch(self.subscription.topic_name, str(shipped_profile() or ""),
                                      count_missing=self.COUNTS_INPUT_GAPS)
        if self.input_qos == AUTO:
            self.get_logger().info(f"input_qos auto: {self.subscription.topic_name} subscribed "
                                   f"{RELIABILITY_WORDS[self.subscribed_qos]}; follows what its publishers offer "
                                   "(reliable when all of them are)")
        self.input_timer = self.create_timer(INPUT_CHECK_PERIOD_S, self._check_input,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _subscribe(self, topic: str, qos: str) -> Any:
        """The input subscription (as source `self._source`); a publisher matching, leaving or offering an
        incompatible QoS has the input looked at at once, not at the next tick."""
        events = SubscriptionEventCallbacks(matched=self._on_input_event, incompatible_qos=self._on_input_event)
        return self.create_subscription(PointCloud2, topic, partial(self._on_message, self._source), qos_profile(qos),
                                        event_callbacks=events)

    def _on_input_event(self, _status: Any) -> None:
        self._check_input()

    def _check_input(self) -> None:
        """Timer and input events: resubscribe an `auto` input when its publishers' QoS asks for another
        reliability; warn (throttled) when the input has publishers but stays silent or loses scans."""
        if self.subscription is None or self.input_watch is None:
            return
        topic = self.subscription.topic_name
        publishers = self.get_publishers_info_by_topic(topic)
        now = time.monotonic()
        wanted = offered_qos(publishers)
        if self._retiring is not None and now >= self._retiring[1]:
            self.destroy_subscription(self._retiring[0])
            self._retiring = None
            self._overlap.stop()
        if self.input_qos == AUTO and wanted != self.subscribed_qos:
            if self._retiring is not None:
                self.destroy_subscription(self._retiring[0])
            # the new one matches while the old one still delivers: no scan is lost in the switch
            self._retiring = (self.subscription, now + RESUBSCRIBE_OVERLAP_S)
            self._source = 1 - self._source
            self._overlap.start()
            self.subscription = self._subscribe(topic, wanted)
            self.get_logger().info(f"input_qos auto: {topic} resubscribed {RELIABILITY_WORDS[wanted]} (was "
                                   f"{RELIABILITY_WORDS[self.subscribed_qos]}): what its {len(publishers)} "
                                   "publisher(s) offer")
            self.subscribed_qos = wanted
            self.input_watch.restart(now)
        problem = self.input_watch.check(now, [endpoint_qos(info) for info in publishers], self.subscribed_qos)
        if problem:
            self.get_logger().warning(problem, throttle_duration_sec=INPUT_WARNING_PERIOD_S)

    def _on_message(self, source: int, msg: PointCloud2) -> None:
        stamp = header_stamp_ns(msg)
        if not self._overlap.accept(source, stamp):
            return  # the same scan through the other subscription of an auto switch
        if self.input_watch is not None:
            self.input_watch.received(time.monotonic(), stamp)
        self.submit(msg, stamp)

    def submit(self, item: Any, stamp_ns: int) -> None:
        """Queue one input (a message, or an in-memory frame): the stamp feeds the gap counter."""
        self.stats.input(stamp_ns)
        self.worker.submit(item)

    def counters(self) -> FrameCounters:
        """The node's frame counters: received, processed (= output), dropped, failed, skipped."""
        return self.worker.counters

    def skipped(self, reason: str) -> Outcome:
        """What `process` returns for a frame it skips (malformed, empty): counted as skipped, by `reason`."""
        self.skip_reasons[reason] += 1
        return SKIPPED

    def missed_note(self) -> str:
        """For the throttled frame log: the scans missing between input stamps so far (counted, and pending until the
        stream says whether they are loss or a slower rate), "" while none."""
        missed, pending = self.stats.frames_missed, self.stats.frames_pending
        if not (missed or pending):
            return ""
        return f", input missed {missed} scan(s) by stamps" + (f" (+{pending} pending)" if pending else "")

    def idle(self) -> bool:
        """True when no frame is pending or in hand."""
        return self.worker.idle()

    def step_clock(self) -> StepClock:
        """A clock for the frame in hand, starting with the time it waited in the worker's slot."""
        return StepClock(self.worker.last_wait_s)

    def publish_diagnostics(self) -> None:
        """One DiagnosticArray with this node's status (counters, gaps, latency percentiles, step medians)."""
        worker = getattr(self, "worker", None)
        if worker is None:
            return
        values, warnings = self.diagnostic_extras()
        counters = vars(self.counters())
        no_output = self.output_watch.check(time.monotonic(), counters, self.skip_reasons)
        warnings = [self.input_watch.problem if self.input_watch is not None else "", no_output, *warnings]
        values = {**{f"skipped_{reason}": count for reason, count in self.skip_reasons.items()}, **values}
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [to_status(self.get_name(), {**counters, **values}, self.stats, self.recent_trouble,
                                warning="; ".join(w for w in warnings if w),
                                error="; ".join(self.diagnostic_errors()))]
        self.diagnostics_pub.publish(msg)

    def diagnostic_extras(self) -> tuple[dict[str, int], list[str]]:
        """A subclass's own `/diagnostics` values, and warnings that turn its status WARN (none here)."""
        return {}, []

    def diagnostic_errors(self) -> list[str]:
        """What a subclass has to report as ERROR on `/diagnostics` now (none here)."""
        return []

    def _on_error(self, exc: BaseException) -> None:
        """A frame that raised: one throttled error line, and the node goes on with the next frame.

        Once the context is shut down (Ctrl-C under load) a failed publish is no error: the worker just stops.
        """
        if not self.context.ok():
            self.worker.stop()
            return
        self.get_logger().error(f"frame failed: {type(exc).__name__}: {exc}", throttle_duration_sec=LOG_PERIOD_S)

    def stop_worker(self) -> None:
        """Finish the frame in hand and stop the worker, before the executor and the context go."""
        self.worker.stop()

    def destroy_node(self) -> None:
        """Stop the worker thread before the node goes."""
        self.stop_worker()
        super().destroy_node()
