"""People apart in a crowd (pass3d_ros.core.stage1.crowd, `stage1.split_groups`): a group too big for one person is
given to the people whose heads it shows."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.scans import SENSOR_HEIGHT, Solid, person_points, raycast

from pass3d_ros.core.stage1 import Stage1Config, crowd, propose


def as_group(people: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(points N x 4, label: all cluster 0, height above ground, person index per point)."""
    xyz = np.concatenate(people)
    points = np.zeros((len(xyz), 4), dtype=np.float32)
    points[:, :3] = xyz
    who = np.repeat(np.arange(len(people)), [len(p) for p in people])
    return points, np.zeros(len(xyz), dtype=np.int32), xyz[:, 2].astype(np.float64), who


@pytest.mark.parametrize("spacing", [0.6, 0.8, 1.2])
def test_each_person_of_a_group_gets_a_part_of_their_own(spacing: float) -> None:
    """Four people 0.6, 0.8 or 1.2 m apart (head to head) in one cluster: four parts (0.6 m since rule C4: a
    neighbour's head no longer hides one). Closer heads of about one height (0.5 m) are read as one flat top and left
    whole: the price of never reading a roof as heads."""
    rng = np.random.default_rng(0)
    people = [person_points(8.0 + i * spacing, 2.0, h, rng) for i, h in enumerate((1.75, 1.62, 1.83, 1.7))]
    points, label, height, who = as_group(people)
    out, n_total, found = crowd.people_apart(points, label, 1, np.array([0]), height)
    assert found == 4 and n_total == 5
    for person in range(4):
        ids, counts = np.unique(out[who == person], return_counts=True)
        assert ids[np.argmax(counts)] >= 1 and counts.max() >= 0.9 * (who == person).sum()
    owners = [np.unique(out[who == p], return_counts=True) for p in range(4)]
    assert len({int(ids[np.argmax(c)]) for ids, c in owners}) == 4  # four different parts


@pytest.mark.parametrize("what", ["a flat top (a van's roof)", "a hedge"])
def test_flat_tops_show_no_heads(what: str) -> None:
    """A surface whose top runs on at one height (a roof 1.9 x 2 m, a hedge 6 m long) has no head: left whole."""
    rng = np.random.default_rng(1)
    size = (1.9, 2.0) if what.startswith("a flat") else (6.0, 0.6)
    n = 3000
    xyz = np.stack([rng.uniform(0, size[0], n), rng.uniform(0, size[1], n), rng.uniform(0.3, 1.5, n)], 1)
    top = xyz[:, 2] > 1.3
    xyz[top, 2] = 1.5 + rng.normal(0.0, 0.02, int(top.sum()))
    points = np.zeros((n, 4), dtype=np.float32)
    points[:, :3] = xyz
    label = np.zeros(n, dtype=np.int32)
    out, n_total, found = crowd.people_apart(points, label, 1, np.array([0]), xyz[:, 2].astype(np.float64))
    assert found == 0 and n_total == 1, what
    np.testing.assert_array_equal(out, label)


def test_one_person_is_no_crowd() -> None:
    """A single head: nothing to part (the part is judged whole, as before)."""
    rng = np.random.default_rng(2)
    points, label, height, _ = as_group([person_points(8.0, 2.0, 1.75, rng)])
    out, n_total, found = crowd.people_apart(points, label, 1, np.array([0]), height)
    assert found == 0 and n_total == 1
    np.testing.assert_array_equal(out, label)


def group_by_a_wall(spacing: float) -> tuple[list[Solid], int]:
    """Four people (a torso 0.45 x 0.3 m, a head 0.22 m across on it) standing `spacing` metres apart behind a bench
    0.5 m high that touches their shins, 0.3 m in front of a 7.5 m wall 1.2 m high, 8 m ahead: one cluster too long
    for any road user, and after scan-line runs at half reach still one group (the bench links them). Returns the
    solids (the people's first, then the bench and the wall) and how many are people's."""
    solids = []
    for i, height in enumerate((1.75, 1.65, 1.8, 1.7)):
        y = (i - 1.5) * spacing
        solids.append(Solid((8.0, y, -SENSOR_HEIGHT + (height - 0.27) / 2), (0.3, 0.45, height - 0.27)))
        solids.append(Solid((8.0, y, -SENSOR_HEIGHT + height - 0.135), (0.22, 0.2, 0.27)))
    solids.append(Solid((7.75, 0.0, -SENSOR_HEIGHT + 0.25), (0.2, 4 * spacing, 0.5)))
    solids.append(Solid((8.0 + 0.15 + 0.3 + 0.15, 0.0, -SENSOR_HEIGHT + 0.6), (0.3, 7.5, 1.2)))
    return solids, 8


def test_split_groups_keeps_the_people_of_a_group_by_a_wall() -> None:
    solids, n_people_solids = group_by_a_wall(0.9)
    points, ring, hit = raycast(solids, n_az=1000)
    people = (hit >= 0) & (hit < n_people_solids)
    off = propose(points, ring, Stage1Config(split_groups=False))
    on = propose(points, ring, Stage1Config())
    assert (off.cluster_id[people] >= 0).mean() < 0.1  # without the option the group stays dropped with the wall
    assert (on.cluster_id[people] >= 0).mean() > 0.9
    owners = [np.unique(on.cluster_id[hit // 2 == p], return_counts=True) for p in range(n_people_solids // 2)]
    assert len({int(ids[np.argmax(c)]) for ids, c in owners}) == 4  # one part per person
    for k in np.unique(on.cluster_id[people]):
        assert max(on.boxes[k].size[:2]) < 1.3 and on.gives_way[k]
    assert (on.cluster_id[hit == n_people_solids + 1] >= 0).mean() < 0.25  # most of the wall stays dropped
    assert on.boxes[:off.n_proposals] == off.boxes  # the option only adds proposals
