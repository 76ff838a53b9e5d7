"""A scan from an upside-down or tilted sensor through real nodes (two nodes over /pass3d/proposals, and the
one-process pipeline): stage 1 levels it by the mounting it reads, stage 2 reads the levelled points, and the labels,
object markers and detections come back in the sensor's own frame: the same objects as the level scan's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.ros import STAMP0, Collector, Ros, columns, connect, ros_session
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from pass3d_ros.classes import FOREGROUND
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import encode
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode
from pass3d_ros.synthetic.dataset import generate_frame

pytestmark = pytest.mark.ros

SIZE_RULES = [Parameter("classifier", value="size_rules")]


def two_nodes(ros: Ros, overrides: list[Parameter]) -> None:
    ros.add(ClusterProposalNode(context=ros.context, parameter_overrides=overrides))
    ros.add(SegmentationNode(context=ros.context, parameter_overrides=[*SIZE_RULES, *overrides]))


def pipeline(ros: Ros, overrides: list[Parameter]) -> None:
    cluster, segmentation = in_memory_factories()
    ros.add(cluster(context=ros.context, parameter_overrides=overrides))
    ros.add(segmentation(context=ros.context, parameter_overrides=[*SIZE_RULES, *overrides]))


def rotated(frame: Frame, roll_deg: float, pitch_deg: float) -> np.ndarray:
    """The frame's points as a sensor rolled, then pitched (URDF's order) sees them: p_sensor = R^T p_level."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    points = frame.points.copy()
    points[:, :3] = (points[:, :3].astype(np.float64) @ (ry @ rx)).astype(np.float32)
    return points


def cloud_of(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    dtype = np.dtype([("x", np.float32), ("y", np.float32), ("z", np.float32), ("intensity", np.float32),
                      ("ring", np.uint16)])
    cloud = np.zeros(len(points), dtype)
    for k, name in enumerate(("x", "y", "z", "intensity")):
        cloud[name] = points[:, k]
    cloud["ring"] = ring
    return cloud


def label_once(layout, cloud: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """One scan through fresh nodes: /pass3d/labeled's columns and each object marker's wire points (n x 3)."""
    with ros_session() as ros:
        layout(ros, [])
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        objects = Collector(ros, MarkerArray, "/pass3d/objects")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled, objects)
        pub.publish(encode(cloud, stamp_ns=STAMP0, frame_id="lidar"))
        msg, markers = labeled.wait(1)[0], objects.wait(1)[0]
        wires = [np.array([[p.x, p.y, p.z] for p in m.points]) for m in markers.markers
                 if m.type == Marker.LINE_LIST]
        return columns(msg).copy(), wires


@pytest.fixture(scope="module")
def hdl32e_scan() -> Frame:
    return generate_frame(seed=5, index=0, sensor="hdl32e")


@pytest.mark.parametrize("layout", [two_nodes, pipeline], ids=["two_nodes", "pipeline"])
def test_an_upside_down_scan_is_labelled_as_the_level_one_in_its_own_frame(hdl32e_scan: Frame, layout) -> None:
    level, level_wires = label_once(layout, cloud_of(hdl32e_scan.points, hdl32e_scan.ring))
    flipped, flipped_wires = label_once(layout, cloud_of(rotated(hdl32e_scan, 180.0, 0.0), hdl32e_scan.ring))
    # the same points come back (x, -y, -z: the flip is exact in float32), in the sensor's own frame
    assert np.array_equal(flipped["x"], level["x"]) and np.array_equal(flipped["y"], -level["y"])
    assert np.array_equal(flipped["z"], -level["z"])
    objects = np.isin(level["label"], FOREGROUND)
    assert objects.sum() > 200
    agree = np.mean(flipped["label"][objects] == level["label"][objects])
    assert agree > 0.95, agree
    assert len(flipped_wires) > 0 and len(level_wires) > 0
    centres = np.array([w.mean(axis=0) for w in flipped_wires])
    twins = np.array([w.mean(axis=0) * [1.0, -1.0, -1.0] for w in level_wires])  # where the flip puts each box
    gaps = np.array([np.linalg.norm(centres - twin, axis=1).min() for twin in twins])
    assert np.mean(gaps < 0.3) >= 0.8, gaps


def test_a_pitched_scan_gives_the_pipelines_labels_on_both_node_paths(hdl32e_scan: Frame) -> None:
    """Pitched 10 degrees (levelled from the first scan: over PROVISIONAL_LEVEL_DEG): two nodes, the one-process
    pipeline and the offline door label every point alike."""
    points = rotated(hdl32e_scan, 0.0, 10.0)
    offline = ScanPipeline(classifier=SizeRuleClassifier()).run(points, hdl32e_scan.ring)
    assert offline.proposed.result.level is not None
    for layout in (two_nodes, pipeline):
        labeled, _ = label_once(layout, cloud_of(points, hdl32e_scan.ring))
        labels, cluster_id = offline.published_in_input(len(points))
        assert np.array_equal(labeled["label"], labels), layout.__name__
        assert np.array_equal(labeled["cluster_id"], cluster_id), layout.__name__


def test_a_scan_in_another_frame_starts_the_stream_over(hdl32e_scan: Frame) -> None:
    """Scans in frame "a" teach the stream its mounting; a scan in frame "b" (another sensor, or this one mounted
    again) starts it over: the mounting is read afresh and the tracks, kept in the old frame, end."""
    cloud = cloud_of(hdl32e_scan.points, hdl32e_scan.ring)
    with ros_session() as ros:
        cluster_factory, segmentation_factory = in_memory_factories()
        cluster = ros.add(cluster_factory(context=ros.context))
        segmentation = ros.add(segmentation_factory(context=ros.context, parameter_overrides=SIZE_RULES))
        resets = []
        reset_tracks = segmentation.stage2.reset_tracks
        segmentation.stage2.reset_tracks = lambda: (resets.append(1), reset_tracks())
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled)
        for k in range(6):
            pub.publish(encode(cloud, stamp_ns=STAMP0 + k * 100_000_000, frame_id="a"))
            labeled.wait(k + 1)
        assert cluster.stream.mounting.held is not None and not resets
        pub.publish(encode(cloud, stamp_ns=STAMP0 + 6 * 100_000_000, frame_id="b"))
        labeled.wait(7)
        assert cluster.stream.mounting.held is None and resets == [1]
