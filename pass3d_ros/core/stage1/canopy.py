"""People under a canopy: what stands under an awning, a shelter's roof or a covered walkway is cut off the roof.

People walking under a roof 2.0-3.0 m up come within scan-line-run clustering's reach of its underside; their part
of `rerun_dropped` then holds the roof too, rises above `max_top` and is dropped whole (the parking lot's crowd
frames, docs/experiments/sensors.md, rules C2 and C3). Such a part (centred within CANOPY_RANGE_M) loses its points
higher than `max_top` above the ground before its gates, but only where those points are a canopy: they spread
CANOPY_MIN_SPREAD_M or more across in a layer at most CANOPY_MAX_DEPTH_M deep. A trunk or a pole continues upward as
narrow as below (cut, it would be a person-sized column), a tree's crown is deeper than a roof: both stay whole, as
before.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.ground import plane_distance

CANOPY_MIN_SPREAD_M = 2.0  # the roof seen over a part spreads at least this far across (x or y) ...
CANOPY_MAX_DEPTH_M = 1.0  # ... in a layer at most this deep (a crown is 1.5 m deep or more)
CANOPY_RANGE_M = 15.0  # parts centred farther than this are left whole: a roof's underside is read from near only


def looked_at(centre: np.ndarray, top: np.ndarray, max_top: float) -> np.ndarray:
    """Per cluster (its x-y centre, its highest point above the ground), whether a canopy over it is looked for:
    centred within CANOPY_RANGE_M and reaching above `max_top`."""
    return (np.hypot(centre[:, 0], centre[:, 1]) <= CANOPY_RANGE_M) & (top > max_top)


@nb.njit(cache=True, nogil=True)
def _high_points(pts: np.ndarray, label: np.ndarray, slot: np.ndarray, offset: np.ndarray, planes: np.ndarray,
                 x0: float, width: float, max_top: float) -> tuple:
    """The points of the clusters with a slot (slot[label] >= 0) higher than `max_top` above the ground (their
    segment plane's height less their cluster's `offset`), and per slot their bounds (x lo, x hi, y lo, y hi, height
    lo, height hi)."""
    n_slots = offset.shape[0]
    bounds = np.empty((n_slots, 6))
    for k in range(n_slots):
        bounds[k, 0] = bounds[k, 2] = bounds[k, 4] = np.inf
        bounds[k, 1] = bounds[k, 3] = bounds[k, 5] = -np.inf
    high = np.empty(pts.shape[0], dtype=np.int64)
    n_high = 0
    for i in range(pts.shape[0]):
        c = label[i]
        if c < 0 or c >= slot.shape[0] or slot[c] < 0:
            continue
        k = slot[c]
        x = pts[i, 0]
        y = pts[i, 1]
        h = plane_distance(planes, x0, width, x, y, pts[i, 2]) - offset[k]
        if h <= max_top:
            continue
        high[n_high] = i
        n_high += 1
        bounds[k, 0] = min(bounds[k, 0], x)
        bounds[k, 1] = max(bounds[k, 1], x)
        bounds[k, 2] = min(bounds[k, 2], y)
        bounds[k, 3] = max(bounds[k, 3], y)
        bounds[k, 4] = min(bounds[k, 4], h)
        bounds[k, 5] = max(bounds[k, 5], h)
    return high[:n_high], bounds


def under_canopies(points: np.ndarray, label: np.ndarray, parts: np.ndarray, offset: np.ndarray, planes: np.ndarray,
                   segment_edges: np.ndarray, max_top: float) -> np.ndarray:
    """Labels where the points higher than `max_top` above the ground of each cluster of `parts` (ids, chosen by
    `looked_at`) belong to no cluster (-1) where they form a canopy (module docstring); `label` itself when none
    does. Heights as the gates read them: the point's segment plane (`planes`, `segment_edges`), less the local
    ground's `offset` at its cluster's centre (one per part, 0 without a local ground). Points of other clusters are
    never touched."""
    if len(parts) == 0:
        return label
    slot = np.full(int(parts.max()) + 1, -1, dtype=np.int64)
    slot[parts] = np.arange(len(parts))
    high, b = _high_points(points, label, slot, np.asarray(offset, dtype=np.float64), planes,
                           float(segment_edges[0]), float(segment_edges[1] - segment_edges[0]), max_top)
    spread = np.maximum(b[:, 1] - b[:, 0], b[:, 3] - b[:, 2])
    canopy = (spread >= CANOPY_MIN_SPREAD_M) & (b[:, 5] - b[:, 4] <= CANOPY_MAX_DEPTH_M)
    cut = high[canopy[slot[label[high]]]]
    if len(cut) == 0:
        return label
    out = label.copy()
    out[cut] = -1
    return out


def warm_up() -> None:
    """Compile the kernel on one point, with stage 1's dtypes (float32 points, int32 labels)."""
    _high_points(np.zeros((1, 4), dtype=np.float32), np.zeros(1, dtype=np.int32), np.zeros(1, dtype=np.int64),
                 np.zeros(1), np.array([[0.0, 0.0, 1.0, 1.73]]), -80.0, 160.0, 2.3)
