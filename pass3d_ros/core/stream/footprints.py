"""An object's footprint: the ground-plane cells its points fall in, and how much two footprints share. The tracker
matches a scan's objects to its tracks by shared cells as well as by box centres: a car seen from behind, then from
the side, moves its box centre by metres while most of its points stay where the track's last points were, and the two
fragments stage 1 sometimes cuts a car into both lie on the car's cells.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

CELL_M = 0.5  # the side of a footprint cell, metres
MAX_POINTS = 64  # points of an object kept for its footprint (evenly spaced in scan order, so every ring keeps some)
_OFFSET = 1 << 20  # cell indices shifted positive (any position within +-500 km)
_ROW = 1 << 21


class Footprints(NamedTuple):
    """Several objects' footprint points at once: `xy` (M, 2) one object's after another, `counts` (K,) how many each
    has (flat arrays: a scan's 60 objects cost one transform and one sort, not 60)."""

    xy: np.ndarray
    counts: np.ndarray

    @classmethod
    def of(cls, each: Sequence[np.ndarray]) -> Footprints:
        """From one (M_k, 2) array per object."""
        counts = np.array([len(xy) for xy in each], dtype=np.int64)
        return cls(np.concatenate(each).reshape(-1, 2) if len(each) else np.zeros((0, 2)), counts)

    def split(self) -> list[np.ndarray]:
        """One (M_k, 2) array per object."""
        return np.split(self.xy, np.cumsum(self.counts)[:-1]) if len(self.counts) else []


def sample(xy: np.ndarray, limit: int = MAX_POINTS) -> np.ndarray:
    """At most `limit` of the rows of `xy`, evenly spaced (all of them when there are fewer)."""
    if len(xy) <= limit:
        return xy
    return xy[np.linspace(0, len(xy) - 1, limit).astype(np.int64)]


def point_cells(xy: np.ndarray) -> np.ndarray:
    """The key of the CELL_M cell each point of `xy` (M, 2) falls in."""
    index = np.floor(np.asarray(xy, dtype=np.float64) / CELL_M).astype(np.int64) + _OFFSET
    return index[:, 0] * _ROW + index[:, 1]


def cells(xy: np.ndarray) -> np.ndarray:
    """The sorted unique keys of the CELL_M cells the points `xy` (M, 2) fall in."""
    return np.unique(point_cells(xy))


def extent(xy: np.ndarray) -> tuple[float, float, np.ndarray]:
    """The longer and shorter side (m) of the smallest box along the principal axes of the points `xy` (M, 2), and
    the longer side's direction (a unit vector)."""
    if len(xy) < 2:
        return 0.0, 0.0, np.array([1.0, 0.0])
    centred = xy - xy.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    sides = np.ptp(centred @ vectors, axis=0)
    longer = int(np.argmax(sides))
    return float(sides[longer]), float(sides[1 - longer]), vectors[:, longer]


def grouped_cells(xy: np.ndarray, counts: Sequence[int] | np.ndarray) -> list[np.ndarray]:
    """`cells` of each of several footprints at once: `xy` (M, 2) their points one after another, `counts` how many
    each has (a footprint of no points has no cells)."""
    counts = np.asarray(counts, dtype=np.int64)
    group = np.repeat(np.arange(len(counts)), counts)
    keys = point_cells(xy) if len(xy) else np.zeros(0, np.int64)
    order = np.lexsort((keys, group))
    keys, group = keys[order], group[order]
    first = np.r_[True, (keys[1:] != keys[:-1]) | (group[1:] != group[:-1])] if len(keys) else np.zeros(0, bool)
    keys, group = keys[first], group[first]
    return np.split(keys, np.searchsorted(group, np.arange(1, len(counts))))


def group_sample(group: np.ndarray, limit: int = MAX_POINTS) -> np.ndarray:
    """A mask keeping at most `limit` evenly spaced members of each group of `group` (sorted group numbers), as `sample`
    keeps them of one, for all groups at once."""
    n = len(group)
    if not n:
        return np.zeros(0, bool)
    start = np.r_[0, np.flatnonzero(group[1:] != group[:-1]) + 1]
    size = np.diff(np.r_[start, n])
    rank = np.arange(n) - np.repeat(start, size)
    total = np.repeat(size, size)
    step = (rank * limit) // total
    return (total <= limit) | (rank == 0) | (step != ((rank - 1) * limit) // total)


def shared_cells(first: Sequence[np.ndarray], second: Sequence[np.ndarray]) -> np.ndarray:
    """(len(first), len(second)) counts of the cells each footprint of `first` shares with each of `second` (both
    lists of `cells` keys)."""
    out = np.zeros((len(first), len(second)), np.int64)
    if not len(first) or not len(second):
        return out
    keys = np.concatenate(first)
    owner = np.repeat(np.arange(len(first)), [len(k) for k in first])
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    wanted = np.concatenate(second)
    asker = np.repeat(np.arange(len(second)), [len(k) for k in second])
    position, count = matching(keys, wanted)
    np.add.at(out, (owner[position], np.repeat(asker, count)), 1)
    return out


def matching(keys: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The positions in `keys` (sorted) of every entry equal to one of `wanted`, in `wanted`'s order, and how many each
    of `wanted` matched."""
    left = np.searchsorted(keys, wanted, "left")
    count = np.searchsorted(keys, wanted, "right") - left
    ends = np.cumsum(count)
    total = int(ends[-1]) if len(ends) else 0
    return np.repeat(left, count) + np.arange(total) - np.repeat(ends - count, count), count


def overlap(first: Sequence[np.ndarray], second: Sequence[np.ndarray]) -> np.ndarray:
    """Shared cells over the smaller footprint of each pair (0..1): 1 when one footprint lies within the other."""
    shared = shared_cells(first, second)
    smaller = np.minimum(np.array([len(k) for k in first])[:, None], np.array([len(k) for k in second])[None, :])
    return shared / np.maximum(smaller, 1)
