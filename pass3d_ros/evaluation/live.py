"""Live-path evaluation: a bag's clouds through both real nodes in one process, outputs matched by header stamp.

`run_live` (its steps in `LiveHarness`) starts ClusterProposalNode and SegmentationNode on a
SingleThreadedExecutor in a private rclpy context (its own DDS domain, so a real robot on the default domain
never sees the test traffic), publishes the bag's PointCloud2 CDR bytes unchanged on the cluster node's input
topic and listens to the labeled output (and, for per-stage times, to the proposals in between). Ground truth
comes from the bag's `label_gt` field (a legacy `label` only in a cloud that is not a pass3d output, see
`pass3d_ros.data.bag.truth_field`). A recording (`record_out`) holds the labeled clouds and the object markers.
`pass3d_ros.evaluation.report.score` turns a LiveResult into the dict `pass3d_evaluate` writes as JSON.

Layouts (`layout`): `one-process` (the nodes and the evaluator in this process, PointCloud2 over DDS between the
nodes), `in-memory` (the same, stage 1 handing its arrays to stage 2: `pass3d_ros.ros.inprocess`), `two-process`
(the nodes in a child `pass3d_pipeline` process, so input and output cross a process boundary). Per-node counters,
step times and input gaps come from the nodes' /diagnostics (`node_stats`).

Timing: latency = publish wall time -> receipt of /pass3d/labeled; stage1_ms = publish -> receipt of
/pass3d/proposals; stage2_ms = that receipt -> receipt of /pass3d/labeled. Each includes the DDS hop of
its output message, which is what a live consumer sees.
"""

from __future__ import annotations

import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pass3d_ros.classes import IGNORE, NUM_CLASSES, foreign_ids
from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.core.stage1.config import ConfigError
from pass3d_ros.data.bag import (
    LABEL_FIELD,
    TYPESTORE,
    BagFile,
    BagWriter,
    is_output_cloud,
    message_stamp_ns,
    parse_bag_spec,
    truth_field,
)
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, PointCloud2Error, decode, finite_mask, header_stamp_ns

NODE_NAMES: tuple[str, ...] = ("cluster_proposal_node", "segmentation_node")
MARKER_ARRAY_TYPE = "visualization_msgs/msg/MarkerArray"
DISCOVERY_TIMEOUT_S = 15.0
CHILD_START_S = 60.0  # two-process layout: the node process's start-up, on top of discovery
SETTLE_S = 0.3  # after matching: the subscriber side of discovery may finish a moment later
QUIET_S = 1.0  # at the end, both nodes idle and no output for this long: nothing more will come
FRAME_GAP_NS = 100_000_000  # replay spacing between passes of a one-message bag (10 Hz)
SPIN_STEP_S = 0.05  # the evaluator's spin loop looks at its stop flag this often
COUNTER_KEYS = ("received", "processed", "dropped", "failed")
LAYOUTS: tuple[str, ...] = ("one-process", "in-memory", "two-process")


class LiveEvalError(UserError):
    """The live run could not start (discovery) or its bag is unusable; the message says which."""


@dataclass
class LiveFrame:
    """One output frame matched to its input."""

    index: int  # position of the input in the replay: pass x bag messages + position in the bag's topic
    stamp_ns: int
    points: int  # finite input points
    latency_ms: float
    stage1_ms: float | None
    stage2_ms: float | None
    mismatch: bool  # output point count differs from the input's, or no label field
    truth: np.ndarray | None = None  # kept only with keep_labels
    predicted: np.ndarray | None = None  # kept only with keep_labels


@dataclass
class LiveResult:
    """What a live run published, what came back, and the accumulated point-wise confusion."""

    lockstep: bool
    rate: float
    frames_in: int = 0
    frames_out: int = 0
    mismatched: int = 0
    timeouts: int = 0  # lockstep: outputs not back within timeout_s (they may still arrive later)
    skipped: int = 0  # input frames not published: empty, undecodable, or not stamped after their predecessor
    unmatched_outputs: int = 0  # outputs whose stamp matches no pending input
    labeled_frames: int = 0  # output frames that entered the confusion matrix
    latency_ms: list[float] = field(default_factory=list)
    frames: list[LiveFrame] = field(default_factory=list)
    confusion: ConfusionAccumulator = field(default_factory=ConfusionAccumulator)
    node_counters: dict[str, dict[str, int]] = field(default_factory=dict)
    node_stats: dict[str, dict[str, float | None]] = field(default_factory=dict)  # each node's /diagnostics values
    wall_s: float = 0.0
    record_out: Path | None = None

    @property
    def dropped(self) -> int:
        """Inputs without an output: dropped by a node's one-slot mailbox, lost in transport, or skipped by a node."""
        return self.frames_in - self.frames_out


@dataclass
class _Pending:
    index: int
    points: int
    truth: np.ndarray | None
    published: float = 0.0
    proposals_at: float | None = None


def cdr_stamp_ns(raw: bytes | memoryview) -> int:
    """Header stamp of a serialized message whose first field is a std_msgs/Header (PointCloud2 is)."""
    order = "<" if raw[1] == 1 else ">"  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nanosec = struct.unpack_from(order + "iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


def with_stamp(raw: bytes | memoryview, stamp_ns: int) -> bytes:
    """A copy of a serialized message whose first field is a std_msgs/Header, with a new header stamp."""
    order = "<" if raw[1] == 1 else ">"
    out = bytearray(raw)
    struct.pack_into(order + "iI", out, 4, *divmod(stamp_ns, 1_000_000_000))
    return bytes(out)


def _replay(bag: BagFile, repeat: int) -> Iterator[tuple[int, str, int, bytes]]:
    """(replay index, message type, bag time ns, CDR bytes) of the bag's messages, `repeat` times over.

    Pass k shifts the header stamps and bag times by k x (span of the topic + its mean message spacing,
    100 ms for a single message), so stamps keep increasing from pass to pass and the pace stays the bag's.
    """
    first: tuple[int, int] | None = None  # (header stamp, bag time) of the first message
    last: tuple[int, int] = (0, 0)
    count = index = 0
    shift = (0, 0)
    for lap in range(repeat):
        for conn, bag_ns, raw in bag.messages():
            if lap == 0:
                try:
                    stamp = cdr_stamp_ns(raw)
                except (IndexError, struct.error):
                    stamp = last[0]
                if first is None:
                    first = (stamp, bag_ns)
                last, count = (stamp, bag_ns), count + 1
                yield index, conn.msgtype, bag_ns, raw
            else:
                try:
                    shifted = with_stamp(raw, cdr_stamp_ns(raw) + lap * shift[0])
                except (IndexError, struct.error):
                    shifted = bytes(raw)  # too short for a header: the consumer skips it as undecodable
                yield index, conn.msgtype, bag_ns + lap * shift[1], shifted
            index += 1
        if lap == 0:
            if first is None:
                return
            stamp_span, time_span = last[0] - first[0], last[1] - first[1]
            if count > 1:
                shift = (stamp_span + stamp_span // (count - 1), time_span + time_span // (count - 1))
            else:
                shift = (FRAME_GAP_NS, FRAME_GAP_NS)


def _input_frame(raw: bytes, msgtype: str) -> tuple[int, int, np.ndarray | None]:
    """(stamp, finite point count, ground-truth labels of the finite points or None) of one bag message."""
    msg = TYPESTORE.deserialize_cdr(raw, msgtype)
    cloud = decode(msg)
    keep = finite_mask(cloud)
    names = cloud.dtype.names or ()
    field = truth_field(names)
    if field is None and LABEL_FIELD in names and is_output_cloud(names):
        raise LiveEvalError(f"the cloud is a pass3d output: its `{LABEL_FIELD}` field is a prediction, "
                            "not ground truth; play the input bag (ground truth in `label_gt`)")
    truth = None
    if field is not None:
        values = cloud[field][keep]  # checked before the cast, which would wrap 257 onto car
        if foreign_ids(values).size:
            raise LiveEvalError(f"{field} field holds ids other than 0..{NUM_CLASSES - 1} or {IGNORE} (unknown)")
        truth = np.ascontiguousarray(values, dtype=np.uint8)
    return header_stamp_ns(msg), int(np.count_nonzero(keep)), truth


def _overrides(node_parameters: Mapping[str, Mapping[str, Any]] | None) -> dict[str, list]:
    """{node name: [rclpy Parameter]} from {node name: {parameter: value}}, node names checked."""
    from rclpy.parameter import Parameter

    unknown = sorted(set(node_parameters or {}) - set(NODE_NAMES))
    if unknown:
        raise ValueError(f"node_parameters: unknown node(s) {', '.join(unknown)}; nodes: {', '.join(NODE_NAMES)}")
    out: dict[str, list] = {}
    for name in NODE_NAMES:
        values = dict((node_parameters or {}).get(name, {}))
        out[name] = [Parameter(k, value=_plain(v)) for k, v in values.items()]
    return out


def _plain(value: Any) -> Any:
    """A value rclpy accepts: paths as str, tuples and arrays as lists, numpy scalars as Python numbers."""
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _check_declared(node: Any, overrides: list) -> None:
    unknown = [p.name for p in overrides if not node.has_parameter(p.name)]
    if unknown:
        raise ValueError(f"{node.get_name()}: unknown parameter(s) {', '.join(unknown)}")


def _make_node(node_class: type, context: Any, overrides: list, nodes: list[Any]) -> Any:
    """Construct one node with its parameter overrides; a refused parameter is a ConfigError, an unknown one a
    ValueError (the caller's mistake)."""
    from rclpy.exceptions import ParameterException

    try:
        node = node_class(context=context, parameter_overrides=overrides)
    except ParameterException as exc:
        raise ConfigError(f"{node_class.__name__}: {exc}") from exc
    nodes.append(node)
    _check_declared(node, overrides)
    return node


def _wait(predicate: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


class _Session:
    """Shared state of one run: pending inputs by stamp, matched outputs, the optional recording."""

    def __init__(self, result: LiveResult, keep_labels: bool, writer: BagWriter | None, labeled_topic: str,
                 objects_topic: str = "") -> None:
        self.result = result
        self.keep_labels = keep_labels
        self.writer = writer
        self.labeled_topic = labeled_topic
        self.objects_topic = objects_topic
        self.last_labeled_ns = 0
        self.objects_written = 0
        self.pending: dict[int, _Pending] = {}
        self.cond = threading.Condition()
        self.last_output = time.perf_counter()
        self.error: BaseException | None = None

    def on_proposals(self, raw: bytes) -> None:
        now = time.perf_counter()
        stamp = cdr_stamp_ns(raw)
        with self.cond:
            entry = self.pending.get(stamp)
            if entry is not None and entry.proposals_at is None:
                entry.proposals_at = now

    def on_objects(self, raw: bytes) -> None:
        """Record an object MarkerArray at its markers' stamp (the labeled cloud's without markers)."""
        if self.writer is None:
            return
        try:
            stamp = message_stamp_ns(MARKER_ARRAY_TYPE, raw) or self.last_labeled_ns
            self.writer.write_raw(self.objects_topic, MARKER_ARRAY_TYPE, stamp, raw)
            with self.cond:
                self.objects_written += 1
        except Exception as exc:  # an executor callback must not die; run_live re-raises it
            with self.cond:
                self.error = self.error or exc
                self.cond.notify_all()

    def on_labeled(self, raw: bytes) -> None:
        now = time.perf_counter()
        try:
            self._labeled(raw, now)
        except Exception as exc:  # an executor callback must not die; run_live re-raises it
            with self.cond:
                self.error = self.error or exc
                self.cond.notify_all()

    def _labeled(self, raw: bytes, now: float) -> None:
        stamp = cdr_stamp_ns(raw)
        self.last_labeled_ns = stamp
        if self.writer is not None:
            self.writer.write_raw(self.labeled_topic, POINTCLOUD2_TYPE, stamp, raw)
        with self.cond:
            entry = self.pending.get(stamp)
        if entry is None:
            with self.cond:
                self.result.unmatched_outputs += 1
                self.last_output = now
                self.cond.notify_all()
            return
        cloud = decode(TYPESTORE.deserialize_cdr(raw, POINTCLOUD2_TYPE))
        predicted = cloud["label"].astype(np.uint8) if "label" in (cloud.dtype.names or ()) else None
        mismatch = predicted is None or len(predicted) != entry.points
        frame = LiveFrame(
            index=entry.index,
            stamp_ns=stamp,
            points=entry.points,
            latency_ms=1e3 * (now - entry.published),
            stage1_ms=None if entry.proposals_at is None else 1e3 * (entry.proposals_at - entry.published),
            stage2_ms=None if entry.proposals_at is None else 1e3 * (now - entry.proposals_at),
            mismatch=mismatch,
        )
        if self.keep_labels:
            frame.truth, frame.predicted = entry.truth, predicted
        with self.cond:
            for older in [s for s in self.pending if s <= stamp]:  # outputs come in input order
                del self.pending[older]
            result = self.result
            result.frames_out += 1
            result.latency_ms.append(frame.latency_ms)
            result.frames.append(frame)
            if mismatch:
                result.mismatched += 1
            elif entry.truth is not None:
                result.confusion.update(entry.truth, predicted)
                result.labeled_frames += 1
            self.last_output = now
            self.cond.notify_all()


@dataclass
class LiveOptions:
    """How a live run plays its bag (see `run_live`)."""

    lockstep: bool = True
    rate: float = 1.0
    node_parameters: Mapping[str, Mapping[str, Any]] | None = None
    record_out: Path | None = None
    timeout_s: float = 30.0
    keep_labels: bool = True
    stage_timing: bool = True
    domain_id: int | None = None
    force: bool = False
    log_level: str | None = None
    progress: bool = False
    repeat: int = 1
    layout: str = "one-process"

    def check(self) -> None:
        """Refuse values that cannot run (ConfigError naming the option)."""
        if self.layout not in LAYOUTS:
            raise ConfigError(f"layout must be one of {', '.join(LAYOUTS)}, got {self.layout!r}")
        if not (np.isfinite(self.rate) and self.rate >= 0):
            raise ConfigError(f"the rate (--rate) must be a finite number >= 0, got {self.rate}")
        if not (np.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise ConfigError(f"the timeout (--timeout) must be a finite number of seconds > 0, got {self.timeout_s}")
        if self.repeat < 1:
            raise ConfigError(f"repeat must be >= 1, got {self.repeat}")
        if self.log_level is not None and self.log_level.lower() not in LOG_LEVELS:
            raise ConfigError(f"log_level must be one of {', '.join(LOG_LEVELS)}, got {self.log_level!r}")


LOG_LEVELS: dict[str, str] = {"debug": "DEBUG", "info": "INFO", "warn": "WARN", "warning": "WARN", "error": "ERROR"}


def run_live(bag: str | Path | BagFile, options: LiveOptions | None = None, **fields: Any) -> LiveResult:
    """Play `bag` (`PATH` or `PATH#/topic`, or a BagFile the caller opened and closes) through both live nodes
    and collect what comes out.

    Options (a LiveOptions, or its fields as keywords): lockstep publishes the next frame only once the
    previous one's labeled output arrived or `timeout_s` passed (counted in `timeouts`); otherwise publish
    at `rate` x the recorded pace (0: as fast as possible) and wait at most `timeout_s` after the last
    publish for the outputs. `node_parameters` = {"cluster_proposal_node": {...}, "segmentation_node": {...}};
    unknown nodes or parameters are a ValueError, bad weights the node's own error. `record_out`: the
    received labeled clouds and object MarkerArrays as an MCAP bag (`force` replaces an existing one).
    keep_labels=False keeps per-frame records without label arrays (long soaks: the confusion matrix still
    accumulates).
    `domain_id` defaults to a random one in 100..200. `log_level` (debug, info, warn, error) sets both
    nodes' loggers for the rest of the process. `repeat` plays the bag that many times back to back (long
    runs from a short bag), every pass shifted in stamp and time by the bag's span plus one frame spacing
    so stamps keep increasing.
    """
    options = LiveOptions(**fields) if options is None else replace(options, **fields)
    harness = LiveHarness(bag, options)
    try:
        harness.start()
        harness.play()
        harness.drain()
    except BaseException:
        harness.stop(complete=False)
        raise
    harness.stop(complete=True)
    return harness.result


class LiveHarness:
    """One live run in steps: `start` (private context, both nodes, discovery), `play` (publish the bag),
    `drain` (wait for the last outputs, read the node counters), `stop` (tear down, close the recording)."""

    def __init__(self, bag: str | Path | BagFile, options: LiveOptions) -> None:
        options.check()
        self.options = options
        self.overrides = _overrides(options.node_parameters)
        self.result = LiveResult(lockstep=options.lockstep, rate=options.rate,
                                 record_out=Path(options.record_out) if options.record_out else None)
        source = bag.path if isinstance(bag, BagFile) else parse_bag_spec(bag)[0]
        self.writer = (None if options.record_out is None else
                       BagWriter(options.record_out, force=options.force, inputs=(source,), what="--record-out"))
        self.nodes: list[Any] = []
        self.context: Any = None
        self.executor: Any = None
        self.spinner: threading.Thread | None = None
        self.stopping = threading.Event()
        self.session: _Session | None = None
        self.started = 0.0
        self.child: subprocess.Popen | None = None
        self.child_dir: tempfile.TemporaryDirectory | None = None
        self.diagnostics: dict[str, dict[str, float | None]] = {}
        self.owns_bag = not isinstance(bag, BagFile)  # opened here (once: topic, count and messages), closed in stop
        self.bag = BagFile(bag) if self.owns_bag else bag

    def start(self) -> None:
        """Both nodes and a probe node on a single-threaded executor in a private context, all discovered."""
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.logging import LoggingSeverity, set_logger_level
        from sensor_msgs.msg import PointCloud2
        from visualization_msgs.msg import MarkerArray

        from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
        from pass3d_ros.ros.diagnostics import DIAGNOSTICS_TOPIC
        from pass3d_ros.ros.inprocess import in_memory_factories
        from pass3d_ros.ros.qos import qos_profile
        from pass3d_ros.ros.segmentation_node import SegmentationNode

        options = self.options
        if options.log_level is not None:
            for name in NODE_NAMES:
                set_logger_level(name, LoggingSeverity[LOG_LEVELS[options.log_level.lower()]])
        self.context = Context()
        domain_id = random.randint(100, 200) if options.domain_id is None else options.domain_id
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        # Callbacks only hand frames to the nodes' worker threads. rclpy 7.1.6's MultiThreadedExecutor stalls on
        # long runs (ros2/rclpy#1452), so a single-threaded executor is both enough and reliable.
        self.executor = SingleThreadedExecutor(context=self.context)
        remote = options.layout == "two-process"
        stage_timing = options.stage_timing and options.layout == "one-process"  # else it would force an encode
        if remote:
            self._start_child(domain_id)
        else:
            kinds = in_memory_factories() if options.layout == "in-memory" else [ClusterProposalNode, SegmentationNode]
            self.cluster = _make_node(kinds[0], self.context, self.overrides[NODE_NAMES[0]], self.nodes)
            self.segmenter = _make_node(kinds[1], self.context, self.overrides[NODE_NAMES[1]], self.nodes)
        probe = rclpy.create_node(f"pass3d_live_eval_{random.getrandbits(32):08x}", context=self.context)
        self.nodes.append(probe)
        labeled_topic = probe.resolve_topic_name(self._topic(1, "labeled_topic"))  # relative names: as recorded
        if self.writer is not None:
            self.writer.open()
        objects_topic = probe.resolve_topic_name(self._topic(1, "objects_topic"))
        probe.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, 10)
        self.session = _Session(self.result, options.keep_labels, self.writer, labeled_topic, objects_topic)
        output_qos = qos_profile(self._topic(1, "output_qos"), depth=50)
        labeled_sub = probe.create_subscription(PointCloud2, labeled_topic, self.session.on_labeled, output_qos,
                                                raw=True)
        objects_sub = None
        if self.writer is not None:  # the recording holds the object markers beside the labeled clouds
            objects_sub = probe.create_subscription(MarkerArray, objects_topic, self.session.on_objects, output_qos,
                                                    raw=True)
        if stage_timing:
            probe.create_subscription(
                PointCloud2,
                self.cluster.get_parameter("proposals_topic").value,
                self.session.on_proposals,
                qos_profile(self.cluster.get_parameter("output_qos").value, depth=50),
                raw=True,
            )
        self.publisher = probe.create_publisher(PointCloud2, self._topic(0, "input_topic"),
                                                qos_profile("reliable", depth=10))
        for node in self.nodes:
            self.executor.add_node(node)
        self.spinner = threading.Thread(target=self._spin, name="pass3d-live-eval", daemon=True)
        self.spinner.start()

        def connected() -> bool:
            if remote and self.child is not None and self.child.poll() is not None:
                raise LiveEvalError(f"the node process ended (exit {self.child.returncode}): {self._child_log()}")
            local = remote or (
                self.cluster.proposals_pub.get_subscription_count()
                >= int(options.layout == "one-process") + int(stage_timing)
                and self.segmenter.labeled_pub.get_subscription_count() >= 1
            )
            return (
                local
                and self.publisher.get_subscription_count() >= 1
                and labeled_sub.get_publisher_count() >= 1
                and (objects_sub is None or objects_sub.get_publisher_count() >= 1)
            )

        timeout = DISCOVERY_TIMEOUT_S + (CHILD_START_S if remote else 0.0)  # the child loads torch and weights
        if not _wait(connected, timeout):
            raise LiveEvalError(f"the nodes and the evaluator did not discover each other in {timeout:g} s")
        time.sleep(SETTLE_S)

    def play(self) -> None:
        """Publish every usable message of the bag (paced, or in lockstep with the outputs)."""
        from tqdm import tqdm

        options, result, session = self.options, self.result, self.session
        assert session is not None, "start() first"
        self.started = time.perf_counter()
        bar = tqdm(total=self.bag.count * options.repeat, unit="frame", desc="live",
                   disable=None if options.progress else True)  # None: only on a terminal
        pace_start, first_bag_ns, last_stamp = None, 0, None
        for index, msgtype, bag_ns, raw in _replay(self.bag, options.repeat):
            bar.update(1)
            try:
                stamp, points, truth = _input_frame(raw, msgtype)
            except LiveEvalError as exc:
                raise LiveEvalError(f"{self.bag}: message {index}: {exc}") from None
            except (PointCloud2Error, ValueError, IndexError, struct.error):
                result.skipped += 1  # the node would skip it too: nothing to wait for
                continue
            if points == 0 or (last_stamp is not None and stamp <= last_stamp):
                result.skipped += 1
                continue
            last_stamp = stamp
            if not options.lockstep and options.rate > 0:
                if pace_start is None:
                    pace_start, first_bag_ns = time.perf_counter(), bag_ns
                delay = pace_start + (bag_ns - first_bag_ns) / 1e9 / options.rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            entry = _Pending(index, points, truth)
            message = bytes(raw)  # copied before the clock starts: a driver publishes what it holds
            with session.cond:
                if session.error is not None:
                    raise session.error
                session.pending[stamp] = entry
                result.frames_in += 1
                entry.published = time.perf_counter()
            self.publisher.publish(message)
            if options.lockstep:
                with session.cond:
                    arrived = session.cond.wait_for(
                        lambda s=stamp: s not in session.pending or session.error is not None, options.timeout_s
                    )
                    if not arrived:
                        result.timeouts += 1
        bar.close()

    def drain(self) -> None:
        """Wait until every pending output came back or the nodes fell quiet; then take the node counters."""
        session, timeout_s = self.session, self.options.timeout_s
        assert session is not None, "start() first"

        def idle() -> bool:
            if self.options.layout == "two-process":
                return True  # the child's workers: "quiet" (no output for QUIET_S) stands for idle
            return self.cluster.idle() and self.segmenter.idle()

        def finished() -> bool:
            with session.cond:
                if not session.pending or session.error is not None:
                    return True
                quiet = time.perf_counter() - session.last_output >= QUIET_S
            return quiet and idle()

        _wait(finished, timeout_s)
        self.result.wall_s = time.perf_counter() - self.started
        if self.writer is not None:  # each labeled cloud's markers follow it: record them too
            _wait(lambda: session.objects_written >= self.result.frames_out, min(timeout_s, QUIET_S))
        _wait(idle, timeout_s)  # counters final
        if session.error is not None:
            raise session.error
        if self.options.layout == "two-process":  # counters from the child's next /diagnostics
            from pass3d_ros.ros.diagnostics import DIAGNOSTICS_PERIOD_S

            self.diagnostics.clear()
            _wait(lambda: all(name in self.diagnostics for name in NODE_NAMES), 3 * DIAGNOSTICS_PERIOD_S)
            stats = dict(self.diagnostics)
            self.result.node_counters = {name: {key: int(values[key] or 0) for key in COUNTER_KEYS if key in values}
                                         for name, values in stats.items()}
            self.result.node_stats = stats
            return
        self.result.node_counters = {
            NODE_NAMES[0]: asdict(self.cluster.counters()),
            NODE_NAMES[1]: asdict(self.segmenter.counters()),
        }
        self.result.node_stats = {NODE_NAMES[0]: self.cluster.stats.snapshot(),
                                  NODE_NAMES[1]: self.segmenter.stats.snapshot()}

    def _topic(self, node: int, parameter: str) -> str:
        """A topic (or QoS) parameter of a local node, or its value for the child process's nodes."""
        if self.options.layout == "two-process":
            from pass3d_ros.ros.cluster_proposal_node import NODE_PARAMETERS as CLUSTER
            from pass3d_ros.ros.segmentation_node import NODE_PARAMETERS as SEGMENTATION

            values = dict(self.options.node_parameters or {}).get(NODE_NAMES[node], {})
            return str(values.get(parameter, (CLUSTER, SEGMENTATION)[node][parameter][0]))
        return (self.cluster, self.segmenter)[node].get_parameter(parameter).value

    def _on_diagnostics(self, msg: Any) -> None:
        from pass3d_ros.ros.diagnostics import status_values

        for status in msg.status:
            if status.name in NODE_NAMES:
                self.diagnostics[status.name] = status_values(status)

    def _start_child(self, domain_id: int) -> None:
        """`pass3d_pipeline` in a child process on this run's DDS domain, with the node parameters as a YAML file."""
        import yaml

        self.child_dir = tempfile.TemporaryDirectory(prefix="pass3d_live_")
        folder = Path(self.child_dir.name)
        params = {name: {"ros__parameters": {p.name: p.value for p in self.overrides[name]}}
                  for name in NODE_NAMES if self.overrides[name]}
        args = [sys.executable, "-m", "pass3d_ros.ros.pipeline", "--ros-args"]
        if params:
            (folder / "params.yaml").write_text(yaml.safe_dump(params))
            args += ["--params-file", str(folder / "params.yaml")]
        if self.options.log_level is not None:
            args += ["--log-level", self.options.log_level.lower()]
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
        with open(folder / "nodes.log", "wb") as log:
            self.child = subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)

    def _child_log(self) -> str:
        if self.child_dir is None:
            return ""
        path = Path(self.child_dir.name) / "nodes.log"
        return path.read_text(errors="replace")[-2000:] if path.exists() else ""

    def _spin(self) -> None:
        """The executor's callbacks until stop(): a loop of our own, because Executor.shutdown() from another thread
        destroys its guard condition under a spin() that may be waiting on it (rclpy Jazzy)."""
        while not self.stopping.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=SPIN_STEP_S)

    def stop(self, complete: bool) -> None:
        """Stop spinning, destroy the nodes (their workers join), shut the context down; then close the
        recording (`complete`) or abort it, so an unfinished run leaves no bag that looks complete."""
        import rclpy

        self.stopping.set()
        if self.spinner is not None:
            self.spinner.join(timeout=5)
        if self.executor is not None:
            self.executor.shutdown()
        for node in reversed(self.nodes):
            node.destroy_node()
        if self.context is not None:
            rclpy.try_shutdown(context=self.context)
        if self.child is not None:
            self.child.send_signal(signal.SIGINT)
            try:
                self.child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.child.kill()
                self.child.wait()
        if self.child_dir is not None:
            self.child_dir.cleanup()
        if self.owns_bag:
            self.bag.close()
        if self.writer is not None:
            if complete:
                self.writer.close()
            else:
                self.writer.abort()
