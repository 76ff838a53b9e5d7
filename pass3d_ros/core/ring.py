"""Ring (laser) index of every point of a scan that lacks a ring field, recovered from the firing order.

A Velodyne scan stored in firing order (KITTI `.bin`) lists one laser's revolution after the other, each
sweeping azimuth upwards. Three boundary rules are tried and the better one that passes validation wins:

* ``azimuth_wrap``: a new ring starts where the azimuth crosses the start angle in the direction of rotation:
  the +x axis, from quadrant 4 into quadrant 1 (KITTI's layout; the +-180 degree jump is then not a ring
  start), or the -x axis for scans cut behind the sensor. A camera crop that keeps the firing order keeps
  KITTI's boundaries (each ring is then an arc [0, a] followed by [-a, 0]).
* ``azimuth_jump``: a new ring starts where the azimuth steps backwards by a large angle: scans whose rings
  are frontal arcs that do not contain the start angle (a crop of a scan cut behind the sensor).

Validation: the ring count is at most Stage1Config's ``n_rings`` (a few lasers may return nothing) and not far
below it, and the mean elevation falls ring by ring. Among valid candidates the one with the smallest elevation
spread inside rings wins. If none is valid, rings come from binning the elevation angle
(``elevation_bins``), which is approximate for lasers whose spacing is not uniform.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.config import Stage1Config

RING_SOURCES: tuple[str, ...] = ("field", "azimuth_wrap", "azimuth_jump", "elevation_bins")


class Rings(NamedTuple):
    """Ring index per point and how it was obtained (one of RING_SOURCES)."""

    ring: np.ndarray  # (N,) uint16
    source: str


@nb.njit(cache=True, inline="always")
def _is_start(x0: float, y0: float, x1: float, y1: float, rule: int, min_cos_jump: float) -> bool:
    """Whether the step from point 0 to point 1 starts a ring under `rule`.

    rule 0: crossing of the +x axis from y < 0 to y >= 0; rule 1: crossing of the -x axis from y > 0 to
    y <= 0; rule 2: a backward azimuth step whose angle has a cosine below `min_cos_jump`.
    """
    if rule == 0:
        return y0 < 0.0 and y1 >= 0.0 and x0 > 0.0 and x1 > 0.0
    if rule == 1:
        return y0 > 0.0 and y1 <= 0.0 and x0 < 0.0 and x1 < 0.0
    cross = x0 * y1 - y0 * x1
    if cross > 0.0:
        return False
    dot = x0 * x1 + y0 * y1
    return dot < min_cos_jump * np.sqrt((x0 * x0 + y0 * y0) * (x1 * x1 + y1 * y1))


@nb.njit(cache=True)
def _count_rings(pts: np.ndarray, min_cos_jump: float, min_gap: int) -> np.ndarray:
    """Rings found by each of the three rules (one pass); starts closer than `min_gap` points are noise."""
    count = np.ones(3, dtype=np.int64)
    last = np.zeros(3, dtype=np.int64)
    for i in range(1, pts.shape[0]):
        x0 = pts[i - 1, 0]
        y0 = pts[i - 1, 1]
        x1 = pts[i, 0]
        y1 = pts[i, 1]
        for rule in range(3):
            if i - last[rule] >= min_gap and _is_start(x0, y0, x1, y1, rule, min_cos_jump):
                count[rule] += 1
                last[rule] = i
    return count


@nb.njit(cache=True)
def _segment(pts: np.ndarray, rule: int, min_cos_jump: float, min_gap: int) -> np.ndarray:
    """Ring index per point under one rule, counted as in `_count_rings`."""
    n = pts.shape[0]
    ring = np.zeros(n, dtype=np.uint16)
    current = 0
    last = 0
    for i in range(1, n):
        if i - last >= min_gap and _is_start(pts[i - 1, 0], pts[i - 1, 1], pts[i, 0], pts[i, 1], rule, min_cos_jump):
            current += 1
            last = i
        ring[i] = current
    return ring


@nb.njit(cache=True)
def _ring_stats(pts: np.ndarray, ring: np.ndarray, n_max: int, min_range: float, stride: int) -> tuple:
    """Per-ring mean tangent of elevation and the mean within-ring standard deviation of it, over every
    `stride`-th point beyond `min_range`."""
    count = np.zeros(n_max, dtype=np.int64)
    total = np.zeros(n_max, dtype=np.float64)
    total2 = np.zeros(n_max, dtype=np.float64)
    min_r2 = min_range * min_range
    for i in range(0, pts.shape[0], stride):
        r2 = pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]
        if r2 >= min_r2 and r2 > 0.0:
            t = pts[i, 2] / np.sqrt(r2)
            k = ring[i]
            count[k] += 1
            total[k] += t
            total2[k] += t * t
    mean = np.full(n_max, np.nan)
    spread = 0.0
    used = 0
    for k in range(n_max):
        if count[k] > 0:
            mean[k] = total[k] / count[k]
            spread += np.sqrt(max(total2[k] / count[k] - mean[k] * mean[k], 0.0)) * count[k]
            used += count[k]
    return mean, spread / max(used, 1)


def _validate(pts: np.ndarray, ring: np.ndarray, n_found: int, tolerance: int, min_range: float) -> float | None:
    """Mean within-ring elevation spread (standard deviation of tan) of a valid segmentation, else None."""
    stride = max(1, min(4, len(pts) // (64 * n_found)))
    mean, spread = _ring_stats(pts, ring, n_found, min_range, stride)
    mean = mean[np.isfinite(mean)]
    if len(mean) < n_found - tolerance or not np.all(np.diff(mean) < 0.0):
        return None
    return float(spread)


def elevation_bins(elev: np.ndarray, n_rings: int) -> np.ndarray:
    """Fallback ring index: uniform elevation bins between robust extremes, ring 0 the highest."""
    if len(elev) == 0:
        return np.zeros(0, dtype=np.uint16)
    lo, hi = np.percentile(elev, [0.2, 99.8])
    step = max((hi - lo) / n_rings, 1e-6)
    ring = np.floor((hi - elev) / step)
    return np.clip(ring, 0, n_rings - 1).astype(np.uint16)


def recover_rings(
    points: np.ndarray,
    config: Stage1Config | None = None,
    *,
    min_jump_deg: float = 45.0,
    min_ring_points: int = 8,
    missing_tolerance: int = 4,
    min_range: float = 4.0,
) -> Rings:
    """Ring index per point of a scan in firing order (see the module docstring for the rules); the ring count
    to expect is `config.n_rings` (default: Stage1Config()).

    `min_jump_deg`: backward azimuth step that starts a ring in the ``azimuth_jump`` rule;
    `min_ring_points`: boundaries closer than this many points are noise; `missing_tolerance`: how many
    lasers may be absent; `min_range`: points nearer than this are left out of validation statistics
    (lasers sit off the sensor origin, so close points have distorted elevations).
    """
    n_rings = (config or Stage1Config()).n_rings
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if len(pts) == 0:
        return Rings(np.zeros(0, dtype=np.uint16), "azimuth_wrap")
    min_cos_jump = float(np.cos(np.deg2rad(min_jump_deg)))
    counts = _count_rings(pts, min_cos_jump, min_ring_points)
    best: tuple[float, np.ndarray, str] | None = None
    for rule, source in ((0, "azimuth_wrap"), (1, "azimuth_wrap"), (2, "azimuth_jump")):
        n_found = int(counts[rule])
        if n_found > n_rings or n_found < n_rings - missing_tolerance:
            continue
        ring = _segment(pts, rule, min_cos_jump, min_ring_points)
        spread = _validate(pts, ring, n_found, missing_tolerance, min_range)
        if spread is not None and (best is None or spread < best[0]):
            best = (spread, ring, source)
    if best is None:
        elev = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
        return Rings(elevation_bins(elev, n_rings), "elevation_bins")
    return Rings(best[1], best[2])


def rings_for(points: np.ndarray, ring: np.ndarray | None, config: Stage1Config | None = None) -> Rings:
    """The given ring field when there is one (checked for length), else the rings recovered under `config`."""
    if ring is not None:
        ring = np.asarray(ring)
        if len(ring) != len(points):
            raise ValueError(f"ring field has {len(ring)} entries for {len(points)} points")
        return Rings(ring.astype(np.uint16, copy=False), "field")
    return recover_rings(points, config)


def warm_up() -> None:
    """Compile the ring kernels on a tiny synthetic scan."""
    az = np.linspace(0.0, 4.0 * np.pi, 64, endpoint=False)
    pts = np.zeros((64, 4), dtype=np.float32)
    pts[:, 0] = 10.0 * np.cos(az)
    pts[:, 1] = 10.0 * np.sin(az)
    pts[:, 2] = np.where(np.arange(64) < 32, 0.0, -1.0)
    recover_rings(pts, Stage1Config(n_rings=2), min_ring_points=2)
