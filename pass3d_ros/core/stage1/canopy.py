"""People under a canopy: what stands under an awning, a shelter's roof or a covered walkway is cut off the roof.

People walking under a roof 2.0-3.0 m up come within scan-line-run clustering's reach of its underside; their part
of `rerun_dropped` then holds the roof too, rises above `max_top` and is dropped whole (the parking lot's crowd
frames, docs/experiments/sensors.md, rules C2 and C3). Such a part loses its points higher than `max_top` above the
ground before its gates, but only where those points are a canopy: they spread CANOPY_MIN_SPREAD_M or more across
in a layer at most CANOPY_MAX_DEPTH_M deep. A trunk or a pole continues upward as narrow as below (cut, it would be
a person-sized column), a tree's crown is deeper than a roof: both stay whole, as before.
"""

from __future__ import annotations

import numpy as np

CANOPY_MIN_SPREAD_M = 2.0  # the roof seen over a part spreads at least this far across (x or y) ...
CANOPY_MAX_DEPTH_M = 1.0  # ... in a layer at most this deep (a crown is 1.5 m deep or more)
CANOPY_RANGE_M = 15.0  # parts centred farther than this are left whole: a roof's underside is read from near only


def under_canopies(points: np.ndarray, label: np.ndarray, parts: np.ndarray, height: np.ndarray,
                   max_top: float) -> np.ndarray:
    """Labels where the points higher than `max_top` of the clusters `parts` (ids) belong to no cluster (-1),
    for each such cluster centred within CANOPY_RANGE_M whose points above `max_top` form a canopy (module docstring).
    `height`: each point's height above the ground (NaN where not read); points of other clusters are never
    touched."""
    out = label.copy()
    if len(parts) == 0:
        return out
    n = int(max(label.max(initial=-1), parts.max())) + 1
    chosen = np.zeros(n, dtype=bool)
    chosen[parts] = True
    inside = np.flatnonzero((label >= 0) & chosen[np.maximum(label, 0)])
    count = np.maximum(np.bincount(label[inside], minlength=n), 1)
    centre = np.stack([np.bincount(label[inside], weights=points[inside, k], minlength=n) / count for k in (0, 1)], 1)
    near = chosen & (np.hypot(centre[:, 0], centre[:, 1]) <= CANOPY_RANGE_M)
    high = inside[near[label[inside]] & (height[inside] > max_top)]
    if len(high) == 0:
        return out
    owner = label[high]
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    for k, values in enumerate((points[high, 0], points[high, 1], height[high])):
        np.minimum.at(lo[:, k], owner, values)
        np.maximum.at(hi[:, k], owner, values)
    spread = np.max(hi[:, :2] - lo[:, :2], axis=1)
    canopy = (spread >= CANOPY_MIN_SPREAD_M) & (hi[:, 2] - lo[:, 2] <= CANOPY_MAX_DEPTH_M)
    out[high[canopy[owner]]] = -1
    return out
