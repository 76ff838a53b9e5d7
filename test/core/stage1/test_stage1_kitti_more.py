"""Stage 1 on the kitti_more failures (issue 37): a car joined to clutter close beside it is clustered again by
scan-line runs at tighter thresholds (`Stage1Config.split_rerun`, pass3d_ros.core.stage1.split) instead of dropped
whole for a footprint too wide for any road user.

The scene reproduces KITTI object frame 000015 of kitti_more (a parked car 4-5 m beside the vehicle, a hedge behind it
seen over its roof); the real frame is read only where it lies beside the repository (licence: never in it)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from helpers.scans import SENSOR_HEIGHT, Solid, raycast

from pass3d_ros.core.stage1 import Stage1Config, propose, split

KITTI_CAR = (3.88, 1.63, 1.53)  # mean KITTI car box (DESIGN.md)
CAR_X, CAR_Y = 4.4, 2.8  # where frame 000015's car stands (sensor frame)
KITTI_MORE = Path(__file__).resolve().parents[4] / "shared" / "data" / "kitti_more" / "object" / "training"


def car_and_hedge(gap: float, hedge_length: float = 3.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A KITTI car parked side-on beside the vehicle and a 2 m deep, 2 m tall hedge `gap` metres behind its far side
    (shifted 1 m along the car): (points, ring, hit), hit 0 = car, 1 = hedge (helpers.scans.raycast)."""
    _, width, height = KITTI_CAR
    car = Solid((CAR_X, CAR_Y, -SENSOR_HEIGHT + height / 2), KITTI_CAR)
    hedge = Solid((CAR_X + 1.0, CAR_Y + width / 2 + gap + 1.0, -SENSOR_HEIGHT + 1.0), (hedge_length, 2.0, 2.0))
    return raycast([car, hedge], n_az=2000)


def car_recall(result, hit: np.ndarray) -> float:
    """Share of the car's points inside a proposal."""
    return float((result.cluster_id[hit == 0] >= 0).mean())


def test_split_rerun_is_on_by_default() -> None:
    assert Stage1Config().split_rerun


@pytest.mark.parametrize("gap", [0.55, 0.6, 0.7])
def test_car_joined_to_hedge_beside_it_is_kept(gap: float) -> None:
    """Between rings the hedge seen over the roof lies within th_prop (1 m) of the car: one cluster too wide for any
    road user, dropped whole without the re-run (frame 000015's failure). Clustered again at half the thresholds, the
    car is a part of its own: a car-long proposal that holds all its points, the hedge apart."""
    points, ring, hit = car_and_hedge(gap)
    before = propose(points, ring, Stage1Config(split_rerun=False))
    after = propose(points, ring, Stage1Config())
    assert car_recall(before, hit) < 0.05
    assert car_recall(after, hit) > 0.99
    assert after.n_split >= 1
    ids, counts = np.unique(after.cluster_id[hit == 0], return_counts=True)
    own = ids[np.argmax(counts)]
    assert own >= 0 and counts.max() == counts.sum()
    assert abs(after.boxes[own].size[0] - KITTI_CAR[0]) < 0.3
    assert after.boxes[own].size[1] < 2.0  # the hedge is not in the car's box
    assert np.mean(after.cluster_id[hit == 1] == own) < 0.05


def test_a_too_long_cluster_is_left_to_the_gap_cut() -> None:
    """The re-run looks only at clusters too wide but not too long: behind a 15 m hedge the car stays lost, as
    before (long hedges and walls cut into car-sized pieces would only add background proposals)."""
    points, ring, hit = car_and_hedge(0.6, hedge_length=15.0)
    before = propose(points, ring, Stage1Config(split_rerun=False))
    after = propose(points, ring, Stage1Config())
    assert after.n_split == before.n_split
    np.testing.assert_array_equal(after.cluster_id, before.cluster_id)
    assert car_recall(after, hit) < 0.05


def test_rerun_runs_cuts_only_where_the_tight_runs_part() -> None:
    """Unit: two clusters on two rings; cluster 1 holds two dense walls 0.4 m apart in each ring (one run at th_ring
    0.5 m, two at 0.25 m), cluster 0 one dense wall. Only cluster 1 is cut; its parts take ids 2 and 3, cluster 0 and
    the unclustered points keep theirs."""
    wall = np.linspace(0.0, 2.0, 41)  # 0.05 m apart
    xs = np.concatenate([wall, wall + 2.4])
    rows = []
    for z in (-1.0, -1.05):
        rows.append(np.stack([np.full(41, 8.0), wall - 6.0, np.full(41, z)], axis=1))  # cluster 0
        rows.append(np.stack([np.full(82, 8.0), xs, np.full(82, z)], axis=1))  # cluster 1
    pts = np.concatenate([np.concatenate([r, np.full((len(r), 1), 0.5)], axis=1) for r in rows]).astype(np.float32)
    ring = np.repeat(np.array([0, 0, 1, 1], dtype=np.uint16), [41, 82, 41, 82])
    label = np.repeat(np.array([0, 1, 0, 1], dtype=np.int32), [41, 82, 41, 82])
    label[0] = -1
    out, n, cut = split.rerun_runs(pts, ring, label, 2, np.array([0, 1]), Stage1Config())
    assert cut == 1 and n == 4
    assert out[0] == -1 and (out[1:41] == 0).all() and (out[123:164] == 0).all()
    first, second = out[41:82], out[82:123]
    assert len(set(first)) == 1 and len(set(second)) == 1 and {first[0], second[0]} == {2, 3}
    np.testing.assert_array_equal(out[164:], out[41:123])
    same, n_same, none = split.rerun_runs(pts, ring, label, 2, np.array([0]), Stage1Config())
    assert none == 0 and n_same == 2 and same is label


def test_old_proposals_stay_first_and_unchanged() -> None:
    """The re-run only adds: every proposal without it is there with it, first, with the same box."""
    points, ring, _ = car_and_hedge(0.6)
    other_car = Solid((-12.0, -6.0, -SENSOR_HEIGHT + KITTI_CAR[2] / 2), KITTI_CAR)  # an ordinary scene
    more, more_ring, _ = raycast([other_car], n_az=2000)
    for pts, rng in ((points, ring), (more, more_ring)):
        before = propose(pts, rng, Stage1Config(split_rerun=False))
        after = propose(pts, rng, Stage1Config())
        for a, b in zip(before.boxes, after.boxes, strict=False):
            np.testing.assert_allclose(a.center, b.center)
            np.testing.assert_allclose(a.size, b.size)
        old = before.cluster_id >= 0
        np.testing.assert_array_equal(after.cluster_id[old], before.cluster_id[old])


def kitti_more_root() -> Path | None:
    """$PASS3D_KITTI_MORE (an object/training folder), else ../shared/data/kitti_more beside the repository."""
    for candidate in (os.environ.get("PASS3D_KITTI_MORE"), KITTI_MORE):
        if candidate and (Path(candidate) / "velodyne" / "000015.bin").is_file():
            return Path(candidate)
    return None


@pytest.mark.kitti
def test_real_frame_000015_car_is_kept() -> None:
    """The real frame: its car (about 4,500 labelled points, 4-6 m away) was in no proposal; now nearly all of it is."""
    root = kitti_more_root()
    if root is None:
        pytest.skip("kitti_more frames absent: set PASS3D_KITTI_MORE or place them in ../shared/data/kitti_more")
    from pass3d_ros.data.kitti_object import read_kitti_object

    frame = next(f for f in read_kitti_object(root) if f.name == "000015")
    car = frame.labels == 1
    assert car.sum() > 4000
    before = propose(frame.points, config=Stage1Config(split_rerun=False))
    after = propose(frame.points)
    assert (before.cluster_id[car] >= 0).mean() < 0.05
    assert (after.cluster_id[car] >= 0).mean() > 0.95
