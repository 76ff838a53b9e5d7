"""Split instead of drop, second kind: road users cut out of taller structures (pass3d_ros.core.stage1.protrusion)."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1.protrusion import protruding_parts

MAX_TOP = 2.3


def cloud(*parts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xyz = np.concatenate(parts)
    return np.c_[xyz, np.zeros(len(xyz))].astype(np.float32), xyz[:, 2]


def cut(points: np.ndarray, height: np.ndarray) -> tuple[np.ndarray, int, int]:
    return protruding_parts(points, np.zeros(len(points), dtype=np.int32), height, 1, np.array([0]), MAX_TOP, 5)


def box(rng: np.random.Generator, lo: list[float], hi: list[float], n: int) -> np.ndarray:
    return rng.uniform(lo, hi, (n, 3))


@pytest.mark.parametrize("side", [0.45, 0.6])
def test_person_against_a_mast_becomes_its_own_part(side: float) -> None:
    rng = np.random.default_rng(0)
    mast = box(rng, [7.9, -0.1, 0.0], [8.1, 0.1, 6.0], 200)
    person = box(rng, [7.75, side - 0.25, 0.0], [8.25, side + 0.25, 1.7], 80)
    points, height = cloud(mast, person)
    out, total, made = cut(points, height)
    assert (total, made) == (2, 1)
    assert np.all(out[:200] == 0)  # the mast keeps its id (and stays dropped by the gates)
    assert np.mean(out[200:] == 1) >= 0.6  # most of the person is the new part


def test_person_against_a_building_front_becomes_its_own_part() -> None:
    rng = np.random.default_rng(1)
    wall = box(rng, [9.95, -10.0, 0.0], [10.05, 10.0, 6.0], 4000)
    person = box(rng, [9.45, 2.0, 0.0], [9.8, 2.5, 1.75], 100)
    points, height = cloud(wall, person)
    out, total, made = cut(points, height)
    assert (total, made) == (2, 1) and np.all(out[:4000] == 0) and np.mean(out[4000:] == 1) >= 0.6


def test_two_people_against_a_wall_are_two_parts() -> None:
    rng = np.random.default_rng(2)
    wall = box(rng, [9.95, -10.0, 0.0], [10.05, 10.0, 6.0], 4000)
    left = box(rng, [9.4, -3.0, 0.0], [9.75, -2.5, 1.7], 80)
    right = box(rng, [9.4, 3.0, 0.0], [9.75, 3.5, 1.8], 80)
    out, total, made = cut(*cloud(wall, left, right))
    assert (total, made) == (3, 1)
    first, second = (np.bincount(out[span]).argmax() for span in (slice(4000, 4080), slice(4080, None)))
    assert first >= 1 and second >= 1 and first != second
    assert np.mean(out[4000:4080] == first) >= 0.6 and np.mean(out[4080:] == second) >= 0.6


@pytest.mark.parametrize("name", ["bare mast", "tree", "plain wall", "low hedge"])
def test_structures_alone_give_no_part(name: str) -> None:
    rng = np.random.default_rng(3)
    parts = {
        "bare mast": [box(rng, [7.9, -0.1, 0.0], [8.1, 0.1, 6.0], 200)],
        "tree": [box(rng, [7.85, -0.15, 0.0], [8.15, 0.15, 2.5], 100),
                 box(rng, [6.0, -2.0, 2.5], [10.0, 2.0, 6.0], 600)],
        "plain wall": [box(rng, [9.95, -10.0, 0.0], [10.05, 10.0, 6.0], 4000)],
        "low hedge": [box(rng, [9.5, -5.0, 0.0], [10.5, 5.0, 1.2], 800)],  # nothing above max_top: not examined
    }[name]
    points, height = cloud(*parts)
    out, total, made = cut(points, height)
    assert (total, made) == (1, 0) and out is not None and np.all(out == 0)


def test_only_the_named_clusters_are_examined() -> None:
    rng = np.random.default_rng(4)
    mast = box(rng, [7.9, -0.1, 0.0], [8.1, 0.1, 6.0], 200)
    person = box(rng, [7.75, 0.35, 0.0], [8.25, 0.85, 1.7], 80)
    points, height = cloud(mast, person)
    label = np.zeros(len(points), dtype=np.int32)
    out, total, made = protruding_parts(points, label, height, 2, np.array([1]), MAX_TOP, 5)  # cluster 1 is empty
    assert out is label and (total, made) == (2, 0)
    out, total, made = protruding_parts(points, label, height, 1, np.zeros(0, dtype=np.int64), MAX_TOP, 5)
    assert out is label and (total, made) == (1, 0)


def test_nothing_is_cut_from_beside_a_bulky_mass() -> None:
    """A bush beside the edge of a tree's crown protrudes too, but the structure around it is wide: no part."""
    rng = np.random.default_rng(5)
    crown = box(rng, [6.0, 0.0, 2.5], [9.0, 3.0, 6.0], 1500)
    trunk = box(rng, [7.4, 1.4, 0.0], [7.6, 1.6, 2.5], 80)
    bush = box(rng, [9.3, 1.0, 0.0], [9.9, 1.8, 1.0], 120)
    out, total, made = cut(*cloud(crown, trunk, bush))
    assert (total, made) == (1, 0) and np.all(out == 0)
