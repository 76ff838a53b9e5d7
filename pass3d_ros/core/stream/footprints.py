"""An object's footprint: the ground-plane cells its points fall in, and how much two footprints share. The tracker
matches a scan's objects to its tracks by shared cells as well as by box centres: a car seen from behind, then from
the side, moves its box centre by metres while most of its points stay where the track's last points were, and the two
fragments stage 1 sometimes cuts a car into both lie on the car's cells.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numba as nb
import numpy as np

CELL_M = 0.5  # the side of a footprint cell, metres
MAX_POINTS = 64  # points of an object kept for its footprint (evenly spaced in scan order, so every ring keeps some)
GOLDEN = 0.6180339887498949  # footprint_members' hash: index times this, modulo 1 (evenly spread, fixed per point)
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
        return pieces(self.xy, self.counts)


MIN_EDGE_POINTS = 5  # footprint points a track and a detection each need for `edge_shifts` to read a move


@nb.njit(cache=True, nogil=True)
def edge_shifts(rows: np.ndarray, states: np.ndarray, offsets: np.ndarray, counts: np.ndarray, xy: np.ndarray,
                starts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far each track's object moved since its prediction, read from the box edge that moved least: per track
    row of `rows`, its predicted footprint (`states`' x, y plus its first `counts` `offsets`) and its detection's
    footprint points (`xy[starts[k]:starts[k + 1]]`) are measured along the footprint's principal axis and across it;
    on each axis the nearer of the two edges' shifts is the move. A moving car moves both ends alike; a parked car seen
    by another side keeps one end where it was while its box centre jumps by metres. (R, 2) shifts, (R, 2) moves of
    the footprints' box centres (the two edges' mean shift) and whether each was read (MIN_EDGE_POINTS on both
    sides)."""
    shifts = np.zeros((len(rows), 2))
    centres = np.zeros((len(rows), 2))
    read = np.zeros(len(rows), np.bool_)
    for k in range(len(rows)):
        r = rows[k]
        n, first, last = counts[r], starts[k], starts[k + 1]
        if n < MIN_EDGE_POINTS or last - first < MIN_EDGE_POINTS:
            continue
        mx, my = 0.0, 0.0
        for i in range(n):
            mx += offsets[r, i, 0]
            my += offsets[r, i, 1]
        mx, my = mx / n, my / n
        cxx, cyy, cxy = 0.0, 0.0, 0.0
        for i in range(n):
            dx, dy = offsets[r, i, 0] - mx, offsets[r, i, 1] - my
            cxx += dx * dx
            cyy += dy * dy
            cxy += dx * dy
        theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
        axes = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
        for a in range(2):
            ax, ay = axes[a, 0], axes[a, 1]
            lo, hi = np.inf, -np.inf
            for i in range(n):
                v = (states[r, 0] + offsets[r, i, 0]) * ax + (states[r, 1] + offsets[r, i, 1]) * ay
                lo, hi = min(lo, v), max(hi, v)
            dlo, dhi = np.inf, -np.inf
            for i in range(first, last):
                v = xy[i, 0] * ax + xy[i, 1] * ay
                dlo, dhi = min(dlo, v), max(dhi, v)
            move = dlo - lo if abs(dlo - lo) <= abs(dhi - hi) else dhi - hi
            centre = 0.5 * (dlo - lo + dhi - hi)
            shifts[k, 0] += move * ax
            shifts[k, 1] += move * ay
            centres[k, 0] += centre * ax
            centres[k, 1] += centre * ay
        read[k] = True
    return shifts, centres, read


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


def cell_sets(xy: np.ndarray, counts: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`cells` of each of several footprints at once (`xy` (M, 2) their points one after another, `counts` how many
    each has): every footprint's sorted unique keys one after another, and where each starts (its end last)."""
    counts = np.asarray(counts, dtype=np.int64)
    return _unique_groups(np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2), counts)


def pieces(flat: np.ndarray, sizes: np.ndarray) -> list[np.ndarray]:
    """`flat` cut into consecutive pieces of `sizes` (a list of views: np.split costs ten times more)."""
    ends = np.cumsum(sizes).tolist()
    return [flat[start:end] for start, end in zip([0, *ends[:-1]] if ends else [], ends, strict=True)]


MARKS = 1024  # a footprint whose cells' bounding box holds at most this many cells is sorted by marking them


@nb.njit(cache=True, nogil=True)
def _insert(out: np.ndarray, first: int, written: int, key: int) -> int:
    """`key` into the sorted unique keys out[first:written] unless there; the new end (an insertion sort step)."""
    at = written
    while at > first and out[at - 1] > key:
        at -= 1
    if at > first and out[at - 1] == key:
        return written
    for k in range(written, at, -1):
        out[k] = out[k - 1]
    out[at] = key
    return written + 1


@nb.njit(cache=True, nogil=True)
def _group_cells(columns: np.ndarray, rows: np.ndarray, n: int, out: np.ndarray, written: int,
                 marks: np.ndarray) -> int:
    """The sorted unique keys of the cells (columns[:n], rows[:n]) written to `out` from `written`; the new end. The
    cells are marked in their bounding box (`marks`, all False, left so) and read back in key order: a footprint's
    box holds a few dozen cells, and marking has none of an insertion sort's unforeseeable branches; a larger box
    (or one whose size overflows: a non-finite or far-flung point) is insertion sorted."""
    if n == 0:
        return written
    c0, c1, r0, r1 = columns[0], columns[0], rows[0], rows[0]
    for m in range(1, n):
        c0, c1 = min(c0, columns[m]), max(c1, columns[m])
        r0, r1 = min(r0, rows[m]), max(r1, rows[m])
    width, height = c1 - c0 + 1, r1 - r0 + 1  # either wraps below 1 for cells of a non-finite point or far apart
    if not (0 < width <= len(marks) and 0 < height <= len(marks) and width * height <= len(marks)):
        first = written
        for m in range(n):
            written = _insert(out, first, written, (columns[m] + _OFFSET) * _ROW + rows[m] + _OFFSET)
        return written
    for m in range(n):
        marks[(columns[m] - c0) * height + rows[m] - r0] = True
    for c in range(width):
        for r in range(height):
            if marks[c * height + r]:
                marks[c * height + r] = False
                out[written] = (c0 + c + _OFFSET) * _ROW + r0 + r + _OFFSET
                written += 1
    return written


@nb.njit(cache=True, nogil=True)
def _unique_groups(xy: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each group's sorted unique cell keys (`point_cells` of groups of `counts` consecutive points), one group after
    another, and where each starts (the end last)."""
    out = np.empty(len(xy), np.int64)
    starts = np.zeros(len(counts) + 1, np.int64)
    longest = 0
    for g in range(len(counts)):
        longest = max(longest, counts[g])
    columns, rows = np.empty(longest, np.int64), np.empty(longest, np.int64)
    marks = np.zeros(MARKS, np.bool_)
    start = 0
    written = 0
    for g in range(len(counts)):
        for m in range(counts[g]):
            columns[m] = np.int64(np.floor(xy[start + m, 0] / CELL_M))
            rows[m] = np.int64(np.floor(xy[start + m, 1] / CELL_M))
        written = _group_cells(columns, rows, counts[g], out, written, marks)
        start += counts[g]
        starts[g + 1] = written
    return out[:written], starts


@nb.njit(cache=True, nogil=True)
def rows_cells(xy: np.ndarray, counts: np.ndarray, rows: np.ndarray,
               shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`cell_sets` of footprints kept as rows of `xy` (R, L, 2), row r's first counts[r] points: those of `rows`, row r
    moved by shift[r, :2] (a track's remembered offsets carried to its predicted centre)."""
    total = 0
    for r in rows:
        total += counts[r]
    out = np.empty(total, np.int64)
    starts = np.zeros(len(rows) + 1, np.int64)
    columns, cell_rows = np.empty(xy.shape[1], np.int64), np.empty(xy.shape[1], np.int64)
    marks = np.zeros(MARKS, np.bool_)
    written = 0
    for g in range(len(rows)):
        r = rows[g]
        for m in range(counts[r]):
            columns[m] = np.int64(np.floor((xy[r, m, 0] + shift[r, 0]) / CELL_M))
            cell_rows[m] = np.int64(np.floor((xy[r, m, 1] + shift[r, 1]) / CELL_M))
        written = _group_cells(columns, cell_rows, counts[r], out, written, marks)
        starts[g + 1] = written
    return out[:written], starts


@nb.njit(cache=True, nogil=True)
def keep_rows(xy: np.ndarray, chosen: np.ndarray, kept: np.ndarray, rows: np.ndarray, centres: np.ndarray,
              into: np.ndarray, counts: np.ndarray) -> None:
    """Footprints kept as rows (`rows_cells`): object k's points xy[chosen] (kept[k] of them, one object's after
    another) less its row's centre (centres[rows[k], :2]) into row rows[k] of `into`, its count into `counts`; an
    object of no points keeps its row's footprint."""
    start = 0
    for k in range(len(kept)):
        r = rows[k]
        if kept[k]:
            for m in range(kept[k]):
                into[r, m, 0] = xy[chosen[start + m], 0] - centres[r, 0]
                into[r, m, 1] = xy[chosen[start + m], 1] - centres[r, 1]
            counts[r] = kept[k]
        start += kept[k]


@nb.njit(cache=True, nogil=True)
def _starts(kept: np.ndarray) -> np.ndarray:
    """Where each object's share starts in an array of all of them, one object's after another."""
    start = np.zeros(len(kept), np.int64)
    for k in range(1, len(kept)):
        start[k] = start[k - 1] + kept[k - 1]
    return start


@nb.njit(cache=True, nogil=True)
def evenly_spaced(members: np.ndarray, owner: np.ndarray, count: int, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """At most `limit` evenly spaced of each object's `members` (in their order; `owner` each one's object, 0 ..
    count - 1), one object's after another, and how many each has: of an object of n members, those at
    np.linspace(0, n - 1, limit) (all of them when n <= limit), for all objects in two passes and no sort."""
    total = np.zeros(count, np.int64)
    for k in owner:
        total[k] += 1
    kept = np.minimum(total, limit)
    start = _starts(kept)
    out = np.empty(int(kept.sum()), members.dtype)
    rank = np.zeros(count, np.int64)
    taken = np.zeros(count, np.int64)
    for m in range(len(members)):
        k = owner[m]
        r = rank[k]
        rank[k] += 1
        n = total[k]
        if n <= limit or (taken[k] < limit and r == int(taken[k] * ((n - 1) / (limit - 1)))):
            out[start[k]] = members[m]
            start[k] += 1
            taken[k] += 1
    return out, kept


@nb.njit(cache=True, nogil=True)
def footprint_members(members: np.ndarray, owner: np.ndarray, count: int, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Each object's footprint points among its `members` (in their order; `owner` each one's object, 0 .. count - 1),
    one object's after another, and how many each has: first thinned to about 2 x `limit` of each object's points by
    a fixed hash of the point's index (frac(index x golden ratio) below the object's share), then of the rest the first
    of each run sharing rank * limit // total: at most `limit` spread over the object. The members are put in their
    objects' order first (a stable counting sort), so each object is then one short run of memory, read twice."""
    total = np.zeros(count, np.int64)
    for k in owner:
        total[k] += 1
    at = _starts(total)
    ordered = np.empty(len(members), members.dtype)
    for m in range(len(members)):
        ordered[at[owner[m]]] = members[m]
        at[owner[m]] += 1
    thin = np.empty(len(members), members.dtype)
    out = np.empty(len(members), members.dtype)
    kept = np.zeros(count, np.int64)
    written = 0
    start = 0
    for k in range(count):
        share = min(1.0, 2 * limit / max(total[k], 1))
        left = 0
        for m in range(start, start + total[k]):
            x = ordered[m] * GOLDEN
            thin[left] = ordered[m]
            left += x - np.floor(x) < share
        start += total[k]
        first = written
        if left <= limit:
            out[written:written + left] = thin[:left]
            written += left
        elif limit > 0:
            out[written] = thin[0]
            written += 1
            rest = 0  # rank * limit modulo left, kept as the rank grows: a new run where it passes left
            for r in range(1, left):
                rest += limit
                run = rest >= left
                rest -= left * run
                out[written] = thin[r]
                written += run
        kept[k] = written - first
    return out[:written], kept


def nearest_owner(xy: np.ndarray, footprints: Sequence[np.ndarray]) -> np.ndarray:
    """For each point of `xy` (M, 2), the index of the footprint (each (F_k, 2+) points) holding the point nearest it
    in x, y."""
    every = np.concatenate([np.asarray(f, dtype=np.float64)[:, :2] for f in footprints])
    which = np.repeat(np.arange(len(footprints)), [len(f) for f in footprints])
    return which[_nearest(np.ascontiguousarray(xy, dtype=np.float64), every)]


@nb.njit(cache=True, nogil=True)
def _nearest(xy: np.ndarray, every: np.ndarray) -> np.ndarray:
    """Index into `every` of the point nearest each point of `xy`."""
    out = np.empty(len(xy), np.int64)
    for i in range(len(xy)):
        best, at = np.inf, 0
        for j in range(len(every)):
            dx, dy = xy[i, 0] - every[j, 0], xy[i, 1] - every[j, 1]
            d = dx * dx + dy * dy
            if d < best:
                best, at = d, j
        out[i] = at
    return out


def shared_cells(first: tuple[np.ndarray, np.ndarray], second: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(len(first), len(second)) counts of the cells each footprint of `first` shares with each of `second` (both
    `cell_sets`: keys, starts)."""
    return _shared(first[0], first[1], second[0], second[1])


@nb.njit(cache=True, nogil=True)
def _shared(first: np.ndarray, first_at: np.ndarray, second: np.ndarray, second_at: np.ndarray) -> np.ndarray:
    """The shared counts of `shared_cells`, each pair's two sorted key lists merged (pairs whose key ranges do not
    meet are skipped: most pairs of a scan lie apart)."""
    out = np.zeros((len(first_at) - 1, len(second_at) - 1), np.int64)
    for i in range(len(first_at) - 1):
        a0, a1 = first_at[i], first_at[i + 1]
        if a0 == a1:
            continue
        for j in range(len(second_at) - 1):
            b0, b1 = second_at[j], second_at[j + 1]
            if b0 == b1 or first[a1 - 1] < second[b0] or second[b1 - 1] < first[a0]:
                continue
            a, b, n = a0, b0, 0
            while a < a1 and b < b1:
                if first[a] == second[b]:
                    n += 1
                    a += 1
                    b += 1
                elif first[a] < second[b]:
                    a += 1
                else:
                    b += 1
            out[i, j] = n
    return out


def matching(keys: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The positions in `keys` (sorted) of every entry equal to one of `wanted`, in `wanted`'s order, and how many each
    of `wanted` matched."""
    left = np.searchsorted(keys, wanted, "left")
    count = np.searchsorted(keys, wanted, "right") - left
    ends = np.cumsum(count)
    total = int(ends[-1]) if len(ends) else 0
    return np.repeat(left, count) + np.arange(total) - np.repeat(ends - count, count), count
