"""Low fragments joined to the proposal beside them (pass3d_ros.core.stage1.fragments): a car's boot, cut off its
windows and roof a laser step away, joins the roof's proposal; a person's legs, a fragment beside a person-sized
proposal, one too far away and one that would make the proposal too long for any footprint stay as they are."""

from __future__ import annotations

import dataclasses

import numpy as np

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.core.stage1 import Stage1Config, propose
from pass3d_ros.core.stage1.fragments import JOIN_GAP_M, join_fragments
from pass3d_ros.core.stage1.refinement import _cluster_rects, boxes_of
from pass3d_ros.data.spec import open_dataset

SENSOR_HEIGHT_M = 1.73
PLANES = np.array([[0.0, 0.0, 1.0, SENSOR_HEIGHT_M]])  # one flat ground plane under the sensor
EDGES = np.array([-100.0, 100.0])


def slab(rng: np.random.Generator, x: tuple[float, float], y: tuple[float, float], height: tuple[float, float],
         n: int) -> np.ndarray:
    """`n` points uniform in the box (x, y, height above the road), as stage 1's N x 4 float32 points."""
    lo = np.array([x[0], y[0], height[0] - SENSOR_HEIGHT_M, 0.0])
    hi = np.array([x[1], y[1], height[1] - SENSOR_HEIGHT_M, 0.0])
    return (lo + rng.random((n, 4)) * (hi - lo)).astype(np.float32)


def joined(kept_part: tuple, fragment: tuple) -> tuple[np.ndarray, np.ndarray, list]:
    """A kept cluster (x, y, height ranges) and a dropped one beside it through `join_fragments`: the fragment's
    labels after it, and the kept proposal's box before and after."""
    rng = np.random.default_rng(0)
    points = np.concatenate([slab(rng, *kept_part, 60), slab(rng, *fragment, 80)])
    label = np.repeat(np.array([0, 1], dtype=np.int32), [60, 80])
    kept = np.array([0])
    z = points[:60, 2]
    boxes = boxes_of(_cluster_rects(points, label, kept), np.array([z.min()]), np.array([z.max()]))
    out, grown = join_fragments(points, label, kept, boxes, PLANES, EDGES, Stage1Config())
    return out[60:], boxes[0], grown[0]


ROOF = ((25.5, 26.4), (1.9, 3.3), (0.63, 1.39))  # a car's rear window and roof 25 m ahead, seen from behind
BOOT = ((24.2, 24.6), (1.9, 3.5), (0.36, 0.85))  # its boot and bumper, a laser step nearer and lower


def test_a_cars_boot_joins_its_roofs_proposal() -> None:
    fragment, before, after = joined(ROOF, BOOT)
    assert np.all(fragment == 0)
    assert before.size[:2].max() < 1.5 < 2.0 < after.size[:2].max()  # the box now reaches the boot: 2.2 m long
    assert after.center[2] - after.size[2] / 2 < before.center[2] - before.size[2] / 2


def test_a_persons_legs_do_not_join_the_car_beside_them() -> None:
    legs = ((24.3, 24.55), (2.4, 2.6), (0.0 + 0.3, 0.85))
    fragment, before, after = joined(ROOF, legs)
    assert np.all(fragment == 1) and np.allclose(after.size, before.size)


def test_a_fragment_beside_a_person_sized_proposal_stays_dropped() -> None:
    person = ((25.5, 26.0), (2.3, 2.8), (0.9, 1.75))
    fragment, _, _ = joined(person, BOOT)
    assert np.all(fragment == 1)


def test_a_fragment_too_far_away_stays_dropped() -> None:
    far = ((25.5 - JOIN_GAP_M - 1.0, 25.5 - JOIN_GAP_M - 0.2), (1.9, 3.5), (0.36, 0.85))
    fragment, _, _ = joined(ROOF, far)
    assert np.all(fragment == 1)


def test_a_fragment_that_makes_the_proposal_too_long_stays_dropped() -> None:
    long_part = ((20.0, 26.5), (1.9, 3.3), (0.63, 1.39))  # 6.5 m: with the boot 1.0 m further it passes max_length 7
    fragment, _, _ = joined(long_part, ((19.0, 19.6), (1.9, 3.5), (0.36, 0.85)))
    assert np.all(fragment == 1)


def test_a_kerb_or_a_step_stays_dropped() -> None:
    kerb = ((24.0, 25.0), (1.9, 3.5), (0.05, 0.2))
    fragment, _, _ = joined(ROOF, kerb)
    assert np.all(fragment == 1)


def test_a_low_thing_beside_or_beyond_the_proposal_stays_dropped() -> None:
    """A hedge beside a cyclist, a parked motorbike behind one: not the lower part of the same object seen from the
    sensor (that lies nearer, under the proposal's bearings)."""
    beside = ((25.5, 26.5), (3.6, 4.4), (0.36, 0.85))
    beyond = ((26.8, 27.2), (1.9, 3.5), (0.36, 0.85))
    for fragment_box in (beside, beyond):
        fragment, _, _ = joined(ROOF, fragment_box)
        assert np.all(fragment == 1), fragment_box


def test_on_a_drive_the_option_gives_a_followed_car_its_boot_and_adds_no_proposal() -> None:
    """Drive 358's car 12 in scan 23, 25 m ahead and seen from behind (docs/experiments/sensors.md, rule J): off, the
    proposal holds its windows and roof only; on, the whole car. The step adds no proposal, and it is off by default."""
    frame = list(open_dataset("synthetic:drive=24,seed=358,sensor=hdl64e"))[23]
    car = frame.instance == 12
    assert not Stage1Config().join_fragments
    off = propose(frame.points, frame.ring, Stage1Config())
    on = propose(frame.points, frame.ring, dataclasses.replace(Stage1Config(), join_fragments=True))
    assert np.mean(off.cluster_id[car] >= 0) < 0.5 and np.mean(on.cluster_id[car] >= 0) > 0.95
    assert len(on.boxes) == len(off.boxes)
