"""`people_in_groups` on the segmentation node (pass3d_pipeline's two nodes in memory): the parameter reaches stage 2,
which then reads each scan's groups again (pass3d_ros.core.stage2.groups); off by default, where it reads none."""

from __future__ import annotations

import pytest
from helpers.ros import STAMP0, Collector, connect, ros_session, scan_message
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.core.stage2 import groups
from pass3d_ros.data.spec import open_dataset
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.qos import qos_profile

pytestmark = pytest.mark.ros


@pytest.mark.parametrize("on", [None, True])
def test_the_parameter_reaches_stage_2(monkeypatch: pytest.MonkeyPatch, on: bool | None) -> None:
    calls: list[int] = []
    original = groups.people_in_groups

    def counting(points, members, result, classifier):
        calls.append(len(members))
        return original(points, members, result, classifier)

    monkeypatch.setattr(groups, "people_in_groups", counting)
    scans = list(open_dataset("synthetic:frames=2,seed=3,sensor=hdl32e"))
    overrides = [Parameter("classifier", value="size_rules")]
    if on is not None:
        overrides.append(Parameter("people_in_groups", value=on))
    with ros_session() as ros:
        cluster, segmentation = in_memory_factories()
        ros.add(cluster(context=ros.context))
        node = ros.add(segmentation(context=ros.context, parameter_overrides=overrides))
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled)
        for k, frame in enumerate(scans):
            pub.publish(scan_message(frame, STAMP0 + k * 100_000_000))
            labeled.wait(k + 1)
        expected = groups.DEFAULT_ENABLED if on is None else on
        assert node.stage2.people_in_groups is expected
        assert len(calls) == (len(scans) if expected else 0) and all(n > 0 for n in calls)
