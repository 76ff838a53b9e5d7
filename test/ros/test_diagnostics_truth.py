"""`/diagnostics` tells the truth (issue 40, item 4): malformed clouds that produce nothing are counted as skipped and
turn the status WARN; a stage-2 child that stops answering is killed and restarted with an ERROR, and its frame is
never published late; a sensor's rate change is learnt, not reported as frames lost.

The node tests run in-process with real publishers and subscribers on a real executor (helpers.ros.Ros).
"""

from __future__ import annotations

import contextlib
import os
import signal
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from helpers.ros import STAMP0, Collector, Ros, connect, wait_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from pass3d_ros.msgs.pointcloud2 import encode, header_stamp_ns
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.diagnostics import (
    NO_OUTPUT_WARN_S,
    NodeStats,
    OutputWatch,
    RecentTrouble,
    status_values,
    to_status,
)
from pass3d_ros.ros.input_watch import MAX_PENDING, Cadence, InputWatch
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode


def statuses(diagnostics: Collector, name: str) -> list[DiagnosticStatus]:
    """Every status of node `name` received so far."""
    with diagnostics.cond:
        return [s for msg in diagnostics.messages for s in msg.status if s.name == name]


def stamps_of(collector: Collector) -> list[int]:
    with collector.cond:
        return [header_stamp_ns(msg) for msg in collector.messages]


# ---- skipped frames ----

@pytest.mark.ros
def test_a_stream_of_malformed_clouds_is_skipped_and_warned_about(ros: Ros) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    xyz = {k: np.zeros(1000, np.float32) for k in ("x", "y", "z")}
    started = time.monotonic()
    sent = 0
    while time.monotonic() - started < NO_OUTPUT_WARN_S + 2.5:  # 20 Hz of clouds shorter than width * point_step
        msg = encode(xyz, stamp_ns=STAMP0 + sent * 50_000_000)
        msg.data = msg.data[:-10]
        pub.publish(msg)
        sent += 1
        time.sleep(0.05)
    assert wait_until(lambda: node.worker.counters.skipped == sent and node.worker.idle(), timeout=10.0)

    warned = [s for s in statuses(diagnostics, node.get_name()) if s.level == DiagnosticStatus.WARN]
    assert warned, [s.message for s in statuses(diagnostics, node.get_name())]
    assert "no output for" in warned[-1].message and "skipped (malformed" in warned[-1].message, warned[-1].message
    values = status_values(warned[-1])
    assert values["processed"] == 0 and values["skipped"] > 0 and values["skipped_malformed"] == values["skipped"]
    assert node.worker.counters.processed == 0 and clouds.messages == []


def test_output_watch_warns_only_while_input_produces_nothing() -> None:
    watch = OutputWatch(after_s=3.0)
    counters = {"received": 0, "processed": 0, "skipped": 0, "dropped": 0, "failed": 0}
    for second in range(10):  # frames in, and out: fine
        counters.update(received=10 * second, processed=10 * second)
        assert watch.check(float(second), counters, {}) == ""
    for second in range(10, 16):  # frames in, skipped: a warning once 3 s have gone by without output
        counters.update(received=10 * second, skipped=10 * (second - 9))
        problem = watch.check(float(second), counters, {"malformed": 10 * (second - 9)})
        assert (problem != "") == (second >= 12), (second, problem)
    assert problem == "no output for 6 s while 30 frames came in: 30 skipped (malformed 30)"
    for second in range(16, 20):  # the input stops: the warning goes once the last skips are 3 s old
        assert (watch.check(float(second), counters, {"malformed": 60}) != "") == (second < 18)


# ---- a stage-2 child that stops answering ----

@pytest.mark.ros
def test_a_stopped_stage2_child_is_killed_restarted_and_its_frame_never_published(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter("classifier", value="size_rules"), Parameter("process", value=True),
        Parameter("stage2_timeout", value=1.0)]))
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    connect(pub, labeled)
    name = node.get_name()

    pub.publish(encode(proposal_columns, stamp_ns=STAMP0))
    labeled.wait(1)
    first = node.classifier.pid
    os.kill(first, signal.SIGSTOP)
    try:
        stale = [STAMP0 + k * 100_000_000 for k in (1, 2)]
        for stamp in stale:  # the first waits in the stopped child, the second in the node's slot
            pub.publish(encode(proposal_columns, stamp_ns=stamp))
            time.sleep(0.3)
        assert wait_until(lambda: any(s.level == DiagnosticStatus.ERROR for s in statuses(diagnostics, name)),
                          timeout=5.0), [s.message for s in statuses(diagnostics, name)]
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(first, signal.SIGCONT)  # a stopped child left behind would outlive the test
    error = next(s for s in statuses(diagnostics, name) if s.level == DiagnosticStatus.ERROR)
    assert f"stage-2 process {first} answered nothing for 1 s (stage2_timeout)" in error.message, error.message
    with pytest.raises(ProcessLookupError):
        os.kill(first, 0)  # killed and reaped

    assert wait_until(lambda: node.classifier.restarts == 1, timeout=60.0)
    assert node.classifier.pid != first and node.classifier.hangs == 1
    fresh = STAMP0 + 10 * 100_000_000
    pub.publish(encode(proposal_columns, stamp_ns=fresh))
    assert wait_until(lambda: fresh in stamps_of(labeled), timeout=10.0)
    time.sleep(0.3)

    assert stamps_of(labeled) == [STAMP0, fresh], "a frame of the stopped child must never come out"
    counters = node.counters()
    assert node.frames_hung >= 1 and counters.dropped == 2 and counters.processed == 2 and counters.failed == 0
    assert wait_until(lambda: status_values(statuses(diagnostics, name)[-1]).get("stage2_hangs") == 1, timeout=5.0)
    assert f"stage 2 process {first} answered nothing for 1 s (hung or stopped): killed" in capfd.readouterr().err


@pytest.mark.ros
def test_a_result_later_than_stage2_timeout_is_dropped_not_published(
    ros: Ros, proposal_columns: dict[str, np.ndarray]
) -> None:
    node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter("classifier", value="size_rules"), Parameter("stage2_timeout", value=0.3)]))
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    connect(pub, labeled)
    segment = node.classifier.segment
    slow = [True]

    def stalled(points: np.ndarray, members: list[np.ndarray]):  # a stage 2 that stalls once (swap, a GIL hog)
        if slow.pop() if slow else False:
            time.sleep(0.6)
        return segment(points, members)

    node.classifier.segment = stalled
    pub.publish(encode(proposal_columns, stamp_ns=STAMP0))
    assert wait_until(lambda: node.frames_late == 1 and node.worker.idle(), timeout=10.0)
    pub.publish(encode(proposal_columns, stamp_ns=STAMP0 + 100_000_000))
    labeled.wait(1)
    time.sleep(0.2)
    assert stamps_of(labeled) == [STAMP0 + 100_000_000]
    assert node.counters().dropped == 1 and node.counters().processed == 1


# ---- a rate change is no loss ----

PERIOD_NS = 100_000_000


def rate_changes(rates_hz: tuple[float, ...] = (20.0, 5.0, 10.0), seconds: float = 5.0) -> list[int]:
    """Header stamps of a sensor that changes its rate, nothing lost."""
    stamps, stamp = [], STAMP0
    for rate in rates_hz:
        for _ in range(int(seconds * rate)):
            stamp += int(1e9 / rate)
            stamps.append(stamp)
    return stamps


def test_a_rate_change_is_learnt_not_reported_as_frames_missed() -> None:
    stats = NodeStats()
    for stamp in rate_changes():
        stats.input(stamp)
    snapshot = stats.snapshot()
    assert snapshot["frames_missed_upstream"] == 0 and snapshot["input_gaps"] == 0
    assert snapshot["input_rate_changes"] == 2 and snapshot["input_period_ms"] == pytest.approx(100.0)
    status = to_status("cluster_proposal_node", {"received": 100, "processed": 100}, stats, RecentTrouble())
    assert status.level == DiagnosticStatus.OK, status.message

    stamp = rate_changes()[-1]
    for k in (1, 2, 6, 7, 8):  # then at 10 Hz, frames 3, 4 and 5 lost: loss at the new rate is still loss
        stats.input(stamp + k * PERIOD_NS)
    assert stats.snapshot()["frames_missed_upstream"] == 3 and stats.snapshot()["input_gaps"] == 1


def test_the_input_watch_blames_no_publisher_for_a_rate_change() -> None:
    watch = InputWatch("/velodyne_points", None)
    for stamp in rate_changes(seconds=2.0):
        watch.received((stamp - STAMP0) / 1e9, stamp)
        now = (stamp - STAMP0) / 1e9
        assert watch.check(now, ["sensor"], "sensor") == "", now
    assert watch.missing(now)[0] == 0


def test_a_slower_rate_is_pending_not_lost_until_the_stream_says_which() -> None:
    stats = NodeStats()
    stamps = [STAMP0 + k * PERIOD_NS for k in range(10)]
    stamps += [stamps[-1] + k * 4 * PERIOD_NS for k in range(1, 4)]  # 2.5 Hz, or three of every four frames lost?
    for stamp in stamps:
        stats.input(stamp)
    assert stats.snapshot()["frames_missed_upstream"] == 0, "not yet known to be loss"
    stats.input(stamps[-1] + PERIOD_NS)  # back on the 10 Hz cadence: those were lost
    assert stats.snapshot()["frames_missed_upstream"] == 9 and stats.snapshot()["input_gaps"] == 3


def test_a_stream_that_never_settles_holds_a_bounded_number_of_intervals_pending() -> None:
    """10 Hz learnt, then 5 Hz with irregular loss for 3000 scans: no interval comes back on period and no new period
    is regular enough to be a rate change, so without a bound every interval stayed pending (5 minutes at 10 Hz: 3000
    of them, each scan's cost growing with them); the oldest are confirmed as loss instead."""
    cadence = Cadence()
    for _ in range(50):
        cadence.add(PERIOD_NS)
    rng = np.random.default_rng(0)
    for multiple in rng.choice([2, 4, 6], 3000, p=[0.6, 0.3, 0.1]):
        cadence.add(int(multiple) * PERIOD_NS)
        assert cadence.pending() <= 5 * MAX_PENDING
    assert cadence.missed > 0


def test_loss_turns_the_status_warn_only_while_it_is_recent() -> None:
    """One drop an hour ago does not hold a node at WARN for ever: the status follows the counts' growth over the
    last TROUBLE_WINDOW_S; the totals stay in the values."""
    stats, recent = NodeStats(), RecentTrouble(window_s=10.0)
    counters = {"received": 100, "processed": 100, "dropped": 0, "failed": 0}

    def level(now_s: float) -> int:
        return to_status("segmentation_node", counters, stats, recent, now_s=now_s).level

    assert level(0.0) == DiagnosticStatus.OK
    counters.update(received=110, processed=109, dropped=1)
    assert level(1.0) == DiagnosticStatus.WARN
    assert level(10.5) == DiagnosticStatus.WARN  # within 10 s of the drop
    status = to_status("segmentation_node", counters, stats, recent, now_s=12.0)
    assert status.level == DiagnosticStatus.OK and status_values(status)["dropped"] == 1
    counters.update(failed=1)
    assert level(13.0) == DiagnosticStatus.WARN
    assert RecentTrouble().update(0.0, {"dropped": 3})  # a node's first status after loss already warns
