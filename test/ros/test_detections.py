"""/pass3d/detections and /pass3d/label_info (vision_msgs) through real nodes: the two nodes over
/pass3d/proposals and the one-process pipeline; markers only, with one INFO line, where vision_msgs does not import.

vision_msgs has no PyPI wheel: the tests that need it are skipped, with the reason, unless it imports (a ROS install,
or the package built from source and put on PYTHONPATH / LD_LIBRARY_PATH, as .ci/colcon-check does).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
import rclpy.logging
from helpers.objects import assert_one_object_per_point_group
from helpers.ros import STAMP0, WAIT_S, Collector, Ros, columns, connect, scan_message
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from pass3d_ros.classes import BACKGROUND, CAR, CLASS_NAMES, CYCLIST, FOREGROUND, PEDESTRIAN
from pass3d_ros.core.objects import SPLIT_ID_STRIDE, LabelledObject, frame_objects
from pass3d_ros.core.stage1 import proposal_members, propose
from pass3d_ros.core.stage2.segmentation import SegmentResult, people_only
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.data.frame import Box3D, Frame
from pass3d_ros.msgs.pointcloud2 import header_stamp_ns
from pass3d_ros.ros import detections, segmentation_node
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.proposals import dense_ids, nearest_proposals, source_ids
from pass3d_ros.ros.qos import latched_profile, qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode

pytestmark = pytest.mark.ros

needs_vision_msgs = pytest.mark.skipif(detections.MISSING is not None,
                                       reason=f"{detections.MISSING}: no PyPI wheel; .ci/colcon-check builds it")
OBJECT_NAMES = {CLASS_NAMES[k] for k in FOREGROUND}
SIZE_RULES = [Parameter("classifier", value="size_rules")]
SCAN_BY_SCAN = [*SIZE_RULES, Parameter("tracking", value=False)]  # each scan's own objects, as offline
FRAMES = 3


def two_nodes(ros: Ros, overrides: list[Parameter] = SCAN_BY_SCAN) -> None:
    """cluster_proposal_node and segmentation_node, joined by /pass3d/proposals."""
    ros.add(ClusterProposalNode(context=ros.context))
    ros.add(SegmentationNode(context=ros.context, parameter_overrides=overrides))


def pipeline(ros: Ros, overrides: list[Parameter] = SCAN_BY_SCAN) -> None:
    """pass3d_pipeline's two nodes, joined in memory."""
    cluster, segmentation = in_memory_factories()
    ros.add(cluster(context=ros.context))
    ros.add(segmentation(context=ros.context, parameter_overrides=overrides))


class Latched:
    """A late subscriber to the latched /pass3d/label_info."""

    def __init__(self, node: Node) -> None:
        self.messages: list = []
        self.got = threading.Event()
        node.create_subscription(detections.vision.LabelInfo, "/pass3d/label_info", self._on, latched_profile())

    def _on(self, msg: object) -> None:
        self.messages.append(msg)
        self.got.set()


def offline_objects(frame: Frame) -> list[LabelledObject]:
    """The objects stage 1 + size rules find in `frame`, computed offline."""
    stage1 = propose(frame.points, frame.ring)
    members = proposal_members(stage1.cluster_id, stage1.cluster_id2)
    result = SizeRuleClassifier().segment(frame.points, members)
    return frame_objects(frame.points, stage1.cluster_id, result.proposal_class, result.labels,
                         result.confidence).objects


def yaw_of(orientation: object) -> float:
    """The yaw of a quaternion that turns about z only."""
    assert orientation.x == 0.0 and orientation.y == 0.0
    return 2.0 * math.atan2(orientation.z, orientation.w)


def test_source_ids_map_dense_proposals_back_to_the_message_ids() -> None:
    first = np.array([4, 4, -1, 9, 9, 2, -1])
    second = np.array([-1, 9, 7, -1, -1, -1, -1])
    dense = dense_ids(first, second)
    np.testing.assert_array_equal(source_ids((first, second), dense[:2], dense[2]), [2, 4, 7, 9])
    points = np.array([[1, 0], [1, 0], [30, 0], [50, 0], [50, 0], [3, 0], [0, 0]], np.float32)
    cut = nearest_proposals(points, *dense, limit=2)
    np.testing.assert_array_equal(source_ids((first, second), cut[:2], cut[2]), [2, 4])  # the two nearest


def test_without_vision_msgs_one_info_line_and_markers_only(ros: Ros, frame: Frame, monkeypatch: pytest.MonkeyPatch,
                                                            capfd: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(detections, "MISSING", "vision_msgs does not import (No module named 'vision_msgs')")
    rclpy.logging.get_logger("segmentation_node").set_level(LoggingSeverity.INFO)  # another test may have raised it
    two_nodes(ros)
    segmenter = next(node for node in ros.nodes if isinstance(node, SegmentationNode))
    assert segmenter.detections is None
    names = {name for name, _ in ros.probe.get_topic_names_and_types()}
    assert "/pass3d/detections" not in names and "/pass3d/label_info" not in names
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    objects = Collector(ros, MarkerArray, "/pass3d/objects")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, labeled, objects)
    pub.publish(scan_message(frame, STAMP0))
    assert header_stamp_ns(objects.wait(1)[0].markers[0]) == STAMP0
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "/pass3d/detections and /pass3d/label_info are off" in line]
    assert len(lines) == 1 and "INFO" in lines[0] and "No module named 'vision_msgs'" in lines[0], err


def test_detection_ids_are_cluster_ids_or_with_tracking_confirmed_track_ids() -> None:
    obj = LabelledObject(center=(1.0, 2.0, 0.5), size=(4.0, 1.7, 1.5), yaw=0.4, label=1, score=0.75, cluster_id=12)
    assert detections.detection_id(obj, False) == "12"
    assert detections.detection_id(obj, True) == ""
    assert detections.detection_id(dataclasses.replace(obj, track_id=0), True) == "0"


@needs_vision_msgs
def test_detections_message_fields() -> None:
    obj = LabelledObject(center=(1.0, 2.0, 0.5), size=(4.0, 1.7, 1.5), yaw=0.4, label=1, score=0.75, cluster_id=12)
    header = detections.vision.Detection3DArray().header
    header.frame_id = "lidar"
    message = detections.detections_message([obj], header)
    assert message.header.frame_id == "lidar" and len(message.detections) == 1
    detection = message.detections[0]
    assert detection.id == "12" and detection.header.frame_id == "lidar"
    tracked = detections.detections_message([obj, dataclasses.replace(obj, track_id=4)], header, tracking=True)
    assert [d.id for d in tracked.detections] == ["", "4"], "a tentative track's detection has no id yet"
    center = detection.bbox.center
    assert (center.position.x, center.position.y, center.position.z) == (1.0, 2.0, 0.5)
    assert yaw_of(center.orientation) == pytest.approx(0.4)
    assert (detection.bbox.size.x, detection.bbox.size.y, detection.bbox.size.z) == (4.0, 1.7, 1.5)
    (result,) = detection.results
    assert result.hypothesis.class_id == "car" and result.hypothesis.score == 0.75
    assert result.pose.pose.position.x == 1.0 and yaw_of(result.pose.pose.orientation) == pytest.approx(0.4)
    info = detections.label_info_message(0.25)
    assert [(c.class_id, c.class_name) for c in info.class_map] == list(enumerate(CLASS_NAMES))
    assert info.threshold == pytest.approx(0.25)


@needs_vision_msgs
@pytest.mark.parametrize("layout", [two_nodes, pipeline], ids=["two_nodes", "pipeline"])
def test_detections_per_labelled_frame_and_label_info_for_a_late_subscriber(
        ros: Ros, frame: Frame, layout: Callable[[Ros], None]) -> None:
    layout(ros)
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    markers = Collector(ros, MarkerArray, "/pass3d/objects")
    found = Collector(ros, detections.vision.Detection3DArray, "/pass3d/detections")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, labeled, markers, found)
    stamps = [STAMP0 + k * 100_000_000 for k in range(FRAMES)]
    for count, stamp in enumerate(stamps, start=1):
        pub.publish(scan_message(frame, stamp))  # one at a time: a busy node keeps only the newest frame
        labeled.wait(count)
        found.wait(count)

    assert [header_stamp_ns(m) for m in found.messages] == [header_stamp_ns(m) for m in labeled.messages] == stamps
    expected = offline_objects(frame)
    assert len(expected) >= 2, "the synthetic street has objects"
    for cloud_msg, array, boxes in zip(labeled.messages, found.messages, markers.wait(FRAMES), strict=True):
        assert array.header.frame_id == cloud_msg.header.frame_id == "velodyne_test"
        cloud = columns(cloud_msg)
        assert [(d.id, d.results[0].hypothesis.class_id) for d in array.detections] == [
            (str(o.cluster_id), o.class_id) for o in expected], "one detection per object"
        wires = [m for m in boxes.markers if m.type == Marker.LINE_LIST]
        assert len(wires) == len(array.detections), "the markers draw the same objects"
        for detection in array.detections:
            assert header_stamp_ns(detection) == header_stamp_ns(cloud_msg)
            (result,) = detection.results
            assert result.hypothesis.class_id in OBJECT_NAMES and 0.0 < result.hypothesis.score <= 1.0
            size = detection.bbox.size
            assert size.x > 0 and size.y > 0 and size.z > 0
            label = CLASS_NAMES.index(result.hypothesis.class_id)
            mine = (cloud["cluster_id"] == int(detection.id)) & (cloud["label"] == label)
            center = detection.bbox.center.position
            box = Box3D(np.array([center.x, center.y, center.z]), np.array([size.x, size.y, size.z]),
                        yaw_of(detection.bbox.center.orientation))
            xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]])[mine]
            assert box.contains(xyz, margin=(0.01, 0.01, 0.01)).all(), "the box holds its object's points"
        for detection, obj in zip(array.detections, expected, strict=True):
            center, size = detection.bbox.center.position, detection.bbox.size
            assert (center.x, center.y, center.z) == pytest.approx(obj.center, abs=1e-4)
            assert (size.x, size.y, size.z) == pytest.approx(obj.size, abs=1e-4)
            assert detection.results[0].hypothesis.score == pytest.approx(obj.score, abs=1e-6)

    late = Latched(ros.make_node("late_listener"))
    assert late.got.wait(WAIT_S), "a late subscriber gets the latched LabelInfo"
    time.sleep(0.3)
    assert len(late.messages) == 1
    info = late.messages[0]
    assert [(c.class_id, c.class_name) for c in info.class_map] == list(enumerate(CLASS_NAMES))
    assert info.threshold == 0.0


@needs_vision_msgs
@pytest.mark.parametrize("layout", [two_nodes, pipeline], ids=["two_nodes", "pipeline"])
def test_with_tracking_on_by_default_detections_carry_the_confirmed_track_ids_of_the_cloud(
        ros: Ros, frame: Frame, layout: Callable[[Ros], None]) -> None:
    """Tracking is on by default: a scan seen once makes tentative tracks (detections without ids, track_id -1 in the
    cloud); seen again, every plausible object's track is confirmed and keeps its id, and each detection's id is the
    track_id of its points in /pass3d/labeled, with their class. An implausible box starts no track (rule M4): its
    detection keeps an empty id and its points track_id -1, scan after scan."""
    layout(ros, SIZE_RULES)
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    found = Collector(ros, detections.vision.Detection3DArray, "/pass3d/detections")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, labeled, found)
    for count in range(1, FRAMES + 1):
        pub.publish(scan_message(frame, STAMP0 + (count - 1) * 100_000_000))
        labeled.wait(count)
        found.wait(count)

    expected = offline_objects(frame)
    first, *later = found.messages
    assert len(first.detections) == len(expected) >= 2
    assert {d.id for d in first.detections} == {""}, "one sighting: every track tentative"
    assert (columns(labeled.messages[0])["track_id"] == -1).all()
    plausible = sum(obj.plausible for obj in expected)
    assert plausible >= 2
    ids = [sorted(d.id for d in array.detections) for array in later]
    assert ids[0] == ids[-1] and ids[0].count("") == len(expected) - plausible, "no track for an implausible box"
    assert len(set(ids[0]) - {""}) == plausible, "one kept id per plausible object"
    for cloud_msg, array in zip(labeled.messages[1:], later, strict=True):
        cloud = columns(cloud_msg)
        for detection in array.detections:
            if not detection.id:
                continue
            mine = cloud["track_id"] == int(detection.id)
            assert mine.any(), "a detection's id is its points' track_id"
            label = CLASS_NAMES.index(detection.results[0].hypothesis.class_id)
            assert (cloud["label"][mine] == label).all()
        tracked = cloud["track_id"] >= 0
        assert set(np.unique(cloud["track_id"][tracked]).astype(str)) == set(ids[0]) - {""}


class MixedClassifier(SizeRuleClassifier):
    """Size rules with every point's label scrambled by where it lies (a stand-in for a network that mixes classes
    within a proposal): proposals of several classes, background proposals with road-user points, points labelled
    through their second proposal; each proposal's class is its points' majority, as the network's."""

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        result = super().segment(points, members)
        cell = (np.floor(points[:, 0] * 2.0) + np.floor(points[:, 1] * 2.0)).astype(np.int64) % 6
        inside = np.zeros(len(points), bool)
        for member in members:
            inside[member] = True
        labels = np.where(cell < 3, result.labels, np.array([0, 0, 0, CAR, PEDESTRIAN, CYCLIST])[cell])
        labels = np.where(inside, labels, BACKGROUND).astype(np.uint8)
        confidence = np.where(inside, 0.4 + 0.1 * cell, 1.0).astype(np.float32)
        proposal_class = np.array([np.bincount(labels[m], minlength=4).argmax() if len(m) else -1 for m in members],
                                  np.int16)
        return SegmentResult(labels, confidence, proposal_class)


def mixed_offline(frame: Frame) -> tuple[list[LabelledObject], np.ndarray]:
    """The objects and published labels of `frame` under MixedClassifier, computed offline."""
    stage1 = propose(frame.points, frame.ring)
    members = proposal_members(stage1.cluster_id, stage1.cluster_id2)
    result = people_only(MixedClassifier().segment(frame.points, members), members, stage1.people_only())
    published = frame_objects(frame.points, stage1.cluster_id, result.proposal_class, result.labels,
                              result.confidence)
    return published.objects, published.labels


@pytest.mark.parametrize("layout", [two_nodes, pipeline], ids=["two_nodes", "pipeline"])
def test_every_road_user_point_is_in_exactly_one_object_of_its_class(
        ros: Ros, frame: Frame, layout: Callable[[Ros], None], monkeypatch: pytest.MonkeyPatch) -> None:
    """The one object concept through the nodes, with a classifier that mixes classes within proposals: every
    road-user point of /pass3d/labeled has the (cluster_id, label) of exactly one detection and marker, every
    detection has points, and it all equals the offline computation (pass3d_segment's)."""
    monkeypatch.setattr(segmentation_node, "open_classifier", lambda *args, **kwargs: MixedClassifier())
    layout(ros)
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    markers = Collector(ros, MarkerArray, "/pass3d/objects")
    collectors = [labeled, markers]
    if detections.MISSING is None:
        found = Collector(ros, detections.vision.Detection3DArray, "/pass3d/detections")
        collectors.append(found)
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, *collectors)
    pub.publish(scan_message(frame, STAMP0))
    cloud = columns(labeled.wait(1)[0])
    expected, labels = mixed_offline(frame)
    np.testing.assert_array_equal(cloud["label"], labels)
    assert len(expected) >= 5 and {o.label for o in expected} == set(FOREGROUND), "the scrambled labels make objects"
    assert any(o.cluster_id >= SPLIT_ID_STRIDE for o in expected), "a minority class became an object of its own"
    wires = [m for m in markers.wait(1)[0].markers if m.type == Marker.LINE_LIST]
    assert len(wires) == len(expected)
    assert_one_object_per_point_group(cloud["label"], cloud["cluster_id"], [(o.cluster_id, o.label) for o in expected])
    if detections.MISSING is None:
        array = found.wait(1)[0]
        got = [(d.id, CLASS_NAMES.index(d.results[0].hypothesis.class_id)) for d in array.detections]
        assert got == [(str(o.cluster_id), o.label) for o in expected]
        assert_one_object_per_point_group(cloud["label"], cloud["cluster_id"], got)
