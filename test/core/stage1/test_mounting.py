"""Mounting from the scan (issue 38): `stage1.sensor_height` auto learns the sensor's height and tilt from a stream's
ground planes, holds the median of its first scans and bounds the ground seeds from it; a number keeps today's
meaning; the cluster node reports the estimate on /diagnostics and warns when a hand-set height disagrees.

Synthetic scans (pass3d_ros.synthetic) are rendered by a VLP-32C mounted 0.6 m and 1.73 m above the road; a tilted
mount is the level scan rotated (the beams turn with the sensor).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from helpers.ros import STAMP0, Collector, Ros, connect, scan_message, wait_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from pass3d_ros.core.stage1 import Stage1Config, propose
from pass3d_ros.core.stage1.config import AUTO, ConfigError, config_from_text, parse_params
from pass3d_ros.core.stage1.mounting import (
    HEIGHT_DISAGREE_M,
    HIGH_MOUNT_M,
    MOUNTING_SCANS,
    NO_GROUND_SCANS,
    Mounting,
    problems,
    read_mounting,
)
from pass3d_ros.core.stream import MountingHolder, ScanStream
from pass3d_ros.data.frame import Frame
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.diagnostics import status_values
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.synthetic.sensor import sensor_model

HEIGHT_TOLERANCE_M = 0.05  # a held height is this close to the mount (a flat synthetic road)
TILT_TOLERANCE_DEG = 0.5  # a held roll / pitch is this close to the mount's
SCANS = MOUNTING_SCANS + 1  # the last scan runs on the held mounting


def frames_at(height: float) -> list[Frame]:
    """SCANS consecutive synthetic VLP-32C frames with the sensor `height` above the road."""
    sensor = sensor_model("vlp32c", mount_height_m=height)
    return [generate_frame(38, index, sensor) for index in range(SCANS)]


@pytest.fixture(scope="module")
def low() -> list[Frame]:
    return frames_at(0.6)


@pytest.fixture(scope="module")
def kitti_high() -> list[Frame]:
    return frames_at(1.73)


def run_stream(frames: list[Frame], config: Stage1Config, stream: ScanStream | None = None) -> tuple[ScanStream, list]:
    """Stage 1 over `frames` as one stream; the stream and each frame's result."""
    if stream is None:
        stream = ScanStream(intensity_match=False)
        stream.follow("sensor")
    results = []
    for frame in frames:
        scan = stream.prepare(frame.points, frame.ring, config)
        assert scan.kept is None
        results.append(stream.propose(scan, config))
    return stream, results


def tilted(frame: Frame, roll_deg: float, pitch_deg: float) -> Frame:
    """`frame` as a sensor rolled about x and pitched about y (REP-103: positive pitch points x down) sees it: the
    points in the rotated sensor's frame, p_sensor = R^T p_level with R = R_y(pitch) R_x(roll)."""
    r, p = math.radians(roll_deg), math.radians(pitch_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    points = frame.points.copy()
    points[:, :3] = (points[:, :3].astype(np.float64) @ (ry @ rx)).astype(np.float32)  # rows: p^T R = (R^T p)^T
    return Frame(frame.name, points, ring=frame.ring, labels=frame.labels, ground=frame.ground)


# ---- the parameter ----

def test_sensor_height_is_auto_by_default_and_takes_a_number_or_auto() -> None:
    assert Stage1Config().sensor_height == AUTO
    assert Stage1Config(sensor_height=0.6).sensor_height == 0.6
    one = Stage1Config(sensor_height=1)  # a YAML's 1 arrives as an int
    assert one.sensor_height == 1.0 and type(one.sensor_height) is float
    assert Stage1Config(sensor_height=" Auto ").sensor_height == AUTO
    assert Stage1Config().seed_height == 1.73 and Stage1Config(sensor_height=0.6).seed_height == 0.6


@pytest.mark.parametrize(("value", "message"), [
    ("tall", "sensor_height='tall' must be auto or a number in [0, 10]"),
    (True, "sensor_height=True must be auto or a number in [0, 10]"),
    (-0.5, "sensor_height=-0.5 outside [0, 10]"),
    (12.0, "sensor_height=12 outside [0, 10]"),
])
def test_any_other_value_is_refused_with_a_clear_message(value: object, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        Stage1Config(sensor_height=value)


def test_the_tools_param_reads_a_number_or_auto() -> None:
    assert parse_params(["sensor_height=0.6"]).sensor_height == 0.6
    assert parse_params(["stage1.sensor_height=auto"]).sensor_height == AUTO
    assert config_from_text([("sensor_height", "'auto'")]).sensor_height == AUTO
    with pytest.raises(ConfigError, match="sensor_height='high' must be auto or a number"):
        parse_params(["sensor_height=high"])
    with pytest.raises(ConfigError, match="sensor_height='True' must be auto or a number"):
        parse_params(["sensor_height=True"])


def test_problems_name_a_hand_set_height_off_the_estimate_and_an_upside_down_reading() -> None:
    level = Mounting(1.73, 0.5, -0.5)
    assert problems(Stage1Config(), level) == [] and problems(Stage1Config(sensor_height=1.9), level) == []
    off = problems(Stage1Config(sensor_height=1.73 + HEIGHT_DISAGREE_M + 0.2), level)
    assert len(off) == 1 and "sensor_height is 2.23 m" in off[0] and "1.73" in off[0]
    steep = Mounting(1.73, 4.0, 4.0)
    assert round(steep.tilt_deg, 1) == 5.7  # acos(cos 4 cos 4): roll, then pitch, as URDF turns
    assert problems(Stage1Config(), steep) == [], "a steady tilt is levelled, nothing to warn about"
    flipped = problems(Stage1Config(), Mounting(1.73, 180.0, 0.0))
    assert len(flipped) == 1 and "upside down" in flipped[0] and "stage1.mount" in flipped[0]
    assert problems(Stage1Config(sensor_height=0.2), None) == []


def test_a_high_mount_hears_of_range_scaling_until_it_is_on() -> None:
    high = Mounting(3.5, 0.3, -0.2)
    said = problems(Stage1Config(range_scaling=False), high)
    assert len(said) == 1 and "3.50 m above the ground" in said[0] and "stage1.range_scaling:=true" in said[0]
    assert problems(Stage1Config(), high) == [], "on by default"
    assert problems(Stage1Config(range_scaling=False), Mounting(HIGH_MOUNT_M - 0.1, 0.0, 0.0)) == []


def test_readings_that_disagree_or_no_ground_at_all_make_the_mounting_unsure(low: list[Frame]) -> None:
    holder = MountingHolder()
    for k, frame in enumerate(low[:MOUNTING_SCANS]):
        points = frame.points if k % 2 else tilted(frame, 0.0, 6.0).points  # a loose mount nodding 6 degrees
        holder.observe(points, Stage1Config())
    assert holder.held is not None
    assert len(holder.unsure()) == 1 and "disagree" in holder.unsure()[0]
    steady = MountingHolder()
    for frame in low[:MOUNTING_SCANS]:
        steady.observe(frame.points, Stage1Config())
    assert steady.held is not None and steady.unsure() == []
    sky = MountingHolder()
    wall = np.zeros((500, 4), np.float32)
    wall[:, 0], wall[:, 1] = 5.0, np.linspace(-10.0, 10.0, 500)
    for k in range(NO_GROUND_SCANS):
        assert sky.unsure() == [], k
        sky.observe(wall, Stage1Config())
    assert len(sky.unsure()) == 1 and "no ground read in 10 scans" in sky.unsure()[0]


def test_offline_tools_say_once_that_a_pitched_stream_is_levelled(capsys: pytest.CaptureFixture[str]) -> None:
    import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
    from pass3d_ros.data.spec import open_dataset
    from pass3d_ros.evaluation.offline import evaluate_stage1

    spec = "synthetic:frames=6,seed=97,sensor=vlp16,pitch=8"
    evaluate_stage1(((spec, frame) for frame in open_dataset(spec)), Stage1Config())
    err = capsys.readouterr().err
    assert err.count("the scans are levelled before stage 1") == 1, err
    pitch = float(re.search(r"pitch (-?[0-9.]+)\)", err).group(1))
    assert abs(pitch - 8.0) < 1.0, err  # the simulated road has slopes of its own


# ---- the estimate ----

@pytest.mark.parametrize("height", [0.6, 1.73])
def test_the_held_height_is_the_mounts(height: float, low: list[Frame], kitti_high: list[Frame]) -> None:
    frames = low if height == 0.6 else kitti_high
    stream, _ = run_stream(frames, Stage1Config())
    held = stream.mounting.held
    assert held is not None and stream.mounting.readings == MOUNTING_SCANS
    assert abs(held.height_m - height) < HEIGHT_TOLERANCE_M, held
    assert held.tilt_deg < 1.0, held
    assert stream.mountings == {"sensor": {**held.to_dict(), "held": True, "scans": MOUNTING_SCANS}}


def test_a_tilted_mount_reads_its_roll_and_pitch(kitti_high: list[Frame]) -> None:
    level, _ = run_stream(kitti_high, Stage1Config())
    stream, _ = run_stream([tilted(f, 3.0, -4.0) for f in kitti_high], Stage1Config())
    held, flat = stream.mounting.held, level.mounting.held
    assert held is not None and flat is not None
    assert abs((held.roll_deg - flat.roll_deg) - 3.0) < TILT_TOLERANCE_DEG, held
    assert abs((held.pitch_deg - flat.pitch_deg) + 4.0) < TILT_TOLERANCE_DEG, held
    assert abs(held.tilt_deg - 5.0) < 2 * TILT_TOLERANCE_DEG and abs(held.height_m - flat.height_m) < 0.05
    assert problems(Stage1Config(), held) == [], "a steady tilt is levelled, nothing to warn about"


def test_one_upside_down_scan_reads_its_mount_where_the_horizon_lasers_outnumber_the_road() -> None:
    """A Pandar64 upside down sees the road with its few upward lasers and everything at its own height with its dense
    horizon band: the densest plane is that band, with the road beneath it; the search looks again beneath it."""
    from pass3d_ros.data.spec import open_dataset

    frame = next(iter(open_dataset("synthetic:frames=1,seed=97,sensor=pandar64,roll=180")))
    reading = read_mounting(frame.points)
    assert reading is not None and reading.inverted, reading
    assert abs(reading.height_m - 1.73) < HEIGHT_TOLERANCE_M, reading
    assert reading.tilt_deg > 180.0 - TILT_TOLERANCE_DEG, reading


def test_an_upside_down_scan_whose_road_is_a_few_dozen_returns_reads_its_mount() -> None:
    """An RS-32 upside down: 60 of the 3,000 sampled returns lie beneath the densest plane, yet they are the road
    (the search once gave up under 100 of them, and the stream lost its first scan)."""
    from pass3d_ros.data.spec import open_dataset

    frame = next(iter(open_dataset("synthetic:frames=1,seed=97,sensor=rs32,roll=180")))
    reading = read_mounting(frame.points)
    assert reading is not None and reading.inverted, reading
    assert abs(reading.height_m - 1.73) < HEIGHT_TOLERANCE_M, reading
    assert reading.tilt_deg > 180.0 - TILT_TOLERANCE_DEG, reading


def test_the_estimate_is_held_after_the_first_scans_and_a_new_stream_starts_over(low: list[Frame]) -> None:
    stream = ScanStream(intensity_match=False)
    stream.follow("robot")
    run_stream(low[:MOUNTING_SCANS - 1], Stage1Config(), stream)
    assert stream.mounting.held is None and stream.mounting.estimate is not None
    assert stream.mountings["robot"]["held"] is False
    run_stream(low[MOUNTING_SCANS - 1:], Stage1Config(), stream)
    held = stream.mounting.held
    assert held is not None
    run_stream(low[:1], Stage1Config(), stream)
    assert stream.mounting.held is held  # held: later scans change nothing
    stream.follow("another robot")
    assert stream.mounting.held is None and stream.mounting.estimate is None


def test_a_holder_without_ground_readings_holds_nothing() -> None:
    holder = MountingHolder()
    wall = np.zeros((500, 4), np.float32)
    wall[:, 0] = 5.0
    wall[:, 1] = np.linspace(-10.0, 10.0, 500)
    wall[:, 2] = np.tile(np.linspace(-1.0, 2.0, 25), 20)  # a wall 5 m ahead: no ground under the sensor
    for _ in range(2 * MOUNTING_SCANS):
        assert holder.observe(wall, Stage1Config()) == (None, None)
    assert holder.held is None and holder.estimate is None and holder.report() is None


# ---- what stage 1 does with it ----

def same_output(a, b) -> bool:
    return (np.array_equal(a.cluster_id, b.cluster_id) and np.array_equal(a.cluster_id2, b.cluster_id2)
            and np.array_equal(a.ground, b.ground) and a.n_proposals == b.n_proposals)


def test_a_numeric_height_runs_as_before(low: list[Frame]) -> None:
    """A number is used as it is on every scan, held mounting or not: a stream gives what `propose` gives alone."""
    for config in (Stage1Config(sensor_height=1.73), Stage1Config(sensor_height=0.6)):
        _, results = run_stream(low, config)
        for frame, result in zip(low, results, strict=True):
            assert same_output(result, propose(frame.points, frame.ring, config))


def test_auto_on_a_kitti_mount_gives_the_old_default_output(kitti_high: list[Frame]) -> None:
    """Held within SEED_DEADBAND_M of 1.73 m, the seeds keep the old bound: the very output of sensor_height 1.73."""
    _, auto = run_stream(kitti_high, Stage1Config())
    _, fixed = run_stream(kitti_high, Stage1Config(sensor_height=1.73))
    assert all(same_output(a, f) for a, f in zip(auto, fixed, strict=True))


def with_mirror_returns(frame: Frame, depth: float = 1.2) -> Frame:
    """`frame` plus a wet road's mirror returns after its points: the ground points ahead (x 2..15 m, |y| < 6 m)
    again, `depth` lower, with their rings (not ground)."""
    x, y = frame.points[:, 0], frame.points[:, 1]
    mirrored = np.flatnonzero(frame.ground & (x > 2.0) & (x < 15.0) & (np.abs(y) < 6.0))
    mirror = frame.points[mirrored].copy()
    mirror[:, 2] -= depth
    ring = None if frame.ring is None else np.concatenate([frame.ring, frame.ring[mirrored]])
    return Frame(frame.name, np.concatenate([frame.points, mirror]), ring=ring,
                 ground=np.concatenate([frame.ground, np.zeros(len(mirror), bool)]))


def test_a_low_sensor_with_auto_keeps_its_ground_under_mirror_returns(low: list[Frame]) -> None:
    """A 0.6 m sensor over a wet road: mirror returns 1.2 m under the road are above KITTI's bound (2.73 m under the
    sensor) and pull the seeds down; auto, held at 0.6 m, leaves them out (1.6 m under the sensor)."""
    recall = {}
    for name, config in (("auto", Stage1Config()), ("fixed", Stage1Config(sensor_height=1.73))):
        stream, _ = run_stream(low[:MOUNTING_SCANS], config)
        wet = with_mirror_returns(low[MOUNTING_SCANS])
        scan = stream.prepare(wet.points, wet.ring, config)
        result = stream.propose(scan, config)
        n = len(low[MOUNTING_SCANS].points)
        truth = wet.ground[:n]
        recall[name] = float(np.count_nonzero(result.ground[:n] & truth) / np.count_nonzero(truth))
    assert recall["auto"] > 0.9, recall
    assert recall["auto"] > recall["fixed"] + 0.2, recall


# ---- the cluster node ----

def statuses(diagnostics: Collector, name: str) -> list[DiagnosticStatus]:
    with diagnostics.cond:
        return [s for msg in diagnostics.messages for s in msg.status if s.name == name]


@pytest.mark.ros
def test_the_node_reports_the_mounting_and_warns_on_a_hand_set_height_half_a_metre_off(
        ros: Ros, kitti_high: list[Frame]) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context,
                                       parameter_overrides=[Parameter("stage1.sensor_height", value=1.23)]))
    assert node.config.sensor_height == 1.23
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    for i, frame in enumerate(kitti_high):
        pub.publish(scan_message(frame, STAMP0 + i * 100_000_000))
        assert wait_until(lambda i=i: node.worker.counters.processed == i + 1 and node.worker.idle(), timeout=20.0)
    held = node.stream.mounting.held
    assert held is not None and abs(held.height_m - 1.73) < HEIGHT_TOLERANCE_M

    def warned() -> list[DiagnosticStatus]:
        return [s for s in statuses(diagnostics, node.get_name())
                if s.level == DiagnosticStatus.WARN and "sensor_height is 1.23 m" in s.message]

    assert wait_until(lambda: bool(warned()), timeout=5.0), [s.message for s in statuses(diagnostics, node.get_name())]
    values = status_values(warned()[-1])
    assert values["mounting"] == "held"
    assert abs(values["sensor_height_m"] - 1.73) < HEIGHT_TOLERANCE_M and values["sensor_tilt_deg"] < 1.0
    assert {"sensor_roll_deg", "sensor_pitch_deg"} <= set(values)

    # auto (a string over the double) is taken at run time and the warning goes; any other word is refused
    assert node.set_parameters([Parameter("stage1.sensor_height", value="auto")])[0].successful
    assert node.config.sensor_height == AUTO
    refused = node.set_parameters([Parameter("stage1.sensor_height", value="tall")])[0]
    assert not refused.successful and "must be auto or a number" in refused.reason
    assert not node.set_parameters([Parameter("stage1.sensor_height", value=11.0)])[0].successful
    changed = len(statuses(diagnostics, node.get_name()))
    assert wait_until(lambda: any("mounting:" not in s.message and status_values(s)["mounting"] == "held"
                                  for s in statuses(diagnostics, node.get_name())[changed:]), timeout=5.0)
