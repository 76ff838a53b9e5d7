"""Returns of the vehicle's own body (and the sensor's mount), read from a recording without labels: returns near the
sensor and off the ground that come back from the same place relative to the sensor in nearly every scan while the
scene around changes. Their farthest range is the `stage1.min_range` that leaves them out of stage 1 (nuScenes keeps
them, and stage 1 proposes them as one object that stage 2 calls a car: docs/adapt.md).

`SelfReturnReader` judges the scans it is given (pass3d_adapt gives it scans spread over a recording; a stream with
`stage1.min_range: auto` gives it one every half second: pass3d_ros.core.stream.body).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SEARCH_M = 4.0  # body returns are looked for nearer than this (3D range): a roof sensor's view of its own vehicle
SCENE_M = (8.0, 40.0)  # the scene's cells, whose persistence tells a recording made standing still
CELL_DEG = 1.0  # cells of azimuth x elevation
PERSISTENT = 0.9  # a body cell holds a return in at least this share of the scans...
SPREAD_M = 0.1  # ...at a steady range: the median absolute deviation of its range over the scans at most this
ABOVE_GROUND_M = 0.25  # only returns this far above the ground near the sensor count (the road persists too)
GROUND_NEAR_M = 10.0  # the ground's height is the median height of stage 1's ground points within this range
MIN_SCANS = 5  # fewer scans cannot tell a body from a scene that happens to stay
MIN_CELLS = 3  # fewer persistent cells are taken for noise
STILL_SHARE = 0.5  # scene cells this persistent (of those seen in half the scans or more): the vehicle stood still
MARGIN_M = 0.1  # the radius lies this far beyond the farthest body return, rounded up to 0.1 m
_AZIMUTH_CELLS = round(360.0 / CELL_DEG)


@dataclass(frozen=True)
class SelfReturns:
    """What a recording says about its vehicle's own returns; `radius_m` 0.0 when none were read (`note` says why)."""

    radius_m: float
    cells: int  # persistent cells found near the sensor
    scans: int
    scene_persistent: float | None  # the share of scene cells that persisted (None: no scene cell seen often)
    note: str


class SelfReturnReader:
    """Collects each scan's nearest return per cell near the sensor and in the scene; `read()` judges them."""

    def __init__(self) -> None:
        self._near: list[tuple[np.ndarray, np.ndarray]] = []
        self._scene: list[tuple[np.ndarray, np.ndarray]] = []

    def add(self, points: np.ndarray, ground: np.ndarray) -> None:
        """One scan: (N, >=3) points in the sensor frame and stage 1's ground mask of them."""
        xyz = points[:, :3].astype(np.float64)
        r = np.linalg.norm(xyz, axis=1)
        off = ~ground & (r > 0.0)
        horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
        near_ground = ground & (horizontal < GROUND_NEAR_M)
        if near_ground.any():
            off &= xyz[:, 2] > float(np.median(xyz[near_ground, 2])) + ABOVE_GROUND_M
        azimuth = np.floor((np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])) + 180.0) / CELL_DEG).astype(np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            elevation = np.floor((np.degrees(np.arcsin(np.clip(xyz[:, 2] / r, -1.0, 1.0))) + 90.0) / CELL_DEG)
        key = np.nan_to_num(elevation).astype(np.int64) * _AZIMUTH_CELLS + azimuth % _AZIMUTH_CELLS
        near = off & (r < SEARCH_M)
        scene = off & (r >= SCENE_M[0]) & (r < SCENE_M[1])
        self._near.append(_nearest_per_cell(key[near], r[near]))
        self._scene.append(_nearest_per_cell(key[scene], r[scene]))

    @property
    def scans(self) -> int:
        """Scans added (and not dropped)."""
        return len(self._near)

    def drop_oldest(self, count: int) -> None:
        """Forget the `count` oldest scans."""
        del self._near[:count], self._scene[:count]

    def read(self) -> SelfReturns:
        """The body's radius, or 0.0 with the reason: too few scans, a still vehicle, nothing persistent."""
        scans = self.scans
        if scans < MIN_SCANS:
            return SelfReturns(0.0, 0, scans, None, f"{scans} scan(s): {MIN_SCANS} or more are "
                                                    "needed to tell the vehicle's own returns from the scene")
        scene_share = _persistent_share(self._scene, scans)
        if scene_share is not None and scene_share >= STILL_SHARE:
            return SelfReturns(0.0, 0, scans, scene_share, f"{100 * scene_share:.0f} % of the scene stayed put: "
                                                           "the vehicle stood still, so nothing near it is taken for "
                                                           "its body")
        cells, ranges = _persistent_cells(self._near, scans)
        if len(cells) < MIN_CELLS:
            return SelfReturns(0.0, len(cells), scans, scene_share, "no returns of the vehicle's own body")
        farthest = float(ranges.max())
        radius = float(np.ceil((farthest + MARGIN_M) * 10.0) / 10.0)
        return SelfReturns(radius, len(cells), scans, scene_share,
                           f"{len(cells)} cells near the sensor return from the same place in {100 * PERSISTENT:.0f} "
                           f"% of the scans or more, the farthest at {farthest:.2f} m (median over the scans)")


def _nearest_per_cell(key: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's key and its nearest return's range."""
    order = np.lexsort((r, key))
    first = np.flatnonzero(np.r_[True, np.diff(key[order]) != 0]) if len(order) else np.zeros(0, dtype=np.int64)
    return key[order][first], r[order][first]


def _cell_statistics(per_scan: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """Over the scans: each cell's key, how many scans saw it, its median range and the median absolute deviation of
    its range."""
    keys = np.concatenate([k for k, _ in per_scan]) if per_scan else np.zeros(0, dtype=np.int64)
    ranges = np.concatenate([r for _, r in per_scan]) if per_scan else np.zeros(0)
    if len(keys) == 0:
        empty = np.zeros(0)
        return empty.astype(np.int64), empty.astype(np.int64), empty, empty
    order = np.lexsort((ranges, keys))
    keys, ranges = keys[order], ranges[order]
    cells, start, count = np.unique(keys, return_index=True, return_counts=True)
    median = ranges[start + count // 2]
    group = np.repeat(np.arange(len(cells)), count)
    deviation = np.abs(ranges - median[group])
    deviation = deviation[np.lexsort((deviation, group))]
    return cells, count, median, deviation[start + count // 2]


def _persistent_cells(per_scan: list[tuple[np.ndarray, np.ndarray]], scans: int) -> tuple[np.ndarray, np.ndarray]:
    """The cells seen in PERSISTENT of the scans at a steady range, and their median ranges (a scan whose body return
    was missed there reads a farther one)."""
    cells, count, median, spread = _cell_statistics(per_scan)
    keep = _persistent(count, spread, scans)
    return cells[keep], median[keep]


def _persistent_share(per_scan: list[tuple[np.ndarray, np.ndarray]], scans: int) -> float | None:
    """Of the cells seen in half the scans or more, the share that persisted (None: no such cell)."""
    _, count, _, spread = _cell_statistics(per_scan)
    often = count >= 0.5 * scans
    if not often.any():
        return None
    return float(np.mean(_persistent(count[often], spread[often], scans)))


def _persistent(count: np.ndarray, spread: np.ndarray, scans: int) -> np.ndarray:
    """Cells seen in PERSISTENT of the `scans` at a steady range (a median absolute deviation of SPREAD_M or less)."""
    return (count >= PERSISTENT * scans) & (spread <= SPREAD_M)
