"""The few-points gate per range (Stage1Config.range_scaling; pass3d_ros.core.stage1.sensor_params.RangeGate): the
lasers that cross a person-tall object at each range, against KITTI's HDL-64E at 1.73 m."""

from __future__ import annotations

import numpy as np
import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers the synthetic: format)
from pass3d_ros.classes import PEDESTRIAN
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config, propose
from pass3d_ros.core.stage1.lasers import LASER_TABLES
from pass3d_ros.core.stage1.mounting import Mounting, level_rotation
from pass3d_ros.core.stage1.refinement import points_needed
from pass3d_ros.core.stage1.sensor_params import (
    MIN_RING_SAMPLES,
    PEAK_MIN_RANGE,
    RANGE_STEP_M,
    RangeGate,
    SensorScale,
    effective_config,
    lasers_across,
    level_elevations,
    range_gate,
    ring_elevations,
)
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import resolve_dataset

EDGES = np.array([-80.0, 80.0])


def flat_ground(height: float) -> np.ndarray:
    """One plane `height` below the sensor (a x + b y + c z + d = 0, normal up)."""
    return np.array([[0.0, 0.0, 1.0, height]])


def scale_of(elevations: np.ndarray | tuple[float, ...], median_gap: float = 1.0) -> SensorScale:
    """A frame's SensorScale holding only what range_gate reads: the lasers and the median-gap vertical factor."""
    return SensorScale(len(elevations), float("nan"), float("nan"), median_gap, 30.0, 5, 1.0,
                       elevations_deg=np.asarray(elevations, dtype=np.float64), vertical_factor=median_gap)


def frames(spec: str) -> list[Frame]:
    return list(resolve_dataset(spec).frames())


@pytest.fixture(scope="module")
def high_vlp32c() -> list[Frame]:
    return frames("synthetic:sensor=vlp32c,frames=2,seed=11,height=3.5")


def test_the_hdl64e_at_its_height_keeps_the_papers_gate_at_every_range() -> None:
    gate = range_gate(scale_of(LASER_TABLES["hdl64e"]), flat_ground(1.73), EDGES)
    assert gate is not None and np.all(gate.factor == 1.0)


def test_a_high_vlp32c_sees_a_person_with_few_lasers() -> None:
    vlp32c = LASER_TABLES["vlp32c"]
    high = range_gate(scale_of(vlp32c), flat_ground(3.5), EDGES)
    level = range_gate(scale_of(vlp32c), flat_ground(1.73), EDGES)
    assert high is not None and level is not None
    at15 = np.array([15.0])
    assert lasers_across(np.asarray(vlp32c), 3.5)[int(15.0 / RANGE_STEP_M)] == 3  # -7.254, -8.843, -11.31 degrees
    assert high.at(at15)[0] < 0.25
    assert level.at(at15)[0] == 1.0  # level, its dense middle lasers cover a person 15 m away as the HDL-64E's do
    assert np.all((high.factor > 0.0) & (high.factor <= 1.0))


def test_a_level_sensor_keeps_its_median_gap_factor() -> None:
    """A level HDL-32E's laser counts differ from its median gap's factor (0.32) by quantization only: no range within
    max_range is replaced, so its gate is today's."""
    hdl32e = np.asarray(LASER_TABLES["hdl32e"])
    median_gap = 0.42 / (4.0 / 3.0)  # REFERENCE_DV_DEG over its 1.333-degree gap
    gate = range_gate(scale_of(hdl32e, median_gap), flat_ground(1.73), EDGES)
    assert gate is not None
    within = gate.at(np.arange(0.5, Stage1Config().max_range, RANGE_STEP_M))
    np.testing.assert_array_equal(within, 1.0)  # th_num_near holds the median-gap factor
    high = range_gate(scale_of(hdl32e, median_gap), flat_ground(3.5), EDGES)
    assert high is not None and high.at(np.array([3.0]))[0] < 0.5  # 3 m from a 3.5 m mast: one laser


def test_the_gate_scales_th_num_near_by_its_factor_and_keeps_the_floor() -> None:
    config = Stage1Config()
    rng = np.array([5.0, 15.0, 40.0])
    gate = RangeGate(np.full(400, 0.1))
    np.testing.assert_allclose(points_needed(rng, config, gate), np.maximum(5, [3.0, 3.0, 1.5]))
    np.testing.assert_allclose(points_needed(rng, config), [30.0, 30.0, 15.0])


def test_ring_elevations_read_the_lasers(high_vlp32c: list[Frame]) -> None:
    frame = high_vlp32c[0]
    read = ring_elevations(frame.points, frame.ring)
    table = np.sort(np.asarray(LASER_TABLES["vlp32c"]))
    assert len(read) >= 16
    nearest = np.abs(read[:, None] - table[None, :]).min(axis=1)
    assert np.all(nearest < 0.3), nearest


def test_ring_elevations_are_each_rings_lower_median_of_the_far_sample() -> None:
    """Each ring with MIN_RING_SAMPLES or more sampled points at PEAK_MIN_RANGE or farther gives the lower median of
    their elevations, in ring order (a reference by sorting); rings with fewer, and near points, give nothing."""
    rng = np.random.default_rng(5)
    n = 16 * 400
    ring = rng.integers(0, 12, n).astype(np.uint16)
    ring[ring == 7] = 3  # no ring 7
    ring[np.flatnonzero(ring == 9)[MIN_RING_SAMPLES * 16 - 40:]] = 2  # ring 9 left a few samples only
    horizontal = rng.uniform(0.5 * PEAK_MIN_RANGE, 4 * PEAK_MIN_RANGE, n)
    angle = rng.uniform(-np.pi, np.pi, n)
    z = np.round(horizontal * np.tan(np.radians(-20.0 + 2.0 * ring + rng.normal(0, 0.2, n))), 2)  # ties too
    points = np.column_stack([horizontal * np.cos(angle), horizontal * np.sin(angle), z, np.zeros(n)])
    points = points.astype(np.float32)
    sample, rings = points[::16].astype(np.float64), ring[::16]
    h = np.hypot(sample[:, 0], sample[:, 1])
    far = h >= PEAK_MIN_RANGE
    elevation, rings = np.degrees(np.arctan2(sample[far, 2], h[far])), rings[far]
    want = [np.sort(elevation[rings == k])[(np.count_nonzero(rings == k) - 1) // 2] for k in range(12)
            if np.count_nonzero(rings == k) >= MIN_RING_SAMPLES]
    assert len(want) == 10  # rings 7 and 9 give none
    np.testing.assert_array_equal(ring_elevations(points, ring), want)
    assert len(ring_elevations(points[:0], ring[:0])) == 0


def test_effective_config_reads_the_lasers_for_the_gate(high_vlp32c: list[Frame]) -> None:
    frame = high_vlp32c[0]
    cfg, scale = effective_config(Stage1Config(range_scaling=True), frame.points, frame.ring, 32)
    assert scale.elevations_deg is not None and len(scale.elevations_deg) >= 16
    assert cfg.th_num_near == scale.th_num_near == pytest.approx(max(1.0, 30.0 * scale.density))  # as before
    assert scale.vertical_factor >= scale.density  # density's vertical part
    _, off = effective_config(Stage1Config(range_scaling=False), frame.points, frame.ring, 32)
    assert off.elevations_deg is None
    _, binned = effective_config(Stage1Config(range_scaling=True), frame.points, frame.ring, 32, binned=True)
    assert binned.elevations_deg is None, "elevation bins are no lasers: the median-gap factor stays"


def test_range_scaling_keeps_the_hdl64e_proposals() -> None:
    for frame in frames("synthetic:frames=2,seed=11"):
        on = propose(frame.points, frame.ring, Stage1Config(range_scaling=True))
        off = propose(frame.points, frame.ring, Stage1Config(range_scaling=False))
        assert on.sensor is not None and on.sensor.elevations_deg is not None
        np.testing.assert_array_equal(on.cluster_id, off.cluster_id)


def test_range_scaling_finds_the_people_a_high_vlp32c_sees(high_vlp32c: list[Frame]) -> None:
    found = {False: 0, True: 0}
    total = 0
    for frame in high_vlp32c:
        people = frame.labels == PEDESTRIAN
        total += int(people.sum())
        for on in found:
            result = propose(frame.points, frame.ring, Stage1Config(range_scaling=on, sensor_height=3.5))
            found[on] += int(np.count_nonzero(result.cluster_id[people] >= 0))
    assert total > 0
    assert found[True] >= found[False] + 0.2 * total, (found, total)


def test_a_tilted_sensors_lasers_are_counted_where_they_point() -> None:
    """Rolled 10 degrees, a VLP-32C's dense middle lasers run 10 degrees above the horizon on one side and below it on
    the other: on the high side a person 15 m away is crossed by its sparse lasers and the gate falls there; on the
    low side its dense lasers cross them and the median-gap factor stays."""
    vlp32c = np.asarray(LASER_TABLES["vlp32c"])
    flat = level_elevations(vlp32c, np.eye(3))
    np.testing.assert_allclose(flat, np.broadcast_to(vlp32c, flat.shape), atol=1e-9)
    rolled = level_rotation(Mounting(1.73, 10.0, 0.0), given=True)
    turned = level_elevations(vlp32c, rolled)
    horizon = turned[:, int(np.argmin(np.abs(vlp32c)))]  # the 0-degree laser, sector by sector
    assert horizon.max() == pytest.approx(10.0, abs=0.6) and horizon.min() == pytest.approx(-10.0, abs=0.6)
    gate = range_gate(scale_of(vlp32c), flat_ground(1.73), EDGES, rolled)
    assert gate is not None and gate.factor.shape[0] == len(turned)
    at15 = gate.factor[:, int(15.0 / RANGE_STEP_M)]
    assert at15.min() < 0.5 and at15.max() == 1.0
    azimuths = np.linspace(-np.pi, np.pi, len(turned), endpoint=False) + np.pi / len(turned)
    xy = np.column_stack([np.cos(azimuths), np.sin(azimuths)])
    np.testing.assert_array_equal(gate.at(np.full(len(turned), 15.0), xy), at15)


def test_a_sensor_denser_than_the_hdl64e_keeps_its_gate() -> None:
    """An OS2-128's lasers are 0.17 degrees apart and its points 0.35: its median-gap factor is 2.5 x 0.48 = 1.2 of
    the HDL-64E's, capped at 1 as a whole; read per range its lasers are never under half, so its gate stays."""
    os2 = np.linspace(11.25, -11.25, 128)
    gate = range_gate(scale_of(os2, median_gap=2.07), flat_ground(1.7), EDGES)
    assert gate is not None
    np.testing.assert_array_equal(gate.at(np.arange(0.5, Stage1Config().max_range, RANGE_STEP_M)), 1.0)


def test_range_scaling_finds_the_people_a_pitched_vlp32c_sees() -> None:
    found = {False: 0, True: 0}
    total = 0
    for on in found:
        pipeline = ScanPipeline(Stage1Config(range_scaling=on), intensity_match=False)
        for frame in frames("synthetic:sensor=vlp32c,frames=2,seed=11,pitch=10"):
            people = frame.labels == PEDESTRIAN
            total += int(people.sum()) if on else 0
            proposed = pipeline.propose(frame.points, frame.ring)
            ids = proposed.in_input(proposed.result.cluster_id, len(frame.points), -1)
            found[on] += int(np.count_nonzero(ids[people] >= 0))
    assert total > 0
    assert found[True] >= found[False] + 0.15 * total, (found, total)
