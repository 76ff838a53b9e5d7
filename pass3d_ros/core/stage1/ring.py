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
(r: horizontal range): one straight line per laser in the plane (u = 1 / r, t = z / r); fitted with the true rings,
these lines give back all but a few of a real KITTI scan's 120k rings. The search reads a sample of about 20k points
chosen by a hash of their coordinates, so it finds the same lines whatever the point order:

1. A Hough accumulator over (intercept, slope); each band of intercepts reads the slope row sharpest there (the
   HDL-64E's blocks differ), and the peaks of that profile seed the lines.
2. Gaps are evened out against the local spacing (a missed peak is added, a doubled one merged), each point takes
   the nearest line, and the lines are refitted by least squares; a line whose points span too little range (a
   ring on flat ground) or whose slope is no laser height takes its neighbours' slope.
3. A gap that holds a laser's worth of far points gets a line of its own; steps 2-3 repeat until the count
   settles.
4. The lines are kept when their count is near 16, 32, 40, 64 or 128 and nearly all far points lie within a quarter
   gap of their line (`line_quality`); ring 0 is the line with the highest elevation.

Motion-corrected scans (``elevation_lines_moving``). KITTI's odometry / SemanticKITTI scans are corrected for the
car's motion during the revolution: each return is seen from where the sensor was when it fired, so the near lasers'
lines smear (by about a laser spacing at 0.8 m per revolution). `estimate_motion` finds the origin motion that
sharpens the lines most (linear in azimuth, zero facing forward: KITTI's convention) and the search runs on the points
seen from the moving origin.

With Stage1Config's ``sensor`` set to a known model (``laser_table``, ``laser_table_moving``) the table's lasers
seed the lines instead of the peaks, for scans whose point order does not give the table's laser count.

If nothing is valid, rings come from binning the elevation angle (``elevation_bins``), approximate even for
evenly spaced lasers: the result's ``source`` says so, for the caller to report.
"""

from __future__ import annotations

from concurrent.futures import Executor
from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.lasers import MISSING_LINES, STANDARD_RING_COUNTS, laser_elevations, ring_limit
from pass3d_ros.core.stage1.ring_field import measure_ring_order

RING_SOURCES: tuple[str, ...] = (
    "field", "azimuth_wrap", "azimuth_jump", "laser_table", "laser_table_moving", "elevation_lines",
    "elevation_lines_moving", "elevation_bins",
)
FIRING_ORDER_SOURCES: tuple[str, ...] = ("azimuth_wrap", "azimuth_jump")  # rings read from the point order

_T_MAX = 0.8  # largest |tan(elevation)| the line search covers (about 38.7 degrees)
_T_BIN = 0.0005  # accumulator bin of tan(elevation), about 0.03 degrees
_U_MAX, _U_CELLS = 0.5, 32  # the line assignment's first-guess table: u = 1 / range up to 0.5 (2 m), in 32 cells
_SPLIT_POINTS = 20000  # a scan with fewer points is assigned on one thread (a hand-off costs more than half)
_N_BINS = round(2 * _T_MAX / _T_BIN)  # accumulator bins
_SLOPES = np.round(np.arange(-0.1, 0.3001, 0.01), 4)  # laser heights above the origin searched (m)
_SEARCH_POINTS = 20000  # points the line search's accumulator reads, about (hash-chosen: the same in any order)
_FIT_POINTS = 10000  # points the line fits read, about (a hash-chosen part of the search sample)
_MIN_LINE_RANGE = 2.0  # nearer points are left out of the line search and fits (m)
_MAX_LINES = 144  # a line search that finds more lines than this has failed
_FILL_ROUNDS = 4  # rounds of gap filling and refitting at most
_MIN_QUALITY = 0.97  # line_quality a line set needs
_QUALITY_RANGE = 5.0  # line_quality reads the points beyond this range (m): clean elevations
_HALF_BAND = 120  # accumulator bins either side that choose a band's slope row (0.06 in tan(elevation))
_MOTION_STEPS = np.round(np.arange(-2.0, 2.01, 0.1), 2)  # origin motions along x per revolution searched (m)
_MOTION_SLOPES = np.array([0.12, 0.2])  # slope rows the motion search reads
_MOTION_POINTS = 1000  # sample points the motion search reads, about
_MOTION_GAIN = 1.2  # a motion is taken when it sharpens the lines by this factor
_MIN_U_VAR = 1e-4  # a line's points fix its slope when their u = 1 / r varies more than this (variance)
_BAND_MARGIN = 1.5  # a band reads its own slope row only when that row is this much sharper than the whole scan's


class LaserLines(NamedTuple):
    """The laser lines t = a + b u of one scan (intercepts descending: ring 0 first) and the origin motion per
    revolution they hold under: a property of the sensor, so a later scan of the same sensor can reuse them.

    No lines (`NO_LINES`, `empty`) records a line search that found none: a stream of the same sensor skips the
    search (30-40 ms a scan) and bins by elevation at once, until its holder clears it to search again."""

    a: np.ndarray
    b: np.ndarray
    motion: tuple[float, float] = (0.0, 0.0)

    @property
    def empty(self) -> bool:
        """Whether this records a search that found no lines."""
        return len(self.a) == 0


NO_LINES = LaserLines(np.zeros(0), np.zeros(0))


class Rings(NamedTuple):
    """Ring index per point, how it was obtained (one of RING_SOURCES), the number of rings found, and the laser
    lines they were read from (line sources; `NO_LINES` when a line search found none)."""

    ring: np.ndarray  # (N,) uint16
    source: str
    n_rings: int = 0
    lines: LaserLines | None = None


@nb.njit(cache=True, nogil=True, inline="always")
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


@nb.njit(cache=True, nogil=True)
def _ring_starts(pts: np.ndarray, min_cos_jump: float, min_gap: int, max_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Rings found by each of the three rules (one pass; starts closer than `min_gap` points are noise), and where
    each rule's rings start (3 x max_count + 1: ring r of a rule starts at point starts[rule, r]; recorded while the
    count is at most `max_count`). The pass stops once every rule has found more than `max_count` (none can be the
    firing order). Recording the starts spares a second pass over the points per rule (`_fill_rings`)."""
    starts = np.zeros((3, max_count + 1), dtype=np.int64)
    c0, c1, c2 = 1, 1, 1  # counters and last starts in registers, not arrays: a third of the pass's time
    l0, l1, l2 = 0, 0, 0
    for i in range(1, pts.shape[0]):
        if c0 > max_count and c1 > max_count and c2 > max_count:
            break
        x0 = pts[i - 1, 0]
        y0 = pts[i - 1, 1]
        x1 = pts[i, 0]
        y1 = pts[i, 1]
        if i - l0 >= min_gap and _is_start(x0, y0, x1, y1, 0, min_cos_jump):
            if c0 <= max_count:
                starts[0, c0] = i
            c0 += 1
            l0 = i
        if i - l1 >= min_gap and _is_start(x0, y0, x1, y1, 1, min_cos_jump):
            if c1 <= max_count:
                starts[1, c1] = i
            c1 += 1
            l1 = i
        if i - l2 >= min_gap and _is_start(x0, y0, x1, y1, 2, min_cos_jump):
            if c2 <= max_count:
                starts[2, c2] = i
            c2 += 1
            l2 = i
    count = np.empty(3, dtype=np.int64)
    count[0], count[1], count[2] = c0, c1, c2
    return count, starts


@nb.njit(cache=True, nogil=True)
def _fill_rings(n: int, starts: np.ndarray, n_found: int) -> np.ndarray:
    """Ring index per point of n points whose `n_found` rings start at `starts` (one rule's row of `_ring_starts`)."""
    ring = np.empty(n, dtype=np.uint16)
    for r in range(n_found):
        ring[starts[r]:starts[r + 1] if r + 1 < n_found else n] = r
    return ring


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True, inline="always")
def _walk(t: float, u: float, a: np.ndarray, b: np.ndarray, k: int) -> tuple[int, float]:
    """From line k, the nearest line to (u, t) walking up or down while the distance |t - a - b u| falls."""
    best = abs(t - a[k] - b[k] * u)
    while k > 0:
        d = abs(t - a[k - 1] - b[k - 1] * u)
        if d >= best:
            break
        best = d
        k -= 1
    while k < a.shape[0] - 1:
        d = abs(t - a[k + 1] - b[k + 1] * u)
        if d >= best:
            break
        best = d
        k += 1
    return k, best


@nb.njit(cache=True, nogil=True)
def _assign_lines(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple:
    """Nearest line (a descending) per point, and its |t - a - b u| distance. A table over t - mean(b) u gives a
    first line near the point's; from there the search walks up or down while the distance falls (lines do not
    cross where points lie)."""
    n = pts.shape[0]
    k_lines = a.shape[0]
    ring = np.zeros(n, dtype=np.uint16)
    resid = np.empty(n, dtype=np.float64)
    b_mean = b.mean()
    key0 = a[k_lines - 1] - 0.1
    n_cells = int((a[0] + 0.1 - key0) / _T_BIN) + 2
    first = np.empty(n_cells, dtype=np.int64)  # first line at or below each cell's key
    k = k_lines - 1
    for c in range(n_cells):
        key = key0 + c * _T_BIN
        while k > 0 and a[k - 1] <= key:
            k -= 1
        first[c] = k
    for i in range(n):
        r = max(np.sqrt(pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]), 0.1)
        u = 1.0 / r
        t = pts[i, 2] * u
        c = int((t - b_mean * u - key0) / _T_BIN)
        ring[i], resid[i] = _walk(t, u, a, b, first[min(max(c, 0), n_cells - 1)])
    return ring, resid


@nb.njit(cache=True, nogil=True)
def _first_guess_table(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """`_assign_known_part`'s first-guess table over (u, t) cells, each holding the line nearest its centre, and
    the t of its first cell; it spans every finite line over u in [0, _U_MAX]."""
    k_lines = a.shape[0]
    u_step = _U_MAX / _U_CELLS
    low, high = 0.0, 0.0
    for k in range(k_lines):
        for edge in (a[k], a[k] + b[k] * _U_MAX):
            if np.isfinite(edge):
                low, high = min(low, edge), max(high, edge)
    key0 = low - 0.1
    n_cells = int((high + 0.1 - key0) / _T_BIN) + 2
    first = np.empty((_U_CELLS, n_cells), dtype=np.int64)
    for j in range(_U_CELLS):
        u = (j + 0.5) * u_step
        k = k_lines - 1
        for c in range(n_cells):
            t = key0 + (c + 0.5) * _T_BIN
            while k > 0 and abs(t - a[k - 1] - b[k - 1] * u) < abs(t - a[k] - b[k] * u):
                k -= 1
            first[j, c] = k
    return first, key0


@nb.njit(cache=True, nogil=True)
def _assign_known_part(pts: np.ndarray, lo: int, hi: int, a: np.ndarray, b: np.ndarray, vx: float, vy: float,
                       tol: np.ndarray, min_range: float, first: np.ndarray, key0: float,
                       ring: np.ndarray) -> tuple[int, int]:
    """`_assign_lines` for points lo..hi-1 under the settled lines a stream holds, seen from an origin moving by
    (vx, vy) per revolution (`_moved_origin`, computed per point here), writing `ring`; returns the counts their
    `line_quality` is made of (points within `tol` of their line, and all, beyond `min_range`): one pass over the
    points instead of three.

    The first-guess table (`_first_guess_table`) is over (u, t) cells, so the walk rarely moves, in any point order
    (over t alone, near points have several lines to walk and a shuffled scan pays for the unpredictable walks:
    4.4 -> 2.8 ms and, in a slower hour, 5.9 -> 4.7 ms on 13 real shuffled 120k-point scans, the same rings). A
    search's own lines may still cross; it keeps `_assign_lines`, whose walks it was tuned with.
    """
    u_step = _U_MAX / _U_CELLS
    n_cells = first.shape[1]
    last = a.shape[0] - 1
    moving = vx != 0.0 or vy != 0.0
    min_r2 = min_range * min_range
    far = 0
    close = 0
    for i in range(lo, hi):
        x, y = pts[i, 0], pts[i, 1]
        if moving:  # float32, as _moved_origin stores them
            tau = _revolution_time(x, y)
            x, y = np.float32(x - vx * tau), np.float32(y - vy * tau)
        r2 = x * x + y * y
        r = max(np.sqrt(r2), 0.1)
        u = 1.0 / r
        t = pts[i, 2] * u
        k = first[min(int(u / u_step), _U_CELLS - 1), min(max(int((t - key0) / _T_BIN), 0), n_cells - 1)]
        best = abs(t - a[k] - b[k] * u)  # `_walk`, written out: as a call it took 1.5-2.5x the whole pass's time
        while k > 0:
            d = abs(t - a[k - 1] - b[k - 1] * u)
            if d >= best:
                break
            best = d
            k -= 1
        while k < last:
            d = abs(t - a[k + 1] - b[k + 1] * u)
            if d >= best:
                break
            best = d
            k += 1
        ring[i] = k
        if r2 >= min_r2:
            far += 1
            if best < tol[k]:
                close += 1
    return close, far


def _assign_known_lines(pts: np.ndarray, a: np.ndarray, b: np.ndarray, vx: float, vy: float, tol: np.ndarray,
                        min_range: float, helper: Executor | None = None) -> tuple[np.ndarray, float]:
    """Ring per point from a stream's settled lines (`_assign_known_part`) and their `line_quality`. With a
    `helper` (a one-thread executor) the second half of the points is assigned there while this thread assigns the
    first: the kernel releases the GIL, so a shuffled or column-ordered scan's largest step takes half the time
    (the same rings)."""
    n = pts.shape[0]
    ring = np.zeros(n, dtype=np.uint16)
    first, key0 = _first_guess_table(a, b)
    args = (a, b, vx, vy, tol, min_range, first, key0, ring)
    if helper is None or n < _SPLIT_POINTS:
        close, far = _assign_known_part(pts, 0, n, *args)
    else:
        half = n // 2
        other = helper.submit(_assign_known_part, pts, half, n, *args)
        close, far = _assign_known_part(pts, 0, half, *args)
        close_other, far_other = other.result()
        close, far = close + close_other, far + far_other
    return ring, close / far if far > 0 else 0.0


@nb.njit(cache=True, nogil=True)
def _line_sums(pts: np.ndarray, ring: np.ndarray, resid: np.ndarray, tol: np.ndarray, min_range: float,
               k_lines: int) -> np.ndarray:
    """Least-squares sums (n, sum u, sum t, sum u^2, sum u t) of every line's points within `tol` of it and beyond
    `min_range`."""
    sums = np.zeros((k_lines, 5))
    min_r2 = min_range * min_range
    for i in range(pts.shape[0]):
        k = ring[i]
        r2 = pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1]
        if r2 < min_r2 or resid[i] > tol[k]:
            continue
        r = np.sqrt(r2)
        u = 1.0 / r
        t = pts[i, 2] / r
        sums[k, 0] += 1.0
        sums[k, 1] += u
        sums[k, 2] += t
        sums[k, 3] += u * u
        sums[k, 4] += u * t
    return sums


def _refit_lines(sums: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lines refitted from their least-squares sums: a line whose points span enough of u takes its own slope when
    it is a laser height the search covers (`_SLOPES`), the others the slope interpolated between the fitted lines
    around it (lasers of one block share their height; a ring on flat ground has one range, or spreads along the
    ground's own line t = -height u), and every line with points its intercept at that slope."""
    n = sums[:, 0]
    has = n >= 3.0
    safe = np.maximum(n, 1.0)
    mu, mt = sums[:, 1] / safe, sums[:, 2] / safe
    var = sums[:, 3] / safe - mu * mu
    fitted = has & (var > _MIN_U_VAR)
    own = np.zeros_like(b)
    own[fitted] = (sums[fitted, 4] / n[fitted] - mu[fitted] * mt[fitted]) / var[fitted]
    fitted &= (own >= _SLOPES[0]) & (own <= _SLOPES[-1])
    b = np.where(fitted, own, b)
    if fitted.any() and not fitted.all():
        b[~fitted] = np.interp(-a[~fitted], -a[fitted], b[fitted])
    a = np.where(has, mt - b * mu, a)
    return a, b


def _peaks(profile: np.ndarray, half: int, floor: float) -> np.ndarray:
    """Bins that hold the largest value within `half` bins either side and at least `floor` (first of ties)."""
    padded = np.pad(profile, half, constant_values=-1.0)
    local = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=1)
    peaks = np.flatnonzero((profile >= local) & (profile >= floor))
    if len(peaks) > 1:
        peaks = peaks[np.concatenate(([True], np.diff(peaks) > half))]
    return peaks


def search_sample(pts: np.ndarray, size: int = _SEARCH_POINTS) -> np.ndarray:
    """About `size` of the points (float32, contiguous), chosen by a hash of their x coordinate's bits: the same
    points whatever the order they come in, and a smaller sample of a sample is part of it."""
    if len(pts) <= size:
        return np.ascontiguousarray(pts)
    bits = np.ascontiguousarray(pts[:, 0]).view(np.uint32) * np.uint32(2654435761)
    return np.ascontiguousarray(pts[bits < np.uint32(size / len(pts) * 2.0**32)])


def _sharpen(acc: np.ndarray) -> np.ndarray:
    """Accumulator rows smoothed along the intercept by [1, 2, 1], less the larger of their means 2..3 bins either
    side: a laser's line is a narrow spike at its slope, smeared votes (ground, walls, wrong slopes) are broad and
    cancel."""
    padded = np.pad(acc, ((0, 0), (4, 4)))
    smooth = 2.0 * acc + padded[:, 3:-5] + padded[:, 5:-3]
    left = 2.0 * (padded[:, 1:-7] + padded[:, 2:-6])
    right = 2.0 * (padded[:, 6:-2] + padded[:, 7:-1])
    return smooth - np.maximum(left, right)


def _accumulate(pts: np.ndarray) -> np.ndarray:
    """The sharpened (slope, intercept) accumulator of the line search over the points (a search sample)."""
    return _sharpen(_line_accumulator(pts, 1, _MIN_LINE_RANGE, _SLOPES, _N_BINS))


@nb.njit(cache=True, nogil=True, inline="always")
def _revolution_time(x: float, y: float) -> float:
    """Time within a revolution, -0.5..0.5, of a return at (x, y): 0 facing forward, +-0.5 at the back, linear in
    azimuth (pseudo-azimuth stands in for it, a few tenths of a degree off)."""
    s = abs(x) + abs(y)
    p = y / s if s > 0.0 else 0.0
    if x >= 0.0:
        return 0.25 * p
    return 0.5 - 0.25 * p if y >= 0.0 else -0.5 - 0.25 * p


@nb.njit(cache=True, nogil=True)
def _moved_origin(pts: np.ndarray, vx: float, vy: float) -> np.ndarray:
    """x, y, z of the points seen from an origin that moves by (vx, vy) over one revolution, linearly in time
    (`_revolution_time`): KITTI's motion-corrected scans."""
    out = np.empty((pts.shape[0], 3), dtype=np.float32)
    for i in range(pts.shape[0]):
        tau = _revolution_time(pts[i, 0], pts[i, 1])
        out[i, 0] = pts[i, 0] - vx * tau
        out[i, 1] = pts[i, 1] - vy * tau
        out[i, 2] = pts[i, 2]
    return out


@nb.njit(cache=True, nogil=True)
def _motion_scores(pts: np.ndarray, vxs: np.ndarray, vys: np.ndarray, slopes: np.ndarray) -> np.ndarray:
    """Line sharpness of the points seen from an origin moving by (vxs[k], vys[k]) per revolution, in slope row
    slopes[k]: the sum of squared positive votes of a [1, 2, 1]-smoothed intercept histogram less the larger of its
    means 2..3 bins either side (as `_sharpen`)."""
    n_bins = _N_BINS
    hist = np.zeros(n_bins + 8)
    scores = np.zeros(vxs.shape[0])
    min_r2 = _MIN_LINE_RANGE * _MIN_LINE_RANGE
    n = pts.shape[0]
    tau = np.empty(n)
    for i in range(n):
        tau[i] = _revolution_time(pts[i, 0], pts[i, 1])
    inv_bin = 1.0 / _T_BIN
    for k in range(vxs.shape[0]):
        hist[:] = 0.0
        for i in range(n):
            x = pts[i, 0] - vxs[k] * tau[i]
            y = pts[i, 1] - vys[k] * tau[i]
            r2 = x * x + y * y
            if r2 < min_r2:
                continue
            u = 1.0 / np.sqrt(r2)
            b = int((pts[i, 2] * u - slopes[k] * u + _T_MAX) * inv_bin)
            if 0 <= b < n_bins:
                hist[b + 4] += 1.0
        total = 0.0
        for b in range(4, n_bins + 4):
            if hist[b] == 0.0:
                continue
            smooth = 2.0 * hist[b] + hist[b - 1] + hist[b + 1]
            side = 2.0 * max(hist[b - 3] + hist[b - 2], hist[b + 2] + hist[b + 3])
            if smooth > side:
                total += (smooth - side) ** 2
        scores[k] = total
    return scores


def estimate_motion(sample: np.ndarray) -> tuple[float, float]:
    """Origin motion over one revolution (x, y metres) that sharpens the laser lines of a motion-corrected scan
    most, searched on the returns below -0.15 in tan(elevation) (near lasers: motion correction bends their lines
    most): along x (driving) in a few slope rows, then along y, then finer; (0, 0) unless it sharpens them by
    `_MOTION_GAIN`."""
    low = sample[sample[:, 2] < -0.15 * np.hypot(sample[:, 0], sample[:, 1])]
    low = np.ascontiguousarray(low[::max(1, len(low) // _MOTION_POINTS)])
    if len(low) < 100:
        return 0.0, 0.0
    n_x = len(_MOTION_STEPS)
    vxs = np.tile(_MOTION_STEPS, len(_MOTION_SLOPES))
    slopes = np.repeat(_MOTION_SLOPES, n_x)
    scores = _motion_scores(low, vxs, np.zeros_like(vxs), slopes)
    k = int(scores.argmax())
    still = float(scores[int(np.abs(vxs).argmin()) + (k // n_x) * n_x])
    vx, vy, slope, best = float(vxs[k]), 0.0, float(slopes[k]), float(scores[k])
    for step in (0.1, 0.02):
        offsets = step * np.arange(-4, 5)
        ys = _motion_scores(low, np.full(9, vx), vy + offsets, np.full(9, slope))
        vy = vy + float(offsets[int(ys.argmax())])
        xs = _motion_scores(low, vx + 0.5 * offsets, np.full(9, vy), np.full(9, slope))
        vx, best = vx + 0.5 * float(offsets[int(xs.argmax())]), max(best, float(xs.max()), float(ys.max()))
    if best < _MOTION_GAIN * still:
        return 0.0, 0.0
    return vx, vy


def _lines_from_scan(acc: np.ndarray, half_band: int = _HALF_BAND) -> tuple[np.ndarray, np.ndarray]:
    """Line intercepts (descending) and slopes at the peaks of the accumulator's sharpest slope per elevation band:
    each intercept bin reads the slope row with the largest sum of squared positive responses within `half_band`
    bins (a laser block's common height above the origin; the HDL-64E's two blocks differ) when it is clearly
    sharper there than the row sharpest over the whole scan, else that row. A ring whose points
    share one range (flat ground) votes a spike into every row, so rows are chosen over a band, and each line's own
    slope is left to the refits."""
    positive = np.maximum(acc, 0.0) ** 2
    cumulative = np.pad(np.cumsum(positive, axis=1), ((0, 0), (half_band + 1, half_band)), mode="edge")
    cumulative[:, :half_band + 1] = 0.0
    sharpness = cumulative[:, 2 * half_band + 1:] - cumulative[:, :-2 * half_band - 1]
    rows = sharpness.argmax(axis=0)
    overall = int(positive.sum(axis=1).argmax())
    columns = np.arange(acc.shape[1])
    rows[sharpness[rows, columns] < _BAND_MARGIN * sharpness[overall]] = overall
    profile = acc[rows, columns]
    top = np.sort(profile)[-8:].mean() if len(profile) else 0.0
    peaks = _peaks(profile, 2, max(16.0, 0.05 * top))
    while len(peaks) > 2:
        gaps = np.diff(peaks)
        k = int(gaps.argmin())
        if gaps[k] >= 0.5 * np.median(gaps):
            break
        peaks = np.delete(peaks, k if profile[peaks[k]] < profile[peaks[k + 1]] else k + 1)
    a = (peaks + 0.5) * _T_BIN - _T_MAX
    return a[::-1].copy(), _SLOPES[rows[peaks]][::-1].copy()


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


def _even_out(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lines (intercepts descending) with the gaps evened out against the local spacing (median of the 7 nearest
    gaps): a gap of about n spacings gets n - 1 lines spread through it (a laser whose peak was missed), two lines
    closer than half a spacing become one (a laser that peaked twice)."""
    for _ in range(4):
        if len(a) < 4:
            return a, b
        gaps = a[:-1] - a[1:]
        padded = np.pad(gaps, 3, mode="edge")
        local = np.median(np.lib.stride_tricks.sliding_window_view(padded, 7), axis=1)
        close = set(np.flatnonzero(gaps < 0.5 * local).tolist())
        wide = set(np.flatnonzero(gaps > 1.6 * local).tolist())
        if not close and not wide:
            return a, b
        new_a, new_b = [a[0]], [b[0]]
        for k in range(len(gaps)):
            if k in close:
                new_a[-1] = 0.5 * (new_a[-1] + a[k + 1])
                new_b[-1] = 0.5 * (new_b[-1] + b[k + 1])
                continue
            if k in wide:
                steps = round(float(gaps[k] / local[k]))
                for j in range(1, steps):
                    new_a.append(a[k] - gaps[k] * j / steps)
                    new_b.append(b[k] + (b[k + 1] - b[k]) * j / steps)
            new_a.append(a[k + 1])
            new_b.append(b[k + 1])
        a, b = np.array(new_a), np.array(new_b)
    return a, b


def _fill_gaps(pts: np.ndarray, a: np.ndarray, b: np.ndarray, min_range: float = 5.0,
               share: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Lines (intercepts descending) with a line added in every gap that holds a laser's worth of points: points
    beyond `min_range` (clean elevations) lying more than 0.3 of the gap away from their nearest line, into the gap
    (or beyond the outermost lines), at least `share` of a typical line's close points. The new line's slope is
    its neighbours' mean, its intercept the median of those points."""
    if len(a) < 3:
        return a, b
    r = np.hypot(pts[:, 0], pts[:, 1]).astype(np.float64)
    far = r >= min_range
    u = 1.0 / r[far]
    t = pts[far, 2] / r[far]
    ring, _ = _assign_lines(np.ascontiguousarray(pts[far]), a, b)
    ring = ring.astype(np.int64)
    signed = t - a[ring] - b[ring] * u
    gaps = a[:-1] - a[1:]
    below = np.r_[gaps, gaps[-1]]  # gap to the next line down, per line
    above = np.r_[gaps[0], gaps]
    into_below = signed < -0.3 * below[ring]  # gap index = ring (between line ring and ring + 1)
    into_above = signed > 0.3 * above[ring]  # gap index = ring - 1
    close = np.bincount(ring[~(into_below | into_above)], minlength=len(a))
    need = share * np.median(close)
    gap_of = np.where(into_below, ring, np.where(into_above, ring - 1, -2))
    counts = np.bincount(gap_of[gap_of >= -1] + 1, minlength=len(a) + 1)  # gaps -1 (above the top) .. len(a) - 1
    new_a, new_b = list(a), list(b)
    for g in np.flatnonzero((counts >= need) & (counts > 0)) - 1:  # an empty gap never gets a line
        slope = b[0] if g < 0 else b[-1] if g >= len(a) - 1 else 0.5 * (b[g] + b[g + 1])
        members = gap_of == g
        new_a.append(float(np.median(t[members] - slope * u[members])))
        new_b.append(slope)
    if len(new_a) == len(a):
        return a, b
    order = np.argsort(-np.asarray(new_a), kind="stable")
    return np.asarray(new_a)[order], np.asarray(new_b)[order]


def fit_laser_lines(pts: np.ndarray, a: np.ndarray, b: np.ndarray, iterations: int = 2) -> tuple:
    """Ring per point after `iterations` refits of the lines (a: intercepts, descending; b: slopes), its distance to
    its line, and the refitted lines."""
    a = np.ascontiguousarray(a, dtype=np.float64).copy()
    b = np.ascontiguousarray(b, dtype=np.float64).copy()
    for step in range(iterations + 1):
        order = np.argsort(-a, kind="stable")
        a, b = a[order], b[order]
        ring, resid = _assign_lines(pts, a, b)
        if step == iterations:
            break
        sums = _line_sums(pts, ring, resid, _close_tolerance(a, 0.4), _MIN_LINE_RANGE, len(a))
        a, b = _refit_lines(sums, a, b)
    return ring, resid, a, b


def _close_tolerance(a: np.ndarray, share: float) -> np.ndarray:
    """Per line, `share` of the gap to its nearer neighbour (at least one accumulator bin)."""
    if len(a) < 2:
        return np.full(len(a), 0.01)
    gaps = np.abs(np.diff(a))
    return np.maximum(share * np.minimum(np.r_[gaps, np.inf], np.r_[np.inf, gaps]), _T_BIN)


@nb.njit(cache=True, nogil=True)
def _share_close(pts: np.ndarray, ring: np.ndarray, resid: np.ndarray, tol: np.ndarray, min_range: float) -> float:
    """Share of the points beyond `min_range` whose residual is below their line's tolerance (0 when none is)."""
    min_r2 = min_range * min_range
    far = 0
    close = 0
    for i in range(pts.shape[0]):
        if pts[i, 0] * pts[i, 0] + pts[i, 1] * pts[i, 1] >= min_r2:
            far += 1
            if resid[i] < tol[ring[i]]:
                close += 1
    return close / far if far > 0 else 0.0


def line_quality(pts: np.ndarray, ring: np.ndarray, resid: np.ndarray, a: np.ndarray,
                 min_range: float = _QUALITY_RANGE) -> float:
    """Share of the points beyond `min_range` (clean elevations) within a quarter gap of their line: about 1 when
    the lines are the lasers, far lower for lines drawn through a scan that does not fit the model (uniform
    residuals give about one half)."""
    return float(_share_close(pts, ring, resid, _close_tolerance(a, 0.25), min_range))


def standard_ring_count(n_found: int) -> int | None:
    """The standard laser count (lasers.STANDARD_RING_COUNTS) that `n_found` lines can be: at most it, and at most
    lasers.MISSING_LINES of it below; None if none fits."""
    for count in STANDARD_RING_COUNTS:
        if count - MISSING_LINES[count] <= n_found <= count:
            return count
    return None


def _search_lines(sample: np.ndarray, acc: np.ndarray, half_band: int
                  ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Laser lines of a fit sample and how well they fit it (`line_quality`): the accumulator's peaks
    (`_lines_from_scan`), evened out, refitted, gaps that hold a laser filled, until the count settles; None unless it
    is near a standard count and the fit reaches _MIN_QUALITY."""
    a, b = _even_out(*_lines_from_scan(acc, half_band))
    if not 2 <= len(a) <= _MAX_LINES:
        return None
    _, _, a, b = fit_laser_lines(sample, a, b, 1)
    for _ in range(_FILL_ROUNDS):
        n_lines = len(a)
        a, b = _fill_gaps(sample, *_even_out(a, b))
        if len(a) > _MAX_LINES:
            return None
        _, _, a, b = fit_laser_lines(sample, a, b, 1)
        a, b = _even_out(a, b)
        if len(a) == n_lines:
            break
    if standard_ring_count(len(a)) is None or not np.all(np.isfinite(a) & np.isfinite(b)):
        return None
    ring, resid, a, b = fit_laser_lines(sample, a, b, 1)
    quality = line_quality(sample, ring, resid, a)
    return None if quality < _MIN_QUALITY else (a, b, quality)


def rings_from_known_lines(points: np.ndarray, lines: LaserLines, source: str,
                           helper: Executor | None = None) -> Rings | None:
    """Rings of a scan in any point order from the laser lines of an earlier scan of the same sensor (no search: a
    sensor's lines do not change), None unless they fit this scan as well as a search's must (`line_quality` over
    all its points: a changed sensor or mounting fails it). A motion-corrected scan whose motion changed gets the
    lines again under its own motion (`estimate_motion`). `NO_LINES` fits nothing: None. `helper`: a one-thread
    executor that assigns half of the points (`_assign_known_lines`)."""
    if lines.empty:
        return None
    pts = np.ascontiguousarray(points, dtype=np.float32)
    found = _rings_under(pts, lines, lines.motion, source, helper)
    if found is None:
        motion = estimate_motion(search_sample(pts))
        if motion != lines.motion:
            found = _rings_under(pts, lines, motion, source, helper)
    return found


def _rings_under(pts: np.ndarray, lines: LaserLines, motion: tuple[float, float], source: str,
                 helper: Executor | None) -> Rings | None:
    """Rings from `lines` seen from an origin moving by `motion`, None unless they pass `line_quality`."""
    moving = motion != (0.0, 0.0)
    ring, quality = _assign_known_lines(pts, lines.a, lines.b, motion[0], motion[1], _close_tolerance(lines.a, 0.25),
                                        _QUALITY_RANGE, helper)
    if quality < _MIN_QUALITY:
        return None
    return Rings(ring, source + ("_moving" if moving else ""), len(lines.a), lines._replace(motion=motion))


def rings_from_lines(points: np.ndarray, sensor: str = "auto", tilted: bool = False) -> Rings | None:
    """Rings of a scan in any point order, from its laser lines (module docstring): seeded by `sensor`'s laser
    table, or found in the scan (`sensor` "auto"; None when no line set near a standard count fits the scan). The
    lines are searched and fitted on a sample of the points that does not depend on their order. On a `tilted` scan
    (one stage 1 levels), where an origin motion sharpens the lines, the lines seen from the still origin are searched
    too and the better fitting set wins, of two that fit as well the one of fewer lines: a tilted sensor's uneven scene
    reads as motion (a scan pitched 10 degrees found no lines from its estimated motion and every laser from the still
    origin; an upside-down Pandar64 113 lines from its motion, fitting as well as its 64 lasers from the still one).
    Level scans keep the motion's lines alone: on the level HDL-32E of the parking lot the still origin's lines lost
    crowds that elevation bins kept apart (docs/experiments/sensors.md, rule Z)."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    sample = search_sample(pts)
    vx, vy = estimate_motion(sample)
    moving = vx != 0.0 or vy != 0.0
    if sensor != "auto":
        seen, acc = _search_view(sample, vx, vy)
        a, b = _lines_from_table(acc, laser_elevations(sensor))
        _, _, a, b = fit_laser_lines(seen, a, b)
        ring, _, a, b = fit_laser_lines(_moved_origin(pts, vx, vy) if moving else pts, a, b, 0)
        return Rings(ring, "laser_table" + ("_moving" if moving else ""), len(a), LaserLines(a, b, (vx, vy)))
    best: tuple[float, np.ndarray, np.ndarray, float, float] | None = None
    for motion in ((vx, vy), (0.0, 0.0)) if moving and tilted else ((vx, vy),):
        seen, acc = _search_view(sample, *motion)
        for half_band in (_HALF_BAND, _N_BINS):
            found = _search_lines(seen, acc, half_band)
            if found is not None:
                if best is None or found[2] > best[0] or (found[2] == best[0] and len(found[0]) < len(best[1])):
                    best = (found[2], found[0], found[1], *motion)  # of two that fit as well, the fewer lines
                break
    if best is None:
        return None
    _, a, b, mx, my = best
    still = mx == 0.0 and my == 0.0
    ring, _, a, b = fit_laser_lines(pts if still else _moved_origin(pts, mx, my), a, b, 0)
    return Rings(ring, "elevation_lines" + ("" if still else "_moving"), len(a), LaserLines(a, b, (mx, my)))


def _search_view(sample: np.ndarray, vx: float, vy: float) -> tuple[np.ndarray, np.ndarray]:
    """The fit sample seen from the origin moving by (vx, vy) over the revolution (the still one at 0, 0), and the
    line accumulator of the search sample seen so."""
    moving = vx != 0.0 or vy != 0.0
    seen = _moved_origin(sample, vx, vy) if moving else sample
    acc = _accumulate(seen)
    fit = search_sample(seen, _FIT_POINTS) if not moving else _moved_origin(search_sample(sample, _FIT_POINTS), vx, vy)
    return fit, acc


def recover_rings(
    points: np.ndarray,
    config: Stage1Config,
    *,
    min_jump_deg: float = 45.0,
    min_ring_points: int = 8,
    missing_tolerance: int = 4,
    min_range: float = 4.0,
    lines: LaserLines | None = None,
    helper: Executor | None = None,
    tilted: bool = False,
) -> Rings:
    """Ring index per point of a scan without a ring field (see the module docstring for the rules): the firing
    order (expecting `config.n_rings` rings, or a named `config.sensor`'s laser count), else a named sensor's table,
    else the laser lines found in the scan, else elevation bins. `lines`, the laser lines of an earlier scan of the
    same sensor (`Rings.lines`), are tried first: only a scan in no firing order yields lines, so a stream that held
    them is read from them without the firing-order count or a line search (a live stream pays for the search once).
    `NO_LINES` (what a failed search returns) skips the search: such a stream pays for it once too. A named table
    comes after the firing order because the order gives exact rings (on KITTI's HDL-64E the table's lines lost a
    third of the cars' points at stage 1: docs/adapt.md).

    `helper`: a one-thread executor that assigns half of the points under held `lines`; `tilted`: the scan is one
    stage 1 levels (`rings_from_lines`).

    `min_jump_deg`: backward azimuth step that starts a ring in the ``azimuth_jump`` rule;
    `min_ring_points`: boundaries closer than this many points are noise; `missing_tolerance`: how many
    lasers may be absent; `min_range`: points nearer than this are left out of validation statistics
    (lasers sit off the sensor origin, so close points have distorted elevations).
    """
    n_rings = config.n_rings
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if len(pts) == 0:
        return Rings(np.zeros(0, dtype=np.uint16), "azimuth_wrap", 0)
    if config.sensor != "auto":  # the firing order first: it gives exact rings, the table's lines only near ones
        known = _from_known(pts, lines, "laser_table", helper)
        if known is not None:
            return known
        ordered = _from_firing_order(pts, ring_limit(config.sensor, n_rings), min_jump_deg, min_ring_points,
                                     missing_tolerance, min_range)
        if ordered is not None:
            return ordered
        found = rings_from_lines(pts, config.sensor)
        assert found is not None
        return found
    known = _from_known(pts, lines, "elevation_lines", helper)
    if known is not None:
        return known
    ordered = _from_firing_order(pts, n_rings, min_jump_deg, min_ring_points, missing_tolerance, min_range)
    if ordered is not None:
        return ordered
    searched = lines is not None and lines.empty  # a search of this stream found none: not again
    found = rings_from_lines(pts, tilted=tilted) if len(pts) >= 64 and not searched else None
    if found is not None:
        return found
    elev = np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1]))
    return Rings(elevation_bins(elev, n_rings), "elevation_bins", n_rings, NO_LINES if len(pts) >= 64 else None)


def _from_firing_order(pts: np.ndarray, n_rings: int, min_jump_deg: float, min_ring_points: int,
                       missing_tolerance: int, min_range: float) -> Rings | None:
    """Rings from the point order (azimuth wrap or jump, `recover_rings`' arguments), the best-validated rule that
    finds between `n_rings` - `missing_tolerance` and `n_rings` rings; None when none does."""
    min_cos_jump = float(np.cos(np.deg2rad(min_jump_deg)))
    counts, starts = _ring_starts(pts, min_cos_jump, min_ring_points, n_rings)
    best: tuple[float, np.ndarray, str, int] | None = None
    for rule, source in ((0, "azimuth_wrap"), (1, "azimuth_wrap"), (2, "azimuth_jump")):
        n_found = int(counts[rule])
        if n_found > n_rings or n_found < n_rings - missing_tolerance:
            continue
        ring = _fill_rings(len(pts), starts[rule], n_found)
        spread = _validate(pts, ring, n_found, missing_tolerance, min_range)
        if spread is not None and (best is None or spread < best[0]):
            best = (spread, ring, source, n_found)
    return None if best is None else Rings(best[1], best[2], best[3])


def _from_known(pts: np.ndarray, lines: LaserLines | None, source: str, helper: Executor | None) -> Rings | None:
    """`rings_from_known_lines`, None without lines."""
    return None if lines is None else rings_from_known_lines(pts, lines, source, helper)


def rings_for(points: np.ndarray, ring: np.ndarray | None, config: Stage1Config,
              lines: LaserLines | None = None, helper: Executor | None = None, tilted: bool = False) -> Rings:
    """The given ring field when there is one (checked for length), else the rings recovered under `config`
    (trying an earlier scan's laser `lines` before a line search, half of them assigned on `helper`; `tilted`: a
    scan stage 1 levels)."""
    if ring is not None:
        ring = np.asarray(ring)
        if len(ring) != len(points):
            raise ValueError(f"ring field has {len(ring)} entries for {len(points)} points")
        return Rings(ring.astype(np.uint16, copy=False), "field", int(ring.max()) + 1 if len(ring) else 0)
    return recover_rings(points, config, lines=lines, helper=helper, tilted=tilted)


def warm_up() -> None:
    """Compile the ring kernels (and the ring field's) on a tiny synthetic scan."""
    az = np.linspace(0.0, 4.0 * np.pi, 64, endpoint=False)
    pts = np.zeros((64, 4), dtype=np.float32)
    pts[:, 0] = 10.0 * np.cos(az)
    pts[:, 1] = 10.0 * np.sin(az)
    pts[:, 2] = np.where(np.arange(64) < 32, 0.0, -1.0)
    recover_rings(pts, Stage1Config(n_rings=2), min_ring_points=2)
    rings_from_lines(pts, "vlp16")
    rings_from_lines(pts)
    rings_from_known_lines(pts, LaserLines(np.array([0.0, -0.1]), np.zeros(2)), "elevation_lines")
    _motion_scores(pts, np.zeros(1), np.zeros(1), np.zeros(1))
    _moved_origin(pts, 0.1, 0.0)
    measure_ring_order(pts, (np.arange(64) // 32).astype(np.uint16))
    ring, resid, a, _ = fit_laser_lines(pts, np.array([0.0, -0.1]), np.zeros(2), 1)
    line_quality(pts, ring, resid, a)
