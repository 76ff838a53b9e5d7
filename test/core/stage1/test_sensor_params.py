"""Stage-1 parameters that follow the sensor (pass3d_ros.core.stage1.sensor_params) and the node's intensity and ring
reports for other drivers."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.ros import STAMP0, Collector, connect, ros_session, scan_message
from rclpy.logging import LoggingSeverity
from sensor_msgs.msg import PointCloud2

from pass3d_ros.core.scan_checks import MAX_COORDINATE_M, intensity_divisor, scan_summary, unit_intensity
from pass3d_ros.core.stage1 import Stage1Config, propose
from pass3d_ros.core.stage1 import ring as ring_module
from pass3d_ros.core.stage1.ring import elevation_bins
from pass3d_ros.core.stage1.sensor_params import REFERENCE_DV_DEG, effective_config, laser_spacing, resolutions
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import decode
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.synthetic.dataset import generate_frame


@pytest.fixture(scope="module")
def hdl64_frames() -> list[Frame]:
    return [generate_frame(5, i) for i in range(3)]


def every_other_ring(frame: Frame) -> Frame:
    """A 32-laser scan: the even rings of an HDL-64E frame, renumbered 0..31."""
    keep = frame.ring % 2 == 0
    return Frame(frame.name, frame.points[keep], ring=(frame.ring[keep] // 2).astype(np.uint16),
                 labels=frame.labels[keep])


def recall_and_count(frame: Frame, config: Stage1Config) -> tuple[int, int]:
    """Foreground points inside a proposal, and foreground points."""
    result = propose(frame.points, frame.ring, config)
    fg = frame.labels > 0
    return int(np.count_nonzero(result.cluster_id[fg] >= 0)), int(np.count_nonzero(fg))


def test_hdl64e_keeps_the_papers_values(hdl64_frames: list[Frame]) -> None:
    cfg = Stage1Config()
    assert (cfg.th_num_near, cfg.th_num_range, cfg.th_num_floor, cfg.th_prop, cfg.th_ring) == (30.0, 20.0, 5, 1.0, 0.5)
    assert cfg.sensor == "auto" and cfg.sensor_scaling and cfg.seed_height == 1.73
    for frame in hdl64_frames:
        effective, scale = effective_config(cfg, frame.points, frame.ring, 64)
        assert effective is cfg and scale.density == 1.0
        assert abs(scale.vertical_deg - REFERENCE_DV_DEG) < 0.05
        result = propose(frame.points, frame.ring, cfg)
        assert result.sensor is not None and result.sensor.th_num_near == 30.0 and result.sensor.th_num_floor == 5
        off = propose(frame.points, frame.ring, Stage1Config(sensor_scaling=False))
        np.testing.assert_array_equal(result.cluster_id, off.cluster_id)
        np.testing.assert_array_equal(result.cluster_id2, off.cluster_id2)


def test_32_rings_get_a_smaller_th_num_and_a_higher_recall(hdl64_frames: list[Frame]) -> None:
    scaled = unscaled = total = 0
    for frame in map(every_other_ring, hdl64_frames):
        result = propose(frame.points, frame.ring, Stage1Config(n_rings=32))
        assert result.sensor is not None and result.sensor.n_rings == 32
        assert 0.4 < result.sensor.density < 0.6
        assert result.sensor.th_num_near < 20.0 and result.sensor.th_num_floor < 5
        assert "th_num_near" in result.sensor.describe()
        inside, n_fg = recall_and_count(frame, Stage1Config(n_rings=32))
        plain, _ = recall_and_count(frame, Stage1Config(n_rings=32, sensor_scaling=False))
        assert inside >= plain
        scaled, unscaled, total = scaled + inside, unscaled + plain, total + n_fg
    assert scaled > unscaled, (scaled, unscaled, total)


def test_a_scaled_config_is_derived_without_a_second_validation(hdl64_frames: list[Frame],
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    config = Stage1Config(n_rings=32)
    frame = every_other_ring(hdl64_frames[0])
    checked: list[Stage1Config] = []
    monkeypatch.setattr(Stage1Config, "validate", lambda self: checked.append(self))
    effective, scale = effective_config(config, frame.points, frame.ring, 32)
    assert scale.density < 0.6 and effective is not config and checked == [], "validated once, where it was made"
    assert (effective.th_num_near, effective.th_num_floor) == (scale.th_num_near, scale.th_num_floor)
    assert effective.th_num_near < config.th_num_near == 30.0 and config.th_num_floor == 5, "the given one is kept"
    assert {k: v for k, v in effective.to_dict().items() if v != config.to_dict()[k]}.keys() == {
        "th_num_near", "th_num_floor"}


def test_resolutions_of_an_empty_or_tiny_scan_are_unknown() -> None:
    vertical, horizontal = resolutions(np.zeros((1, 4), np.float32), np.zeros(1, np.uint16))
    assert np.isnan(vertical) and np.isnan(horizontal)
    effective, scale = effective_config(Stage1Config(), np.zeros((1, 4), np.float32), np.zeros(1, np.uint16), 1)
    assert scale.density == 1.0 and effective.th_num_near == 30.0


@pytest.mark.parametrize(("sensor", "lo", "hi"), [("hdl32e", 1.2, 1.45), ("vlp16", 1.8, 2.2), ("vlp32c", 0.3, 0.4)])
def test_laser_spacing_reads_the_lasers_in_any_point_order(sensor: str, lo: float, hi: float) -> None:
    points = generate_frame(3, 0, sensor).points
    spacing = laser_spacing(points)
    assert lo <= spacing <= hi, spacing  # the datasheets: 1.33, 2.0, 0.33 degrees (median gap)
    shuffled = points[np.random.default_rng(1).permutation(len(points))]
    assert laser_spacing(shuffled) == laser_spacing(points[::-1]) == spacing, "the points' order does not matter"


def test_laser_spacing_is_unknown_without_laser_lines() -> None:
    uniform = np.random.default_rng(0).uniform(-1, 1, (30000, 4)).astype(np.float32) * np.float32([40, 40, 5, 1])
    assert np.isnan(laser_spacing(uniform)), "uniform elevations hold no lasers"
    assert np.isnan(laser_spacing(uniform[:50])) and np.isnan(laser_spacing(np.zeros((0, 4), np.float32)))


def in_elevation_bins(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and their 64 elevation-bin rings in canonical order, as stage 1 holds a scan with no other rings."""
    ring = elevation_bins(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])), 64)
    order = np.lexsort((np.arctan2(points[:, 1], points[:, 0]), ring))
    return points[order], ring[order]


def test_elevation_bins_take_the_laser_spacing_not_the_bins() -> None:
    points, ring = in_elevation_bins(generate_frame(3, 0, "hdl32e").points)
    _, as_rings = effective_config(Stage1Config(), points, ring, 64)
    effective, binned = effective_config(Stage1Config(), points, ring, 64, binned=True)
    assert as_rings.vertical_deg < 0.8, "64 bins over an HDL-32E's 41 degrees: half its spacing"
    assert 1.2 <= binned.vertical_deg <= 1.45 and binned.horizontal_deg == as_rings.horizontal_deg
    assert effective.th_num_near == binned.th_num_near < as_rings.th_num_near
    uniform = np.random.default_rng(0).uniform(-1, 1, (30000, 4)).astype(np.float32) * np.float32([40, 40, 5, 1])
    points, ring = in_elevation_bins(uniform)
    assert effective_config(Stage1Config(), points, ring, 64, binned=True)[1] == \
        effective_config(Stage1Config(), points, ring, 64)[1], "no lasers read: the bins' estimate stays"


def test_a_laser_spacing_read_before_is_not_read_again(monkeypatch: pytest.MonkeyPatch) -> None:
    """Binned rings given the spacing an earlier scan read (SensorScale.spacing_deg, nan included) run as if they
    had read it themselves, without reading it; rings that are lasers read none."""
    points, ring = in_elevation_bins(generate_frame(3, 0, "hdl32e").points)
    read, scale = effective_config(Stage1Config(), points, ring, 64, binned=True)
    assert scale.spacing_deg == laser_spacing(points)
    assert effective_config(Stage1Config(), points, ring, 64)[1].spacing_deg is None

    def no_read(points: np.ndarray) -> float:
        raise AssertionError("laser_spacing read again")

    monkeypatch.setattr("pass3d_ros.core.stage1.sensor_params.laser_spacing", no_read)
    given, given_scale = effective_config(Stage1Config(), points, ring, 64, binned=True, spacing=scale.spacing_deg)
    assert given_scale == scale and given_scale.spacing_deg == scale.spacing_deg and given == read
    _, unknown = effective_config(Stage1Config(), points, ring, 64, binned=True, spacing=float("nan"))
    assert unknown == effective_config(Stage1Config(), points, ring, 64)[1], "nan: the bins' estimate stays"

def test_resolutions_read_before_are_not_read_again(hdl64_frames: list[Frame],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame given the resolutions an earlier frame read (SensorScale.resolution) runs with them, unread."""
    frame = hdl64_frames[0]
    read, scale = effective_config(Stage1Config(), frame.points, frame.ring, 64)
    assert scale.resolution == resolutions(frame.points, frame.ring)

    def no_read(points: np.ndarray, ring: np.ndarray) -> tuple[float, float]:
        raise AssertionError("resolutions read again")

    monkeypatch.setattr("pass3d_ros.core.stage1.sensor_params.resolutions", no_read)
    given, given_scale = effective_config(Stage1Config(), frame.points, frame.ring, 64, resolution=scale.resolution)
    assert given_scale == scale and given == read

def test_a_scan_whose_lines_are_not_found_runs_with_its_laser_spacing(monkeypatch: pytest.MonkeyPatch) -> None:
    """The HDL-32E frame of nuScenes: no ring field, no firing order, a line search that finds nothing."""
    points = generate_frame(3, 0, "hdl32e").points
    points = points[np.random.default_rng(2).permutation(len(points))]
    monkeypatch.setattr(ring_module, "rings_from_lines", lambda *args, **kwargs: None)
    result = propose(points)
    assert result.ring_source == "elevation_bins" and result.sensor is not None
    assert 1.2 <= result.sensor.vertical_deg <= 1.45, result.sensor.describe()


def reference_resolutions(points: np.ndarray, ring: np.ndarray, stride: int = 16) -> tuple[float, float]:
    """`resolutions` as its docstring defines it, with plain numpy arc tangents and medians."""
    i = np.arange(0, len(points) - 1, stride)
    x, y, z = (points[i, k].astype(np.float64) for k in range(3))
    x1, y1 = points[i + 1, 0].astype(np.float64), points[i + 1, 1].astype(np.float64)
    far = np.hypot(x, y) >= 2.0
    step = np.abs(np.arctan2(x * y1 - y * x1, x * x1 + y * y1))
    same = (ring[i + 1] == ring[i]) & far & (step > 0.0)
    horizontal = float(np.degrees(np.median(step[same])))
    elev, rings = np.degrees(np.arctan2(z, np.hypot(x, y)))[far], ring[i][far]
    present = np.unique(rings)
    medians = np.array([np.sort(elev[rings == k])[np.count_nonzero(rings == k) // 2] for k in present])
    return float(np.median(np.abs(np.diff(medians)) / np.diff(present))), horizontal


@pytest.mark.parametrize(("seed", "unordered"), [(0, False), (1, False), (2, True), (3, True)])
def test_resolutions_match_their_definition(seed: int, unordered: bool) -> None:
    """The kernel takes its medians over z / r and a key of each step (no arc tangent per point): the same numbers as
    the definition, with uneven rings, a missing ring, steps past 90 degrees (most of them in a ring of unordered
    azimuths, where the median step is about 90 degrees) and even and odd sample counts."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(40, 400, size=12)
    counts[5] = 0
    pts, rings = [], []
    for k, count in enumerate(counts):
        az = rng.uniform(0.0, 2.0 * np.pi, count)
        az = az if unordered else np.sort(az)
        az[::7] = rng.uniform(0.0, 2.0 * np.pi, len(az[::7]))  # steps of any size, some past 90 degrees
        r = rng.uniform(1.0, 40.0, count)
        pts.append(np.stack([r * np.cos(az), r * np.sin(az), r * np.tan(np.deg2rad(2.0 - 1.5 * k)), r], axis=1))
        rings.append(np.full(count, k, np.uint16))
    points, ring = np.concatenate(pts).astype(np.float32), np.concatenate(rings)
    np.testing.assert_allclose(resolutions(points, ring), reference_resolutions(points, ring), rtol=1e-9)


@pytest.mark.parametrize(("high", "divisor"), [(0.9, 1.0), (1.0, 1.0), (200.0, 255.0), (255.0, 255.0),
                                                (3000.0, 65535.0), (65535.0, 65535.0), (1e6, 1e6)])
def test_intensity_full_scale_is_detected(high: float, divisor: float) -> None:
    assert intensity_divisor(high) == divisor
    values = np.array([0.0, high / 2, high], np.float32)
    np.testing.assert_allclose(unit_intensity(values, divisor), values / divisor, rtol=1e-6)
    dirty = np.array([np.nan, np.inf, -np.inf, -1.0, 2 * divisor], np.float32)
    np.testing.assert_array_equal(unit_intensity(dirty, divisor), [0.0, 0.0, 0.0, 0.0, 1.0])


def _scan(intensity: list[float]) -> np.ndarray:
    points = np.ones((len(intensity), 4), np.float32)
    points[:, 3] = intensity
    return points


def test_constant_intensity_is_recognised() -> None:
    assert scan_summary(_scan([1.0] * 10)).constant_intensity()
    assert not scan_summary(_scan([0.1, 0.2])).constant_intensity()
    assert not scan_summary(_scan([1.0])).constant_intensity()
    assert not scan_summary(_scan([np.nan, np.nan])).constant_intensity()


@pytest.mark.parametrize("case", range(6))
def test_scan_summary_matches_the_numpy_checks(case: int) -> None:
    """The one-pass summary says what separate NumPy reductions say, on scans broken in each way the node checks."""
    rng = np.random.default_rng(case)
    points = rng.uniform(-80, 80, (500, 4)).astype(np.float32)
    points[:, 3] = rng.uniform(0, 1, 500)
    if case == 1:
        points[rng.integers(0, 500, 3), rng.integers(0, 3, 3)] = np.nan
    if case == 2:
        points[7, 2] = -2 * MAX_COORDINATE_M
    if case == 3:
        points[[4, 9], 3] = [np.inf, np.nan]
    if case == 4:
        points[:, 3] *= 255.0
    if case == 5:
        points[11, 0] = np.inf
    summary = scan_summary(points)
    with np.errstate(invalid="ignore"):
        assert summary.plausible == bool((np.abs(points[:, :3]) <= MAX_COORDINATE_M).all())
    finite = np.isfinite(points[:, 3])
    assert summary.nonfinite_intensity == np.count_nonzero(~finite)
    assert summary.intensity_low == points[finite, 3].min() and summary.intensity_high == points[finite, 3].max()
    assert bool(summary.intensity_problem()) == (case in (3, 4))
    scaled = summary.scaled(1 / 255)
    points[:, 3] *= np.float32(1 / 255)
    assert scaled.intensity_low == points[finite, 3].min() and scaled.intensity_high == points[finite, 3].max()


def test_node_reports_sensor_and_warns_on_intensity_and_binned_rings(
    hdl64_frames: list[Frame], capfd: pytest.CaptureFixture[str]
) -> None:
    """16-bit and constant intensity each warn once, the ring source and effective values are logged, and a scan
    whose rings cannot be recovered warns that they came from elevation bins."""
    with ros_session() as ros:
        node = ros.add(ClusterProposalNode(context=ros.context))
        node.get_logger().set_level(LoggingSeverity.INFO)  # another test may have raised the shared logger's level
        clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, clouds)
        frame = hdl64_frames[1]
        wide = Frame(frame.name, frame.points * np.array([1, 1, 1, 65535], np.float32), ring=frame.ring)
        pub.publish(scan_message(wide, STAMP0))
        out = clouds.wait(1)[0]
        np.testing.assert_allclose(decode(out)["intensity"], frame.points[:, 3], atol=1e-5)

        flat = frame.points.copy()
        flat[:, 3] = 1.0
        pub.publish(scan_message(Frame(frame.name, flat, ring=frame.ring), STAMP0 + 1))
        clouds.wait(2)

        rng = np.random.default_rng(0)
        blob = np.concatenate([rng.uniform(-30, 30, (4000, 3)), np.full((4000, 1), 0.5)], axis=1).astype(np.float32)
        pub.publish(scan_message(Frame(frame.name, blob), STAMP0 + 2, with_ring=False))
        clouds.wait(3)
    err = capfd.readouterr().err
    assert "divided by 65535" in err
    # the stream's scale settles over its first three scans; until then the flat 0..1 scan is read on its own
    assert "every point reads 1; stage 2 will have no intensity information" in err
    assert "rings from field: 64 rings" in err and "th_num_near 30" in err, err
    assert "rings could not be recovered" in err and "rings from elevation_bins" in err


def test_ring_field_limit_follows_the_sensor() -> None:
    """A 128-laser driver's ring field is plausible under "auto" (the node once threw it away above 63); a named
    sensor allows exactly its lasers."""
    from pass3d_ros.core.stage1.lasers import ring_limit

    assert ring_limit("auto", 64) == 128 and ring_limit("auto", 200) == 200
    assert ring_limit("vlp16", 64) == 16 and ring_limit("os1-128", 64) == 128
