"""Footprints (pass3d_ros.core.stream.footprints): the compiled group operations give what the plain ones give."""

from __future__ import annotations

import itertools

import numpy as np

from pass3d_ros.core.stream.footprints import (
    cell_sets,
    cells,
    evenly_spaced,
    extent,
    footprint_members,
    rows_cells,
    shared_cells,
)


def grouped_cells(xy: np.ndarray, counts: np.ndarray) -> list[np.ndarray]:
    """`cell_sets` as one array per footprint."""
    keys, starts = cell_sets(xy, counts)
    return [keys[a:b] for a, b in itertools.pairwise(starts)]


def _groups(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    counts = rng.integers(0, 40, count)
    centres = np.repeat(rng.uniform(-20, 20, (count, 2)), counts, axis=0)
    return centres + rng.normal(0, 1.0, (int(counts.sum()), 2)), counts


def test_grouped_cells_are_each_groups_cells() -> None:
    rng = np.random.default_rng(3)
    xy, counts = _groups(rng, 30)
    pieces = np.split(xy, np.cumsum(counts)[:-1])
    for got, points in zip(grouped_cells(xy, counts), pieces, strict=True):
        assert np.array_equal(got, cells(points) if len(points) else np.zeros(0, np.int64))


def test_shared_cells_count_what_sets_share() -> None:
    rng = np.random.default_rng(4)
    first_points, second_points = _groups(rng, 12), _groups(rng, 9)
    shared = shared_cells(cell_sets(*first_points), cell_sets(*second_points))
    for i, a in enumerate(grouped_cells(*first_points)):
        for j, b in enumerate(grouped_cells(*second_points)):
            assert shared[i, j] == len(set(a.tolist()) & set(b.tolist()))
    assert shared.sum() > 0, "the random groups overlap somewhere (else this test tests nothing)"


def _linspace_sample(members: np.ndarray, limit: int) -> np.ndarray:
    return members if len(members) <= limit else members[np.linspace(0, len(members) - 1, limit).astype(np.int64)]


def test_evenly_spaced_keeps_linspace_positions_per_object() -> None:
    rng = np.random.default_rng(5)
    owner = rng.integers(0, 7, 2000)
    owner[owner == 3] = 4  # an object with no points
    members = np.sort(rng.choice(100_000, 2000, replace=False))
    chosen, kept = evenly_spaced(members, owner, 7, 64)
    start = 0
    for k in range(7):
        mine = members[owner == k]
        assert np.array_equal(chosen[start:start + kept[k]], _linspace_sample(mine, 64))
        start += kept[k]
    assert kept[3] == 0 and start == len(chosen)


def test_extent_of_a_rotated_box() -> None:
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, 21), np.linspace(-0.8, 0.8, 9)), -1).reshape(-1, 2)
    turn = np.array([[np.cos(0.6), -np.sin(0.6)], [np.sin(0.6), np.cos(0.6)]])
    length, width, axis = extent(grid @ turn.T + [5.0, -3.0])
    assert abs(length - 4.0) < 1e-6 and abs(width - 1.6) < 1e-6
    assert abs(abs(axis @ turn[:, 0]) - 1.0) < 1e-6


def test_footprint_members_thin_by_the_hash_then_keep_the_first_of_each_rank_run() -> None:
    rng = np.random.default_rng(6)
    owner = rng.integers(0, 5, 3000)
    owner[owner == 2] = 1  # an object with no points
    members = np.arange(3000) * 3
    chosen, kept = footprint_members(members, owner, 5, 64)
    start = 0
    for k in range(5):
        mine = members[owner == k]
        share = min(1.0, 128 / max(len(mine), 1))
        mine = mine[np.modf(mine * 0.6180339887498949)[0] < share]
        rank = np.arange(len(mine))
        step = rank * 64 // max(len(mine), 1)
        want = mine[(rank == 0) | (step != np.r_[-1, step[:-1]])] if len(mine) > 64 else mine
        assert np.array_equal(chosen[start:start + kept[k]], want) and kept[k] == min(len(mine), 64)
        start += kept[k]
    assert kept[2] == 0 and kept.max() == 64


def test_wide_footprints_and_footprints_kept_as_rows_give_their_points_cells() -> None:
    """A footprint too wide to sort by marking its cells gives the same cells; footprints kept as rows of one array
    (a track's offsets), each moved by its row's centre, give the cells of their moved points."""
    rng = np.random.default_rng(5)
    wide = rng.uniform(-40, 40, (50, 2))
    assert np.array_equal(grouped_cells(wide, [50])[0], cells(wide))
    xy, counts = _groups(rng, 8)
    kept = np.zeros((8, 40, 2))
    for k, piece in enumerate(np.split(xy, np.cumsum(counts)[:-1])):
        kept[k, :len(piece)] = piece
    centres = rng.uniform(-5, 5, (8, 4))
    order = np.array([3, 0, 5, 7])
    keys, starts = rows_cells(kept, counts, order, centres)
    for g, row in enumerate(order):
        expected = cells(kept[row, :counts[row]] + centres[row, :2]) if counts[row] else np.zeros(0, np.int64)
        assert np.array_equal(keys[starts[g]:starts[g + 1]], expected)
