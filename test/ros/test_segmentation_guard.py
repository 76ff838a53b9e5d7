"""segmentation_node guards its input and its stage-2 process: points with absurd coordinates are dropped, proposals
beyond max_proposals are not classified, and a killed stage-2 child is restarted while the node stays up.

In-process, with real publishers and subscribers on a real executor (helpers.ros.Ros).
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from helpers.ros import STAMP0, Collector, Ros, connect, wait_until
from rclpy.logging import LoggingSeverity
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.objects import frame_objects
from pass3d_ros.core.stage1 import proposal_members
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.segmentation import nearest_first
from pass3d_ros.msgs.pointcloud2 import decode, encode
from pass3d_ros.ros.diagnostics import status_values
from pass3d_ros.ros.proposals import members_from_ids, nearest_proposals
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode

pytestmark = pytest.mark.ros


def points_of(columns: dict[str, np.ndarray]) -> np.ndarray:
    return np.stack([columns[k] for k in ("x", "y", "z", "intensity")], axis=1).astype(np.float32)


def start(ros: Ros, **values) -> tuple[SegmentationNode, Collector, object]:
    node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()]))
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    connect(pub, labeled)
    return node, labeled, pub


def test_nearest_proposals_keeps_what_the_classifier_would_choose(proposal_columns: dict[str, np.ndarray]) -> None:
    columns = proposal_columns
    points, first, second = points_of(columns), columns["cluster_id"], columns["cluster_id2"]
    members = proposal_members(first, second)
    for limit in (1, 5, len(members) - 1, len(members), 500):
        cut_first, cut_second, count = nearest_proposals(points, first.astype(np.int64), second.astype(np.int64),
                                                         len(members), limit)
        chosen = nearest_first(points, members, limit)
        assert count == len(chosen) == min(limit, len(members))
        got = proposal_members(cut_first, cut_second, n_proposals=count)
        assert all(np.array_equal(a, members[i]) for a, i in zip(got, chosen, strict=True))


def test_a_point_at_1e20_m_is_dropped_and_the_frame_labeled(
    ros: Ros, proposal_columns: dict[str, np.ndarray], lite_weights: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    bad = {k: v.copy() for k, v in proposal_columns.items()}
    inside = int(np.flatnonzero(bad["cluster_id"] >= 0)[0])  # a point of a proposal: it reaches the network
    bad["x"][inside] = 1e20
    node, labeled, pub = start(ros, classifier="network", weights=str(lite_weights))
    pub.publish(encode(bad, stamp_ns=STAMP0))
    cloud = decode(labeled.wait(1)[0])

    keep = np.arange(len(bad["x"])) != inside
    first = proposal_columns["cluster_id"][keep].astype(np.int64)
    points = points_of(proposal_columns)[keep]
    expected = open_classifier(str(lite_weights), "network").segment(
        points, members_from_ids(first, proposal_columns["cluster_id2"][keep].astype(np.int64)))
    assert len(cloud) == len(keep) - 1 and np.all(np.abs(cloud["x"]) < 1e4)
    published = frame_objects(points, first, expected.proposal_class, expected.labels, expected.confidence)
    np.testing.assert_array_equal(cloud["label"], published.labels)
    assert node.points_dropped == 1 and node.counters().failed == 0
    assert "x/y/z: dropping 1 points with non-finite or absurd coordinates" in capfd.readouterr().err


def test_a_nan_intensity_reads_0_and_its_proposal_is_labeled(
    ros: Ros, proposal_columns: dict[str, np.ndarray], lite_weights: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    bad = {k: v.copy() for k, v in proposal_columns.items()}
    inside = int(np.flatnonzero(bad["cluster_id"] >= 0)[0])  # a point of a proposal: it reaches the network
    bad["intensity"][inside] = np.nan
    node, labeled, pub = start(ros, classifier="network", weights=str(lite_weights), intensity_match=False,
                               tracking=False)
    pub.publish(encode(bad, stamp_ns=STAMP0))
    cloud = decode(labeled.wait(1)[0])

    points = points_of(bad)
    points[inside, 3] = 0.0
    first = proposal_columns["cluster_id"].astype(np.int64)
    expected = open_classifier(str(lite_weights), "network").segment(
        points, members_from_ids(first, proposal_columns["cluster_id2"].astype(np.int64)))
    published = frame_objects(points, first, expected.proposal_class, expected.labels, expected.confidence)
    np.testing.assert_array_equal(cloud["label"], published.labels)
    assert np.isfinite(cloud["confidence"]).all() and cloud["intensity"][inside] == 0.0
    assert node.counters().failed == 0
    assert "intensity: 1 values are not finite, read as 0" in capfd.readouterr().err


def test_every_point_its_own_proposal_is_cut_to_max_proposals(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    flood = {k: v.copy() for k, v in proposal_columns.items()}
    n = len(flood["x"])
    flood["cluster_id"] = np.arange(n, dtype=np.int32)
    flood["cluster_id2"] = np.full(n, -1, np.int32)
    node, labeled, pub = start(ros, classifier="size_rules", max_proposals=20)
    classified: list[int] = []
    segment = node.classifier.segment
    node.classifier.segment = lambda points, members: classified.append(len(members)) or segment(points, members)

    pub.publish(encode(flood, stamp_ns=STAMP0))
    cloud = decode(labeled.wait(1)[0])
    assert classified == [20], "only max_proposals proposals reach the classifier"
    assert len(cloud) == n and np.count_nonzero(cloud["label"] != BACKGROUND) <= 20
    assert node.proposals_cut == n - 20 and node.counters().failed == 0
    assert f"{n} proposals in one frame, max_proposals 20: the nearest 20 are classified" in capfd.readouterr().err


def test_a_killed_stage2_process_is_restarted_and_frames_labeled_again(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    node, labeled, pub = start(ros, classifier="size_rules", process=True)
    node.get_logger().set_level(LoggingSeverity.INFO)  # another test may have raised the shared logger's level
    diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
    name = node.get_name()

    def statuses() -> list[DiagnosticStatus]:
        return [s for msg in diagnostics.messages for s in msg.status if s.name == name]

    pub.publish(encode(proposal_columns, stamp_ns=STAMP0))
    expected = decode(labeled.wait(1)[0])["label"]
    first = node.classifier.pid
    os.kill(first, signal.SIGKILL)  # what the out-of-memory killer does
    assert wait_until(lambda: node.classifier.down_for() is not None, timeout=5.0)
    stamp = STAMP0
    deadline = time.monotonic() + 90.0
    while len(labeled.messages) < 2 and time.monotonic() < deadline:  # frames meanwhile are dropped, not queued
        stamp += 100_000_000
        pub.publish(encode(proposal_columns, stamp_ns=stamp))
        time.sleep(0.3)
    again = labeled.wait(2)[1]

    np.testing.assert_array_equal(decode(again)["label"], expected)
    assert node.classifier.restarts == 1 and node.classifier.pid != first
    counters = node.counters()
    assert counters.dropped >= 1 and counters.failed == 0 and node.frames_down >= 1
    assert wait_until(lambda: any(status_values(s).get("stage2_restarts") == 1 for s in statuses()))
    down = [s for s in statuses() if "stage-2 process down" in s.message]
    assert down and all(s.level == DiagnosticStatus.WARN for s in down)
    err = capfd.readouterr().err
    assert err.count(f"stage 2 process {first} died (killed by SIGKILL") == 1, err
    assert f"stage 2 restarted in process {node.classifier.pid} (restart 1" in err
