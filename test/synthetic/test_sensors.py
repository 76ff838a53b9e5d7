"""Sensor models of the synthetic generator: ring counts, elevation spreads, driver point order, the spec, the
unchanged KITTI default and stage 1 on a VLP-16 scan."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1 import lasers, propose
from pass3d_ros.data.spec import DatasetError, open_dataset
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.synthetic.sensor import SENSOR_NAMES, driver_intensity, sensor_model
from pass3d_ros.synthetic.specs import parse_synthetic_spec

# Stage-1 foreground recall on VLP-16 frames 0-2 of seed 3 measured 0.66 (per frame 0.39 / 0.53 / 0.97: one car
# behind another loses most of its few rings); the floor leaves room for scene tuning, not for a broken pipeline.
RECALL_FLOOR_VLP16 = 0.5


@pytest.fixture(scope="module")
def frame_per_sensor() -> dict:
    return {name: generate_frame(3, 0, sensor_model(name)) for name in SENSOR_NAMES}


def _elevation_deg(frame, sensor) -> np.ndarray:
    """Elevation of every point seen from its laser's firing point."""
    xyz = frame.points[:, :3].astype(np.float64)
    z = xyz[:, 2] - sensor.vertical_offset_m[frame.ring]
    return np.rad2deg(np.arctan2(z, np.hypot(xyz[:, 0], xyz[:, 1])))


@pytest.mark.parametrize("name", SENSOR_NAMES)
def test_sensor_frame_has_every_ring_labels_and_unit_intensity(frame_per_sensor, name):
    frame, sensor = frame_per_sensor[name], sensor_model(name)
    assert sensor.n_lasers == len(lasers.LASER_TABLES[name])
    assert int(frame.ring.max()) + 1 == sensor.n_lasers and len(np.unique(frame.ring)) == sensor.n_lasers
    assert frame.points[:, 3].min() >= 0.0 and frame.points[:, 3].max() <= 1.0
    assert set(np.unique(frame.labels)) >= {0, 1} and frame.ground.any()
    assert len(frame.boxes) > 0


@pytest.mark.parametrize("name", SENSOR_NAMES)
def test_ring_elevations_follow_the_laser_table(frame_per_sensor, name):
    """Median elevation of each ring's points lies within 0.1 degrees of the model's angle, which is the laser
    table's (KITTI's HDL-64E: its fitted lines, within 0.75 degrees of the S2 manual's table)."""
    frame, sensor, table = frame_per_sensor[name], sensor_model(name), np.asarray(lasers.LASER_TABLES[name])
    tolerance = 0.75 if name == "hdl64e" else 1e-9
    assert np.abs(sensor.elevation_deg - table).max() <= tolerance
    far = np.linalg.norm(frame.points[:, :2], axis=1) > 5.0
    elev = _elevation_deg(frame, sensor)
    for ring in np.unique(frame.ring[far]):
        sel = far & (frame.ring == ring)
        if sel.sum() >= 20:
            assert abs(np.median(elev[sel]) - sensor.elevation_deg[ring]) < 0.1, (name, ring)


@pytest.mark.parametrize("name", ["os1-64", "pandar64", "vlp16", "os1-32", "pandar40", "pandar40p", "pandarxt32",
                                  "rs32"])
def test_driver_point_order(frame_per_sensor, name):
    """Hesai, RoboSense and Velodyne drivers: column after column (firing order; a RoboSense column's points spread
    over its lasers' azimuth offsets); Ouster: an organized cloud, row (ring) after row, each sweeping clockwise."""
    frame, sensor = frame_per_sensor[name], sensor_model(name)
    az = np.arctan2(frame.points[:, 1], frame.points[:, 0])
    if sensor.azimuth_offset_deg:  # the column's azimuth: each laser points its offset away from it
        az = az - np.deg2rad(np.asarray(sensor.azimuth_offset_deg))[frame.ring]
    if sensor.point_order == "row":
        assert np.all(np.diff(frame.ring.astype(int)) >= 0)
        first = frame.ring == 0
        step = np.angle(np.exp(1j * np.diff(az[first])))
        assert np.mean(step < 0.0) > 0.99  # clockwise
    else:
        turns = np.angle(np.exp(1j * np.diff(az)))
        assert np.mean(np.abs(turns) < np.deg2rad(1.0)) > 0.99  # neighbours come from the same or the next column
        assert len(np.unique(frame.ring[:200])) > 4  # lasers interleave, not ring after ring
        rank = {ring: k for k, ring in enumerate(sensor.firing_order or range(sensor.n_lasers))}
        ranks = np.array([rank[r] for r in frame.ring[:2000]])
        same_col = np.abs(np.angle(np.exp(1j * np.diff(az[:2000])))) < 1e-3
        assert np.all(np.diff(ranks)[same_col] > 0)  # within a column, the driver's firing order


# The sensors added from laser tables: (lasers, driver).
ZOO = {"os1-32": (32, "ouster"), "pandar40": (40, "hesai"), "pandar40p": (40, "hesai"), "pandarxt32": (32, "hesai"),
       "rs32": (32, "robosense")}


@pytest.mark.parametrize("name", ZOO)
def test_zoo_sensor_has_its_tables_lasers_and_its_drivers_rings(frame_per_sensor, name):
    """Every laser of the table gives a ring; the ring field is the driver's numbering (Hesai's channel index and
    Ouster's row: 0 the top laser, so the rings' elevations fall with the number); Hesai columns list their channels
    1..N top down (the UDP block layout), RoboSense blocks theirs in the calibration file's channel order (not by
    angle), Ouster rows sweep clockwise from the back (an organized cloud); intensity on the driver's scale (Hesai and
    RoboSense 0..255, Ouster 16-bit)."""
    frame, sensor = frame_per_sensor[name], sensor_model(name)
    count, driver = ZOO[name]
    assert sensor.n_lasers == count == len(lasers.LASER_TABLES[name]) and sensor.driver == driver
    assert np.array_equal(np.unique(frame.ring), np.arange(count))
    far = np.linalg.norm(frame.points[:, :2], axis=1) > 5.0
    elev = _elevation_deg(frame, sensor)
    medians = [np.median(elev[far & (frame.ring == r)]) for r in range(count) if np.sum(far & (frame.ring == r)) > 20]
    assert np.all(np.diff(medians) < 0.0)
    ring = frame.ring.astype(int)
    if driver == "hesai":
        same_column = np.diff(ring) > 0
        assert np.mean(same_column) > 0.9  # within a column the channel index only rises: top laser first
        assert driver_intensity(sensor, np.float32([1.0]))[0] == 255.0
    elif driver == "robosense":
        assert np.mean(np.diff(ring) > 0) < 0.7  # a block's channels are not listed top down
        az = np.degrees(np.arctan2(frame.points[:, 1], frame.points[:, 0]))
        spread = [np.ptp(np.unwrap(az[k:k + 32], period=360.0)) for k in range(0, 3200, 32)]
        assert np.median(spread) > 14.0  # a block's points spread over the lasers' azimuth offsets (16 degrees)
        assert driver_intensity(sensor, np.float32([1.0]))[0] == 255.0
    else:
        assert np.all(np.diff(ring) >= 0)  # row after row
        assert driver_intensity(sensor, np.float32([1.0]))[0] == 65535.0


def test_default_sensor_is_unchanged():
    """No sensor, the hdl64e name and the hdl64e model give the same bytes (KITTI's HDL-64E, as before)."""
    for seed in (7, 99):
        base = generate_frame(seed, 0)
        for sensor in ("hdl64e", sensor_model("hdl64e")):
            other = generate_frame(seed, 0, sensor)
            assert other.points.tobytes() == base.points.tobytes()
            assert other.ring.tobytes() == base.ring.tobytes() and other.labels.tobytes() == base.labels.tobytes()


def test_spec_parses_sensor():
    spec = parse_synthetic_spec("sensor=VLP16,frames=2,seed=5")
    assert spec == {"frames": 2, "seed": 5, "start": 0, "sensor": "vlp16", "height": None, "roll": 0.0, "pitch": 0.0,
                    "without": frozenset()}
    assert parse_synthetic_spec("frames=1,without=dark+clutter")["without"] == frozenset({"dark", "clutter"})
    assert parse_synthetic_spec("frames=1")["sensor"] == "hdl64e"
    with pytest.raises(DatasetError, match="unknown sensor"):
        parse_synthetic_spec("sensor=hdl128")
    frame = next(iter(open_dataset("synthetic:sensor=vlp16,frames=1,seed=5")))
    assert frame.points.tobytes() == generate_frame(5, 0, "vlp16").points.tobytes()


def test_mount_height_and_driver_intensity():
    low = generate_frame(3, 0, sensor_model("vlp16", mount_height_m=1.2))
    ground_z = np.median(low.points[low.ground & (np.linalg.norm(low.points[:, :2], axis=1) < 8.0), 2])
    assert abs(ground_z + 1.2) < 0.15
    for box in low.boxes:
        assert box.contains(low.points[low.instance == box.instance, :3]).all() or box.label == 0
    values = np.array([0.0, 0.5, 1.0], dtype=np.float32)
    assert driver_intensity(sensor_model("vlp16"), values).tolist() == [0.0, 128.0, 255.0]
    assert driver_intensity(sensor_model("os1-64"), values)[-1] == 65535.0


@pytest.mark.parametrize("name", ["hdl64e", "pandar64"])
def test_spec_height_mounts_the_sensor_that_high(name):
    """height=H (pass3d_adapt scans the nearest simulated sensor at the user's measured mount): the road lies H m
    below the sensor, and the same scene without it at the model's 1.73 m."""
    for text, expected in ((f"synthetic:sensor={name},frames=1,seed=3,height=2.1", 2.1),
                           (f"synthetic:sensor={name},frames=1,seed=3", 1.73)):
        frame = next(iter(open_dataset(text)))
        near = frame.ground & (np.linalg.norm(frame.points[:, :2], axis=1) < 8.0)
        assert abs(np.median(frame.points[near, 2]) + expected) < 0.15, text
    for bad in ("height=abc", "height=9", "height=nan", "height=0.1"):
        with pytest.raises(DatasetError, match=r"height must be a number of metres in 0\.3\.\.4"):
            parse_synthetic_spec(f"frames=1,{bad}")


def test_stage1_finds_proposals_on_a_vlp16_scan():
    """Stage 1 (tuned for KITTI's 64 lasers) on VLP-16 frames: 16 rings 2 degrees apart split objects into few
    runs, so recall is lower than on the HDL-64E (see RECALL_FLOOR_VLP16)."""
    fg = hit = 0
    for index in range(3):
        frame = generate_frame(3, index, "vlp16")
        result = propose(frame.points, frame.ring)
        assert len(result.boxes) > 0
        mask = frame.labels > 0
        fg += int(mask.sum())
        hit += int((result.cluster_id[mask] >= 0).sum())
    assert hit / fg > RECALL_FLOOR_VLP16
