"""People under a canopy (pass3d_ros.core.stage1.canopy, `stage1.cut_canopies`): a roof over a part is cut off it; a
trunk, a pole or a tree's crown is not."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1 import Stage1Config, canopy

MAX_TOP = Stage1Config().max_top
LEVEL = np.array([[0.0, 0.0, 1.0, 0.0]])  # one segment plane: a point's height above the ground is its z
EDGES = np.array([-80.0, 80.0])


def cut(points: np.ndarray, label: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """`canopy.under_canopies` on level ground without a local offset."""
    return canopy.under_canopies(points, label, parts, np.zeros(len(parts)), LEVEL, EDGES, MAX_TOP)


def slab(rng: np.random.Generator, lo: tuple[float, float, float], hi: tuple[float, float, float],
         n: int) -> np.ndarray:
    """`n` points spread uniformly in the box from `lo` to `hi` (x, y, height above ground)."""
    return rng.uniform(lo, hi, (n, 3))


def person(rng: np.random.Generator, x: float, y: float, n: int = 150) -> np.ndarray:
    """A standing person 1.75 m tall, 0.45 m across."""
    return slab(rng, (x - 0.2, y - 0.2, 0.0), (x + 0.2, y + 0.2, 1.75), n)


def cluster_of(*pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points N x 4 with z the height above the ground, label: all cluster 0, which piece each point came from)."""
    xyz = np.concatenate(pieces)
    points = np.zeros((len(xyz), 4), dtype=np.float32)
    points[:, :3] = xyz
    which = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
    return points, np.zeros(len(xyz), dtype=np.int64), which


def test_people_under_a_roof_are_cut_off_it() -> None:
    """Three people 8 m ahead under a roof 6 x 3 m, 2.4-2.7 m up: the roof's points leave the cluster, the people's
    stay."""
    rng = np.random.default_rng(0)
    roof = slab(rng, (5.0, -1.5, 2.4), (11.0, 1.5, 2.7), 600)
    points, label, which = cluster_of(person(rng, 7.0, 0.0), person(rng, 8.0, 0.6), person(rng, 9.0, -0.5), roof)
    out = cut(points, label, np.array([0]))
    assert (out[which < 3] == 0).all()
    assert (out[which == 3] == -1).mean() > 0.95  # all of the roof above max_top (2.3 m): here all of it


@pytest.mark.parametrize("what", ["a trunk", "a tree with its crown", "a pole with a lamp head"])
def test_columns_and_crowns_stay_whole(what: str) -> None:
    """What continues upward as narrow as below (a trunk, a pole and its lamp) or as a layer deeper than a roof (a
    crown 3 m across, 2.5-4.5 m up) is not a canopy: the cluster stays as it was (and is dropped, as before)."""
    rng = np.random.default_rng(1)
    trunk = slab(rng, (8.0, 0.0, 0.0), (8.3, 0.3, 4.0), 300)
    pieces = {"a trunk": [trunk],
              "a tree with its crown": [trunk, slab(rng, (6.6, -1.4, 2.5), (9.7, 1.7, 4.5), 800)],
              "a pole with a lamp head": [slab(rng, (8.0, 0.0, 0.0), (8.15, 0.15, 5.0), 200),
                                          slab(rng, (8.0, 0.0, 4.8), (9.2, 0.3, 5.0), 60)]}[what]
    points, label, _ = cluster_of(*pieces)
    np.testing.assert_array_equal(cut(points, label, np.array([0])), label, err_msg=what)


def test_far_parts_are_not_looked_at_and_other_clusters_are_left_alone() -> None:
    """A part centred beyond CANOPY_RANGE_M, or one not reaching above max_top, is not looked at; a roofed cluster not
    among the parts asked about keeps its points."""
    centre = np.array([[8.0, 0.0], [20.0, 0.0], [8.0, 0.0]])
    top = np.array([2.7, 2.7, 2.0])
    np.testing.assert_array_equal(canopy.looked_at(centre, top, MAX_TOP), [True, False, False])
    rng = np.random.default_rng(2)
    points, label, _ = cluster_of(person(rng, 8.0, 0.0), slab(rng, (5.0, -1.5, 2.4), (11.0, 1.5, 2.7), 600))
    label[:] = 3
    np.testing.assert_array_equal(cut(points, label, np.array([1])), label)


def test_cut_canopies_is_on_by_default() -> None:
    """On since rule C3 passed (docs/experiments/sensors.md); `cut_canopies=false` gives the proposals before it."""
    assert Stage1Config().cut_canopies is True
    assert Stage1Config(cut_canopies=False).cut_canopies is False
