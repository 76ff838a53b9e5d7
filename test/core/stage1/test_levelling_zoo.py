"""Stage 1 on sensors as robots mount them and drivers send them: simulated scans of every sensor the simulator knows
(the lasers cast from the tilted, high or upside-down sensor, points in its own frame, the driver's ring field) are
levelled by the mounting read from their first scan; stage 1 finds the road users it finds on the level mount
(stage-1 foreground recall within 0.05), and proposes exactly the same with the ring field as without it."""

from __future__ import annotations

import numpy as np
import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.core.metrics import Stage1Metrics
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1.ring import rings_from_lines
from pass3d_ros.data.spec import open_dataset
from pass3d_ros.synthetic.sensor import SENSOR_NAMES

MOUNTS = ("pitch=10", "roll=10", "pitch=-7,roll=4", "height=3.5", "roll=180")


def proposed(spec: str, ring: bool = True) -> tuple[float, list[np.ndarray]]:
    """Stage-1 foreground recall of one stream through the door (stage 1 only), and each scan's cluster ids; `ring`:
    with the driver's ring field, else without one."""
    pipeline = ScanPipeline(intensity_match=False)
    metrics = Stage1Metrics()
    ids = []
    for frame in open_dataset(spec):
        result = pipeline.propose(frame.points, frame.ring if ring else None)
        metrics.update_result(frame.name, result.result, result.kept_values(frame.labels))
        ids.append(result.result.cluster_id)
    return metrics.summary()["stage1"]["foreground_recall"], ids


def spec(sensor: str, mount: str = "") -> str:
    return f"synthetic:frames=1,seed=97,sensor={sensor}" + (f",{mount}" if mount else "")


SEE = "(docs/experiments/sensors.md)"
KNOWN_SHORT = {
    ("vlp16", "height=3.5"): f"a VLP-16 3.5 m up meets the road 13 m out and crosses near road users with few lasers: "
                             f"0.89 against 0.97 level {SEE}",
    ("vlp32c", "height=3.5"): "a VLP-32C 3.5 m up crosses a person 15 m away with 3 lasers: 0.81 against 0.96 level "
                              f"(0.62 without stage1.range_scaling) {SEE}",
    ("rs32", "height=3.5"): "a RoboSense RS-32 3.5 m up, like the VLP-32C whose lower lasers it shares within a "
                            "degree: 0.77 against 0.96 level; a car 7.5 m away crossed by 2 lasers (108 points, half "
                            f"proposed), a person 15.7 m away by 2 (7 points), one 13.1 m away by 1 (2 points) {SEE}",
    ("vlp32c", "roll=180"): "upside down 0.906 against 0.962 level: its lasers reach 15 degrees down, not 25, and "
                            "cross a person 13 m away with 10 lasers, not 17 (a car 34 m away with 5, not 7); it loses "
                            "a pedestrian of 11 points at 13 m and a car of 25 points at 34 m that the level mount "
                            f"keeps {SEE}",
    ("hdl64e", "roll=180"): "upside down, only the HDL-64E's few lasers above its horizon (+2 degrees at most) point "
                            "down, meeting the road 50 m out: near road users show their heads alone (0.00; with "
                            f"stage1.mount given too) {SEE}",
}
CASES = [pytest.param(sensor, mount, marks=pytest.mark.xfail(strict=True, reason=KNOWN_SHORT[sensor, mount]))
         if (sensor, mount) in KNOWN_SHORT else (sensor, mount) for sensor in SENSOR_NAMES for mount in MOUNTS]


@pytest.fixture(scope="module")
def level() -> dict[str, float]:
    return {sensor: proposed(spec(sensor))[0] for sensor in SENSOR_NAMES}


def test_the_level_mounts_find_the_road_users(level: dict[str, float]) -> None:
    assert min(level.values()) > 0.9, level


@pytest.mark.parametrize(("sensor", "mount"), CASES)
def test_tilted_high_and_upside_down_mounts_find_what_the_level_one_finds(
        sensor: str, mount: str, level: dict[str, float]) -> None:
    assert proposed(spec(sensor, mount))[0] >= level[sensor] - 0.05


# KITTI's scans come without a ring field
RING_CASES = [(sensor, mount) for sensor in SENSOR_NAMES if sensor != "hdl64e" for mount in ("", *MOUNTS)]


@pytest.mark.parametrize(("sensor", "mount"), RING_CASES)
def test_the_ring_field_proposes_what_the_scan_alone_does(sensor: str, mount: str) -> None:
    _, with_field = proposed(spec(sensor, mount))
    _, without = proposed(spec(sensor, mount), ring=False)
    for a, b in zip(with_field, without, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("sensor", "mount", "lasers"),
                         [("pandar64", "roll=180", 64), ("hdl32e", "pitch=-7,roll=4", 32)])
def test_a_tilted_scan_without_a_ring_field_reads_its_lasers(sensor: str, mount: str, lasers: int) -> None:
    """Upside down the Pandar64's scene reads as motion, and from the moving origin 113 lines fit as well as the 64
    lasers do from the still one (the pitched and rolled HDL-32E: 48 as well as 32): of two line sets that fit as well,
    the fewer lines are the lasers."""
    frame = next(iter(open_dataset(spec(sensor, mount))))
    rings = rings_from_lines(frame.points, tilted=True)
    assert rings is not None and rings.n_rings == lasers and rings.source == "elevation_lines"


@pytest.mark.xfail(strict=True, reason="known short of stage 1 on any sensor (docs/experiments/sensors.md, the RS-32 "
                   "section): a car 5 m to the side is linked ring to ring with a post 0.3 m behind it; the cluster "
                   "tops out at 2.38 m and max_top (2.3) drops it with the car; rerun_dropped keeps only "
                   "people-sized parts")
def test_a_car_beside_a_post_is_still_proposed() -> None:
    """The Pandar40's second zoo scan (its lasers at their azimuth offsets): the car of 2,266 points is proposed."""
    pipeline = ScanPipeline(intensity_match=False)
    frames = list(open_dataset("synthetic:frames=2,seed=97,sensor=pandar40"))
    for frame in frames:
        result = pipeline.propose(frame.points, frame.ring)
    frame = frames[-1]
    cid = result.in_input(result.result.cluster_id, len(frame.points), -1)
    car = frame.labels == 1
    sizes = np.bincount(frame.instance[car & (frame.instance >= 0)])
    biggest = (frame.instance == int(np.argmax(sizes))) & car
    assert biggest.sum() > 2000
    assert np.mean(cid[biggest] >= 0) > 0.5
