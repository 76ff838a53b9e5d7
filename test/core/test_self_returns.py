"""The vehicle's own returns (pass3d_ros.core.self_returns): returns that stay put near the sensor while the scene
changes are the body, and their radius becomes stage1.min_range; a still vehicle, too few scans or returns that come
and go read nothing. Read by pass3d_adapt over a recording, and by a stream with stage1.min_range auto."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pass3d_ros.adapt.sensor import read_sensor
from pass3d_ros.core import self_returns
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage1.config import AUTO, ConfigError
from pass3d_ros.core.stream import BodyHolder, ScanStream, body
from pass3d_ros.data.frame import Frame
from pass3d_ros.ros.diagnostics import status_values
from pass3d_ros.synthetic.dataset import generate_frame

BODY_HEIGHT_M = -0.4  # a roof 0.4 m below the sensor, 3.2 m x 1.6 m around it


def _body(rng: np.random.Generator) -> np.ndarray:
    """The roof's returns: the same grid every scan, with 1 cm of range noise."""
    x, y = np.meshgrid(np.linspace(-1.6, 1.6, 33), np.linspace(-0.8, 0.8, 17))
    xyz = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, BODY_HEIGHT_M)])
    xyz = xyz[np.hypot(xyz[:, 0], xyz[:, 1]) > 0.6]
    xyz *= 1.0 + rng.normal(0.0, 0.01, (len(xyz), 1)) / np.linalg.norm(xyz, axis=1, keepdims=True)
    return np.column_stack([xyz, np.full(len(xyz), 0.2)]).astype(np.float32)


def _with_body(frame: Frame, body: np.ndarray | None) -> Frame:
    points = frame.points if body is None else np.vstack([frame.points, body])
    return dataclasses.replace(frame, points=points, ring=None, labels=None, ground=None, instance=None,
                               vehicle_other=None)


def _recording(scans: int, body: bool = True, still: bool = False, every: int = 1) -> list[tuple[str, Frame]]:
    """`scans` synthetic VLP-16 scans of a drive (or one scan again and again: `still`), a body in every `every`-th."""
    rng = np.random.default_rng(3)
    frames = [generate_frame(seed=23, index=0 if still else i, sensor="vlp16") for i in range(scans)]
    return [("rec", _with_body(f, _body(rng) if body and i % every == 0 else None)) for i, f in enumerate(frames)]


def test_a_body_that_stays_put_while_the_scene_moves_is_read_as_a_radius():
    recording = _recording(8)
    reading = read_sensor(recording, Stage1Config()).self_returns
    corner = float(np.linalg.norm([1.6, 0.8, BODY_HEIGHT_M]))
    assert reading.cells >= self_returns.MIN_CELLS and reading.scans == 8
    assert corner < reading.radius_m <= corner + 2 * self_returns.MARGIN_M + 0.1, reading
    body = _body(np.random.default_rng(0))
    assert np.all(np.linalg.norm(body[:, :3], axis=1) < reading.radius_m)
    assert reading.scene_persistent is not None and reading.scene_persistent < self_returns.STILL_SHARE
    assert "return from the same place" in reading.note


def test_a_recording_without_a_body_reads_none():
    reading = read_sensor(_recording(8, body=False), Stage1Config()).self_returns
    assert reading.radius_m == 0.0 and reading.note == "no returns of the vehicle's own body", reading


@pytest.mark.parametrize(("kwargs", "note"), [
    ({"scans": self_returns.MIN_SCANS - 1}, f"{self_returns.MIN_SCANS} or more are needed"),
    ({"scans": 6, "still": True}, "the vehicle stood still"),
    ({"scans": 8, "every": 2}, "no returns of the vehicle's own body"),  # in half the scans: not the body
])
def test_what_cannot_be_told_from_the_scene_reads_nothing(kwargs, note):
    reading = read_sensor(_recording(**kwargs), Stage1Config()).self_returns
    assert reading.radius_m == 0.0 and note in reading.note, reading


@pytest.mark.parametrize("roof", [False, True])
def test_returns_on_the_ground_near_the_sensor_are_not_the_body(roof):
    """The road around a level sensor comes back at the same ranges in every scan too, and stage 1 may leave its
    nearest ring out of the ground: returns less than ABOVE_GROUND_M above the ground it found do not count (a roof
    twice that height above it does)."""
    reader = self_returns.SelfReturnReader()
    turn = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    road = [np.column_stack([r * np.cos(turn), r * np.sin(turn), np.full(360, -1.7), np.zeros(360)]) for r in (3, 6)]
    top = np.column_stack([np.full(20, 1.0), np.linspace(-0.5, 0.5, 20), np.full(20, -1.7 + 2 * 0.25), np.zeros(20)])
    for k in range(6):
        scene = np.column_stack([np.full(50, 20.0 + 3 * k), np.linspace(-5, 5, 50), np.zeros(50), np.zeros(50)])
        parts = [*road, scene] + ([top] if roof else [])
        marked = np.zeros(sum(len(p) for p in parts), dtype=bool)
        marked[360:720] = True  # stage 1's ground: the far ring only
        reader.add(np.vstack(parts), marked)
    reading = reader.read()
    assert (reading.radius_m > 0.0) == roof, reading
    assert roof or reading.note == "no returns of the vehicle's own body"


def test_pass3d_adapt_leaves_the_body_out_and_writes_its_radius_for_the_nodes(tmp_path, monkeypatch):
    """End to end: the radius read is stage1.min_range in the parameter file (the nodes' parameter), said in the
    report; the checks ran without the body (the sensor read again). Asked for auto, the tool reads the recording
    whole and writes the number."""
    import json

    import yaml

    from pass3d_ros.data.semantickitti import write_semantickitti_frame
    from pass3d_ros.tools import adapt

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))
    seq = tmp_path / "drive"
    for _, frame in _recording(10):
        write_semantickitti_frame(seq, frame)
    out = tmp_path / "mine"
    assert adapt.main(["--data", f"semantickitti:{seq}", "--out", str(out), "--minutes", "2", "--draws", "1",
                       "--guard-scenes", "2", "--anchor-frames", "4", "--epochs", "1", "--no-progress",
                       "--threads", "1", "--param", "stage1.min_range=auto"]) == 0
    report = json.loads((out / "report.json").read_text())
    radius = report["sensor"]["self_returns"]["radius_m"]
    assert radius > 1.5, report["sensor"]["self_returns"]
    params = yaml.safe_load((out / "pass3d_params.yaml").read_text())
    assert params["/**/cluster_proposal_node"]["ros__parameters"]["stage1"]["min_range"] == radius
    assert f"left out nearer than {radius:.1f} m" in (out / "report.md").read_text()
    assert report["sensor"]["bottom_deg"] > -16.0, "the sensor was read with the body in it"


def _simple_scan(k: int, still: bool) -> tuple[np.ndarray, np.ndarray]:
    """A cheap scan: a ground ring at 6 m (marked ground), a wall that moves 3 m a scan unless `still`, a roof grid
    0.5 m above the ground within 2 m of the sensor."""
    turn = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    road = np.column_stack([6 * np.cos(turn), 6 * np.sin(turn), np.full(360, -1.7), np.zeros(360)])
    wall = np.column_stack([np.full(50, 20.0 + (0 if still else 3 * k)), np.linspace(-5, 5, 50), np.zeros(50),
                            np.zeros(50)])
    roof = np.column_stack([np.full(20, 1.5), np.linspace(-0.5, 0.5, 20), np.full(20, -1.2), np.zeros(20)])
    points = np.vstack([road, wall, roof]).astype(np.float32)
    return points, np.arange(len(points)) < 360


def test_min_range_takes_a_number_or_auto_and_stays_0_by_default():
    assert Stage1Config().min_range == 0.0 and Stage1Config(min_range=" Auto ").min_range == AUTO
    with pytest.raises(ConfigError, match="min_range='near' must be auto or a number in"):
        Stage1Config(min_range="near")


def test_a_body_holder_waits_while_the_vehicle_stands_and_reads_once_it_moves():
    now = [0.0]
    holder = BodyHolder(clock=lambda: now[0])
    for k in range(2 * body.WINDOW):  # standing: every window reads a still scene, nothing is held
        assert holder.observe(*_simple_scan(k, still=True)) is None
        now[0] += body.SAMPLE_EVERY_S
    assert holder.held is None and holder.radius_m == 0.0
    decided = None
    for k in range(body.WINDOW):  # driving: once the still scans are dropped, the roof is read
        decided = decided or holder.observe(*_simple_scan(k, still=False))
        now[0] += body.SAMPLE_EVERY_S
    assert decided is not None and holder.held is decided
    corner = float(np.linalg.norm([1.5, 0.5, -1.2]))
    assert corner < holder.radius_m <= corner + 2 * self_returns.MARGIN_M, decided
    assert holder.observe(*_simple_scan(0, still=False)) is None, "held: no more reading"


def test_a_body_holder_offers_a_scan_every_half_second_of_the_stream():
    """Offline (no clock) each scan is one revolution at 10 Hz: one scan in five is read, so a window takes five
    times as many scans; a live clock that runs faster than that offers fewer."""
    holder = BodyHolder()
    every = round(body.SAMPLE_EVERY_S / body.OFFLINE_SCAN_S)
    for k in range(every * (body.WINDOW - 1) + 1):
        holder.observe(*_simple_scan(k, still=False))
        assert (holder.held is not None) == (k == every * (body.WINDOW - 1)), k
    holder.reset()
    assert holder.held is None and holder.radius_m == 0.0


def test_a_stream_with_min_range_auto_leaves_the_body_out_once_read():
    """stage1.min_range auto on a stream of the synthetic drive with a roof: the first scans keep the roof, and once
    the reading is held every scan is prepared without it; min_range 0 keeps it for good."""
    recording = _recording(body.WINDOW + 1)
    now = [0.0]
    auto = ScanStream(clock=lambda: now[0])
    fixed = ScanStream(clock=lambda: now[0])
    config = Stage1Config(min_range=AUTO)
    for _, frame in recording[:-1]:
        assert np.linalg.norm(auto.prepare(frame.points, None, config).points[:, :3], axis=1).min() < 1.5
        auto.propose(auto.prepare(frame.points, None, config), config)
        fixed.propose(fixed.prepare(frame.points), Stage1Config())
        now[0] += body.SAMPLE_EVERY_S
    assert auto.body.held is not None and fixed.body.held is None
    radius = auto.min_range(config)
    assert radius == auto.body.radius_m > np.linalg.norm([1.6, 0.8, BODY_HEIGHT_M])
    last = recording[-1][1].points
    kept = auto.prepare(last, None, config)
    assert np.linalg.norm(kept.points[:, :3], axis=1).min() >= radius
    assert len(kept.points) == np.count_nonzero(np.linalg.norm(last[:, :3], axis=1) >= radius)
    assert len(fixed.prepare(last).points) == len(last)
    auto.follow("another")
    assert auto.body.held is None and auto.min_range(config) == 0.0, "a new stream reads its own"


@pytest.mark.ros
def test_the_node_with_min_range_auto_reads_the_body_says_so_and_leaves_it_out(ros, monkeypatch):
    """cluster_proposal_node with stage1.min_range auto (every scan offered here): once the window is read it logs
    the reading, reports the radius on /diagnostics and publishes the next scans without the body."""
    from diagnostic_msgs.msg import DiagnosticArray
    from helpers.ros import STAMP0, Collector, columns, connect, scan_message, wait_until
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
    from pass3d_ros.ros.qos import qos_profile

    monkeypatch.setattr(body, "SAMPLE_EVERY_S", 0.0)
    node = ros.add(ClusterProposalNode(context=ros.context,
                                       parameter_overrides=[Parameter("stage1.min_range", value="auto")]))
    assert node.config.min_range == AUTO
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    diagnostics = Collector(ros, DiagnosticArray, "/diagnostics")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    recording = _recording(body.WINDOW + 1)
    for i, (_, frame) in enumerate(recording):
        pub.publish(scan_message(frame, STAMP0 + i * 100_000_000))
        assert wait_until(lambda i=i: node.worker.counters.processed == i + 1 and node.worker.idle(), timeout=20.0)
    held = node.stream.body.held
    assert held is not None and held.radius_m > np.linalg.norm([1.6, 0.8, BODY_HEIGHT_M])
    assert wait_until(lambda: len(clouds.messages) == len(recording), timeout=10.0)
    first, last = (columns(clouds.messages[k]) for k in (0, -1))
    ranges = [np.sqrt(c["x"].astype(float) ** 2 + c["y"].astype(float) ** 2 + c["z"].astype(float) ** 2)
              for c in (first, last)]
    assert ranges[0].min() < 1.5 and ranges[1].min() >= held.radius_m

    def reported() -> bool:
        with diagnostics.cond:
            found = [status_values(st) for msg in diagnostics.messages for st in msg.status
                     if st.name == node.get_name()]
        return any(v.get("min_range_m") == held.radius_m for v in found)

    assert wait_until(reported, timeout=5.0)
