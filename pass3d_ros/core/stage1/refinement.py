"""Proposal refinement: boxes around clusters, gates that keep what could be a car / pedestrian / cyclist,
and the enlarged boxes' point membership.

Boxes are minimal-area rectangles in the sensor's x-y plane (convex hull of the Akl-Toussaint survivors,
then every hull edge direction: the rotating-calipers candidates; exact, and on a KITTI frame's 33 kept
clusters 0.12 ms against 0.41 ms for a 1-degree search over 90 angles) extruded over the cluster's z range.
z is the sensor's up axis, perpendicular to the ground for a level-mounted sensor (KITTI's ground normal is
within 2 degrees of it); Box3D holds a yaw only. Gates: a point count that falls as 1/distance, a bottom
near and a top not far above the ground, and footprints an occluded or whole road user can have. The ground is the
segment planes, moved by the local ground's offset around each cluster when the planes come as a
`pass3d_ros.core.stage1.ground.LocalGround` (Stage1Config.local_ground): a plane extrapolated 60 m from the road it was
fitted on can sit tenths of a metre off the ground under a far car, enough to call its top too low. Kept
boxes are enlarged (per side) and take in every point inside, ground points too: wheels and feet often sit
in the ground band; with a local ground a box also reaches down to the ground band under it (`enlarged_membership`'s
`floors`), however high its own lowest point is.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.ground import LocalGround, fit_ground, plane_distance
from pass3d_ros.core.stage1.sensor_params import RangeGate
from pass3d_ros.data.frame import Box3D


@nb.njit(cache=True, nogil=True)
def _cluster_stats(pts: np.ndarray, label: np.ndarray, n_clusters: int, planes: np.ndarray,
                   edges: np.ndarray) -> tuple:
    """Count, x-y sums, x/y/z bounds, and lowest and highest height above the ground plane of every cluster."""
    count = np.zeros(n_clusters, dtype=np.int64)
    sums = np.zeros((n_clusters, 2))
    lo = np.full((n_clusters, 3), np.inf)
    hi = np.full((n_clusters, 3), -np.inf)
    bottom = np.full(n_clusters, np.inf)
    top = np.full(n_clusters, -np.inf)
    x0 = edges[0]
    width = edges[1] - edges[0]
    for i in range(pts.shape[0]):  # coordinates read once, bounds unrolled: a fifth faster than a loop over axes
        c = label[i]
        if c < 0:
            continue
        x = pts[i, 0]
        y = pts[i, 1]
        z = pts[i, 2]
        count[c] += 1
        sums[c, 0] += x
        sums[c, 1] += y
        lo[c, 0] = min(lo[c, 0], x)  # min and max, not branches: no misprediction on a cluster's first points
        hi[c, 0] = max(hi[c, 0], x)
        lo[c, 1] = min(lo[c, 1], y)
        hi[c, 1] = max(hi[c, 1], y)
        lo[c, 2] = min(lo[c, 2], z)
        hi[c, 2] = max(hi[c, 2], z)
        h = plane_distance(planes, x0, width, x, y, z)
        bottom[c] = min(bottom[c], h)
        top[c] = max(top[c], h)
    return count, sums, lo, hi, bottom, top


@nb.njit(cache=True, nogil=True)
def _cross(ox: float, oy: float, ax: float, ay: float, bx: float, by: float) -> float:
    """z of (a - o) x (b - o): positive when o, a, b turn counter-clockwise."""
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@nb.njit(cache=True, nogil=True)
def _hull_candidates(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points not strictly inside the octagon of extreme points (Akl-Toussaint): the hull's
    vertices are among them, and usually few points remain.

    The extremes are kept in registers (not re-read through their indices) and every point is tested against all 8
    edges without an early exit, a degenerate edge (coinciding extremes) replaced by a copy of a real one: the same
    products and the same survivors, and the loop vectorises (a frame's clusters 0.31 -> 0.14 ms)."""
    n = x.shape[0]
    # support points facing 180, 225, ..., 495 degrees: counter-clockwise; ties keep the first point
    e0 = e1 = e2 = e3 = e4 = e5 = e6 = e7 = 0
    v0 = v4 = x[0]
    v1 = v5 = x[0] + y[0]
    v2 = v6 = y[0]
    v3 = v7 = y[0] - x[0]
    for i in range(1, n):
        xi = x[i]
        yi = y[i]
        s = xi + yi
        d = yi - xi
        if xi < v0:
            v0, e0 = xi, i
        if s < v1:
            v1, e1 = s, i
        if yi < v2:
            v2, e2 = yi, i
        if d < v3:
            v3, e3 = d, i
        if xi > v4:
            v4, e4 = xi, i
        if s > v5:
            v5, e5 = s, i
        if yi > v6:
            v6, e6 = yi, i
        if d > v7:
            v7, e7 = d, i
    ext = np.array([e0, e1, e2, e3, e4, e5, e6, e7])
    ax = np.empty(8)
    ay = np.empty(8)
    bx = np.empty(8)
    by = np.empty(8)
    n_edges = 0
    for t in range(8):
        a = ext[t]
        b = ext[(t + 1) % 8]
        if a == b:
            continue
        ax[n_edges], ay[n_edges], bx[n_edges], by[n_edges] = x[a], y[a], x[b], y[b]
        n_edges += 1
    keep = np.empty(n, dtype=np.int64)
    if n_edges == 0:  # all extremes coincide (every point is the same point): all stay
        for i in range(n):
            keep[i] = i
        return keep
    for e in range(n_edges, 8):
        ax[e], ay[e], bx[e], by[e] = ax[0], ay[0], bx[0], by[0]
    outside = np.empty(n, dtype=np.bool_)
    for i in range(n):
        inside = True
        for e in range(8):
            inside &= _cross(ax[e], ay[e], bx[e], by[e], x[i], y[i]) > 0.0
        outside[i] = not inside
    m = 0
    for i in range(n):
        keep[m] = i
        m += outside[i]
    return keep[:m]


BINNED_MIN_POINTS = 2000  # `_binned_candidates` filters clusters from this many points (below, the octagon alone)
HULL_BINS = 64  # x bins of `_binned_candidates`' inner hull
INSIDE_MARGIN_M = 1e-6  # a point is dropped only this far inside the inner hull or more (rounding never drops a vertex)


@nb.njit(cache=True, nogil=True)
def _chain_y(cx: np.ndarray, cy: np.ndarray, m: int, xq: float) -> float:
    """y of the polyline through the first `m` points of (cx, cy), x increasing, at `xq` (within its x range)."""
    a, b = 0, m - 1
    while b - a > 1:
        mid = (a + b) // 2
        if cx[mid] <= xq:
            a = mid
        else:
            b = mid
    dx = cx[b] - cx[a]
    if dx <= 0.0:
        return min(cy[a], cy[b])
    return cy[a] + (cy[b] - cy[a]) * (xq - cx[a]) / dx


@nb.njit(cache=True, nogil=True)
def _convex_hull(x: np.ndarray, y: np.ndarray, order: np.ndarray) -> tuple[np.ndarray, int]:
    """The convex hull of the points (x, y) by the monotone chain over `order` (ascending x, then y): the vertices'
    indices counter-clockwise from the first point, the lower chain first (its last vertex, the rightmost point, at
    the second value less one)."""
    n = order.shape[0]
    hull = np.empty(2 * n + 1, dtype=np.int64)
    k = 0
    for t in range(n):
        i = order[t]
        while k >= 2 and _cross(x[hull[k - 2]], y[hull[k - 2]], x[hull[k - 1]], y[hull[k - 1]], x[i], y[i]) <= 0.0:
            k -= 1
        hull[k] = i
        k += 1
    lower = k + 1
    for t in range(n - 2, -1, -1):
        i = order[t]
        while k >= lower and _cross(x[hull[k - 2]], y[hull[k - 2]], x[hull[k - 1]], y[hull[k - 1]], x[i], y[i]) <= 0.0:
            k -= 1
        hull[k] = i
        k += 1
    return hull[:max(k - 1, 1)], lower - 1


@nb.njit(cache=True, nogil=True)
def _binned_candidates(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points a cluster's convex hull may have as vertices, for large clusters: the hull of the
    lowest and highest point of each of HULL_BINS x bins lies inside the cluster's hull, and a point of bin b whose y
    lies between that inner hull's upper and lower chain over bins b-1 .. b+1 (each chain's least reach there, at the
    ends of that span: the chains are concave and convex), by INSIDE_MARGIN_M, is no vertex. A wall's long cluster
    keeps a few hundred of its 36,000 points (the octagon half of them: its rectangle 0.7 -> 0.2 ms). The end bins
    are never filtered; without an inner hull, the octagon's survivors (`_hull_candidates`)."""
    n = x.shape[0]
    x_lo, x_hi = x.min(), x.max()
    if not x_hi > x_lo:
        return _hull_candidates(x, y)
    width = (x_hi - x_lo) / HULL_BINS
    lowest = np.full(HULL_BINS, -1, dtype=np.int64)
    highest = np.full(HULL_BINS, -1, dtype=np.int64)
    for i in range(n):
        b = min(int((x[i] - x_lo) / width), HULL_BINS - 1)
        if lowest[b] < 0 or y[i] < y[lowest[b]]:
            lowest[b] = i
        if highest[b] < 0 or y[i] > y[highest[b]]:
            highest[b] = i
    chosen = np.concatenate((lowest[lowest >= 0], highest[highest >= 0]))
    sx, sy = x[chosen], y[chosen]
    hull, n_lower = _convex_hull(sx, sy, np.argsort(sx + 1e-9 * sy))
    if n_lower < 2:
        return _hull_candidates(x, y)
    low = hull[:n_lower]  # left to right
    up = np.concatenate((hull[:1], hull[n_lower:][::-1], hull[n_lower - 1:n_lower]))  # left to right too
    lx, ly, ux, uy = sx[low], sy[low], sx[up], sy[up]
    left, right = max(lx[0], ux[0]), min(lx[-1], ux[-1])
    below = np.full(HULL_BINS, -np.inf)  # a point of bin b strictly between these is strictly inside the inner hull
    above = np.full(HULL_BINS, np.inf)
    for b in range(HULL_BINS):
        e0, e1 = x_lo + (b - 1) * width, x_lo + (b + 2) * width  # bin b, a bin either side (the index's rounding)
        if e0 <= left or e1 >= right:
            continue
        top = min(_chain_y(ux, uy, len(ux), e0), _chain_y(ux, uy, len(ux), e1)) - INSIDE_MARGIN_M
        bottom = max(_chain_y(lx, ly, len(lx), e0), _chain_y(lx, ly, len(lx), e1)) + INSIDE_MARGIN_M
        if top > bottom:
            below[b], above[b] = top, bottom
    keep = np.empty(n, dtype=np.int64)
    m = 0
    for i in range(n):
        b = min(int((x[i] - x_lo) / width), HULL_BINS - 1)
        keep[m] = i
        m += not (above[b] < y[i] < below[b])
    return keep[:m]


RADIX_MIN_POINTS = 2000  # `_hull_order` radix-sorts from this many points (below, argsort is as fast)


@nb.njit(cache=True, nogil=True)
def _hull_order(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The monotone chain's point order: np.argsort of x + 1e-9 y, the same permutation however it is sorted where
    no two points with different coordinates share a key (tied points at the same x-y are interchangeable in the
    hull). Large inputs (a wall's 36k points leave 18k hull candidates: argsort 1.0 ms) take a radix sort, 4x faster;
    it falls back to argsort where a key is shared by different points."""
    key = x + 1e-9 * y
    n = key.shape[0]
    if n < RADIX_MIN_POINTS:
        return np.argsort(key)
    order = _radix_argsort(key)
    for t in range(1, n):
        a = order[t - 1]
        b = order[t]
        if key[a] == key[b] and (x[a] != x[b] or y[a] != y[b]):
            return np.argsort(key)
    return order


@nb.njit(cache=True, nogil=True)
def _radix_argsort(key: np.ndarray) -> np.ndarray:
    """Stable argsort of float64 keys (no NaN): least-significant-digit radix sort, 11 bits a pass, over the keys'
    bits mapped to unsigned integers that order as the floats do; a pass whose digit is the same for all is
    skipped."""
    n = key.shape[0]
    bits = key.view(np.uint64)
    sign = np.uint64(1) << np.uint64(63)
    mapped = np.empty(n, dtype=np.uint64)
    for i in range(n):
        v = bits[i]
        mapped[i] = ~v if v & sign else v | sign
    order = np.arange(n)
    spare = np.empty(n, dtype=np.int64)
    count = np.empty(2049, dtype=np.int64)
    digit_mask = np.uint64(2047)
    for p in range(6):
        shift = np.uint64(11 * p)
        count[:] = 0
        for i in range(n):
            count[((mapped[i] >> shift) & digit_mask) + 1] += 1
        if count[1:].max() == n:
            continue
        for d in range(2048):
            count[d + 1] += count[d]
        for t in range(n):
            i = order[t]
            d = (mapped[i] >> shift) & digit_mask
            spare[count[d]] = i
            count[d] += 1
        order, spare = spare, order
    return order


@nb.njit(cache=True, nogil=True)
def _min_area_rect(x_all: np.ndarray, y_all: np.ndarray) -> tuple:
    """(centre x, centre y, length, width, yaw) of the minimal-area rectangle around 2D points; length >= width.

    Convex hull (monotone chain over the Akl-Toussaint survivors, or a large cluster's `_binned_candidates`), then
    each hull edge direction in turn.
    """
    keep = _hull_candidates(x_all, y_all) if x_all.shape[0] < BINNED_MIN_POINTS else _binned_candidates(x_all, y_all)
    x = x_all[keep]
    y = y_all[keep]
    hull, _ = _convex_hull(x, y, _hull_order(x, y))
    h = hull.shape[0]
    best_area = np.inf
    bux, buy, bu, bv, length, width = 1.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for e in range(h):
        a = hull[e]
        b = hull[(e + 1) % h]
        ux = x[b] - x[a]
        uy = y[b] - y[a]
        norm = np.sqrt(ux * ux + uy * uy)
        if norm == 0.0:
            ux, uy, norm = 1.0, 0.0, 1.0
        ux /= norm
        uy /= norm
        u_lo = np.inf
        u_hi = -np.inf
        v_lo = np.inf
        v_hi = -np.inf
        for t in range(h):
            p = hull[t]
            u = x[p] * ux + y[p] * uy
            v = y[p] * ux - x[p] * uy
            u_lo = min(u_lo, u)
            u_hi = max(u_hi, u)
            v_lo = min(v_lo, v)
            v_hi = max(v_hi, v)
        area = (u_hi - u_lo) * (v_hi - v_lo)
        if area < best_area:
            best_area = area
            bux, buy = ux, uy
            bu = 0.5 * (u_lo + u_hi)
            bv = 0.5 * (v_lo + v_hi)
            length = u_hi - u_lo
            width = v_hi - v_lo
    cx = bu * bux - bv * buy
    cy = bu * buy + bv * bux
    yaw = np.arctan2(buy, bux)
    if width > length:
        length, width = width, length
        yaw += 0.5 * np.pi
    if yaw > 0.5 * np.pi:
        yaw -= np.pi
    elif yaw <= -0.5 * np.pi:
        yaw += np.pi
    return cx, cy, length, width, yaw


def min_area_rectangle(xy: np.ndarray) -> tuple[float, float, float, float, float]:
    """Minimal-area rectangle around 2D points: (centre x, centre y, length, width, yaw), length >= width."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        raise ValueError("min_area_rectangle needs at least one point")
    return tuple(float(v) for v in _min_area_rect(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])))


@nb.njit(cache=True, nogil=True)
def grouped_points(first: np.ndarray, second: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Point indices grouped by group id (a counting sort: ascending within each group, as the points come), and the
    k + 1 bounds of the groups; a point belongs to group first[i] and to second[i] (ids below 0: none; `second`
    empty: no second group)."""
    two = second.shape[0] > 0
    bounds = np.zeros(k + 1, dtype=np.int64)
    for i in range(first.shape[0]):
        if first[i] >= 0:
            bounds[first[i] + 1] += 1
        if two and second[i] >= 0:
            bounds[second[i] + 1] += 1
    for j in range(k):
        bounds[j + 1] += bounds[j]
    fill = bounds[:k].copy()
    index = np.empty(bounds[k], dtype=np.int64)
    for i in range(first.shape[0]):
        if first[i] >= 0:
            index[fill[first[i]]] = i
            fill[first[i]] += 1
        if two and second[i] >= 0:
            index[fill[second[i]]] = i
            fill[second[i]] += 1
    return index, bounds


@nb.njit(cache=True, nogil=True)
def grouped_by_slot(label: np.ndarray, slot: np.ndarray, n_slots: int) -> tuple[np.ndarray, np.ndarray]:
    """The points of the clusters that have a slot (slot[cluster] >= 0), grouped by slot in point order (a counting
    sort), and the n_slots + 1 bounds of the groups."""
    group = np.full(label.shape[0], -1, dtype=np.int64)
    for i in range(label.shape[0]):
        if label[i] >= 0:
            group[i] = slot[label[i]]
    return grouped_points(group, np.empty(0, dtype=np.int64), n_slots)


@nb.njit(cache=True, nogil=True)
def _cluster_rects(pts: np.ndarray, label: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Minimal-area rectangle (cx, cy, length, width, yaw) of each candidate cluster (rows in candidate order)."""
    n_clusters = label.max() + 1 if label.shape[0] > 0 else 0
    slot = np.full(max(n_clusters, 1), -1, dtype=np.int64)
    for t in range(candidates.shape[0]):
        slot[candidates[t]] = t
    k = candidates.shape[0]
    members, start = grouped_by_slot(label, slot, k)
    xs = np.empty(start[k])
    ys = np.empty(start[k])
    for j in range(start[k]):
        xs[j] = pts[members[j], 0]
        ys[j] = pts[members[j], 1]
    out = np.zeros((k, 5))
    for t in range(k):
        if start[t + 1] > start[t]:
            cx, cy, length, width, yaw = _min_area_rect(xs[start[t]:start[t + 1]], ys[start[t]:start[t + 1]])
            out[t, 0] = cx
            out[t, 1] = cy
            out[t, 2] = length
            out[t, 3] = width
            out[t, 4] = yaw
    return out


def points_needed(rng: np.ndarray, config: Stage1Config, gate: RangeGate | None = None,
                  xy: np.ndarray | None = None) -> np.ndarray:
    """The few-points gate: the points a cluster centred `rng` metres away (horizontally) needs, th_num_near up to
    th_num_range, then falling as 1 / range, times `gate`'s factor at that range (in the direction `xy`: RangeGate.at)
    when given, never below th_num_floor."""
    near = config.th_num_near if gate is None else config.th_num_near * gate.at(rng, xy)
    return np.maximum(config.th_num_floor, near * config.th_num_range / np.maximum(rng, config.th_num_range))


PART_MARGIN_M = 2.0  # `Gated.may_part`: slack on the bottom and top gates for the local ground's offsets at a part's
# centre, which differ from those at its cluster's (1.0 m changed the proposals of 10 of 129 judge frames, 2.0 none)


class Gated(NamedTuple):
    """What the gates say of a frame's clusters (`gate_clusters`)."""

    z_lo: np.ndarray  # per cluster: lowest z
    z_hi: np.ndarray  # per cluster: highest z
    fitted: np.ndarray  # cluster ids passing every gate but the footprint one
    rects: np.ndarray  # their rectangles (cx, cy, length, width, yaw)
    keep: np.ndarray  # mask over `fitted`: kept
    footprint: np.ndarray  # mask over `fitted`: footprint gate passed
    count: np.ndarray  # per cluster: points
    may_part: np.ndarray  # per cluster: enough points for two parts the few-points gate keeps, within max_range, and
    # low and high enough (within PART_MARGIN_M) that a part could pass the bottom and top gates


def cluster_heights(points: np.ndarray, label: np.ndarray, n_clusters: int, planes: np.ndarray,
                    segment_edges: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per cluster id: its point count, its centre (x, y), and its lowest and highest point above the segment planes
    `planes` (the local ground's offset at the centre, which the gates take off both, not applied; +-inf for a
    cluster without points)."""
    count, sums, _, _, bottom, top = _cluster_stats(points, label, n_clusters, planes, segment_edges)
    return count, sums / np.maximum(count, 1)[:, None], bottom, top


def gate_clusters(
    points: np.ndarray,
    label: np.ndarray,
    n_clusters: int,
    planes: np.ndarray | LocalGround,
    segment_edges: np.ndarray,
    config: Stage1Config,
    fit_all: bool = False,
    gate: RangeGate | None = None,
) -> Gated:
    """The gates of `select_proposals` (see `Gated`).

    `planes`: the segment planes (n_seg x 4), or a LocalGround (GroundFit.local), whose offsets around each cluster
    centre move its bottom and top heights (module docstring). Fitted: the clusters that pass every gate but the
    footprint one, less (unless `fit_all`) those whose x-y extent no footprint rectangle can hold, which fail it
    without a fit. `gate`: the few-points gate's factor per range (`points_needed`).
    """
    local = planes if isinstance(planes, LocalGround) else None
    plane_rows = local.planes if local is not None else planes
    count, sums, lo, hi, bottom, top = _cluster_stats(points, label, n_clusters, plane_rows, segment_edges)
    centre = sums / np.maximum(count, 1)[:, None]
    rng = np.hypot(centre[:, 0], centre[:, 1])
    need = points_needed(rng, config, gate, centre)
    extent = hi - lo
    may_part = ((count >= 2 * need) & (rng <= config.max_range) & (bottom <= config.max_bottom + PART_MARGIN_M)
                & (top >= config.min_top - PART_MARGIN_M))
    ok = (count >= need) & (rng <= config.max_range) & (extent[:, 2] <= config.max_height)
    if local is not None:  # read only where the other gates pass: a few hundred of a frame's thousands of clusters
        read = np.flatnonzero(ok)
        offset = local.offsets(centre[read])
        bottom[read] -= offset
        top[read] -= offset
    ok &= (bottom <= config.max_bottom) & (top >= config.min_top) & (top <= config.max_top)
    # The footprint rectangle's diagonal bounds the x-y extent: clusters too long for any rectangle go now.
    fits = np.maximum(extent[:, 0], extent[:, 1]) <= np.hypot(config.max_length, config.max_width)
    candidates = np.flatnonzero(ok if fit_all else ok & fits)
    if len(candidates) == 0:
        empty = np.zeros(0, dtype=bool)
        return Gated(lo[:, 2], hi[:, 2], candidates, np.zeros((0, 5)), empty, empty, count, may_part)
    rects = _cluster_rects(points, label, candidates)
    footprint = (rects[:, 2] <= config.max_length) & (rects[:, 3] <= config.max_width) & fits[candidates]
    keep = footprint & (np.maximum(rects[:, 2], extent[candidates, 2]) >= config.min_extent)
    return Gated(lo[:, 2], hi[:, 2], candidates, rects, keep, footprint, count, may_part)


def boxes_of(rects: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray) -> list[Box3D]:
    """Box3D per rectangle row (cx, cy, length, width, yaw) over its z range."""
    return [
        Box3D(center=np.array([cx, cy, 0.5 * (z0 + z1)]), size=np.array([length, width, z1 - z0]), yaw=float(yaw))
        for (cx, cy, length, width, yaw), z0, z1 in zip(rects, z_lo, z_hi, strict=True)
    ]


def select_proposals(
    points: np.ndarray,
    label: np.ndarray,
    n_clusters: int,
    planes: np.ndarray | LocalGround,
    segment_edges: np.ndarray,
    config: Stage1Config,
    gate: RangeGate | None = None,
) -> tuple[list[Box3D], np.ndarray]:
    """Boxes of the clusters that pass the config's gates (th_num_*, max_*, min_*; `gate`: the few-points gate's
    factor per range), and those clusters' ids (index = proposal id)."""
    if n_clusters == 0:
        return [], np.zeros(0, dtype=np.int64)
    z_lo, z_hi, candidates, rects, keep, _, _, _ = gate_clusters(points, label, n_clusters, planes, segment_edges,
                                                                 config, gate=gate)
    kept = candidates[keep]
    return boxes_of(rects[keep], z_lo[kept], z_hi[kept]), kept


@nb.njit(cache=True, nogil=True)
def _membership(pts: np.ndarray, label: np.ndarray, own_of: np.ndarray, boxes: np.ndarray, margin: np.ndarray,
                cell: float, floors: np.ndarray, gives_way: np.ndarray) -> tuple:
    """Primary and secondary proposal of every point inside an enlarged box (see `enlarged_membership`);
    `own_of` maps a cluster id to its proposal id or -1; a box reaches down to z = floors[b] where that is lower
    than its enlarged bottom; a box flagged in `gives_way` keeps no point that an unflagged one takes."""
    n = pts.shape[0]
    k = boxes.shape[0]
    primary = np.empty(n, dtype=np.int32)
    secondary = np.full(n, -1, dtype=np.int32)
    if k == 0:
        for i in range(n):
            primary[i] = own_of[label[i]] if label[i] >= 0 else -1
        return primary, secondary
    half = np.empty((k, 3))
    cos_y = np.cos(boxes[:, 6])
    sin_y = np.sin(boxes[:, 6])
    box_lo = np.empty((k, 2))
    box_hi = np.empty((k, 2))
    for b in range(k):
        for a in range(3):
            half[b, a] = 0.5 * boxes[b, 3 + a] + margin[a]
        ex = abs(cos_y[b]) * half[b, 0] + abs(sin_y[b]) * half[b, 1]
        ey = abs(sin_y[b]) * half[b, 0] + abs(cos_y[b]) * half[b, 1]
        box_lo[b, 0] = boxes[b, 0] - ex
        box_hi[b, 0] = boxes[b, 0] + ex
        box_lo[b, 1] = boxes[b, 1] - ey
        box_hi[b, 1] = boxes[b, 1] + ey
    gx0 = box_lo[:, 0].min()
    gy0 = box_lo[:, 1].min()
    nx = int((box_hi[:, 0].max() - gx0) / cell) + 1
    ny = int((box_hi[:, 1].max() - gy0) / cell) + 1
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for rep in range(2):
        if rep == 1:
            for c in range(nx * ny):
                start[c + 1] += start[c]
            fill = start[:-1].copy()
            ids = np.empty(start[nx * ny], dtype=np.int64)
        for b in range(k):
            for ix in range(int((box_lo[b, 0] - gx0) / cell), int((box_hi[b, 0] - gx0) / cell) + 1):
                for iy in range(int((box_lo[b, 1] - gy0) / cell), int((box_hi[b, 1] - gy0) / cell) + 1):
                    c = ix * ny + iy
                    if rep == 0:
                        start[c + 1] += 1
                    else:
                        ids[fill[c]] = b
                        fill[c] += 1
    inv = 1.0 / cell
    occupied = np.zeros(nx * ny + 1, dtype=np.bool_)  # the extra last cell stands for "outside the grid"
    for c in range(nx * ny):
        occupied[c] = start[c + 1] > start[c]
    cells = np.empty(n, dtype=np.int64)
    for i in range(n):  # branch-free, so it vectorises
        fx = (pts[i, 0] - gx0) * inv
        fy = (pts[i, 1] - gy0) * inv
        inside = (fx >= 0.0) & (fy >= 0.0) & (fx < nx) & (fy < ny)
        cells[i] = np.int64(min(max(fx, 0.0), nx - 1)) * ny + np.int64(min(max(fy, 0.0), ny - 1)) if inside else nx * ny
    for i in range(n):  # one pass: the point's own proposal, the boxes it falls in, then who gives way
        primary[i] = own_of[label[i]] if label[i] >= 0 else -1
        c = cells[i]
        if not occupied[c]:
            continue
        x = pts[i, 0]
        y = pts[i, 1]
        for t in range(start[c], start[c + 1]):
            b = ids[t]
            if b == primary[i] or b == secondary[i]:
                continue
            dx = x - boxes[b, 0]
            dy = y - boxes[b, 1]
            if abs(dx * cos_y[b] + dy * sin_y[b]) > half[b, 0] or abs(dy * cos_y[b] - dx * sin_y[b]) > half[b, 1]:
                continue
            z = pts[i, 2]
            if abs(z - boxes[b, 2]) > half[b, 2] and not (floors[b] <= z <= boxes[b, 2]):
                continue
            if primary[i] < 0:
                primary[i] = b
            elif secondary[i] < 0 or (not gives_way[b] and gives_way[secondary[i]]):
                secondary[i] = b
            elif not gives_way[b] and gives_way[primary[i]]:
                primary[i] = secondary[i]
                secondary[i] = b
        # a flagged proposal beside an unflagged one leaves the point to it
        if primary[i] >= 0 and secondary[i] >= 0 and gives_way[primary[i]] != gives_way[secondary[i]]:
            if gives_way[primary[i]]:
                primary[i] = secondary[i]
            secondary[i] = -1
    return primary, secondary


def boxes_array(boxes: list[Box3D]) -> np.ndarray:
    """K x 7 float64 rows (cx, cy, cz, length, width, height, yaw)."""
    if not boxes:
        return np.zeros((0, 7))
    return np.array([[*b.center, *b.size, b.yaw] for b in boxes], dtype=np.float64)


def enlarged_membership(
    points: np.ndarray,
    label: np.ndarray,
    kept: np.ndarray,
    boxes: list[Box3D],
    margin: tuple[float, float, float],
    cell: float = 2.0,
    floors: np.ndarray | None = None,
    gives_way: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(cluster_id, cluster_id2) per point: its own kept cluster's proposal first, then the enlarged boxes it
    falls in (lowest id first); -1 where there is none. `margin` (Stage1Config.enlarge) is added on each side, as
    in Box3D.contains. `floors` (one z per box, or None): a box also takes in the points of its enlarged footprint
    from that z up to its centre, when it lies below the enlarged bottom (`ground_floors`: the ground band under
    it). `gives_way` (one bool per box, or None): a flagged proposal (a part of `rerun_dropped`) holds no point
    that an unflagged one holds, its own cluster's points included, so the proposals without the flag keep exactly
    the points they would hold without the flagged ones, and stage 2's label of a flagged part never overwrites
    theirs (an enlarged part box beside a car took in the car's edge)."""
    label = np.ascontiguousarray(label, dtype=np.int32)
    own_of = np.full(max(int(label.max()) + 1, 1) if len(label) else 1, -1, dtype=np.int32)
    own_of[kept] = np.arange(len(kept), dtype=np.int32)
    floors = np.full(len(boxes), np.inf) if floors is None else np.ascontiguousarray(floors, dtype=np.float64)
    if len(floors) != len(boxes):
        raise ValueError(f"{len(floors)} floors for {len(boxes)} boxes")
    gives_way = np.zeros(len(boxes), dtype=np.bool_) if gives_way is None else np.asarray(gives_way, dtype=np.bool_)
    if len(gives_way) != len(boxes):
        raise ValueError(f"{len(gives_way)} gives_way flags for {len(boxes)} boxes")
    return _membership(points, label, own_of, boxes_array(boxes), np.asarray(margin, dtype=np.float64), float(cell),
                       floors, gives_way)


def ground_floors(boxes: list[Box3D], local: LocalGround, band: float) -> np.ndarray:
    """Per box, the bottom of the ground band under its centre: the local ground's z there less `band`
    (Stage1Config.th_dist, the ground test's half-width), for `enlarged_membership`'s `floors`."""
    if not boxes:
        return np.zeros(0)
    return local.heights(np.array([b.center[:2] for b in boxes], dtype=np.float64)) - band


def warm_up() -> None:
    """Compile the refinement kernels on a tiny cluster."""
    pts = np.zeros((8, 4), dtype=np.float32)
    pts[:, 0] = [5.0, 6.0, 6.0, 5.0, 5.0, 6.0, 6.0, 5.0]
    pts[:, 1] = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0]
    pts[:, 2] = [-1.0, -1.0, -1.0, -1.0, 0.0, 0.0, 0.0, 0.0]
    label = np.zeros(8, dtype=np.int32)
    planes = np.array([[0.0, 0.0, 1.0, 1.73]])
    config = Stage1Config(th_num_floor=1, th_num_near=1.0)
    boxes, kept = select_proposals(pts, label, 1, planes, np.array([-80.0, 80.0]), config)
    enlarged_membership(pts, label, kept, boxes, config.enlarge)
    local = fit_ground(pts, config).local
    boxes, kept = select_proposals(pts, label, 1, local, local.segment_edges, config)
    enlarged_membership(pts, label, kept, boxes, config.enlarge, floors=ground_floors(boxes, local, config.th_dist))
