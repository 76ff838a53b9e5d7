"""The objects as vision_msgs, for trackers and planners: `/pass3d/detections` (Detection3DArray, one Detection3D per
object, the labelled cloud's header) and `/pass3d/label_info` (LabelInfo: the class map, latched).

vision_msgs is optional: a ROS install has it (`ros-jazzy-vision-msgs`, package.xml); PyPI has no wheel. Where it
does not import, `DetectionOutputs.open` logs one INFO line saying why and the node publishes its markers only.
The objects themselves come from `pass3d_ros.core.objects`; this module only fills the messages.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile

from pass3d_ros.classes import CLASS_NAMES
from pass3d_ros.core.objects import LabelledObject
from pass3d_ros.ros.qos import latched_profile

try:
    from vision_msgs import msg as vision
except ImportError as exc:  # PyPI's ROS: no vision_msgs wheel
    vision = None
    MISSING: str | None = f"vision_msgs does not import ({exc})"
else:
    MISSING = None


def detection_id(obj: LabelledObject, tracking: bool) -> str:
    """A detection's `id`: its cluster id, or with tracking on its track id ("" while the track is tentative:
    vision_msgs' id may be empty, and a tentative track's id may never be seen again)."""
    if not tracking:
        return str(obj.cluster_id)
    return str(obj.track_id) if obj.track_id >= 0 else ""


def detections_message(objects: Sequence[LabelledObject], header: Any, level: np.ndarray | None = None,
                       tracking: bool = False) -> Any:
    """A Detection3DArray: `header` (the labelled cloud's), one Detection3D per object with its oriented box, one
    hypothesis (class name, score, the box's pose) and `detection_id` as `id`. `level`: the rotation from the
    sensor's frame to the level frame the objects' boxes are in; the poses are given in the sensor's frame.
    `tracking`: the objects carry their tracks' ids, voted classes and scores (core.tracked_scan)."""
    detections = []
    for obj in objects:
        detection = vision.Detection3D(header=header, id=detection_id(obj, tracking))
        _set_pose(detection.bbox.center, obj, level)
        detection.bbox.size.x, detection.bbox.size.y, detection.bbox.size.z = obj.size
        result = vision.ObjectHypothesisWithPose()
        result.hypothesis.class_id = obj.class_id
        result.hypothesis.score = obj.score
        _set_pose(result.pose.pose, obj, level)
        detection.results = [result]
        detections.append(detection)
    return vision.Detection3DArray(header=header, detections=detections)


def _set_pose(pose: Any, obj: LabelledObject, level: np.ndarray | None = None) -> None:
    """Fill a geometry_msgs/Pose with the object's box centre and its yaw about z (about the level frame's z, turned
    back into the sensor's frame, with `level`)."""
    if level is None:
        pose.position.x, pose.position.y, pose.position.z = obj.center
        pose.orientation.z, pose.orientation.w = math.sin(obj.yaw / 2), math.cos(obj.yaw / 2)
        return
    back = np.asarray(level, dtype=float).T  # level frame -> sensor frame
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in back @ np.asarray(obj.center, float))
    c, s = math.cos(obj.yaw), math.sin(obj.yaw)
    w, x, y, z = _quaternion(back @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]))
    pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = w, x, y, z


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (Shepperd's method: the largest diagonal term picks the stable branch)."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        return 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    k = int(np.argmax(np.diag(m)))
    i, j, n = k, (k + 1) % 3, (k + 2) % 3
    s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[n, n])
    q = [0.0, 0.0, 0.0]
    q[i] = 0.25 * s
    q[j] = (m[j, i] + m[i, j]) / s
    q[n] = (m[n, i] + m[i, n]) / s
    return (m[n, j] - m[j, n]) / s, q[0], q[1], q[2]


def label_info_message(threshold: float) -> Any:
    """A LabelInfo: every class id with its name (the ids of /pass3d/labeled's `label`), and the confidence below
    which a point is labelled background (`min_confidence`)."""
    class_map = [vision.VisionClass(class_id=k, class_name=name) for k, name in enumerate(CLASS_NAMES)]
    return vision.LabelInfo(class_map=class_map, threshold=float(threshold))


class DetectionOutputs:
    """The two vision_msgs publishers of a node; `open` gives None (logged once) where vision_msgs is missing."""

    def __init__(self, node: Node, detections_topic: str, label_info_topic: str, qos: QoSProfile) -> None:
        self.detections_pub = node.create_publisher(vision.Detection3DArray, detections_topic, qos)
        self.label_info_pub = node.create_publisher(vision.LabelInfo, label_info_topic, latched_profile())

    @classmethod
    def open(cls, node: Node, detections_topic: str, label_info_topic: str, qos: QoSProfile
             ) -> DetectionOutputs | None:
        """The publishers, or None after one INFO line saying why detections are off (vision_msgs missing, or its
        type support not loading)."""
        reason = MISSING
        if reason is None:
            try:
                return cls(node, detections_topic, label_info_topic, qos)
            except Exception as exc:  # a vision_msgs whose type support does not load (a broken build)
                reason = f"vision_msgs' type support does not load ({exc})"
        names = [node.resolve_topic_name(topic) for topic in (detections_topic, label_info_topic)]
        node.get_logger().info(f"{names[0]} and {names[1]} are off: {reason}; install vision_msgs "
                               "(rosdep: ros-jazzy-vision-msgs) for them. Objects go out as markers only.")
        return None

    def wanted(self) -> bool:
        """Whether anything subscribes to the detections."""
        return self.detections_pub.get_subscription_count() > 0

    @staticmethod
    def message(objects: Sequence[LabelledObject], header: Any, level: np.ndarray | None = None,
                tracking: bool = False) -> Any:
        """One frame's Detection3DArray (`detections_message`)."""
        return detections_message(objects, header, level, tracking)

    def publish(self, message: Any) -> None:
        """Publish one frame's Detection3DArray."""
        self.detections_pub.publish(message)

    def publish_label_info(self, threshold: float) -> None:
        """The class map (latched: late subscribers get it too)."""
        self.label_info_pub.publish(label_info_message(threshold))
