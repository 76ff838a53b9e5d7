"""People under a canopy (pass3d_ros.core.stage1.canopy, `stage1.cut_canopies`): a roof over a part is cut off it; a
trunk, a pole or a tree's crown is not."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1 import Stage1Config, canopy

MAX_TOP = Stage1Config().max_top


def slab(rng: np.random.Generator, lo: tuple[float, float, float], hi: tuple[float, float, float],
         n: int) -> np.ndarray:
    """`n` points spread uniformly in the box from `lo` to `hi` (x, y, height above ground)."""
    return rng.uniform(lo, hi, (n, 3))


def person(rng: np.random.Generator, x: float, y: float, n: int = 150) -> np.ndarray:
    """A standing person 1.75 m tall, 0.45 m across."""
    return slab(rng, (x - 0.2, y - 0.2, 0.0), (x + 0.2, y + 0.2, 1.75), n)


def cluster_of(*pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(points N x 4, label: all cluster 0, height above ground, which piece each point came from)."""
    xyz = np.concatenate(pieces)
    points = np.zeros((len(xyz), 4), dtype=np.float32)
    points[:, :3] = xyz
    which = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
    return points, np.zeros(len(xyz), dtype=np.int32), xyz[:, 2].astype(np.float64), which


def test_people_under_a_roof_are_cut_off_it() -> None:
    """Three people 8 m ahead under a roof 6 x 3 m, 2.4-2.7 m up: the roof's points leave the cluster, the people's
    stay."""
    rng = np.random.default_rng(0)
    roof = slab(rng, (5.0, -1.5, 2.4), (11.0, 1.5, 2.7), 600)
    points, label, height, which = cluster_of(person(rng, 7.0, 0.0), person(rng, 8.0, 0.6), person(rng, 9.0, -0.5),
                                              roof)
    out = canopy.under_canopies(points, label, np.array([0]), height, MAX_TOP)
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
    points, label, height, _ = cluster_of(*pieces)
    out = canopy.under_canopies(points, label, np.array([0]), height, MAX_TOP)
    np.testing.assert_array_equal(out, label, err_msg=what)


def test_far_parts_and_other_clusters_are_left_alone() -> None:
    """The same people under the same roof 20 m away (beyond CANOPY_RANGE_M), and a near roofed cluster not among
    the parts asked about: nothing changes."""
    rng = np.random.default_rng(2)
    far = cluster_of(person(rng, 20.0, 0.0), slab(rng, (17.0, -1.5, 2.4), (23.0, 1.5, 2.7), 600))
    out = canopy.under_canopies(far[0], far[1], np.array([0]), far[2], MAX_TOP)
    np.testing.assert_array_equal(out, far[1])
    points, label, height, _ = cluster_of(person(rng, 8.0, 0.0), slab(rng, (5.0, -1.5, 2.4), (11.0, 1.5, 2.7), 600))
    label[:] = 3
    out = canopy.under_canopies(points, label, np.array([1]), np.where(label == 1, height, np.nan), MAX_TOP)
    np.testing.assert_array_equal(out, label)


def test_cut_canopies_is_off_by_default_and_named_in_the_config() -> None:
    """The option exists and is off until its rule passes (docs/experiments/sensors.md, rule C3)."""
    assert Stage1Config().cut_canopies is False
    assert Stage1Config(cut_canopies=True).cut_canopies is True
