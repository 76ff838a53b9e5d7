"""Recording: QoS matched to the publishers, types from discovery, no empty bag, Ctrl-C keeps the bag; the live
harness records the object markers; the node executables answer --help."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers.ros import wait_until
from rosbags.rosbag2 import Reader

import pass3d_ros.synthetic  # noqa: F401  (registers the synthetic: format)
from pass3d_ros.data.bag import TYPESTORE, BagError, read_bag, topic_types, topics_of_type
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, encode, header_stamp_ns

pytestmark = pytest.mark.ros

MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"


def cloud_publisher(node, topic: str, qos: str):
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.qos import qos_profile

    return node.create_publisher(PointCloud2, topic, qos_profile(qos, 10))


def cloud(stamp_ns: int):
    cols = {"x": np.full(4, stamp_ns % 1000, np.float32), "y": np.zeros(4, np.float32), "z": np.zeros(4, np.float32)}
    return encode(cols, stamp_ns=stamp_ns, frame_id="velodyne")


def start_recorder(domain: int, *args: str) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    return subprocess.Popen([sys.executable, "-m", "pass3d_ros.tools.replay", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def messages(bag: Path) -> list[tuple[str, int, object]]:
    with Reader(bag) as reader:
        return [(c.topic, t, TYPESTORE.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]


def test_records_a_best_effort_publisher(ros, tmp_path: Path) -> None:
    """Sensor drivers and pass3d_replay publish best effort; a reliable subscription would match none of them."""
    topic = f"/best_effort_{os.getpid()}"
    publisher = cloud_publisher(ros.make_node("be_pub"), topic, "sensor")
    out = tmp_path / "be.bag"
    proc = start_recorder(ros.domain, "--record", topic, "--out", str(out), "--count", "3", "--storage", "sqlite3")
    stamp, deadline = 1_000_000_000, time.monotonic() + 30
    while proc.poll() is None and time.monotonic() < deadline:
        publisher.publish(cloud(stamp))
        stamp += 50_000_000
        time.sleep(0.05)
    if proc.poll() is None:
        proc.kill()
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, f"nothing recorded from a best-effort publisher: {stderr}"
    assert "best effort" in stderr and "recorded 3 messages" in stdout
    got = messages(out)
    assert len(got) == 3 and all(t == header_stamp_ns(m) for _, t, m in got)


def test_recording_qos_follows_the_publishers(ros) -> None:
    from pass3d_ros.ros.recorder import recording_qos

    node = ros.make_node("qos_probe")
    mixed, reliable = f"/mixed_{os.getpid()}", f"/reliable_{os.getpid()}"
    assert recording_qos(node, mixed) == "sensor", "no publisher known yet: best effort matches any"
    cloud_publisher(ros.make_node("pub_a"), mixed, "reliable")
    cloud_publisher(ros.make_node("pub_b"), mixed, "sensor")
    cloud_publisher(ros.make_node("pub_c"), reliable, "reliable")
    assert wait_until(lambda: len(node.get_publishers_info_by_topic(mixed)) == 2, 10)
    assert wait_until(lambda: len(node.get_publishers_info_by_topic(reliable)) == 1, 10)
    assert recording_qos(node, mixed) == "sensor" and recording_qos(node, reliable) == "reliable"


def test_empty_recording_leaves_no_bag_and_exits_1(ros, tmp_path: Path) -> None:
    topic = f"/silent_{os.getpid()}"
    out = tmp_path / "empty.bag"
    proc = start_recorder(ros.domain, "--record", f"{topic}:{POINTCLOUD2_TYPE}", "--out", str(out), "--duration", "1")
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 1, (stdout, stderr)
    assert "recorded nothing" in stderr and topic in stderr and "not written" in stderr and "Traceback" not in stderr
    assert list(tmp_path.iterdir()) == [], "no bag (and no build folder) may be left"


def test_recorder_close_refuses_an_empty_bag(ros, tmp_path: Path) -> None:
    from pass3d_ros.ros.recorder import EmptyRecordingError, Recorder

    recorder = Recorder(ros.make_node("empty_rec"), [f"/none_{os.getpid()}"], tmp_path / "empty", qos="sensor")
    with pytest.raises(EmptyRecordingError, match="no message arrived"):
        recorder.close()
    assert list(tmp_path.iterdir()) == []


def test_discovery_waits_for_the_real_type(ros) -> None:
    """A MarkerArray topic that shows up after 2 s is recorded as a MarkerArray, not guessed as PointCloud2."""
    from visualization_msgs.msg import MarkerArray

    from pass3d_ros.ros.qos import qos_profile
    from pass3d_ros.ros.recorder import discover_types

    node = ros.make_node("discover")
    late, typed = f"/late_markers_{os.getpid()}", f"/typed_{os.getpid()}"
    publisher_node = ros.make_node("late_pub")
    timer = threading.Timer(2.5, lambda: publisher_node.create_publisher(MarkerArray, late, qos_profile("reliable")))
    timer.start()
    try:
        started = time.monotonic()
        found = discover_types(node, [late, f"{typed}:{POINTCLOUD2_TYPE}"], timeout=15.0)
    finally:
        timer.cancel()
    assert found == {late: MARKER_ARRAY, typed: POINTCLOUD2_TYPE}
    assert 2.0 < time.monotonic() - started < 15.0
    with pytest.raises(BagError, match=rf"/never_{os.getpid()}.*not found in the ROS graph within 0.3 s"):
        discover_types(node, [f"/never_{os.getpid()}"], timeout=0.3)


def test_undiscovered_topic_is_an_error_naming_it(ros, tmp_path: Path) -> None:
    topic = f"/nobody_{os.getpid()}"
    proc = start_recorder(ros.domain, "--record", topic, "--out", str(tmp_path / "x"), "--discovery-timeout", "0.5")
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 2 and topic in stderr and "not found" in stderr and "Traceback" not in stderr
    assert list(tmp_path.iterdir()) == []


def test_interrupt_keeps_what_was_recorded(ros, tmp_path: Path) -> None:
    """Ctrl-C before --count is reached closes the bag like `ros2 bag record`: complete, readable, counted."""
    from rclpy.qos import ReliabilityPolicy

    topic = f"/interrupted_{os.getpid()}"
    node = ros.make_node("int_pub")
    publisher = cloud_publisher(node, topic, "reliable")
    out = tmp_path / "partial.bag"
    proc = start_recorder(ros.domain, "--record", topic, "--out", str(out), "--count", "1000")

    def subscribed() -> bool:
        infos = node.get_subscriptions_info_by_topic(topic)
        return any(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)

    assert wait_until(lambda: publisher.get_subscription_count() >= 1 and subscribed(), 30), "recorder not up"
    time.sleep(0.5)
    stamps = [2_000_000_000 + k * 100_000_000 for k in range(5)]
    for stamp in stamps:
        publisher.publish(cloud(stamp))
        time.sleep(0.05)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, (stdout, stderr)
    assert "recorded 5 messages" in stdout and "interrupted" in stdout
    assert [t for _, t, _ in messages(out)] == stamps, "the bag must be complete and readable"
    assert [p.name for p in tmp_path.iterdir()] == ["partial.bag"]


def test_live_recording_holds_the_object_markers(tmp_path: Path) -> None:
    from pass3d_ros.evaluation.live import run_live

    bag = tmp_path / "input"
    convert(["synthetic:frames=2,seed=1"], bag, with_labels=True, progress=False, log=lambda _: None)
    record = tmp_path / "labeled"
    result = run_live(bag, lockstep=True, record_out=record, timeout_s=60.0,
                      node_parameters={"segmentation_node": {"classifier": "size_rules"}})
    assert result.frames_out == 2
    assert topic_types(record) == {"/pass3d/labeled": POINTCLOUD2_TYPE, "/pass3d/objects": MARKER_ARRAY}
    assert topics_of_type(record, MARKER_ARRAY) == {"/pass3d/objects": 2}
    with Reader(record) as reader:
        stamps = {c.topic: [t for _, t, _ in reader.messages(connections=[c])] for c in reader.connections}
    assert stamps["/pass3d/objects"] == stamps["/pass3d/labeled"] == [f.stamp_ns for f in result.frames]
    recorded = list(read_bag(record, labels="predicted"))  # the reader still finds the one PointCloud2 topic
    assert len(recorded) == 2
    for rec, got in zip(recorded, result.frames, strict=True):
        np.testing.assert_array_equal(rec.labels, got.predicted)
    assert all(frame.labels is None for frame in read_bag(record)), "an output bag holds no ground truth"


def test_pipeline_help_prints_usage_without_starting() -> None:
    result = subprocess.run([sys.executable, "-m", "pass3d_ros.ros.pipeline", "--help"], capture_output=True,
                            text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: pass3d_pipeline") and "--ros-args" in result.stdout
    assert "--params-file" in result.stdout
    assert "cluster_proposal_node" in result.stdout and "segmentation_node" in result.stdout


@pytest.mark.parametrize("name", ["cluster_proposal_node", "segmentation_node"])
def test_node_executables_print_help(name: str, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    import importlib

    import rclpy

    def started(*_: object, **__: object) -> None:
        raise AssertionError("--help must not start ROS")

    monkeypatch.setattr(rclpy, "init", started)
    main = importlib.import_module(f"pass3d_ros.ros.{name}").main
    assert main([name, "--help"]) == 0 and main([name, "-h"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: {name}") and f"  {name}: " in out and "--ros-args" in out


def test_help_after_ros_args_is_not_ours() -> None:
    from pass3d_ros.ros.run import wants_help

    assert wants_help(["pass3d_pipeline", "-h"]) and wants_help(["pass3d_pipeline", "--help", "--ros-args"])
    assert not wants_help(["pass3d_pipeline", "--ros-args", "--help"]) and not wants_help(["pass3d_pipeline"])


def test_coverage_counts_what_the_stamps_imply() -> None:
    from pass3d_ros.ros.input_watch import coverage

    stamps = [1_000_000_000 + k * 100_000_000 + (k % 3) * 1_000_000 for k in (0, 1, 2, 4, 5, 6, 9)]  # +-ms jitter
    report = coverage(stamps)
    assert (report.got, report.implied, report.missing) == (7, 10, 3)
    assert report.period_s == pytest.approx(0.1, abs=0.002)
    assert coverage(stamps, published=12).missing == 5, "the publisher's count shows the ends lost too"
    assert coverage([5]).missing == 0 and coverage([]).got == 0


def test_recorder_says_how_many_it_got_of_what_the_replay_published(ros, tmp_path: Path) -> None:
    """Stamps with frames 3, 7 and 8 missing and a replay status on /diagnostics that says 12 were published: the
    recorder's coverage is 7 of 12."""
    from pass3d_ros.ros.bag_replay import ReplayStats, announce
    from pass3d_ros.ros.recorder import Recorder

    topic = f"/coverage_{os.getpid()}"
    recorder = Recorder(ros.make_node("cov_rec"), [topic], tmp_path / "cov", qos="reliable")
    node = ros.make_node("cov_pub")
    publisher = cloud_publisher(node, topic, "reliable")
    assert wait_until(lambda: publisher.get_subscription_count() >= 1, 30)
    stamps = [2_000_000_000 + k * 100_000_000 for k in (0, 1, 2, 4, 5, 6, 9)]
    for stamp in stamps:
        publisher.publish(cloud(stamp))
    announce(node, ReplayStats(topic, published=12, passes=1), loop=False)
    assert wait_until(lambda: recorder.counts[topic] == len(stamps) and recorder.replay is not None, 30)
    report = recorder.coverage()
    assert (report.got, report.implied, report.published, report.expected, report.missing) == (7, 10, 12, 12, 5)
    assert sorted(recorder.stamps[topic]) == stamps
    recorder.close()
