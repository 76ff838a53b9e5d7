"""`tracking` on the segmentation node (pass3d_pipeline's two nodes in memory): over a synthetic drive the objects keep
their track ids from scan to scan, detections would carry them, and /diagnostics counts the tracks."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from helpers.ros import STAMP0, Collector, connect, ros_session, scan_message, wait_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.classes import CAR
from pass3d_ros.data.spec import open_dataset
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode

pytestmark = pytest.mark.ros


def test_objects_keep_their_track_ids_over_a_drive(monkeypatch: pytest.MonkeyPatch) -> None:
    published: list[tuple[list, list[str] | None]] = []
    original = SegmentationNode._publish_objects

    def recording(self, frame, objects, ids, clock):
        published.append((objects, ids))
        return original(self, frame, objects, ids, clock)

    monkeypatch.setattr(SegmentationNode, "_publish_objects", recording)
    scans = list(open_dataset("synthetic:drive=6,seed=3,sensor=hdl32e"))
    with ros_session() as ros:
        cluster, segmentation = in_memory_factories()
        ros.add(cluster(context=ros.context))
        node = ros.add(segmentation(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules"), Parameter("tracking", value=True)]))
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled)
        for k, frame in enumerate(scans):
            pub.publish(scan_message(frame, STAMP0 + k * 100_000_000))
            labeled.wait(k + 1)
        assert wait_until(lambda: len(published) == len(scans), timeout=5.0)  # objects go out after the cloud
        # the cars of the first scan nearer than 25 m: each keeps its id in the later scans, near where it was
        first_objects, first_ids = published[0]
        near = [(obj, i) for obj, i in zip(first_objects, first_ids, strict=True)
                if obj.label == CAR and np.hypot(*obj.center[:2]) < 25.0]
        assert near, "the drive starts beside cars"
        last_ids = set(published[-1][1])
        kept = [i for _, i in near if i in last_ids]
        assert len(kept) >= 0.7 * len(near), (len(kept), len(near))
        assert wait_until(lambda: any(s.name.endswith("segmentation_node") and
                                      {v.key for v in s.values} >= {"tracks_alive", "tracks_born", "tracks_lost"}
                                      for m in diagnostics.messages for s in m.status), timeout=5.0)
        assert node.tracker is not None and node.tracker.born >= len(near)
