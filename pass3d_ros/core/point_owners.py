"""Which published object each point of a scan belongs to, and a tracked scan's vote painted back onto those points:
compiled passes over the road-user points and the scan (numpy's lookups, gathers and scatters over them cost about
half a millisecond a scan, half the tracker's budget, where a loop costs a fraction of it)."""

from __future__ import annotations

import numba as nb
import numpy as np

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.objects import FrameObjects

MAX_TABLE = 1 << 16  # object_points looks cluster ids below this up in a table


def object_points(objects: FrameObjects) -> tuple[np.ndarray, np.ndarray]:
    """The points that belong to an object and, for each, its object's index in `objects.objects`: the road-user
    points whose cluster id is an object's (the one-object rule makes that exactly the object's points). Ids below
    MAX_TABLE (a proposal's first object) are looked up in a table, the others (split parts, a few) by binary search."""
    ids = np.array([obj.cluster_id for obj in objects.objects], dtype=np.int64)
    road = np.flatnonzero(objects.labels != BACKGROUND)  # numpy's vectorised pass: a scan is mostly background
    return _owners(road, objects.cluster_id, ids, MAX_TABLE)


@nb.njit(cache=True, nogil=True)
def _owners(road: np.ndarray, point_ids: np.ndarray, ids: np.ndarray, max_table: int) -> tuple[np.ndarray, np.ndarray]:
    """The owners of the `road` points by `ids` (each object's cluster id; the last object of an id wins the table,
    the first the search), those of none dropped: one pass, each point written and the count moved on only for an
    object's (no branch on a coin toss to the processor)."""
    top = -1
    others = 0
    for k in range(len(ids)):
        if 0 <= ids[k] < max_table:
            top = max(top, ids[k])
        else:
            others += 1
    outside = top + 2
    table = np.full(top + 3, -1, np.int64)  # id + 1 -> owner; entry 0 (id -1) and the last (outside) own nothing
    far = np.empty(others, np.int64)
    j = 0
    for k in range(len(ids)):
        if 0 <= ids[k] < max_table:
            table[ids[k] + 1] = k
        else:
            far[j] = k
            j += 1
    order = far[np.argsort(ids[far], kind="mergesort")]
    far_ids = ids[order]
    members = np.empty(len(road), np.int64)
    owner = np.empty(len(road), np.int64)
    n = 0
    for m in range(len(road)):
        i = road[m]
        at = min(np.uint64(np.int64(point_ids[i]) + 1), np.uint64(outside))  # below -1 wraps round: outside
        found = table[at]
        if others and (at == 0 or at == outside):  # a split part's id (none in most scans)
            wanted = np.int64(point_ids[i])
            k = np.searchsorted(far_ids, wanted)
            if k < others and far_ids[k] == wanted:
                found = order[k]
        members[n] = i
        owner[n] = found
        n += found >= 0
    return members[:n], owner[:n]


@nb.njit(cache=True, nogil=True)
def paint(labels: np.ndarray, members: np.ndarray, owner: np.ndarray, voted: np.ndarray, published: np.ndarray,
          no_track: int) -> tuple[np.ndarray, np.ndarray]:
    """A copy of `labels` with each object's points (`members`, `owner` their objects) of its voted class, and each
    point's track id (`published` per object; `no_track` for the points in no object)."""
    out = labels.copy()
    track_id = np.full(len(labels), no_track, np.int32)
    for m in range(len(members)):
        out[members[m]] = voted[owner[m]]
        track_id[members[m]] = published[owner[m]]
    return out, track_id


@nb.njit(cache=True, nogil=True)
def take_rows(points: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """points[rows] (a new C-ordered array of their dtype), gathered row by row: numpy's fancy indexing of a strided
    scan costs half again as much."""
    out = np.empty((len(rows), points.shape[1]), points.dtype)
    for i in range(len(rows)):
        for j in range(points.shape[1]):
            out[i, j] = points[rows[i], j]
    return out
