"""What both PASS3D nodes share: parameters declared from their table, QoS names checked at start-up, one
latest-frame worker fed by the input subscription (or in memory by the node before it), counters on
`/diagnostics` at 1 Hz, frame errors logged (throttled), the worker stopped on destroy."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import PointCloud2

from pass3d_ros.msgs.pointcloud2 import header_stamp_ns
from pass3d_ros.ros.diagnostics import DIAGNOSTICS_PERIOD_S, DIAGNOSTICS_TOPIC, NodeStats, StepClock, to_status
from pass3d_ros.ros.latest_frame import FrameCounters, LatestFrameWorker
from pass3d_ros.ros.params import NodeParameters
from pass3d_ros.ros.qos import QOS_NAMES, qos_profile

LOG_PERIOD_S = 5.0
QOS_PARAMETERS = ("input_qos", "output_qos")


class PointCloudNode(Node):
    """A node that processes the newest PointCloud2 of `input_topic` on a worker thread.

    Its parameter table must hold `input_topic`, `input_qos` and `output_qos`; a QoS name outside QOS_NAMES
    ends start-up with a ValueError.
    """

    # Stamp gaps are counted where the input is the sensor; a node fed by another node leaves them to that one.
    COUNTS_INPUT_GAPS = True

    def __init__(self, parameters: NodeParameters, **kwargs: Any) -> None:
        super().__init__(parameters.node_name, **kwargs)
        parameters.declare(self)
        for name in QOS_PARAMETERS:
            if self.get_parameter(name).value not in QOS_NAMES:
                raise ValueError(f"parameter {name} must be one of {QOS_NAMES}")
        self.stats = NodeStats(count_gaps=self.COUNTS_INPUT_GAPS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def output_publisher(self, msg_type: type, topic_parameter: str) -> Publisher:
        """A publisher on the topic the parameter `topic_parameter` names, with the `output_qos` profile."""
        qos = qos_profile(self.get_parameter("output_qos").value)
        return self.create_publisher(msg_type, self.get_parameter(topic_parameter).value, qos)

    def start_worker(self, process: Callable[[Any], None], name: str, subscribe: bool = True) -> None:
        """Hand the newest input to `process` on a thread; inputs come from `input_topic` (with `input_qos`),
        or only through `submit` when `subscribe` is False (an in-memory hand-off in one process)."""
        self.worker: LatestFrameWorker[Any] = LatestFrameWorker(process, self._on_error, name)
        self.subscription = None
        if subscribe:
            self.subscription = self.create_subscription(
                PointCloud2,
                self.get_parameter("input_topic").value,
                self._on_message,
                qos_profile(self.get_parameter("input_qos").value),
            )

    def _on_message(self, msg: PointCloud2) -> None:
        self.submit(msg, header_stamp_ns(msg))

    def submit(self, item: Any, stamp_ns: int) -> None:
        """Queue one input (a message, or an in-memory frame): the stamp feeds the gap counter."""
        self.stats.input(stamp_ns)
        self.worker.submit(item)

    def counters(self) -> FrameCounters:
        """The node's frame counters: received, processed (= output), dropped, failed."""
        return self.worker.counters

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
        counters = vars(self.counters())
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [to_status(self.get_name(), counters, self.stats)]
        self.diagnostics_pub.publish(msg)

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
