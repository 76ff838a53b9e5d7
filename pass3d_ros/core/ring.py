"""Ring (laser) index of every point of a scan that lacks a ring field: from the firing order when the points
are in it (the fast path), else from a named sensor's laser table or from the scan's own elevation structure.

Firing order. A Velodyne scan stored in firing order (KITTI `.bin`) lists one laser's revolution after the other, each
sweeping azimuth upwards. Three boundary rules are tried and the better one that passes validation wins:

* ``azimuth_wrap``: a new ring starts where the azimuth crosses the start angle in the direction of rotation:
  the +x axis, from quadrant 4 into quadrant 1 (KITTI's layout; the +-180 degree jump is then not a ring
  start), or the -x axis for scans cut behind the sensor. A camera crop that keeps the firing order keeps
  KITTI's boundaries (each ring is then an arc [0, a] followed by [-a, 0]).
* ``azimuth_jump``: a new ring starts where the azimuth steps backwards by a large angle: scans whose rings
  are frontal arcs that do not contain the start angle (a crop of a scan cut behind the sensor).

Validation: the ring count is at most Stage1Config's ``n_rings`` (a few lasers may return nothing) and not far
below it, and the mean elevation falls ring by ring. Among valid candidates the one with the smallest elevation
spread inside rings wins.

Any order (``elevation_lines``). Seen from the sensor origin, a laser with elevation angle e mounted h metres above
the origin (the HDL-64E's two blocks sit about 0.2 and 0.12 m up) returns points with z / r = tan(e) + h / r
(r: horizontal range): one straight line per laser in the plane (u = 1 / r, t = z / r). A Hough accumulator over
(intercept, slope) of every few points finds the lines (peaks of its best-slope profile), each point takes the
nearest line, and each line is refitted to its points by least squares (twice). The lines' count is the ring count
(valid when close below 16, 32, 64 or 128); ring 0 is the line with the highest elevation. With Stage1Config's
``sensor`` set to a known model (``laser_table``) the table's lasers seed the lines instead of the peaks.

If nothing is valid, rings come from binning the elevation angle (``elevation_bins``), approximate even for
evenly spaced lasers: the result's ``source`` says so, for the caller to report.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.config import Stage1Config
from pass3d_ros.core.lasers import STANDARD_RING_COUNTS, laser_elevations

RING_SOURCES: tuple[str, ...] = (
    "field", "azimuth_wrap", "azimuth_jump", "laser_table", "elevation_lines", "elevation_bins"
)
FIRING_ORDER_SOURCES: tuple[str, ...] = ("azimuth_wrap", "azimuth_jump")  # rings read from the point order

_T_MAX = 0.8  # largest |tan(elevation)| the line search covers (about 38.7 degrees)
_T_BIN = 0.0005  # accumulator bin of tan(elevation), about 0.03 degrees
_SLOPES = np.round(np.arange(-0.1, 0.3001, 0.01), 4)  # laser heights above the origin searched (m)
_SEARCH_POINTS = 20000  # points the accumulator reads at most (every k-th point)
_MIN_LINE_RANGE = 2.0  # nearer points are left out of the line search and fits (m)


class Rings(NamedTuple):
    """Ring index per point, how it was obtained (one of RING_SOURCES), and the number of rings found."""

    ring: np.ndarray  # (N,) uint16
    source: str
    n_rings: int = 0


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


@nb.njit(cache=True)
def _line_accumulator(pts: np.ndarray, stride: int, min_range: float, slopes: np.ndarray, n_bins: int) -> np.ndarray:
    """Votes of every `stride`-th point beyond `min_range` for (slope, intercept bin) of t = a + slope * u."""
    acc = np.zeros((slopes.shape[0], n_bins), dtype=np.float32)
    min_r2 = min_range * min_range
    for i in range(0, pts.shape[0], stride):
        r2 = pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]
        if r2 < min_r2:
            continue
        r = np.sqrt(r2)
        u = 1.0 / r
        t = pts[i, 2] / r
        for j in range(slopes.shape[0]):
            b = int(np.floor((t - slopes[j] * u + _T_MAX) / _T_BIN))
            if 0 <= b < n_bins:
                acc[j, b] += 1.0
    return acc


@nb.njit(cache=True)
def _assign_lines(pts: np.ndarray, a: np.ndarray, b: np.ndarray, window: int) -> tuple:
    """Nearest line (a descending) per point, and its |t - a - b u| distance; lines near the binary-search hit of
    t - mean(b) u are the candidates (`window` either side)."""
    n = pts.shape[0]
    k_lines = a.shape[0]
    ring = np.zeros(n, dtype=np.uint16)
    resid = np.empty(n, dtype=np.float64)
    b_mean = b.mean()
    for i in range(n):
        r = max(np.sqrt(pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]), 0.1)
        u = 1.0 / r
        t = pts[i, 2] / r
        key = t - b_mean * u
        lo = 0
        hi = k_lines
        while lo < hi:
            mid = (lo + hi) >> 1
            if a[mid] > key:
                lo = mid + 1
            else:
                hi = mid
        best = np.inf
        best_k = 0
        for k in range(max(0, lo - window), min(k_lines, lo + window + 1)):
            d = abs(t - a[k] - b[k] * u)
            if d < best:
                best = d
                best_k = k
        ring[i] = best_k
        resid[i] = best
    return ring, resid


@nb.njit(cache=True)
def _refit_lines(pts: np.ndarray, ring: np.ndarray, resid: np.ndarray, a: np.ndarray, b: np.ndarray,
                 tol: np.ndarray, min_range: float) -> None:
    """Least-squares refit of every line to its points within `tol` of it (beyond `min_range`), in place; a line
    whose points span too little of u keeps its slope and refits its intercept only."""
    k_lines = a.shape[0]
    sn = np.zeros(k_lines)
    su = np.zeros(k_lines)
    st = np.zeros(k_lines)
    suu = np.zeros(k_lines)
    sut = np.zeros(k_lines)
    min_r2 = min_range * min_range
    for i in range(pts.shape[0]):
        k = ring[i]
        r2 = pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]
        if r2 < min_r2 or resid[i] > tol[k]:
            continue
        r = np.sqrt(r2)
        u = 1.0 / r
        t = pts[i, 2] / r
        sn[k] += 1.0
        su[k] += u
        st[k] += t
        suu[k] += u * u
        sut[k] += u * t
    for k in range(k_lines):
        if sn[k] < 3.0:
            continue
        mu = su[k] / sn[k]
        mt = st[k] / sn[k]
        var = suu[k] / sn[k] - mu * mu
        if var > 1e-4:
            b[k] = (sut[k] / sn[k] - mu * mt) / var
        a[k] = mt - b[k] * mu


def _peaks(profile: np.ndarray, half: int, floor: float) -> np.ndarray:
    """Bins that hold the largest value within `half` bins either side and at least `floor` (first of ties)."""
    padded = np.pad(profile, half, constant_values=-1.0)
    local = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=1)
    peaks = np.flatnonzero((profile >= local) & (profile >= floor))
    if len(peaks) > 1:
        peaks = peaks[np.concatenate(([True], np.diff(peaks) > half))]
    return peaks


def _accumulate(pts: np.ndarray) -> np.ndarray:
    """The (slope, intercept) accumulator of the line search, smoothed along the intercept by [1, 2, 1], less
    the larger of its means 2..3 bins either side: a laser's line is a narrow spike at its slope, smeared votes
    (ground, walls, wrong slopes) are broad and cancel."""
    stride = max(1, len(pts) // _SEARCH_POINTS)
    n_bins = round(2 * _T_MAX / _T_BIN)
    acc = _line_accumulator(pts, stride, _MIN_LINE_RANGE, _SLOPES, n_bins)
    padded = np.pad(acc, ((0, 0), (4, 4)))
    smooth = 2.0 * acc + padded[:, 3:-5] + padded[:, 5:-3]
    left = 2.0 * (padded[:, 1:-7] + padded[:, 2:-6])
    right = 2.0 * (padded[:, 6:-2] + padded[:, 7:-1])
    return smooth - np.maximum(left, right)


def _lines_from_scan(acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line intercepts (descending) and slopes at the peaks of the accumulator's sharpest slope row (largest sum
    of squared positive responses): the lasers' common height above the origin. A ring whose points share one
    range (flat ground) votes a spike into every row, so rows are chosen as a whole, and each line's own slope
    is left to the refits."""
    sharpness = (np.maximum(acc, 0.0) ** 2).sum(axis=1)
    row = int(sharpness.argmax())
    profile = acc[row]
    top = np.sort(profile)[-8:].mean() if len(profile) else 0.0
    peaks = _peaks(profile, 2, max(16.0, 0.05 * top))
    while len(peaks) > 2:
        gaps = np.diff(peaks)
        k = int(gaps.argmin())
        if gaps[k] >= 0.5 * np.median(gaps):
            break
        peaks = np.delete(peaks, k if profile[peaks[k]] < profile[peaks[k + 1]] else k + 1)
    a = (peaks + 0.5) * _T_BIN - _T_MAX
    return a[::-1].copy(), np.full(len(a), _SLOPES[row])


def _lines_from_table(acc: np.ndarray, elevations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line intercepts and slopes seeded by a laser table: each laser takes the accumulator's best cell within
    half the gap to its neighbours; a laser with no votes there keeps its table angle and the median slope."""
    tan_e = np.tan(elevations)
    centre = np.floor((tan_e + _T_MAX) / _T_BIN).astype(np.int64)
    gaps = np.abs(np.diff(centre))
    half = np.maximum(np.minimum(np.r_[gaps, gaps[-1:]], np.r_[gaps[:1], gaps]) // 2, 1)
    a = tan_e.copy()
    b = np.full(len(tan_e), np.nan)
    n_bins = acc.shape[1]
    for k in range(len(tan_e)):
        lo, hi = max(centre[k] - half[k], 0), min(centre[k] + half[k] + 1, n_bins)
        if hi <= lo:
            continue
        window = acc[:, lo:hi]
        j, i = np.unravel_index(int(window.argmax()), window.shape)
        if window[j, i] > 0.0:
            a[k] = (lo + i + 0.5) * _T_BIN - _T_MAX
            b[k] = _SLOPES[j]
    b[np.isnan(b)] = np.nanmedian(b) if np.isfinite(b).any() else 0.0
    return a, b


def fit_laser_lines(pts: np.ndarray, a: np.ndarray, b: np.ndarray, iterations: int = 2) -> tuple:
    """Ring per point after `iterations` refits of the lines (a: intercepts, descending; b: slopes), and the
    refitted lines."""
    a = np.ascontiguousarray(a, dtype=np.float64).copy()
    b = np.ascontiguousarray(b, dtype=np.float64).copy()
    for step in range(iterations + 1):
        order = np.argsort(-a, kind="stable")
        a, b = a[order], b[order]
        ring, resid = _assign_lines(pts, a, b, 6)
        if step == iterations:
            break
        gaps = np.abs(np.diff(a))
        tol = np.maximum(0.4 * np.minimum(np.r_[gaps, np.inf], np.r_[np.inf, gaps]), _T_BIN)
        _refit_lines(pts, ring, resid, a, b, np.where(np.isfinite(tol), tol, 0.01), _MIN_LINE_RANGE)
    return ring, a, b


def standard_ring_count(n_found: int) -> int | None:
    """The standard laser count (16, 32, 64, 128) that `n_found` lines can be: at most it, and at most an eighth
    (at least two) below it; None if none fits."""
    for count in STANDARD_RING_COUNTS:
        if count - max(2, count // 8) <= n_found <= count:
            return count
    return None


def rings_from_lines(points: np.ndarray, sensor: str = "auto") -> Rings | None:
    """Rings of a scan in any point order, from its laser lines (module docstring): seeded by `sensor`'s laser
    table, or found in the scan (`sensor` "auto"; None when their count is not near a standard one)."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    acc = _accumulate(pts)
    if sensor != "auto":
        a, b = _lines_from_table(acc, laser_elevations(sensor))
        ring, a, _ = fit_laser_lines(pts, a, b)
        return Rings(ring, "laser_table", len(a))
    a, b = _lines_from_scan(acc)
    if standard_ring_count(len(a)) is None:
        return None
    ring, a, _ = fit_laser_lines(pts, a, b)
    return Rings(ring, "elevation_lines", len(a))


def recover_rings(
    points: np.ndarray,
    config: Stage1Config | None = None,
    *,
    min_jump_deg: float = 45.0,
    min_ring_points: int = 8,
    missing_tolerance: int = 4,
    min_range: float = 4.0,
) -> Rings:
    """Ring index per point of a scan without a ring field (see the module docstring for the rules): a named
    `config.sensor`'s table, else the firing order (expecting `config.n_rings` rings), else the laser lines found
    in the scan, else elevation bins.

    `min_jump_deg`: backward azimuth step that starts a ring in the ``azimuth_jump`` rule;
    `min_ring_points`: boundaries closer than this many points are noise; `missing_tolerance`: how many
    lasers may be absent; `min_range`: points nearer than this are left out of validation statistics
    (lasers sit off the sensor origin, so close points have distorted elevations).
    """
    cfg = config or Stage1Config()
    n_rings = cfg.n_rings
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if len(pts) == 0:
        return Rings(np.zeros(0, dtype=np.uint16), "azimuth_wrap", 0)
    if cfg.sensor != "auto":
        lines = rings_from_lines(pts, cfg.sensor)
        assert lines is not None
        return lines
    min_cos_jump = float(np.cos(np.deg2rad(min_jump_deg)))
    counts = _count_rings(pts, min_cos_jump, min_ring_points)
    best: tuple[float, np.ndarray, str, int] | None = None
    for rule, source in ((0, "azimuth_wrap"), (1, "azimuth_wrap"), (2, "azimuth_jump")):
        n_found = int(counts[rule])
        if n_found > n_rings or n_found < n_rings - missing_tolerance:
            continue
        ring = _segment(pts, rule, min_cos_jump, min_ring_points)
        spread = _validate(pts, ring, n_found, missing_tolerance, min_range)
        if spread is not None and (best is None or spread < best[0]):
            best = (spread, ring, source, n_found)
    if best is not None:
        return Rings(best[1], best[2], best[3])
    lines = rings_from_lines(pts) if len(pts) >= 64 else None
    if lines is not None:
        return lines
    elev = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
    return Rings(elevation_bins(elev, n_rings), "elevation_bins", n_rings)


def rings_for(points: np.ndarray, ring: np.ndarray | None, config: Stage1Config | None = None) -> Rings:
    """The given ring field when there is one (checked for length), else the rings recovered under `config`."""
    if ring is not None:
        ring = np.asarray(ring)
        if len(ring) != len(points):
            raise ValueError(f"ring field has {len(ring)} entries for {len(points)} points")
        return Rings(ring.astype(np.uint16, copy=False), "field", int(ring.max()) + 1 if len(ring) else 0)
    return recover_rings(points, config)


def warm_up() -> None:
    """Compile the ring kernels on a tiny synthetic scan."""
    az = np.linspace(0.0, 4.0 * np.pi, 64, endpoint=False)
    pts = np.zeros((64, 4), dtype=np.float32)
    pts[:, 0] = 10.0 * np.cos(az)
    pts[:, 1] = 10.0 * np.sin(az)
    pts[:, 2] = np.where(np.arange(64) < 32, 0.0, -1.0)
    recover_rings(pts, Stage1Config(n_rings=2), min_ring_points=2)
    rings_from_lines(pts, "vlp16")
