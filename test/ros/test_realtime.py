"""The real-time path: the in-memory stage 1 -> stage 2 hand-off, publish-on-demand, and /diagnostics counters."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from helpers.ros import WAIT_S, Ros, wait_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from pass3d_ros.data.bag_convert import convert, frame_cloud
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.live import run_live
from pass3d_ros.msgs.pointcloud2 import encode
from pass3d_ros.ros import cluster_proposal_node
from pass3d_ros.ros.diagnostics import DIAGNOSTICS_TOPIC, NodeStats, status_values
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.qos import qos_profile

pytestmark = pytest.mark.ros

STAMP0 = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000


@pytest.fixture(scope="module")
def scan(frame: Frame) -> np.ndarray:
    return frame_cloud(frame)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("realtime") / "drive"
    convert(["synthetic:frames=2,seed=7"], out, progress=False, log=lambda _: None)
    return out


@pytest.fixture
def pair(ros: Ros) -> tuple:
    """Both nodes joined in memory (size_rules stage 2: fast) in the test's private context, and its probe."""
    factories = in_memory_factories()
    cluster = ros.add(factories[0](context=ros.context))
    size_rules = [Parameter("classifier", value="size_rules")]
    segmenter = ros.add(factories[1](context=ros.context, parameter_overrides=size_rules))
    return cluster, segmenter, ros.probe


def test_in_memory_pipeline_labels_like_the_message_path(bag: Path) -> None:
    """Same bag, lockstep: the in-memory hand-off (stage 2 in line, on its own thread, or in a child process) and
    the two nodes over PointCloud2 give the same labels."""
    runs = {layout: run_live(bag, lockstep=True, layout=layout, timeout_s=WAIT_S)
            for layout in ("one-process", "in-memory")}
    overlap = run_live(bag, lockstep=True, layout="in-memory", timeout_s=WAIT_S,
                       node_parameters={"segmentation_node": {"overlap": True}})
    assert overlap.frames_in == overlap.frames_out == 2 and overlap.mismatched == 0
    assert {f.stamp_ns: f.predicted.tobytes() for f in overlap.frames} == {
        f.stamp_ns: f.predicted.tobytes() for f in runs["in-memory"].frames}
    assert overlap.node_counters["segmentation_node"]["processed"] == 2
    assert overlap.node_stats["segmentation_node"]["handoff_p50_ms"] is None  # published on stage 2's thread
    child = run_live(bag, lockstep=True, layout="in-memory", timeout_s=WAIT_S,
                     node_parameters={"segmentation_node": {"overlap": True, "process": True}})
    assert child.frames_in == child.frames_out == 2 and child.mismatched == 0
    assert child.node_counters["segmentation_node"] == {"received": 2, "processed": 2, "dropped": 0, "failed": 0,
                                                        "skipped": 0}
    assert child.node_stats["segmentation_node"]["handoff_p50_ms"] is not None  # by the publishing thread
    assert {f.stamp_ns: f.predicted.tobytes() for f in child.frames} == {
        f.stamp_ns: f.predicted.tobytes() for f in runs["in-memory"].frames}
    for result in runs.values():
        assert result.frames_in == result.frames_out == 2 and result.mismatched == 0
    by_stamp = {layout: {f.stamp_ns: f.predicted for f in r.frames} for layout, r in runs.items()}
    assert by_stamp["one-process"].keys() == by_stamp["in-memory"].keys()
    for stamp, labels in by_stamp["one-process"].items():
        np.testing.assert_array_equal(labels, by_stamp["in-memory"][stamp])
    assert any((labels > 0).any() for labels in by_stamp["in-memory"].values()), "some points labeled as objects"
    assert runs["in-memory"].node_counters["segmentation_node"]["processed"] == 2
    assert runs["in-memory"].node_stats["segmentation_node"]["latency_p50_ms"] > 0


def test_proposals_encoded_only_while_subscribed(pair: tuple, scan: np.ndarray,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    cluster, segmenter, probe = pair
    encoded: list[int] = []
    real_encode = cluster_proposal_node.encode

    def counting_encode(*args: Any, **kwargs: Any) -> Any:
        encoded.append(1)
        return real_encode(*args, **kwargs)

    monkeypatch.setattr(cluster_proposal_node, "encode", counting_encode)
    assert segmenter.subscription is None, "in memory: the segmentation node does not subscribe /pass3d/proposals"
    cluster.submit(encode(scan, stamp_ns=STAMP0, frame_id="velodyne"), STAMP0)
    assert wait_until(lambda: segmenter.worker.counters.processed == 1 and cluster.worker.idle())
    assert encoded == [] and cluster.proposals_pub.get_subscription_count() == 0

    received: list[PointCloud2] = []
    probe.create_subscription(PointCloud2, "/pass3d/proposals", received.append, qos_profile("reliable"))
    assert wait_until(lambda: cluster.proposals_pub.get_subscription_count() == 1)
    cluster.submit(encode(scan, stamp_ns=STAMP0 + PERIOD_NS, frame_id="velodyne"), STAMP0 + PERIOD_NS)
    assert wait_until(lambda: len(received) == 1)
    assert encoded == [1] and segmenter.worker.counters.processed == 2


def test_diagnostics_carry_counters_and_input_gaps(pair: tuple, scan: np.ndarray) -> None:
    cluster, _, probe = pair
    latest: dict[str, dict] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            latest[status.name] = status_values(status)

    probe.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_diagnostics, 10)
    stamps = [STAMP0 + k * PERIOD_NS for k in (0, 1, 2, 3, 4, 7, 8)]  # frames 5 and 6 lost before the node
    for stamp in stamps:
        cluster.submit(encode(scan, stamp_ns=stamp, frame_id="velodyne"), stamp)
        assert wait_until(lambda: cluster.worker.idle())
    expected = len(stamps)

    def complete() -> bool:
        values = [latest.get(name) for name in ("cluster_proposal_node", "segmentation_node")]
        return all(v is not None and v["received"] == expected for v in values)

    assert wait_until(complete, 10.0), latest
    values = latest["cluster_proposal_node"]
    assert values["processed"] == expected and values["dropped"] == 0
    assert values["input_gaps"] == 1 and values["frames_missed_upstream"] == 2
    assert values["input_period_ms"] == pytest.approx(100.0)
    assert 0 < values["latency_p50_ms"] <= values["latency_p95_ms"] <= values["latency_max_ms"]
    assert values["compute_p50_ms"] > 0
    assert latest["segmentation_node"]["processed"] == expected
    segmentation = latest["segmentation_node"]
    assert segmentation["input_gaps"] == 1 and segmentation["frames_missed_upstream"] == 2, "each hop counts its input"


def test_input_gaps_counted_from_stamps() -> None:
    stats = NodeStats()
    for k in (0, 1, 2, 3, 4, 8, 9, 10):  # 5, 6, 7 lost
        stats.input(STAMP0 + k * PERIOD_NS)
    stats.input(STAMP0 + 10 * PERIOD_NS)  # a repeated stamp is out of order, not a gap
    snapshot = stats.snapshot()
    assert snapshot["input_gaps"] == 1 and snapshot["frames_missed_upstream"] == 3
    assert snapshot["stamps_out_of_order"] == 1 and snapshot["input_period_ms"] == pytest.approx(100.0)
    stats.frame({"wait": 1.0, "compute": 4.0})
    assert stats.snapshot()["latency_p50_ms"] == pytest.approx(5.0)


def test_near_duplicate_stamps_at_start_up_are_not_the_cadence() -> None:
    stats = NodeStats()
    for stamp in (STAMP0, STAMP0 + 1_000, STAMP0 + 2_000):  # a driver's start-up burst, stamps 1 us apart
        stats.input(stamp)
    for k in range(1, 60):
        stats.input(STAMP0 + 2_000 + k * PERIOD_NS)
    snapshot = stats.snapshot()
    assert snapshot["input_gaps"] == 0 and snapshot["frames_missed_upstream"] == 0
    assert snapshot["stamps_out_of_order"] == 2 and snapshot["input_period_ms"] == pytest.approx(100.0)


def test_cadence_is_relearnt_after_a_rate_change() -> None:
    stats = NodeStats()
    stamp = STAMP0
    for _ in range(40):  # 20 Hz
        stamp += PERIOD_NS // 2
        stats.input(stamp)
    gaps_by_frame = []
    for _ in range(100):  # then 10 Hz, nothing lost
        stamp += PERIOD_NS
        stats.input(stamp)
        gaps_by_frame.append(stats.snapshot()["input_gaps"])
    assert gaps_by_frame[-1] <= 30, "a rate change may look like loss for a while, not forever"
    assert gaps_by_frame[-1] == gaps_by_frame[40], "once re-learnt, the new rate counts no gaps"
    assert stats.snapshot()["input_period_ms"] == pytest.approx(100.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_heavy_loss_counted_frame_by_frame(seed: int) -> None:
    rng = np.random.default_rng(seed)
    lost = set(rng.choice(np.arange(5, 120), size=59, replace=False).tolist())  # half of 115, none at the ends
    stats = NodeStats()
    for k in range(125):
        if k not in lost:
            stats.input(STAMP0 + k * PERIOD_NS + int(rng.integers(-3_000_000, 3_000_000)))  # +-3 ms jitter
    assert stats.snapshot()["frames_missed_upstream"] == 59


def test_a_long_silence_is_a_pause_not_lost_frames() -> None:
    stats = NodeStats()
    for k in range(10):
        stats.input(STAMP0 + k * PERIOD_NS)
    stats.input(STAMP0 + 3600 * 10**9)  # the bag restarted an hour later
    snapshot = stats.snapshot()
    assert snapshot["stream_pauses"] == 1 and snapshot["frames_missed_upstream"] == 0


def test_a_backlog_of_two_rides_out_one_slow_frame() -> None:
    """While one frame is in hand, two more wait and are processed in order; a third newer one drops the oldest
    waiting (counted)."""
    import threading

    from pass3d_ros.ros.latest_frame import LatestFrameWorker

    release, done = threading.Event(), []
    worker = LatestFrameWorker(lambda item: (release.wait(5), done.append(item)), lambda exc: None, "t", backlog=2)
    worker.submit(0)
    assert wait_until(lambda: not worker.idle() and worker.counters.received == 1)
    time.sleep(0.05)  # frame 0 in hand
    worker.submit(1)
    worker.submit(2)
    release.set()
    assert wait_until(worker.idle)
    assert done == [0, 1, 2] and worker.counters.dropped == 0
    release.clear()
    worker.submit(3)
    time.sleep(0.05)
    for item in (4, 5, 6):
        worker.submit(item)
    release.set()
    assert wait_until(worker.idle)
    worker.stop()
    assert done == [0, 1, 2, 3, 5, 6] and worker.counters.dropped == 1
