"""Split instead of drop (pass3d_ros.core.stage1.split): clusters failing only the footprint gate are cut at their
gaps."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.scans import SENSOR_HEIGHT, Solid, raycast

from pass3d_ros.core.stage1 import Stage1Config, propose, refinement, split
from pass3d_ros.core.stage1.refinement import min_area_rectangle
from pass3d_ros.data.frame import Box3D

KITTI_CAR = (3.88, 1.63, 1.53)  # mean KITTI car box (DESIGN.md)


def parked_row(gap: float, y: float, n: int = 3, x0: float = 3.0) -> list[Solid]:
    """n KITTI-sized cars parked end to end along x, `gap` metres apart, their near side at |y| - width / 2."""
    length, _, height = KITTI_CAR
    return [Solid((x0 + i * (length + gap) + length / 2, y, -SENSOR_HEIGHT + height / 2), KITTI_CAR)
            for i in range(n)]


def car_sized(result) -> list[np.ndarray]:
    """Box sizes of the proposals as long as a car (2-6.5 m, SizeRules' car length)."""
    return [b.size for b in result.boxes if 2.0 <= b.size[0] <= 6.5]


def car_recall(points: np.ndarray, ring: np.ndarray, hit: np.ndarray, on: bool):
    result = propose(points, ring, Stage1Config(split_merged=on))
    return result, float((result.cluster_id[hit >= 0] >= 0).mean())


@pytest.mark.parametrize(("gap", "y"), [(0.5, -3.0), (0.5, -4.0), (0.75, -3.0), (0.75, -4.0)])
def test_cars_end_to_end_become_separate_proposals(gap: float, y: float) -> None:
    points, ring, hit = raycast(parked_row(gap, y), n_az=2000)
    before, recall_before = car_recall(points, ring, hit, on=False)
    after, recall_after = car_recall(points, ring, hit, on=True)
    # Without the split the row chains into one cluster too long for any road user: (nearly) all dropped.
    assert recall_before < 0.1
    assert before.n_split == 0
    # With it the row is cut at both gaps: three car-long proposals, one per car, holding all car points.
    assert after.n_split == 1
    assert recall_after > 0.99
    assert len(car_sized(after)) == 3
    for box in car_sized(after):
        assert abs(box[0] - KITTI_CAR[0]) < 0.3
    owners = []
    for i in range(3):  # each car is (nearly all) one proposal of its own
        ids, counts = np.unique(after.cluster_id[hit == i], return_counts=True)
        assert ids[np.argmax(counts)] >= 0 and counts.max() >= 0.95 * counts.sum()
        owners.append(ids[np.argmax(counts)])
    assert len(set(owners)) == 3


def test_single_car_untouched() -> None:
    points, ring, hit = raycast(parked_row(0.5, -4.0, n=1), n_az=2000)
    before, _ = car_recall(points, ring, hit, on=False)
    after, _ = car_recall(points, ring, hit, on=True)
    assert after.n_split == 0
    assert len(after.boxes) == len(before.boxes) == 1
    np.testing.assert_array_equal(after.cluster_id, before.cluster_id)


@pytest.mark.parametrize("height", [1.2, 1.5, 2.0])
def test_long_wall_yields_no_new_car_sized_proposal(height: float) -> None:
    """A 15 m wall of car height has no gap: it stays one cluster, dropped as before."""
    wall = Solid((4.0 + 7.5, -4.0, -SENSOR_HEIGHT + height / 2), (15.0, 0.2, height))
    points, ring, _ = raycast([wall], n_az=2000)
    before = propose(points, ring, Stage1Config(split_merged=False, rerun_dropped=False))
    after = propose(points, ring, Stage1Config(split_merged=True, rerun_dropped=False))
    assert after.n_split == 0
    assert len(car_sized(after)) == len(car_sized(before))
    np.testing.assert_array_equal(after.cluster_id, before.cluster_id)


def cut_whole(pts: np.ndarray, label: np.ndarray, n_clusters: int) -> tuple:
    """split.cut_at_gaps on the last cluster, with its minimal-area rectangle."""
    c = n_clusters - 1
    rect = np.array([min_area_rectangle(pts[label == c, :2])])
    return split.cut_at_gaps(pts, label, n_clusters, np.array([c]), rect, Stage1Config())


def test_sparse_far_surface_is_not_cut() -> None:
    """Holes as wide as split_gap from point spacing alone (a surface far away) are no gap: one cluster of points
    0.45 m apart along a 12 m line stays whole."""
    x = np.arange(0.0, 12.0, 0.45) + 30.0
    pts = np.zeros((2 * len(x), 4), dtype=np.float32)
    pts[:, 0] = np.repeat(x, 2)
    pts[:, 1] = 5.0
    pts[:, 2] = np.tile([-1.6, -0.5], len(x))
    label = np.zeros(len(pts), dtype=np.int32)
    out, n, cut = cut_whole(pts, label, 1)
    assert cut == 0 and n == 1
    np.testing.assert_array_equal(out, label)


def test_split_parts_get_new_ids_and_count() -> None:
    """Two dense 4 m walls 1 m apart in one cluster: cut once, each part takes a new id after the old ones."""
    x = np.concatenate([np.linspace(5.0, 9.0, 200), np.linspace(10.0, 14.0, 200)])
    pts = np.zeros((400, 4), dtype=np.float32)
    pts[:, 0] = x
    pts[:, 1] = 3.0
    pts[:, 2] = np.tile([-1.6, -0.4], 200)
    label = np.full(400, 4, dtype=np.int32)
    label[:3] = -1  # unclustered points stay so
    out, n, cut = cut_whole(pts, label, 5)
    assert cut == 1 and n == 7
    assert (out[:3] == -1).all()
    assert (out[3:200] == 5).all() and (out[200:] == 6).all()


@pytest.mark.parametrize("kind", ["split_merged", "split_protruding", "both"])
def test_old_proposals_stay_first_and_unchanged(kind: str) -> None:
    """On a synthetic street (frame 3 of seed 7, where cut parts pass the gates), the proposals without the splits
    come first with them, the same boxes; the parts' proposals follow."""
    from pass3d_ros.synthetic.dataset import generate_frame

    frame = generate_frame(7, 3)
    before = propose(frame.points, frame.ring, Stage1Config(split_merged=False, split_protruding=False,
                                                            rerun_dropped=False))
    on = {"split_merged": kind in ("split_merged", "both"), "split_protruding": kind in ("split_protruding", "both")}
    after = propose(frame.points, frame.ring, Stage1Config(**on, rerun_dropped=False))
    assert after.n_split >= 1 and len(after.boxes) > len(before.boxes)
    for a, b in zip(before.boxes, after.boxes, strict=False):
        np.testing.assert_allclose(a.center, b.center)
        np.testing.assert_allclose(a.size, b.size)
        assert a.yaw == b.yaw
    old = before.cluster_id >= 0
    np.testing.assert_array_equal(after.cluster_id[old], before.cluster_id[old])


def person_before_wall(gap: float, yaw: float = 0.5, height: float = 1.75, bottom: float = 0.0,
                       x: float = 8.0) -> list[Solid]:
    """A person (0.3 x 0.6 x `height` m from `bottom` above the ground, turned `yaw` so that a front and a side show)
    standing `gap` metres in front of a 7.5 m long, 1.2 m high wall, `x` metres ahead: one cluster (their faces about
    0.3 + gap apart: beyond th_ring, within th_prop) longer than any road user and without a gap to cut at."""
    person = Solid((x, 0.0, -SENSOR_HEIGHT + bottom + height / 2), (0.3, 0.6, height), yaw)
    wall = Solid((x + 0.15 + gap + 0.15, 0.0, -SENSOR_HEIGHT + 0.6), (0.3, 7.5, 1.2))
    return [person, wall]


@pytest.mark.parametrize("gap", [0.25, 0.35])
def test_rerun_dropped_cuts_a_person_off_a_long_wall(gap: float) -> None:
    points, ring, hit = raycast(person_before_wall(gap), n_az=1000)
    before = propose(points, ring, Stage1Config(rerun_dropped=False))
    after = propose(points, ring, Stage1Config(rerun_dropped=True))
    person = hit == 0
    assert (before.cluster_id[person] >= 0).mean() < 0.1  # dropped with the wall
    assert (after.cluster_id[person] >= 0).mean() > 0.9
    ids, counts = np.unique(after.cluster_id[person], return_counts=True)
    box = after.boxes[ids[np.argmax(counts)]]
    assert max(box.size[:2]) < 1.0 and box.size[2] < 2.0  # the person alone, not the wall
    # What was kept without the option is kept alike: the parts only add proposals.
    assert after.boxes[:before.n_proposals] == before.boxes or before.n_proposals == 0


def test_rerun_dropped_leaves_large_clusters_whole() -> None:
    """A cluster above rerun_max_points is not clustered again: the person stays dropped with the wall."""
    points, ring, hit = raycast(person_before_wall(0.25), n_az=1000)
    n_cluster = int(np.count_nonzero(hit >= 0))
    after = propose(points, ring, Stage1Config(rerun_dropped=True, rerun_max_points=n_cluster // 2))
    assert (after.cluster_id[hit == 0] >= 0).mean() < 0.1


def _car_and_part() -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
    """A car's side (cluster 0, x 5..9 m at y = 0) and a person-sized part (cluster 1) 0.05 m beside its rear end:
    the part's enlarged box (0.1 m margin) takes in the car's last points, and the car's box the part's nearest."""
    car_x = np.linspace(5.0, 9.0, 41)
    person_x = np.linspace(9.05, 9.45, 5)
    xs = np.concatenate([car_x, person_x])
    points = np.zeros((len(xs), 4), dtype=np.float32)
    points[:, 0] = xs
    points[:, 2] = -1.0
    label = np.array([0] * len(car_x) + [1] * len(person_x), dtype=np.int32)
    boxes = [Box3D(center=np.array([7.0, 0.0, -1.0]), size=np.array([4.0, 0.2, 1.0]), yaw=0.0),
             Box3D(center=np.array([9.25, 0.0, -1.0]), size=np.array([0.4, 0.2, 1.0]), yaw=0.0)]
    return points, label, boxes, np.array([0, 1])


def test_a_part_that_gives_way_takes_no_point_of_another_proposal() -> None:
    """Without the flag the part's box takes the car's rear points as their second proposal (and the car's box the
    part's first point); with it, every point another proposal holds is that proposal's alone, the car keeps exactly
    its points, and the part keeps only the points no other proposal holds."""
    points, label, boxes, kept = _car_and_part()
    margin = (0.1, 0.1, 0.4)
    first, second = refinement.enlarged_membership(points, label, kept, boxes, margin)
    assert (second == 1).any() and (second == 0).any()
    gw_first, gw_second = refinement.enlarged_membership(points, label, kept, boxes, margin,
                                                         gives_way=np.array([False, True]))
    car_points = {i for i in range(len(points)) if 0 in (first[i], second[i])}
    assert {i for i in range(len(points)) if 0 in (gw_first[i], gw_second[i])} == car_points
    assert not ((gw_first == 1) & (gw_second >= 0)).any() and not (gw_second == 1).any()
    assert set(np.flatnonzero(gw_first == 1)) == set(np.flatnonzero(label == 1)) - car_points
    with pytest.raises(ValueError, match="gives_way"):
        refinement.enlarged_membership(points, label, kept, boxes, margin, gives_way=np.array([True]))


def test_only_rerun_dropped_parts_give_way() -> None:
    """The person cut off the wall by rerun_dropped gives way, and is the only proposal that does; without the option
    no proposal gives way and no point is people-only."""
    points, ring, hit = raycast(person_before_wall(0.25), n_az=1000)
    before = propose(points, ring, Stage1Config(rerun_dropped=False))
    after = propose(points, ring, Stage1Config(rerun_dropped=True))
    assert not before.gives_way.any() and before.people_only() is None
    assert len(after.gives_way) == after.n_proposals and after.gives_way.any()
    people = after.people_only()
    assert people is not None and people[hit == 0].mean() > 0.9
    assert not after.gives_way[:before.n_proposals].any()


@pytest.mark.parametrize(("what", "shape"), [("a panel seen square on", {"yaw": 0.0}),
                                             ("less than half a person", {"height": 0.7, "bottom": 0.6}),
                                             ("taller than a person", {"height": 2.6, "x": 20.0, "gap": 0.35})])
def test_rerun_dropped_keeps_only_person_shaped_parts(what: str, shape: dict) -> None:
    """A part that is no person standing there (a flat face, no depth; 0.7 m of rise; a top above the gates' max_top,
    2.4 m up where the highest laser reaches it 20 m away) stays dropped with the wall; the same part shaped as a
    person is kept (`test_rerun_dropped_cuts_a_person_off_a_long_wall`, and the controls below)."""
    points, ring, hit = raycast(person_before_wall(**{"gap": 0.25, **shape}), n_az=1000)
    after = propose(points, ring, Stage1Config(rerun_dropped=True))
    assert (after.cluster_id[hit == 0] >= 0).mean() < 0.1, what


@pytest.mark.parametrize(("height", "x"), [(1.75, 12.0), (1.75, 20.0), (2.0, 12.0)])
def test_a_person_12_or_20_m_away_is_kept(height: float, x: float) -> None:
    """The controls of the tall case: a person in its place is kept, a tall one too (2.0 m, seen up to 2.15 m 12 m
    away: rule R4)."""
    points, ring, hit = raycast(person_before_wall(0.35, height=height, x=x), n_az=1000)
    after = propose(points, ring, Stage1Config(rerun_dropped=True))
    assert (after.cluster_id[hit == 0] >= 0).mean() > 0.9
