"""A car track's remembered shape: the voxels its objects' points filled over its last sightings.

Stage 1 often proposes only a part of a car (its windows and roof without the boot, the near half of a parked car whose
far half lies in no cluster): the object, and so the labelled cloud, then holds less than half of the car, and the
car's published class flips between scans (docs/experiments/tracks.md, "Where the ground-truth flicker left comes
from"). The track has seen the rest of the car before. Its shape is the VOXEL_M voxels its objects' points filled in
each of its last `sightings` sightings (tracking frame), each sighting moved by the track's velocity times its age, so
a moving car's shape moves with it; a point of a scan that stage 2 left background, in no proposal and off the ground,
that falls in a voxel of the shape is the track's (rule N).

Kept for speed as one ring of sightings per track in fixed arrays: a sighting's voxel keys sorted once when it is
remembered; a scan's points are then looked up where a coarse grid says a shape may be, one binary search per
sighting, with no per-scan sorting (`shape_owners`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

VOXEL_M = 0.4  # the side of a shape's voxels
SHAPE_POINTS = 128  # voxels of one sighting kept at most (its points strided evenly in scan order down to this)
GRID_M = 1.0  # the coarse grid that finds the shapes a point may fall in
GRID_CELLS = 512  # ... at most this many cells along x or y: shapes far apart (a stamp or a pose that jumps moves a
# sighting by its velocity times hours, or tracks by kilometres) get coarser cells, never a grid of gigabytes
_OFFSET = 1 << 20  # voxel indices shifted positive (any position within +-400 km)
_FIRST_ROWS = 32
_MANY = -2  # a grid cell two shapes or more reach
DENSE_IDS = 1 << 16  # remembered tracks' ids spanning at most this many are found by a table


@nb.njit(cache=True, nogil=True, inline="always")
def _key(x: float, y: float, z: float, voxel: float) -> int:
    return (((int(np.floor(x / voxel)) + _OFFSET) << 42) | ((int(np.floor(y / voxel)) + _OFFSET) << 21)
            | (int(np.floor(z / voxel)) + _OFFSET))


@nb.njit(cache=True, nogil=True, inline="always")
def _moved(points: np.ndarray, i: int, rotation: np.ndarray, shift: np.ndarray) -> tuple[float, float, float]:
    """Point i of `points` in the tracking frame (p @ rotation.T + shift)."""
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    return (rotation[0, 0] * px + rotation[0, 1] * py + rotation[0, 2] * pz + shift[0],
            rotation[1, 0] * px + rotation[1, 1] * py + rotation[1, 2] * pz + shift[1],
            rotation[2, 0] * px + rotation[2, 1] * py + rotation[2, 2] * pz + shift[2])


@nb.njit(cache=True, nogil=True)
def _remember_kernel(points: np.ndarray, road: np.ndarray, labels: np.ndarray, track_id: np.ndarray, label: int,
                     ids: np.ndarray, rows: np.ndarray, at: np.ndarray, rotation: np.ndarray, shift: np.ndarray,
                     keys: np.ndarray, counts: np.ndarray, boxes: np.ndarray, voxel: float) -> None:
    """Sighting `at[j]` of row `rows[j]`, for track `ids[j]` (ascending): the sorted unique voxel keys, in the tracking
    frame (p @ rotation.T + shift), of the points of `road` labelled `label` whose track id is `ids[j]` (every one, or
    evenly strided down to the room of a sighting), and their x-y box."""
    room = keys.shape[2]
    n_ids = ids.shape[0]
    slot = np.full(road.shape[0], -1, np.int64)
    total = np.zeros(n_ids, np.int64)
    first_id = ids[0]
    span = ids[n_ids - 1] - first_id + 1
    dense = span <= DENSE_IDS  # track ids to slots by a table (alive tracks' ids lie close), else a binary search
    table = np.full(span if dense else 0, -1, np.int64)
    for j in range(n_ids):
        if dense:
            table[ids[j] - first_id] = j
    for q in range(road.shape[0]):
        i = road[q]
        if labels[i] != label:
            continue
        wanted = track_id[i] - first_id
        if wanted < 0 or wanted >= span:
            continue
        if dense:
            j = table[wanted]
        else:
            j = np.searchsorted(ids, track_id[i])
            j = j if j < n_ids and ids[j] == track_id[i] else -1
        if j >= 0:
            slot[q] = j
            total[j] += 1
    start = np.zeros(n_ids + 1, np.int64)
    for j in range(n_ids):
        start[j + 1] = start[j] + min(total[j], room)
    buffer = np.empty(start[n_ids], np.int64)
    filled = np.zeros(n_ids, np.int64)
    passed = np.zeros(n_ids, np.int64)
    for j in range(n_ids):
        box = boxes[rows[j], at[j]]
        box[0] = box[2] = np.inf
        box[1] = box[3] = -np.inf
    for q in range(road.shape[0]):
        j = slot[q]
        if j < 0:
            continue
        stride = (total[j] + room - 1) // room
        passed[j] += 1
        if (passed[j] - 1) % stride or filled[j] == start[j + 1] - start[j]:
            continue
        x, y, z = _moved(points, road[q], rotation, shift)
        box = boxes[rows[j], at[j]]
        box[0] = min(box[0], x)
        box[1] = max(box[1], x)
        box[2] = min(box[2], y)
        box[3] = max(box[3], y)
        buffer[start[j] + filled[j]] = _key(x, y, z, voxel)
        filled[j] += 1
    for j in range(n_ids):
        r, k = rows[j], at[j]
        mine = np.sort(buffer[start[j]:start[j] + filled[j]])
        m = 0
        for c in range(mine.shape[0]):
            if m == 0 or mine[c] != keys[r, k, m - 1]:
                keys[r, k, m] = mine[c]
                m += 1
        counts[r, k] = m


@nb.njit(cache=True, nogil=True)
def _found(keys: np.ndarray, key: int) -> bool:
    """Whether `key` is among the sorted `keys`."""
    at = np.searchsorted(keys, key)
    return at < keys.shape[0] and keys[at] == key


@nb.njit(cache=True, nogil=True)
def _owners_kernel(points: np.ndarray, labels: np.ndarray, cluster_id: np.ndarray, ground: np.ndarray,
                   rotation: np.ndarray, shift: np.ndarray,
                   rows: np.ndarray, keys: np.ndarray, counts: np.ndarray, moved: np.ndarray, boxes: np.ndarray,
                   voxel: float, grid_m: float) -> np.ndarray:
    """Per point, the index into `rows` of the shape it falls in (the lowest where several do); -1 for none, and for
    a point labelled a road user, in a proposal (`cluster_id` >= 0) or on the ground (`ground`, when not empty).
    `rotation`, `shift`: points -> tracking frame (p @ rotation.T + shift); `moved` (T, K, 2): how far each sighting
    moved since it was seen; `boxes` (T, K, 4) its x-y box as seen."""
    n = points.shape[0]
    out = np.full(n, -1, np.int64)
    t_count = rows.shape[0]
    if t_count == 0:
        return out
    x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
    reach = np.empty((t_count, 4))
    for t in range(t_count):
        reach[t, 0] = reach[t, 2] = np.inf
        reach[t, 1] = reach[t, 3] = -np.inf
        for k in range(keys.shape[1]):
            if counts[rows[t], k] == 0:
                continue
            b = boxes[rows[t], k]
            reach[t, 0] = min(reach[t, 0], b[0] + moved[t, k, 0] - voxel)
            reach[t, 1] = max(reach[t, 1], b[1] + moved[t, k, 0] + voxel)
            reach[t, 2] = min(reach[t, 2], b[2] + moved[t, k, 1] - voxel)
            reach[t, 3] = max(reach[t, 3], b[3] + moved[t, k, 1] + voxel)
        if not reach[t, 0] <= reach[t, 1]:  # no point in any sighting: a shape of nothing
            continue
        x0, x1 = min(x0, reach[t, 0]), max(x1, reach[t, 1])
        y0, y1 = min(y0, reach[t, 2]), max(y1, reach[t, 3])
    if not x0 < x1 or not np.isfinite(x1 - x0 + y1 - y0):
        return out
    grid_m = max(grid_m, (x1 - x0) / GRID_CELLS, (y1 - y0) / GRID_CELLS)  # the grid only narrows the search
    nx, ny = int((x1 - x0) / grid_m) + 1, int((y1 - y0) / grid_m) + 1
    grid = np.full((nx, ny), -1, np.int64)
    for t in range(t_count):
        if not reach[t, 0] <= reach[t, 1]:
            continue
        for gx in range(int((reach[t, 0] - x0) / grid_m), int((reach[t, 1] - x0) / grid_m) + 1):
            for gy in range(int((reach[t, 2] - y0) / grid_m), int((reach[t, 3] - y0) / grid_m) + 1):
                grid[gx, gy] = t if grid[gx, gy] == -1 else _MANY
    has_ground = ground.shape[0] == n
    for i in range(n):
        if labels[i] != 0 or cluster_id[i] >= 0 or (has_ground and ground[i]):
            continue
        x, y, z = _moved(points, i, rotation, shift)
        if not (x0 <= x < x1 and y0 <= y < y1):  # NaN too: it would index the grid anywhere
            continue
        cell = grid[int((x - x0) / grid_m), int((y - y0) / grid_m)]
        if cell == -1:
            continue
        first, last = (cell, cell + 1) if cell >= 0 else (0, t_count)
        for t in range(first, last):
            if x < reach[t, 0] or x > reach[t, 1] or y < reach[t, 2] or y > reach[t, 3]:
                continue
            r = rows[t]
            hit = False
            for k in range(keys.shape[1]):
                m = counts[r, k]
                if m and _found(keys[r, k, :m], _key(x - moved[t, k, 0], y - moved[t, k, 1], z, voxel)):
                    hit = True
                    break
            if hit:
                out[i] = t
                break
    return out


class ShapeMemory:
    """The remembered sightings of a stream's car tracks (module docstring), by track id: the last `sightings` of
    each, a ring in fixed arrays (a row per track)."""

    def __init__(self, sightings: int, voxel_m: float = VOXEL_M) -> None:
        self.sightings, self.voxel_m = sightings, voxel_m
        self._row: dict[int, int] = {}
        self._free: list[int] = []
        self._grow(_FIRST_ROWS)

    def _grow(self, rows: int) -> None:
        old = getattr(self, "keys", None)
        keys = np.zeros((rows, self.sightings, SHAPE_POINTS), np.int64)
        counts = np.zeros((rows, self.sightings), np.int64)
        stamps = np.zeros((rows, self.sightings))
        boxes = np.zeros((rows, self.sightings, 4))
        nexts = np.zeros(rows, np.int64)
        if old is not None:
            used = len(old)
            keys[:used], counts[:used], stamps[:used] = self.keys, self.counts, self.stamps
            boxes[:used], nexts[:used] = self.boxes, self.nexts
        first = 0 if old is None else len(old)
        self._free.extend(range(rows - 1, first - 1, -1))
        self.keys, self.counts, self.stamps, self.boxes, self.nexts = keys, counts, stamps, boxes, nexts

    def __len__(self) -> int:
        return len(self._row)

    def __contains__(self, track_id: int) -> bool:
        return track_id in self._row

    def rows_of(self, track_ids: list[int]) -> np.ndarray:
        """The rows of tracks that have a shape (each must)."""
        return np.array([self._row[t] for t in track_ids], np.int64)

    def remember(self, track_ids: list[int], stamp_s: float, points: np.ndarray, road: np.ndarray,
                 labels: np.ndarray, track_id: np.ndarray, label: int,
                 to_tracking: tuple[np.ndarray, np.ndarray]) -> None:
        """One sighting at `stamp_s` of each track of `track_ids`: the points among `road` (indices into `points`)
        labelled `label` whose `track_id` is its id, taken into the tracking frame by `to_tracking` (rotation,
        shift), strided evenly down to SHAPE_POINTS; a track with no such point keeps an empty sighting."""
        if not track_ids:
            return
        ids = np.array(sorted(set(track_ids)), np.int64)
        rows = np.empty(len(ids), np.int64)
        for j, track in enumerate(ids.tolist()):
            row = self._row.get(track)
            if row is None:
                if not self._free:
                    self._grow(2 * len(self.keys))
                row = self._row[track] = self._free.pop()
                self.counts[row] = 0
                self.nexts[row] = 0
            rows[j] = row
        at = self.nexts[rows].copy()
        self.nexts[rows] = (at + 1) % self.sightings
        self.stamps[rows, at] = stamp_s
        rotation, shift = to_tracking
        _remember_kernel(points, road, labels, track_id, label, ids, rows, at,
                         np.ascontiguousarray(rotation, np.float64), np.ascontiguousarray(shift, np.float64),
                         self.keys, self.counts, self.boxes, self.voxel_m)

    def keep_only(self, track_ids: set[int]) -> None:
        """Forget the tracks not in `track_ids` (ended ones): their rows are free."""
        for gone in [t for t in self._row if t not in track_ids]:
            self._free.append(self._row.pop(gone))

    def owners(self, points: np.ndarray, labels: np.ndarray, cluster_id: np.ndarray, ground: np.ndarray | None,
               to_tracking: tuple[np.ndarray, np.ndarray], track_ids: list[int], velocities: np.ndarray,
               stamp_s: float) -> np.ndarray:
        """Per point of `points` (N, >=3) labelled background (`labels`), in no proposal (`cluster_id` -1) and off
        the `ground` (when known), the index into `track_ids` of the shape it falls in (each track's sightings moved
        by its velocity (T, 2; tracking frame) times their age at `stamp_s`); -1 for none and for the other points.
        `to_tracking` (rotation, shift) takes the points into the tracking frame."""
        rows = self.rows_of(track_ids)
        if not len(rows):
            return np.full(len(points), -1, np.int64)
        age = stamp_s - self.stamps[rows]  # (T, K)
        moved = np.asarray(velocities, np.float64)[:, None, :] * age[:, :, None]
        rotation, shift = to_tracking
        ground = np.zeros(0, np.bool_) if ground is None else np.asarray(ground, np.bool_)
        return _owners_kernel(points, labels, cluster_id, ground, np.ascontiguousarray(rotation, np.float64),
                              np.ascontiguousarray(shift, np.float64), rows, self.keys, self.counts,
                              np.ascontiguousarray(moved), self.boxes, self.voxel_m, GRID_M)


def warm_up() -> None:
    """Compile the kernels on one tiny shape."""
    memory = ShapeMemory(2)
    cube = np.array([[1.0, 1.0, 0.0], [1.5, 1.2, 0.5]], np.float32)
    identity = (np.eye(3), np.zeros(3))
    memory.remember([0], 0.0, cube, np.arange(2), np.ones(2, np.uint8), np.zeros(2, np.int32), 1, identity)
    memory.owners(cube, np.zeros(2, np.uint8), np.full(2, -1, np.int32), None, identity, [0], np.zeros((1, 2)), 0.1)
