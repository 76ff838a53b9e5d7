"""Ground plane fitting (Zermas et al., ICRA 2017), as PASS3D's stage 1 uses it.

Every parameter comes from `Stage1Config`. The scan is split into `n_seg` segments of equal length along x
(the direction of travel). In each, the mean height of the `n_lpr` lowest points (the lowest point
representative, LPR) sets the seed height; points within `th_seeds` above it seed a plane, fitted as the
smallest eigenvector of their covariance (normal turned upwards). Points with |distance| < `th_dist` from
the plane are ground (two-sided); the plane is fitted `n_iter` times in all, each time from the ground of the
previous fit.

Robustness the paper leaves open, needed on full 360-degree KITTI scans: points more than
`below_ground_margin` under the expected road (-sensor_height; `Stage1Config.seed_height`: while sensor_height is
auto, 1.73 m until the stream holds its estimate, pass3d_ros.core.stage1.mounting) never seed; only points within a
lateral band |y| < `ground_seed_band` seed and fit (terrain falling away 30 m to the side is not the road); sparse
height bins below the road (a pit, stray returns) cannot set the LPR; an outer segment whose plane is degenerate, too
steep, or steps away from its inner neighbour at their shared edge takes the neighbour's plane. The LPR and
the fits read about one point in `fit_stride` (the same planes at a fraction of the cost): the points of every
`fit_stride`-th narrow azimuth sector, so they read the same points whatever order the scan comes in (stage 1 fits
the ground on the points as they come, beside ring recovery); the final ground test reads every point.

Local ground (`Stage1Config.local_ground`): a segment's plane is fitted on the road within |y| < ground_seed_band,
mostly on its near part, and extrapolated to far and lateral objects, where the real ground can lie tenths of a metre
(or, uphill, metres) off it. So the signed plane distances of the fit's sample (within LOCAL_BAND_M) are also
binned in a coarse x-y grid (LOCAL_CELL_M cells) of height histograms built once per frame;
`LocalGround.offsets` reads the ground's offset from the plane around any x-y position from it, in a square window
of half-width local_ground_radius + LOCAL_GROWTH * range (the rings that reach the ground thin out with range): where
the window holds half of LOCAL_MIN_POINTS (scaled to the sample) in the plane's ground band (|distance| < th_dist),
the median of those; where it does not, the plane is off by more than th_dist there (none of the real ground passed
the plane test) and the offset is the lowest dense layer: the lowest 0.1 m bin pair holding LOCAL_MIN_POINTS points
(and, under the band, LOCAL_SHARE of the fullest pair: not a few stray returns), the mean of that bin and the two
above it; 0 (the plane) where the window holds too few points. The median of the band, not its lowest layer: a far
window's sparse ground returns are easily outnumbered by car bodies, walls and hedges.
"""

from __future__ import annotations

from concurrent.futures import Executor, ThreadPoolExecutor
from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.scanline import TWO_THREADS_MIN_POINTS, pseudo_azimuth, pseudo_azimuth_unordered

LOCAL_CELL_M = 2.0  # local ground: x-y cell of the height histograms (m)
LOCAL_BIN_M = 0.1  # local ground: height bin (m)
LOCAL_BAND_M = 2.5  # local ground: signed plane distances within +-this are binned (m)
LOCAL_MIN_POINTS = 24  # local ground: points (of the whole scan) a dense layer needs; half of it, the plane band
LOCAL_SHARE = 0.1  # local ground: ... and this share of the fullest pair (stray returns below the road are not it)
LOCAL_GROWTH = 0.05  # local ground: window half-width grows by this per metre of range


class LocalGround(NamedTuple):
    """Per-segment planes and the x-y grid of plane-distance histograms that corrects them locally (module
    docstring): hist[i, j, b] counts the sample's points of height bin b in cell (i, j). A window is summed when it
    is read (a few hundred windows a frame: cheaper than a summed-area table of the whole grid)."""

    planes: np.ndarray  # (n_seg, 4) float64
    segment_edges: np.ndarray  # (n_seg + 1,) x boundaries
    hist: np.ndarray  # (n_cells, n_cells, n_bins) uint16
    origin: float  # x and y of the grid's first cell corner (the grid is square, centred on the sensor)
    radius: float  # Stage1Config.local_ground_radius
    min_points: int  # LOCAL_MIN_POINTS in the sample the histograms count (about one point in fit_stride)
    band: float  # Stage1Config.th_dist: the plane's ground band

    def offsets(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance (m, along the plane normal) of the local ground from the plane at each x-y position
        (M x >=2); 0 where the window holds too few points."""
        xy = np.ascontiguousarray(np.asarray(xy, dtype=np.float64)[:, :2])
        return _local_offsets(self.hist, self.origin, xy, self.radius, self.min_points, self.band)

    def heights(self, xy: np.ndarray) -> np.ndarray:
        """z of the local ground at each x-y position: its plane's height there, moved by the offset read there
        (`with_local_ground` writes the same out per cell)."""
        xy = np.asarray(xy, dtype=np.float64)[:, :2]
        a, b, c, d = self.planes[segments(xy[:, 0], self.segment_edges, len(self.planes))].T
        return (self.offsets(xy) - a * xy[:, 0] - b * xy[:, 1] - d) / c


class GroundFit(NamedTuple):
    """Ground mask and one plane (a, b, c, d with a x + b y + c z + d = 0, unit normal up) per segment; `local`:
    the local correction of the planes (None when Stage1Config.local_ground is off)."""

    ground: np.ndarray  # (N,) bool
    planes: np.ndarray  # (n_seg, 4) float64
    segment_edges: np.ndarray  # (n_seg + 1,) x boundaries
    local: LocalGround | None = None


@nb.njit(cache=True, nogil=True)
def _segment_of(x: float, x0: float, width: float, n_seg: int) -> int:
    """Segment index of an x coordinate; points beyond the extent fall into the end segments."""
    s = int((x - x0) / width)
    if s < 0:
        return 0
    if s >= n_seg:
        return n_seg - 1
    return s


@nb.njit(cache=True, nogil=True, inline="always")
def plane_distance(planes: np.ndarray, x0: float, width: float, x: float, y: float, z: float) -> float:
    """Signed distance (m, up) of the point (x, y, z) from its segment's plane (`planes` n_seg x 4, segments of
    `width` from `x0`): the height above the ground plane that the ground mask and the gates read. The segment is
    `_segment_of`'s, found by min and max: with its branches the loops that call this ran about 40 % slower."""
    s = min(max(int((x - x0) / width), 0), planes.shape[0] - 1)
    return planes[s, 0] * x + planes[s, 1] * y + planes[s, 2] * z + planes[s, 3]


def segments(x: np.ndarray, segment_edges: np.ndarray, n_seg: int) -> np.ndarray:
    """Segment index of each x coordinate (`_segment_of` over an array)."""
    width = segment_edges[1] - segment_edges[0]
    return np.clip(((x - segment_edges[0]) / width).astype(np.int64), 0, n_seg - 1)


@nb.njit(cache=True, nogil=True)
def _lowest_means(grouped: np.ndarray, bounds: np.ndarray, n_lpr: int, z_floor: float, band: float,
                  outlier_share: float, bin_size: float) -> np.ndarray:
    """Per segment, the mean z of the `n_lpr` lowest candidate points of its part of the sample (`_by_segment`'s
    groups; NaN if none).

    Candidates lie above `z_floor`, within |y| < band, and not below the lowest height bin that holds at
    least `outlier_share` of the fullest bin (a pit or a few stray returns below the road cannot set the LPR).
    """
    n_seg = bounds.shape[0] - 1
    n_bins = 64
    hist = np.zeros((n_seg, n_bins), dtype=np.int64)
    for s in range(n_seg):
        for i in range(bounds[s], bounds[s + 1]):
            z = grouped[i, 2]
            if z < z_floor or abs(grouped[i, 1]) >= band:
                continue
            b = int((z - z_floor) / bin_size)
            if b < n_bins:
                hist[s, b] += 1
    z_low = np.full(n_seg, z_floor)
    for s in range(n_seg):
        need = outlier_share * hist[s].max()
        for b in range(n_bins):
            if hist[s, b] > 0 and hist[s, b] >= need:
                z_low[s] = z_floor + b * bin_size
                break
    low = np.full((n_seg, n_lpr), np.inf)  # per segment, ascending: the n_lpr lowest, in any reading order
    for s in range(n_seg):
        for i in range(bounds[s], bounds[s + 1]):
            z = grouped[i, 2]
            if abs(grouped[i, 1]) >= band:
                continue
            if z < z_low[s] or z >= low[s, n_lpr - 1]:
                continue
            j = n_lpr - 1
            while j > 0 and low[s, j - 1] > z:
                low[s, j] = low[s, j - 1]
                j -= 1
            low[s, j] = z
    out = np.full(n_seg, np.nan)
    for s in range(n_seg):
        total = 0.0
        count = 0
        for j in range(n_lpr):
            if np.isfinite(low[s, j]):
                total += low[s, j]
                count += 1
        if count > 0:
            out[s] = total / count
    return out



@nb.njit(cache=True, nogil=True)
def smallest_eigenvector(cov: np.ndarray) -> np.ndarray:
    """Eigenvector of the smallest eigenvalue of a symmetric 3 x 3 matrix (cyclic Jacobi rotations)."""
    a = cov.copy()
    v = np.eye(3)
    for _ in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off < 1e-30 * (a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]) + 1e-300:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                if a[p, q] == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):
                    akp = a[k, p]
                    akq = a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(3):
                    apk = a[p, k]
                    aqk = a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                for k in range(3):
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    best = 0
    for k in range(1, 3):
        if a[k, k] < a[best, best]:
            best = k
    return v[:, best].copy()


@nb.njit(cache=True, nogil=True)
def _edge_height(plane: np.ndarray, x: float) -> float:
    """Height of a plane at (x, 0)."""
    return -(plane[0] * x + plane[3]) / plane[2]


@nb.njit(cache=True, nogil=True)
def _by_segment(pts: np.ndarray, sample: np.ndarray, x0: float, width: float, n_seg: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """The x, y, z (N x 3, pts' dtype) of the sample's points (`sample`: indices into pts, ascending) grouped by
    segment, each group in sample order (a stable counting sort), and the n_seg + 1 bounds of the groups: gathered
    once, so that a shuffled scan's sample is not read scattered over memory by every pass."""
    n = sample.shape[0]
    seg = np.empty(n, dtype=np.int64)
    bounds = np.zeros(n_seg + 1, dtype=np.int64)
    for i in range(n):
        seg[i] = _segment_of(pts[sample[i], 0], x0, width, n_seg)
        bounds[seg[i] + 1] += 1
    for s in range(n_seg):
        bounds[s + 1] += bounds[s]
    fill = bounds[:n_seg].copy()
    grouped = np.empty((n, 3), dtype=pts.dtype)
    for i in range(n):
        t = fill[seg[i]]
        p = sample[i]
        grouped[t, 0] = pts[p, 0]
        grouped[t, 1] = pts[p, 1]
        grouped[t, 2] = pts[p, 2]
        fill[seg[i]] = t + 1
    return grouped, bounds


@nb.njit(cache=True, nogil=True)
def _moments(acc: np.ndarray, s: int, pts: np.ndarray, plane: np.ndarray, z_floor: float, z_top: float,
             th_dist: float, band: float, seeds: bool) -> None:
    """Segment s's moment sums (count, first and second moments, summed in sample order) over its points `pts`,
    written to acc[s]: of the seeds (`seeds`: z_floor <= z < z_top) or of the points within th_dist of `plane`; both
    within |y| < band."""
    c0 = c1 = c2 = c3 = c4 = c5 = c6 = c7 = c8 = c9 = 0.0
    a = plane[0]
    b = plane[1]
    c = plane[2]
    d = plane[3]
    for i in range(pts.shape[0]):
        x = pts[i, 0]
        y = pts[i, 1]
        z = pts[i, 2]
        if seeds:
            take = z >= z_floor and z < z_top and abs(y) < band
        else:
            take = abs(a * x + b * y + c * z + d) < th_dist and abs(y) < band
        if take:
            c0 += 1.0
            c1 += x
            c2 += y
            c3 += z
            c4 += x * x
            c5 += x * y
            c6 += x * z
            c7 += y * y
            c8 += y * z
            c9 += z * z
    acc[s, 0] = c0
    acc[s, 1] = c1
    acc[s, 2] = c2
    acc[s, 3] = c3
    acc[s, 4] = c4
    acc[s, 5] = c5
    acc[s, 6] = c6
    acc[s, 7] = c7
    acc[s, 8] = c8
    acc[s, 9] = c9


@nb.njit(cache=True, nogil=True)
def _planes_from_sums(acc: np.ndarray, edges: np.ndarray, fallback_z: np.ndarray, min_normal_z: float,
                      min_points: int, max_step: float) -> np.ndarray:
    """Least-squares plane (smallest covariance eigenvector) per segment from accumulated moments.

    The segment holding x = 0 stands alone (horizontal at its `fallback_z` when degenerate); the others,
    outwards from it, take their inner neighbour's plane when they have fewer than `min_points` members, are
    steeper than allowed, or step by more than `max_step` from the neighbour at their shared edge.
    """
    n_seg = edges.shape[0] - 1
    planes = np.zeros((n_seg, 4))
    ok = np.zeros(n_seg, dtype=np.bool_)
    cov = np.empty((3, 3))
    for s in range(n_seg):
        planes[s, 2] = 1.0
        planes[s, 3] = -fallback_z[s]
        n = acc[s, 0]
        if n < max(min_points, 3):
            continue
        mx = acc[s, 1] / n
        my = acc[s, 2] / n
        mz = acc[s, 3] / n
        cov[0, 0] = acc[s, 4] / n - mx * mx
        cov[0, 1] = acc[s, 5] / n - mx * my
        cov[0, 2] = acc[s, 6] / n - mx * mz
        cov[1, 1] = acc[s, 7] / n - my * my
        cov[1, 2] = acc[s, 8] / n - my * mz
        cov[2, 2] = acc[s, 9] / n - mz * mz
        cov[1, 0] = cov[0, 1]
        cov[2, 0] = cov[0, 2]
        cov[2, 1] = cov[1, 2]
        normal = smallest_eigenvector(cov)
        if normal[2] < 0.0:
            normal = -normal
        if normal[2] < min_normal_z:
            continue
        planes[s, 0] = normal[0]
        planes[s, 1] = normal[1]
        planes[s, 2] = normal[2]
        planes[s, 3] = -(normal[0] * mx + normal[1] * my + normal[2] * mz)
        ok[s] = True
    centre = 0
    while centre < n_seg - 1 and edges[centre + 1] <= 0.0:
        centre += 1
    for s in range(centre + 1, n_seg):
        x = edges[s]
        if not ok[s] or abs(_edge_height(planes[s], x) - _edge_height(planes[s - 1], x)) > max_step:
            planes[s] = planes[s - 1]
    for s in range(centre - 1, -1, -1):
        x = edges[s + 1]
        if not ok[s] or abs(_edge_height(planes[s], x) - _edge_height(planes[s + 1], x)) > max_step:
            planes[s] = planes[s + 1]
    return planes


_SECTORS_PER_QUADRANT = 360  # the ground sample's azimuth sectors: about 0.25 degrees each


@nb.njit(cache=True, nogil=True)
def _sample(pts: np.ndarray, stride: int, in_scan_order: bool = True, lo: int = 0, hi: int = -1) -> np.ndarray:
    """Indices (ascending) of the points in every `stride`-th azimuth sector of about 0.25 degrees (sectors of equal
    pseudo-azimuth): about one point in `stride`, spread evenly around the sensor like every `stride`-th point of a
    firing-order scan, and the same points in any order. All points when `stride` is 1. The mask is written for
    every point and the indices gathered after it (a gather inside the loop kept it from vectorising). Points in
    no scan order (`in_scan_order` False) are read without a branch the CPU would mispredict on them (their
    quadrants and their sectors come at random): 115k shuffled points 1.5 -> 0.6-0.8 ms, the same indices. Only the
    points lo .. hi - 1 (hi -1: to the end) are read: two calls on the two halves give the whole scan's indices."""
    hi = pts.shape[0] if hi < 0 else hi
    n = hi - lo
    keep = np.empty(n, dtype=np.bool_)
    if stride <= 1:
        keep[:] = True
        return np.flatnonzero(keep) + lo
    scale = _SECTORS_PER_QUADRANT / stride
    share = 1.0 / stride
    if in_scan_order:
        for i in range(n):
            f = pseudo_azimuth(pts[lo + i, 0], pts[lo + i, 1]) * scale
            keep[i] = f - np.floor(f) < share
        return np.flatnonzero(keep) + lo
    for i in range(n):
        f = pseudo_azimuth_unordered(pts[lo + i, 0], pts[lo + i, 1]) * scale
        keep[i] = f - np.floor(f) < share
    index = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        index[count] = lo + i
        count += keep[i]
    return index[:count]


@nb.njit(cache=True, nogil=True)
def _fit_planes(pts: np.ndarray, sample: np.ndarray, edges: np.ndarray, n_lpr: int, n_iter: int, th_seeds: float,
                th_dist: float, z_floor: float, min_normal_z: float, band: float, outlier_share: float,
                max_step: float, stride: int) -> tuple:
    """The planes, and the sample gathered by segment (`_by_segment`: points and bounds) for `_count_heights`; the
    LPR and the plane fits read `sample` (indices of the points `_sample` picks, about one in `stride`)."""
    n_seg = edges.shape[0] - 1
    x0 = edges[0]
    width = edges[1] - edges[0]
    # Each segment's part of the sample in sample order: its moments are summed in registers (`_moments`) in the
    # order the points come, and the LPR and the local ground's counts need no segment per point.
    grouped, bounds = _by_segment(pts, sample, x0, width, n_seg)
    lpr = _lowest_means(grouped, bounds, n_lpr, z_floor, band, outlier_share, 0.1)
    fallback_z = np.where(np.isnan(lpr), z_floor, lpr)
    acc = np.zeros((n_seg, 10))
    planes = np.zeros((n_seg, 4))
    for s in range(n_seg):
        _moments(acc, s, grouped[bounds[s]:bounds[s + 1]], planes[s], z_floor, lpr[s] + th_seeds, th_dist, band, True)
    min_points = max(n_lpr // stride, 3)
    planes = _planes_from_sums(acc, edges, fallback_z, min_normal_z, min_points, max_step)
    for _ in range(n_iter - 1):
        for s in range(n_seg):
            _moments(acc, s, grouped[bounds[s]:bounds[s + 1]], planes[s], z_floor, 0.0, th_dist, band, False)
        planes = _planes_from_sums(acc, edges, fallback_z, min_normal_z, min_points, max_step)
    return planes, grouped, bounds


@nb.njit(cache=True, nogil=True)
def _ground_test(pts: np.ndarray, planes: np.ndarray, x0: float, width: float, th_dist: float, ground: np.ndarray,
                 lo: int, hi: int) -> None:
    """The final ground test of the points lo .. hi - 1 (every point, not the sample), written to `ground`."""
    for i in range(lo, hi):
        ground[i] = abs(plane_distance(planes, x0, width, pts[i, 0], pts[i, 1], pts[i, 2])) < th_dist


@nb.njit(cache=True, nogil=True)
def _test_and_count(pts: np.ndarray, planes: np.ndarray, x0: float, width: float, th_dist: float,
                    ground: np.ndarray, lo: int, hi: int, grouped: np.ndarray, bounds: np.ndarray, hist: np.ndarray,
                    origin: float) -> None:
    """`_ground_test` of the points lo .. hi - 1, then the sample's heights counted into `hist` (empty: none)."""
    _ground_test(pts, planes, x0, width, th_dist, ground, lo, hi)
    if hist.shape[0] > 0:
        _count_heights(grouped, bounds, planes, hist, origin)


@nb.njit(cache=True, nogil=True)
def _count_heights(grouped: np.ndarray, bounds: np.ndarray, planes: np.ndarray, hist: np.ndarray,
                   origin: float) -> None:
    """Count the sample's signed plane distances (`_by_segment`'s groups, each under its segment's plane) into the
    local ground's per-cell histograms: first each point's slot (branch-free, the last slot for "outside"), then the
    counts (saturating: the same counts in any order)."""
    n = grouped.shape[0]
    nx = hist.shape[0]
    ny = hist.shape[1]
    n_bins = hist.shape[2]
    flat = hist.reshape(-1)
    outside = flat.shape[0]
    slot = np.empty(n, dtype=np.int64)
    inv_cell = 1.0 / LOCAL_CELL_M
    inv_bin = 1.0 / LOCAL_BIN_M
    for s in range(bounds.shape[0] - 1):
        for i in range(bounds[s], bounds[s + 1]):
            x = grouped[i, 0]
            y = grouped[i, 1]
            d = planes[s, 0] * x + planes[s, 1] * y + planes[s, 2] * grouped[i, 2] + planes[s, 3]
            fx = (x - origin) * inv_cell
            fy = (y - origin) * inv_cell
            fb = (d + LOCAL_BAND_M) * inv_bin
            inside = (fx >= 0.0) & (fy >= 0.0) & (fb >= 0.0) & (fx < nx) & (fy < ny) & (fb < n_bins)
            slot[i] = (np.int64(fx) * ny + np.int64(fy)) * n_bins + np.int64(fb) if inside else outside
    for i in range(n):
        if slot[i] < outside and flat[slot[i]] < 65535:  # uint16: saturates, never wraps
            flat[slot[i]] += 1


class PlaneFit(NamedTuple):
    """The first phase of ground plane fitting (`fit_planes`): the segment planes and what the final test needs."""

    points: np.ndarray  # (N, >=3) float32, contiguous: the points the planes were fitted to
    planes: np.ndarray  # (n_seg, 4) float64
    segment_edges: np.ndarray  # (n_seg + 1,) x boundaries
    grouped: np.ndarray  # the sample grouped by segment (the local ground's histogram counts it)
    bounds: np.ndarray
    hist: np.ndarray  # (n_cells, n_cells, n_bins) uint16, empty without a local ground
    origin: float


def fit_ground(points: np.ndarray, config: Stage1Config, in_scan_order: bool = True,
               pool: Executor | None = None) -> GroundFit:
    """Ground mask and planes of a scan (N x >=3, sensor frame, z up) under `config`; see the module docstring.
    `in_scan_order` False: the points are likely in no scan order (the same result, drawn without branches the CPU
    would mispredict on them). `pool`: an executor whose thread is free (never the caller's own): the sample and the
    final test are then split between it and the caller: the same result, about 0.2 ms sooner on a KITTI scan.

    Segments span x in [-ground_x_extent, ground_x_extent] (points beyond fall into the end segments); a plane
    steeper than `ground_max_slope_deg` or stepping more than `ground_max_step` at its inner edge takes its inner
    neighbour's plane (the centre segment's falls back to a horizontal plane at its LPR).
    """
    return ground_of_planes(fit_planes(points, config, in_scan_order, pool), config, pool)


def fit_planes(points: np.ndarray, config: Stage1Config, in_scan_order: bool = True,
               pool: Executor | None = None) -> PlaneFit:
    """`fit_ground`'s first phase: the sample and the segment planes (`pool` as there, for the sample)."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    n_seg = int(config.n_seg)
    width = 2.0 * config.ground_x_extent / n_seg
    edges = -config.ground_x_extent + width * np.arange(n_seg + 1)
    if len(pts) == 0:
        planes = np.tile([0.0, 0.0, 1.0, config.seed_height], (n_seg, 1))
        return PlaneFit(pts, planes, edges, np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros((0, 0, 0), dtype=np.uint16), 0.0)
    # The local ground's grid covers every cluster centre the range gate keeps and its widest window.
    half = config.max_range + config.local_ground_radius + LOCAL_GROWTH * config.max_range
    n_cells = int(np.ceil(2.0 * half / LOCAL_CELL_M)) if config.local_ground else 0
    n_bins = round(2.0 * LOCAL_BAND_M / LOCAL_BIN_M) if n_cells else 0
    hist = np.zeros((n_cells, n_cells, n_bins), dtype=np.uint16)
    origin = -0.5 * n_cells * LOCAL_CELL_M
    stride = int(config.fit_stride)
    n = len(pts)
    middle = _middle(n, pool)
    upper = pool.submit(_sample, pts, stride, in_scan_order, middle, n) if middle < n else None
    sample = _sample(pts, stride, in_scan_order, 0, middle)  # apart: in the kernel, the fit took 3.7 ms, not 2.5
    if upper is not None:
        sample = np.concatenate([sample, upper.result()])
    planes, grouped, bounds = _fit_planes(
        pts, sample, edges, int(config.n_lpr), int(config.n_iter), config.th_seeds, config.th_dist,
        -(config.seed_height + config.below_ground_margin), float(np.cos(np.deg2rad(config.ground_max_slope_deg))),
        config.ground_seed_band, config.ground_lpr_outlier_share, config.ground_max_step, stride,
    )
    return PlaneFit(pts, planes, edges, grouped, bounds, hist, origin)


def ground_of_planes(fit: PlaneFit, config: Stage1Config, pool: Executor | None = None) -> GroundFit:
    """`fit_ground`'s second phase: every point tested against its segment's plane (and the sample counted into the
    local ground), split between `pool`'s thread and the caller's when given: the same mask either way. So the ground
    thread can fit the planes while the caller recovers the rings, and both then share the test."""
    pts, planes, edges = fit.points, fit.planes, fit.segment_edges
    n = len(pts)
    if n == 0:
        local = _local_ground(planes, edges, fit.hist, 0.0, config)
        return GroundFit(np.zeros(0, dtype=bool), planes, edges, local)
    middle = _middle(n, pool)
    ground = np.empty(n, dtype=np.bool_)
    test = (pts, planes, float(edges[0]), float(edges[1] - edges[0]), float(config.th_dist), ground)
    counted = (pool.submit(_test_and_count, *test, middle, n, fit.grouped, fit.bounds, fit.hist, fit.origin)
               if middle < n else None)
    if counted is None:
        _test_and_count(*test, 0, n, fit.grouped, fit.bounds, fit.hist, fit.origin)
    else:
        _ground_test(*test, 0, middle)
        counted.result()
    return GroundFit(ground, planes, edges, _local_ground(planes, edges, fit.hist, fit.origin, config))


def _middle(n: int, pool: Executor | None) -> int:
    """Where a scan of n points is split between two threads (n: not split)."""
    return n // 2 if pool is not None and n >= TWO_THREADS_MIN_POINTS else n


def with_local_ground(points: np.ndarray, fit: GroundFit, band: float) -> np.ndarray:
    """`fit.ground` and the points within `band` (vertically) of the local ground
    (`Stage1Config.local_ground_as_ground`): the local ground is read once per LOCAL_CELL_M cell that holds such a
    point, at its centre, and its height at a point is the point's segment plane's there moved by its cell's offset.
    The same mask without a local ground. Two compiled passes (the cells, then the heights): numpy's unique over a
    scan's 50,000-80,000 non-ground points took 3-11 ms of the 5-30 ms this cost."""
    local = fit.local
    if local is None or len(points) == 0:
        return fit.ground
    pts = np.ascontiguousarray(points, dtype=np.float32)
    cell_of, centres = _local_cells(pts, fit.ground, local.origin, local.hist.shape[0])
    offsets = local.offsets(centres)
    edges = local.segment_edges
    return _near_local_ground(pts, fit.ground, cell_of, offsets, local.planes, float(edges[0]),
                              float(edges[1] - edges[0]), band)


@nb.njit(cache=True, nogil=True)
def _local_cells(points: np.ndarray, ground: np.ndarray, origin: float, n_cells: int) -> tuple:
    """Per point, the index of its LOCAL_CELL_M cell among the cells that hold a non-ground point of the grid (-1:
    ground, or off the grid), and those cells' centres (x, y) in the order of their keys (row, then column)."""
    n = points.shape[0]
    key = np.full(n, -1, dtype=np.int64)
    seen = np.zeros(n_cells * n_cells, dtype=np.int64)
    for k in range(n):
        if ground[k]:
            continue
        i = np.int64(np.floor((np.float64(points[k, 0]) - origin) / LOCAL_CELL_M))
        j = np.int64(np.floor((np.float64(points[k, 1]) - origin) / LOCAL_CELL_M))
        if 0 <= i < n_cells and 0 <= j < n_cells:
            key[k] = i * n_cells + j
            seen[key[k]] = 1
    count = 0
    for c in range(n_cells * n_cells):
        if seen[c]:
            seen[c] = count + 1  # the cell's index, plus one
            count += 1
    centres = np.empty((count, 2))
    for c in range(n_cells * n_cells):
        if seen[c]:
            centres[seen[c] - 1, 0] = origin + LOCAL_CELL_M * (c // n_cells + 0.5)
            centres[seen[c] - 1, 1] = origin + LOCAL_CELL_M * (c % n_cells + 0.5)
    cell_of = np.full(n, -1, dtype=np.int64)
    for k in range(n):
        if key[k] >= 0:
            cell_of[k] = seen[key[k]] - 1
    return cell_of, centres


@nb.njit(cache=True, nogil=True)
def _near_local_ground(points: np.ndarray, ground: np.ndarray, cell_of: np.ndarray, offsets: np.ndarray,
                       planes: np.ndarray, x0: float, width: float, band: float) -> np.ndarray:
    """`ground` with the points of a cell (`cell_of`) within `band` of the local ground there: their segment plane's
    height at them moved by their cell's offset (`LocalGround.heights`, written out in the same order)."""
    out = ground.copy()
    n_seg = planes.shape[0]
    for k in range(points.shape[0]):
        c = cell_of[k]
        if c < 0:
            continue
        x = np.float64(points[k, 0])
        y = np.float64(points[k, 1])
        s = min(max(np.int64((x - x0) / width), 0), n_seg - 1)
        height = (((offsets[c] - planes[s, 0] * x) - planes[s, 1] * y) - planes[s, 3]) / planes[s, 2]
        if abs(np.float64(points[k, 2]) - height) < band:
            out[k] = True
    return out


def _local_ground(planes: np.ndarray, edges: np.ndarray, hist: np.ndarray, origin: float,
                  config: Stage1Config) -> LocalGround | None:
    """The LocalGround of counted histograms (None when config.local_ground is off)."""
    if not config.local_ground:
        return None
    min_points = max(2, round(LOCAL_MIN_POINTS / max(int(config.fit_stride), 1)))
    return LocalGround(planes, edges, hist, float(origin), float(config.local_ground_radius), min_points,
                       float(config.th_dist))


@nb.njit(cache=True, nogil=True)
def _local_offsets(hist: np.ndarray, origin: float, xy: np.ndarray, radius: float, min_points: int,
                   band: float) -> np.ndarray:
    """`LocalGround.offsets`: per position, the window's summed histogram; the median of its plane band when that
    holds min_points // 2, else its lowest dense bin pair (module docstring)."""
    m = xy.shape[0]
    out = np.zeros(m)
    n_cells = hist.shape[0]
    n_bins = hist.shape[2]
    if n_cells <= 0 or n_bins < 3:
        return out
    counts = np.empty(n_bins, dtype=np.int64)
    band_lo = min(max(int((LOCAL_BAND_M - band) / LOCAL_BIN_M + 0.5), 0), n_bins)
    band_hi = min(max(int((LOCAL_BAND_M + band) / LOCAL_BIN_M + 0.5), band_lo), n_bins)
    in_band = max(min_points // 2, 2)
    for q in range(m):
        x = xy[q, 0]
        y = xy[q, 1]
        half = radius + LOCAL_GROWTH * np.hypot(x, y)
        i0 = min(max(int(np.floor((x - half - origin) / LOCAL_CELL_M)), 0), n_cells)
        i1 = min(max(int(np.floor((x + half - origin) / LOCAL_CELL_M)) + 1, 0), n_cells)
        j0 = min(max(int(np.floor((y - half - origin) / LOCAL_CELL_M)), 0), n_cells)
        j1 = min(max(int(np.floor((y + half - origin) / LOCAL_CELL_M)) + 1, 0), n_cells)
        if i1 <= i0 or j1 <= j0:
            continue
        counts[:] = 0
        for i in range(i0, i1):
            for j in range(j0, j1):
                for b in range(n_bins):
                    counts[b] += hist[i, j, b]
        n_band = 0
        for b in range(band_lo, band_hi):
            n_band += counts[b]
        if n_band >= in_band:  # ground near the plane: its median, within the band
            seen = 0
            for b in range(band_lo, band_hi):
                seen += counts[b]
                if 2 * seen >= n_band:
                    out[q] = (b + 0.5) * LOCAL_BIN_M - LOCAL_BAND_M
                    break
            continue
        best = 0
        for b in range(n_bins - 1):
            best = max(best, counts[b] + counts[b + 1])
        below = max(min_points, LOCAL_SHARE * best)  # bins under the plane's ground band: stray returns
        for b in range(n_bins - 1):
            if counts[b] + counts[b + 1] >= (below if b < band_lo else min_points):
                total = 0.0
                weight = 0.0
                for t in range(b, min(b + 3, n_bins)):
                    total += counts[t] * ((t + 0.5) * LOCAL_BIN_M - LOCAL_BAND_M)
                    weight += counts[t]
                out[q] = total / weight
                break
    return out


def warm_up() -> None:
    """Compile the ground kernels on a tiny synthetic scan."""
    rng = np.random.default_rng(0)
    pts = rng.uniform(-10.0, 10.0, size=(200, 4)).astype(np.float32)
    pts[:100, 2] = -1.73
    fit = fit_ground(pts, Stage1Config())
    fit.local.offsets(pts[:4, :2])
    with_local_ground(pts, fit, Stage1Config().th_dist)
    many = np.tile(pts, (TWO_THREADS_MIN_POINTS // len(pts) + 1, 1))  # big enough for the two-thread fit
    with ThreadPoolExecutor(max_workers=1) as pool:
        fit_ground(many, Stage1Config(), in_scan_order=False, pool=pool)
