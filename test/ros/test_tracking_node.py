"""`tracking` on the segmentation node (pass3d_pipeline's two nodes in memory): over a synthetic drive the objects keep
their track ids from scan to scan, /pass3d/labeled carries each point's track_id and the voted classes, the markers
show the ids, and /diagnostics counts the tracks; with tracking off the labelled cloud has no track_id field."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from helpers.ros import STAMP0, Collector, columns, connect, ros_session, scan_message, wait_until
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.classes import BACKGROUND, CAR
from pass3d_ros.core.pipeline import ProposalSegmenter
from pass3d_ros.core.tracked_scan import NO_TRACK
from pass3d_ros.data.spec import open_dataset
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode

pytestmark = pytest.mark.ros


def run_drive(monkeypatch: pytest.MonkeyPatch, tracking: bool, scans: list) -> tuple[list, list, list, list, object]:
    """The drive through both nodes in memory: (objects published per scan, labelled clouds, marker arrays,
    diagnostics messages, the segmentation node)."""
    published: list[list] = []
    original = SegmentationNode._publish_objects

    def recording(self, frame, objects, tracked, clock):
        published.append(objects)
        return original(self, frame, objects, tracked, clock)

    monkeypatch.setattr(SegmentationNode, "_publish_objects", recording)
    with ros_session() as ros:
        cluster, segmentation = in_memory_factories()
        ros.add(cluster(context=ros.context))
        node = ros.add(segmentation(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules"), Parameter("tracking", value=tracking)]))
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        markers = Collector(ros, MarkerArray, "/pass3d/objects")
        diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled, markers)
        for k, frame in enumerate(scans):
            pub.publish(scan_message(frame, STAMP0 + k * 100_000_000))
            labeled.wait(k + 1)
        assert wait_until(lambda: len(published) == len(scans) and len(markers.messages) == len(scans), timeout=5.0)
        if tracking:
            assert wait_until(lambda: any(s.name.endswith("segmentation_node") and
                                          {v.key for v in s.values} >= {"tracks_alive", "tracks_born", "tracks_lost"}
                                          for m in diagnostics.messages for s in m.status), timeout=5.0)
        return published, list(labeled.messages), list(markers.messages), list(diagnostics.messages), node


@pytest.fixture(scope="module")
def scans() -> list:
    return list(open_dataset("synthetic:drive=6,seed=3,sensor=hdl32e"))


def test_objects_keep_their_track_ids_and_points_carry_them(monkeypatch: pytest.MonkeyPatch, scans: list) -> None:
    published, clouds, markers, _, node = run_drive(monkeypatch, True, scans)
    assert all(obj.track_id == NO_TRACK for obj in published[0]), "first sightings are tentative"
    # the confirmed cars of the second scan nearer than 25 m: most keep their id to the last scan
    near = [obj.track_id for obj in published[1]
            if obj.label == CAR and obj.track_id >= 0 and np.hypot(*obj.center[:2]) < 25.0]
    assert len(near) >= 3, "the drive starts beside cars, seen twice by scan 2"
    last_ids = {obj.track_id for obj in published[-1]}
    kept = [i for i in near if i in last_ids]
    assert len(kept) >= 0.7 * len(near), (len(kept), len(near))
    assert node.stage2.tracker is not None and node.stage2.tracker.born >= len(near)
    for objects, cloud, array in zip(published, clouds, markers, strict=True):
        points = columns(cloud)
        assert "track_id" in points.dtype.names
        for obj in objects:  # each object's points carry its track id and its (voted) class
            mine = points["cluster_id"] == obj.cluster_id
            mine &= points["label"] != BACKGROUND
            assert mine.any() and np.all(points["label"][mine] == obj.label)
            assert np.all(points["track_id"][mine] == obj.track_id)
        assert np.all(points["track_id"][points["label"] == BACKGROUND] == NO_TRACK)
        texts = sorted(m.text for m in array.markers if m.type == Marker.TEXT_VIEW_FACING)
        wanted = sorted(obj.class_id if obj.track_id < 0 else f"{obj.class_id} {obj.track_id}" for obj in objects)
        assert texts == wanted


def test_without_tracking_the_labelled_cloud_has_no_track_id(monkeypatch: pytest.MonkeyPatch, scans: list) -> None:
    published, clouds, markers, _, node = run_drive(monkeypatch, False, scans[:2])
    assert node.stage2.tracker is None
    assert "track_id" not in columns(clouds[0]).dtype.names
    assert all(obj.track_id == NO_TRACK for objects in published for obj in objects)
    texts = {m.text for m in markers[-1].markers if m.type == Marker.TEXT_VIEW_FACING}
    assert texts <= {"car", "pedestrian", "cyclist"}


def odometry_message(pose: np.ndarray, stamp_ns: int) -> Odometry:
    """A nav_msgs/Odometry holding `pose` (world from base) at `stamp_ns`."""
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
    p = msg.pose.pose
    p.position.x, p.position.y, p.position.z = (float(v) for v in pose[:3, 3])
    r = pose[:3, :3]
    w = 0.5 * np.sqrt(max(1e-12, 1.0 + np.trace(r)))
    p.orientation.w = float(w)
    p.orientation.x = float((r[2, 1] - r[1, 2]) / (4 * w))
    p.orientation.y = float((r[0, 2] - r[2, 0]) / (4 * w))
    p.orientation.z = float((r[1, 0] - r[0, 1]) / (4 * w))
    return msg


def test_odometry_gives_the_tracker_the_sensors_pose(monkeypatch: pytest.MonkeyPatch, scans: list) -> None:
    """With odometry_topic, each scan reaches the tracker with the pose the odometry gave at its stamp (the drive's
    own poses, the sensor at the odometry frame's origin); a scan without odometry near it is counted."""
    given: list = []
    original = ProposalSegmenter.track

    def recording(self, objects, stamp_s=None, pose=None, **kwargs):
        given.append(pose)
        return original(self, objects, stamp_s, pose, **kwargs)

    monkeypatch.setattr(ProposalSegmenter, "track", recording)
    with ros_session() as ros:
        cluster, segmentation = in_memory_factories()
        ros.add(cluster(context=ros.context))
        node = ros.add(segmentation(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules"), Parameter("tracking", value=True),
            Parameter("odometry_topic", value="/odom")]))
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        odom = ros.probe.create_publisher(Odometry, "/odom", qos_profile("reliable"))
        connect(pub, labeled)
        assert wait_until(lambda: odom.get_subscription_count() > 0, timeout=5.0)
        for k, frame in enumerate(scans[:3]):
            stamp = STAMP0 + (k * 100_000_000 if k < 2 else 1_000_000_000)
            if k < 2:  # the last scan comes 0.9 s after the last odometry, beyond odometry_max_gap
                odom.publish(odometry_message(frame.pose, stamp))
                assert wait_until(lambda k=k: node.odometry is not None and len(node.odometry._stamps) == k + 1,
                                  timeout=5.0)
            pub.publish(scan_message(frame, stamp))
            labeled.wait(k + 1)
    assert len(given) == 3
    for pose, frame in zip(given[:2], scans[:2], strict=True):
        np.testing.assert_allclose(pose, frame.pose, atol=1e-6)
    assert given[2] is None and node.odometry.missing == 1


def test_a_bad_odometry_message_is_skipped_and_warned_about(capfd: pytest.CaptureFixture[str]) -> None:
    with ros_session() as ros:
        node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules"), Parameter("odometry_topic", value="/odom")]))
        odom = ros.probe.create_publisher(Odometry, "/odom", qos_profile("reliable"))
        assert wait_until(lambda: odom.get_subscription_count() > 0, timeout=5.0)
        msg = Odometry()
        msg.header.stamp.sec = STAMP0 // 1_000_000_000
        msg.pose.pose.position.x = float("nan")
        odom.publish(msg)
        assert wait_until(lambda: node.odometry.rejected == 1, timeout=5.0)
        err: list[str] = []
        assert wait_until(lambda: err.append(capfd.readouterr().err) or "skipping odometry message: non-finite "
                          "or implausible position, or zero quaternion (1 so far)" in "".join(err), timeout=5.0)
    assert not node.odometry._stamps
