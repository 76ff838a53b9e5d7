"""What both PASS3D nodes share: parameters declared from their table, QoS names checked at start-up, one
latest-frame worker fed by the input subscription, frame errors logged (throttled), the worker stopped on
destroy."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher
from sensor_msgs.msg import PointCloud2

from pass3d_ros.ros.latest_frame import LatestFrameWorker
from pass3d_ros.ros.params import NodeParameters
from pass3d_ros.ros.qos import QOS_NAMES, qos_profile

LOG_PERIOD_S = 5.0
QOS_PARAMETERS = ("input_qos", "output_qos")


class PointCloudNode(Node):
    """A node that processes the newest PointCloud2 of `input_topic` on a worker thread.

    Its parameter table must hold `input_topic`, `input_qos` and `output_qos`; a QoS name outside QOS_NAMES
    ends start-up with a ValueError.
    """

    def __init__(self, parameters: NodeParameters, **kwargs: Any) -> None:
        super().__init__(parameters.node_name, **kwargs)
        parameters.declare(self)
        for name in QOS_PARAMETERS:
            if self.get_parameter(name).value not in QOS_NAMES:
                raise ValueError(f"parameter {name} must be one of {QOS_NAMES}")

    def output_publisher(self, msg_type: type, topic_parameter: str) -> Publisher:
        """A publisher on the topic the parameter `topic_parameter` names, with the `output_qos` profile."""
        qos = qos_profile(self.get_parameter("output_qos").value)
        return self.create_publisher(msg_type, self.get_parameter(topic_parameter).value, qos)

    def start_worker(self, process: Callable[[PointCloud2], None], name: str) -> None:
        """Subscribe `input_topic` (with `input_qos`) and hand the newest message to `process` on a thread."""
        self.worker: LatestFrameWorker[PointCloud2] = LatestFrameWorker(process, self._on_error, name)
        self.subscription = self.create_subscription(
            PointCloud2,
            self.get_parameter("input_topic").value,
            self.worker.submit,
            qos_profile(self.get_parameter("input_qos").value),
        )

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
