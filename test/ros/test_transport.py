"""Large clouds between processes: the shipped Fast DDS profile applied at start, the input QoS that follows its
publishers (`input_qos: auto`), and the warning when publishers exist but scans do not arrive."""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from helpers.ros import Ros, domain, wait_until
from rclpy.qos import ReliabilityPolicy

from pass3d_ros.ros import dds_profile
from pass3d_ros.ros.dds_profile import PROFILE_NAME, PROFILE_VARIABLE, apply_shipped_profile, shipped_profile
from pass3d_ros.ros.input_watch import InputWatch, OverlapFilter
from pass3d_ros.ros.qos import offered_qos

ROOT = Path(__file__).resolve().parents[2]


def test_the_shipped_profile_is_applied_unless_the_user_chose_one(tmp_path: Path) -> None:
    environ: dict[str, str] = {}
    line = apply_shipped_profile(environ, cwd=tmp_path)
    assert environ == {PROFILE_VARIABLE: str(ROOT / "launch_configs" / PROFILE_NAME)}
    assert line is not None and environ[PROFILE_VARIABLE] in line

    for users in ({PROFILE_VARIABLE: "/mine.xml"}, {"FASTDDS_DEFAULT_PROFILES_FILE": "/mine.xml"}):
        environ = dict(users)
        line = apply_shipped_profile(environ, cwd=tmp_path)
        assert environ == users and "/mine.xml" in (line or ""), "a profile the user set is kept"
    environ = {PROFILE_VARIABLE: ""}
    line = apply_shipped_profile(environ, cwd=tmp_path)
    assert environ == {} and "defaults" in (line or ""), "set empty: defaults (unset: an empty path is an error)"

    environ = {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    assert apply_shipped_profile(environ, cwd=tmp_path) is None and PROFILE_VARIABLE not in environ
    (tmp_path / dds_profile.CWD_PROFILE).write_text("<profiles/>")
    environ = {}
    assert "DEFAULT_FASTRTPS_PROFILES.xml" in (apply_shipped_profile(environ, cwd=tmp_path) or "")
    assert environ == {}


def test_the_installed_profile_is_found_in_the_ament_index(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (tmp_path / "share" / "ament_index" / "resource_index" / "packages" / "pass3d_ros").write_text("")
    installed = tmp_path / "share" / "pass3d_ros" / "config" / PROFILE_NAME
    installed.parent.mkdir(parents=True)
    installed.write_text("<profiles/>")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    assert shipped_profile() == installed
    monkeypatch.delenv("AMENT_PREFIX_PATH")
    assert shipped_profile() == ROOT / "launch_configs" / PROFILE_NAME


def test_the_installed_profile_is_found_beside_an_unsourced_install(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """colcon's layout, <prefix>/lib/pythonX.Y/site-packages/pass3d_ros/ros/, without `source install/setup.bash`."""
    import importlib.util

    module_dir = tmp_path / "lib" / "python3.12" / "site-packages" / "pass3d_ros" / "ros"
    module_dir.mkdir(parents=True)
    (module_dir / "dds_profile.py").write_text(Path(dds_profile.__file__).read_text())
    installed = tmp_path / "share" / "pass3d_ros" / "config" / PROFILE_NAME
    installed.parent.mkdir(parents=True)
    installed.write_text("<profiles/>")
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    spec = importlib.util.spec_from_file_location("installed_dds_profile", module_dir / "dds_profile.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.shipped_profile() == installed


def endpoint(reliability: ReliabilityPolicy) -> Any:
    """A stand-in for rclpy's TopicEndpointInfo."""
    return SimpleNamespace(qos_profile=SimpleNamespace(reliability=reliability))


def test_auto_qos_is_reliable_only_when_every_publisher_is() -> None:
    reliable, best_effort = endpoint(ReliabilityPolicy.RELIABLE), endpoint(ReliabilityPolicy.BEST_EFFORT)
    assert offered_qos([]) == "sensor", "no publisher yet: best effort matches any"
    assert offered_qos([reliable, reliable]) == "reliable"
    assert offered_qos([reliable, best_effort]) == "sensor"


def test_input_watch_names_the_cause_of_a_silent_input() -> None:
    watch = InputWatch("/velodyne_points", "/x/fastdds_large_clouds.xml", silent_after_s=5.0)
    assert watch.check(0.0, [], "sensor") == "", "no publisher: nothing to expect"
    assert watch.check(1.0, ["sensor"], "sensor") == ""
    problem = watch.check(6.5, ["sensor"], "sensor")
    assert "no scan for 6 s" in problem and "FASTRTPS_DEFAULT_PROFILES_FILE=/x/fastdds_large_clouds.xml" in problem
    watch.received(7.0, 10**9)
    assert watch.check(7.5, ["sensor"], "sensor") == "", "scans arrive again"
    assert "QoS mismatch" in watch.check(13.0, ["sensor"], "reliable")
    assert "input_qos auto or reliable" in watch.check(13.0, ["reliable"], "sensor")
    watch.restart(13.0)
    assert watch.check(14.0, ["reliable"], "reliable") == "", "a new subscription gets the grace period again"
    assert watch.check(30.0, ["reliable"], "reliable") == "", "both ends reliable: an idle publisher, no loss"


def feed(watch: InputWatch, start: float, frames: list[int], period: float = 0.1) -> float:
    """Scans `frames` (indices of a 10 Hz stream) arriving on time from `start`; returns the last arrival."""
    for index in frames:
        watch.received(start + index * period, 10**9 + index * int(period * 1e9))
    return start + frames[-1] * period


def test_input_watch_reports_scans_missing_between_arrivals() -> None:
    watch = InputWatch("/velodyne_points", None)
    arrived = [0, 3, 4, 9, 13, 14, 17, 19, 20]  # 9 of 21 (measured over Fast DDS defaults: 1 to 6 of 20); the last
    # arrival on time confirms the gap before it as loss (until then it may be a slower rate)
    now = feed(watch, 0.0, arrived)
    problem = watch.check(now + 0.1, ["sensor"], "sensor")
    expected = arrived[-1] - arrived[0] + 1
    assert f"{expected - len(arrived)} of the last {expected} scans missing" in problem
    assert "every 100 ms" in problem and "fastdds_large_clouds.xml" in problem
    assert watch.check(now + 12.0, [], "sensor") == "", "old arrivals leave the window"

    steady = InputWatch("/velodyne_points", None)
    jitter = np.random.default_rng(1).normal(0, 0.004, 100)
    for i in range(100):
        steady.received(i * 0.1, 10**9 + int((i * 0.1 + jitter[i]) * 1e9))
    assert steady.check(9.95, ["sensor"], "sensor") == "", "stamp jitter is no loss"
    now = feed(steady, 20.0, list(range(10)))  # a pause and a restarted bag: a new stretch, nothing missing
    assert steady.check(now, ["sensor"], "sensor") == ""
    quiet = InputWatch("/pass3d/proposals", None, count_missing=False)
    assert quiet.check(feed(quiet, 0.0, [0, 1, 5, 9, 14, 19]), ["reliable"], "reliable") == ""


def test_overlap_filter_keeps_each_copy_once_even_of_a_repeated_stamp() -> None:
    overlap = OverlapFilter()
    assert overlap.accept(0, 5) and overlap.accept(0, 5), "no switch: everything passes"
    overlap.start()
    old_then_new = [(0, 1), (1, 1), (0, 2), (0, 2), (1, 2), (1, 3), (0, 3), (1, 2), (1, 4)]
    kept = [stamp for source, stamp in old_then_new if overlap.accept(source, stamp)]
    assert kept == [1, 2, 2, 3, 4]
    overlap.stop()
    assert overlap.accept(1, 1)


def probe_node(ros: Ros, topic: str, input_qos: str) -> Any:
    """A PointCloudNode whose work is remembering each scan's stamp."""
    from pass3d_ros.msgs.pointcloud2 import header_stamp_ns
    from pass3d_ros.ros.node_base import PointCloudNode
    from pass3d_ros.ros.params import NodeParameters

    table = {"input_topic": (topic, "", None), "input_qos": (input_qos, "", None), "output_qos": ("reliable", "", None)}
    node = PointCloudNode(NodeParameters(f"probe_{os.getpid()}", table), context=ros.context)
    node.stamps = []
    node.start_worker(lambda msg: node.stamps.append(header_stamp_ns(msg)), "probe")
    return ros.add(node)


def small_cloud(stamp_ns: int) -> Any:
    from pass3d_ros.msgs.pointcloud2 import encode

    cols = {k: np.zeros(8, np.float32) for k in ("x", "y", "z", "intensity")}
    return encode(cols, stamp_ns=stamp_ns, frame_id="velodyne")


@pytest.mark.ros
def test_auto_input_follows_a_reliable_publisher_without_losing_a_scan(ros: Ros) -> None:
    import rclpy
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.qos import qos_profile

    topic = f"/auto_qos_{os.getpid()}"
    node = probe_node(ros, topic, "auto")
    assert node.subscribed_qos == "sensor", "no publisher yet"
    publisher_node = ros.add(rclpy.create_node(f"pub_{os.getpid()}", context=ros.context))
    publisher = publisher_node.create_publisher(PointCloud2, topic, qos_profile("reliable", 50))
    assert wait_until(lambda: publisher.get_subscription_count() >= 1, 10.0)
    sent = []
    for i in range(80):  # 4 s at 20 Hz: the switch to reliable (within about 1 s) happens meanwhile
        stamp = 1_000_000_000 + i * 50_000_000
        publisher.publish(small_cloud(stamp))
        sent.append(stamp)
        time.sleep(0.05)
    assert node.subscribed_qos == "reliable"
    assert wait_until(lambda: len(node.stamps) >= len(sent), 5.0)
    assert node.stamps == sent, "every scan once, in order, across the resubscription"


@pytest.mark.ros
def test_a_silent_input_is_a_warning_on_diagnostics(ros: Ros) -> None:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.qos import qos_profile

    topic = f"/silent_{os.getpid()}"
    node = probe_node(ros, topic, "reliable")
    node.input_watch.silent_after_s = 1.0
    other = ros.add(rclpy.create_node(f"other_{os.getpid()}", context=ros.context))
    other.create_publisher(PointCloud2, topic, qos_profile("sensor"))  # best effort: never matches a reliable reader
    statuses: list[Any] = []
    other.create_subscription(DiagnosticArray, "/diagnostics",
                              lambda msg: statuses.extend(s for s in msg.status if s.name == node.get_name()), 10)
    assert wait_until(lambda: any(s.level == DiagnosticStatus.WARN and "QoS mismatch" in s.message
                                  for s in statuses), 10.0), [s.message for s in statuses]
    assert "input_qos auto" in node.input_watch.problem


@pytest.mark.ros
def test_replay_waits_for_a_subscriber_by_default_and_says_so(tmp_path: Path) -> None:
    import subprocess
    import sys

    from rclpy.serialization import serialize_message

    from pass3d_ros.data.bag import BagWriter
    from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE

    bag = tmp_path / "tiny"
    writer = BagWriter(bag).open()
    writer.write_raw("/velodyne_points", POINTCLOUD2_TYPE, 10**9, serialize_message(small_cloud(10**9)))
    writer.close()
    env = {k: v for k, v in os.environ.items() if k not in dds_profile.USER_VARIABLES}
    env["ROS_DOMAIN_ID"] = str(domain())
    started = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "pass3d_ros.tools.replay", str(bag), "--publish-topic",
                             f"/nobody_{os.getpid()}", "--wait-timeout", "1.5"], capture_output=True, text=True,
                            env=env, timeout=60)
    assert result.returncode == 0, result.stderr
    assert time.monotonic() - started >= 1.5
    assert "waiting up to 1.5 s for 1 subscriber(s)" in result.stderr
    assert "0 of 1 subscriber(s) after 1.5 s; publishing anyway" in result.stderr
    assert f"Fast DDS: large-cloud profile {PROFILE_VARIABLE}=" in result.stderr
    assert "published 1 messages" in result.stdout
