"""Scan-line-run clustering (Zermas et al., ICRA 2017) of the non-ground points of a scan; the thresholds are
Stage1Config's.

Within a ring, in azimuth order, consecutive points closer than `th_ring` form a run; a ring that closes on
itself (its last point near its first) joins its last run to its first. A run takes the label of the nearest
point of the previous ring when that point is closer than `th_prop`; when the previous ring has nothing that
close the search goes on to up to `n_prev_rings` rings back (holes left by dark or removed points). A run
touching several labels merges them (union-find, the smallest label wins); a run touching none starts a new
label. The nearest point is searched in an azimuth window of the neighbouring ring: rings are sorted by a
pseudo-azimuth, a pointer into the previous ring advances with the current one (binary search for older
rings), and the search walks outwards until the angular lower bound on the distance passes the best found;
a point closer than th_ring / 2 ends it early (anything nearer would lie within th_ring of it, in its run).

Bridges (`run_skip`, not in the paper): two runs of a ring whose facing ends lie within th_ring of each other with at
most `run_skip` points of another run between them join. Those points are farther surfaces seen through a gap
(between a walker's arm and body, through a bike frame or a car window); without the bridge they cut the object's
run in pieces, and on a 16-laser scan, where a person at 20 m is 5-10 points on 2-3 rings, the pieces fall below
the point-count gate one by one (stage-1 recall with and without: docs/results.md).
"""

from __future__ import annotations

from concurrent.futures import Executor

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.config import Stage1Config

TWO_THREADS_MIN_POINTS = 8_000  # used points: below this a second thread's start costs more than it saves
LOWER_SHARE = 0.45  # of the used points searched on the calling thread: the lower rings' points cost more (KITTI)


@nb.njit(cache=True, nogil=True, inline="always")
def pseudo_azimuth(x: float, y: float) -> float:
    """A cheap angle in [0, 4) that orders like atan2(y, x) mapped to [0, 2 pi)."""
    s = abs(x) + abs(y)
    if s == 0.0:
        return 0.0
    p = y / s
    if x < 0.0:
        return 2.0 - p
    if y < 0.0:
        return 4.0 + p
    return p


@nb.njit(cache=True, nogil=True, inline="always")
def pseudo_azimuth_unordered(x: float, y: float) -> float:
    """`pseudo_azimuth`'s value (0 for the origin, which it may give as -0), without a branch on the quadrant: for
    points in no scan order, whose quadrants the CPU cannot predict (115k shuffled points: 1.0 -> 0.4 ms; in scan
    order, where those branches are predicted, 0.3 -> 0.45 ms)."""
    s = abs(x) + abs(y)
    p = y / (s if s > 0.0 else np.float32(1.0))
    lower = 4.0 + p if y < 0.0 else p
    return 2.0 - p if x < 0.0 else lower


@nb.njit(cache=True, nogil=True)
def _sort_ring(keys: np.ndarray, idx: np.ndarray) -> None:
    """Sort one ring's (key, index) pairs by key in place: rotate at the wrap, then insertion-sort the jitter."""
    m = keys.shape[0]
    if m < 2:
        return
    ordered = True  # most rings come in azimuth order (KITTI's firing order): one pass, no search for the wrap
    for j in range(1, m):
        if keys[j] < keys[j - 1]:
            ordered = False
            break
    if ordered:
        return
    cut = 0
    biggest = 2.0
    for j in range(1, m):
        drop = keys[j - 1] - keys[j]
        if drop > biggest:
            biggest = drop
            cut = j
    if cut > 0:
        keys[:] = np.concatenate((keys[cut:], keys[:cut]))
        idx[:] = np.concatenate((idx[cut:], idx[:cut]))
    if not _insertion_sort(keys, idx, 16 * m):
        order = np.argsort(keys, kind="mergesort")
        keys[:] = keys[order]
        idx[:] = idx[order]


@nb.njit(cache=True, nogil=True)
def _insertion_sort(keys: np.ndarray, idx: np.ndarray, budget: int) -> bool:
    """Insertion-sort (key, index) pairs by key in place (stable, fast when nearly sorted); False, with the pairs
    partly sorted, as soon as it has moved more than `budget` pairs (the caller then sorts another way)."""
    moves = 0
    for j in range(1, keys.shape[0]):
        k = keys[j]
        v = idx[j]
        i = j - 1
        while i >= 0 and keys[i] > k:
            keys[i + 1] = keys[i]
            idx[i + 1] = idx[i]
            i -= 1
            moves += 1
        keys[i + 1] = k
        idx[i + 1] = v
        if moves > budget:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def _find(parent: np.ndarray, a: int) -> int:
    """Root of a's set, compressing the path on the way."""
    root = a
    while parent[root] != root:
        root = parent[root]
    while parent[a] != root:
        nxt = parent[a]
        parent[a] = root
        a = nxt
    return root


@nb.njit(cache=True, nogil=True)
def _union(parent: np.ndarray, a: int, b: int) -> int:
    """Join the sets of a and b; the smaller root wins and is returned."""
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra == rb:
        return ra
    if ra < rb:
        parent[rb] = ra
        return ra
    parent[ra] = rb
    return rb


@nb.njit(cache=True, nogil=True, inline="always")
def _gap2(q: np.ndarray, a: int, b: int) -> float:
    """Squared distance between sorted positions a and b (rows of `q`: x, y, z, x^2 + y^2)."""
    dx = q[a, 0] - q[b, 0]
    dy = q[a, 1] - q[b, 1]
    dz = q[a, 2] - q[b, 2]
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True, inline="always")
def _lower_bound(keys: np.ndarray, lo: int, hi: int, key: float) -> int:
    """First position in keys[lo:hi] (ascending) whose key is >= `key`, hi if none."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@nb.njit(cache=True, nogil=True, inline="always")
def _nearest_in_ring(q: np.ndarray, k: int, lo: int, hi: int,
                     start: int, best2: float, enough2: float) -> int:
    """Sorted position (lo..hi-1) nearest to position k if closer than sqrt(best2), else -1.

    `start` is the first position at or past k's azimuth. The search walks outwards in azimuth from there;
    a point at azimuth offset d from k is at least r_k sin(d) away (r_k for offsets past 90 degrees), so each
    direction stops when that bound reaches the best distance found. A point closer than sqrt(enough2) ends
    the search at once (with enough2 = (th_ring / 2)^2 anything nearer is within th_ring of it, in its run).
    """
    m = hi - lo
    if m == 0:
        return -1
    px = q[k, 0]
    py = q[k, 1]
    rp2 = q[k, 3]
    found = -1
    for direction in (1, -1):
        j = start if direction == 1 else start - 1
        for _ in range(m):
            if j >= hi:
                j = lo
            elif j < lo:
                j = hi - 1
            qx = q[j, 0]
            qy = q[j, 1]
            if px * qx + py * qy > 0.0:
                cross = px * qy - py * qx
                if cross * cross >= best2 * q[j, 3]:
                    break
            elif rp2 >= best2:
                break
            d2 = _gap2(q, k, j)
            if d2 < best2:
                best2 = d2
                found = j
                if d2 < enough2:
                    return found
            j += direction
    return found


@nb.njit(cache=True, nogil=True)
def _prepare(pts: np.ndarray, ring: np.ndarray, use: np.ndarray, n_rings: int, th_ring: float) -> tuple:
    """The used points sorted ring by ring by pseudo-azimuth: their indices, keys, the rings' starts, their
    coordinates (rows x, y, z, x^2 + y^2: a visit of the nearest-point walk reads one cache line) and whether each
    lies within th_ring of the one before (its own pass, which vectorises: the run walk reads a flag)."""
    n = pts.shape[0]
    start = np.zeros(n_rings + 1, dtype=np.int64)
    for i in range(n):
        if use[i]:
            start[ring[i] + 1] += 1
    for r in range(n_rings):
        start[r + 1] += start[r]
    m = start[n_rings]
    idx = np.empty(m, dtype=np.int64)
    keys = np.empty(m, dtype=np.float64)
    fill = start[:n_rings].copy()
    for i in range(n):
        if use[i]:
            r = ring[i]
            idx[fill[r]] = i
            keys[fill[r]] = pseudo_azimuth(pts[i, 0], pts[i, 1])
            fill[r] += 1
    for r in range(n_rings):
        _sort_ring(keys[start[r]:start[r + 1]], idx[start[r]:start[r + 1]])
    q = np.empty((m, 4), dtype=np.float64)
    for k in range(m):
        i = idx[k]
        x = np.float64(pts[i, 0])
        y = np.float64(pts[i, 1])
        q[k, 0] = x
        q[k, 1] = y
        q[k, 2] = pts[i, 2]
        q[k, 3] = x * x + y * y
    th_ring2 = th_ring * th_ring
    joins = np.empty(m, dtype=np.bool_)
    for k in range(1, m):
        joins[k] = _gap2(q, k - 1, k) < th_ring2
    return idx, keys, start, q, joins


@nb.njit(cache=True, nogil=True)
def _search_rings(q: np.ndarray, keys: np.ndarray, start: np.ndarray, r0: int, r1: int, near: np.ndarray,
                  th_ring: float, th_prop: float, n_prev_rings: int) -> None:
    """For each position of rings r0 .. r1 - 1, the position whose run it takes (the nearest within th_prop in the
    previous ring, or failing that up to `n_prev_rings` rings back; -1 for none), written to `near`. It reads
    positions alone, never labels, so two calls on disjoint ring ranges may run side by side."""
    th_prop2 = th_prop * th_prop
    enough2 = 0.25 * th_ring * th_ring
    for r in range(r0, r1):
        lo = start[r]
        hi = start[r + 1]
        ptr = start[r - 1] if r > 0 else 0
        for k in range(lo, hi):
            near[k] = -1
            if r > 0:
                while ptr < lo and keys[ptr] < keys[k]:
                    ptr += 1
            for back in range(1, n_prev_rings + 1):
                pr = r - back
                if pr < 0:
                    break
                at = ptr if back == 1 else _lower_bound(keys, start[pr], start[pr + 1], keys[k])
                found = _nearest_in_ring(q, k, start[pr], start[pr + 1], at, th_prop2, enough2)
                if found >= 0:
                    near[k] = found
                    break


@nb.njit(cache=True, nogil=True)
def _join_runs(idx: np.ndarray, n: int, q: np.ndarray, start: np.ndarray, joins: np.ndarray, near: np.ndarray,
               th_ring: float, run_skip: int) -> tuple:
    """Runs, their unions with the runs `near` names, bridges and closed rings, ring by ring in order (the module
    docstring's steps after the nearest-point search); labels (compact 0..C-1, -1 where unused) and C."""
    m = idx.shape[0]
    n_rings = start.shape[0] - 1
    run_of = np.empty(m, dtype=np.int64)  # run label per sorted position
    parent = np.empty(m, dtype=np.int64)
    n_runs = 0
    th_ring2 = th_ring * th_ring
    for r in range(n_rings):
        lo = start[r]
        hi = start[r + 1]
        j = lo
        first_run = n_runs
        while j < hi:
            run_lo = j
            j += 1
            while j < hi and joins[j]:
                j += 1
            label = n_runs
            parent[label] = label
            n_runs += 1
            joined = -1
            for k in range(run_lo, j):
                if near[k] >= 0 and run_of[near[k]] != joined:  # a run's points mostly meet one run above
                    joined = run_of[near[k]]
                    label = _union(parent, label, joined)
            for k in range(run_lo, j):
                run_of[k] = label
        if run_skip > 0 and n_runs - first_run > 2:
            _bridge_runs(q, run_of, parent, lo, hi, run_skip, th_ring2)
        if n_runs - first_run > 1 and _gap2(q, lo, hi - 1) < th_ring2:
            _union(parent, run_of[lo], run_of[hi - 1])
    labels = np.full(n, -1, dtype=np.int32)
    compact = np.full(n_runs, -1, dtype=np.int64)
    root_of = np.empty(n_runs, dtype=np.int64)  # each run's root found once, not once per point
    for run in range(n_runs):
        root_of[run] = _find(parent, run)
    n_clusters = 0
    for k in range(m):
        root = root_of[run_of[k]]
        if compact[root] < 0:
            compact[root] = n_clusters
            n_clusters += 1
        labels[idx[k]] = compact[root]
    return labels, n_clusters


@nb.njit(cache=True, nogil=True)
def _bridge_runs(q: np.ndarray, run_of: np.ndarray, parent: np.ndarray, lo: int,
                 hi: int, run_skip: int, th_ring2: float) -> None:
    """Join the runs of one ring (sorted positions lo..hi-1, read as a circle: the ring's start lies straight
    ahead on KITTI) whose facing ends are within th_ring with at most `run_skip` points of other runs between them
    (the module docstring's bridges)."""
    m = hi - lo
    for k in range(lo, hi):
        end = k - 1 if k > lo else hi - 1  # the last point of the run before k
        if run_of[k] == run_of[end]:
            continue
        for step in range(1, run_skip + 1):  # skips the points k .. ahead - 1
            ahead = lo + (k - lo + step) % m
            if ahead == end:
                break
            if _gap2(q, end, ahead) < th_ring2:
                _union(parent, run_of[end], run_of[ahead])
                break


@nb.njit(cache=True, nogil=True)
def group_starts(group: np.ndarray, n_groups: int) -> np.ndarray:
    """Where each group starts (n_groups + 1 offsets, the last = len(group)) in a counting sort of `group`, whose
    values are 0 .. n_groups - 1."""
    start = np.zeros(n_groups + 1, dtype=np.int64)
    for i in range(group.shape[0]):
        start[group[i] + 1] += 1
    for g in range(n_groups):
        start[g + 1] += start[g]
    return start


@nb.njit(cache=True, nogil=True)
def nearer_of_two(levels: np.ndarray, value: float) -> int:
    """Index of the nearer of the two `levels` (ascending, at least 2) around numpy's searchsorted (left) position of
    `value`; the lower one on a tie."""
    pos = min(max(_lower_bound(levels, 0, levels.shape[0], value), 1), levels.shape[0] - 1)
    return pos - 1 if abs(value - levels[pos - 1]) <= abs(levels[pos] - value) else pos


@nb.njit(cache=True, nogil=True)
def _canonical_kernel(pts: np.ndarray, ring: np.ndarray, n_rings: int) -> tuple:
    """Permutation listing the points ring by ring, each ring by pseudo-azimuth (a counting sort on the ring, then
    a bucket sort of each ring that is not already in order), and the rings in that order (written ring by ring
    here instead of gathered)."""
    n = pts.shape[0]
    start = group_starts(ring, n_rings)
    idx = np.empty(n, dtype=np.int64)
    keys = np.empty(n, dtype=np.float64)
    fill = start[:n_rings].copy()
    for i in range(n):
        r = ring[i]
        idx[fill[r]] = i
        keys[fill[r]] = pseudo_azimuth_unordered(pts[i, 0], pts[i, 1])
        fill[r] += 1
    work_ring = np.empty_like(ring)
    for r in range(n_rings):
        lo = start[r]
        hi = start[r + 1]
        ordered = True
        for j in range(lo + 1, hi):
            if keys[j] < keys[j - 1]:
                ordered = False
                break
        if not ordered:
            _bucket_sort(keys[lo:hi], idx[lo:hi])
        work_ring[lo:hi] = r
    return idx, work_ring


@nb.njit(cache=True, nogil=True)
def _bucket_sort(keys: np.ndarray, idx: np.ndarray) -> None:
    """Stable sort of (key, index) pairs by key in [0, 4) in place: a counting sort into as many buckets as pairs,
    then an insertion sort of what is left out of order (a few pairs share a bucket)."""
    m = keys.shape[0]
    count = np.zeros(m + 1, dtype=np.int64)
    bucket = np.empty(m, dtype=np.int64)
    scale = m / 4.0
    for j in range(m):
        b = min(max(int(keys[j] * scale), 0), m - 1)
        bucket[j] = b
        count[b + 1] += 1
    for b in range(m):
        count[b + 1] += count[b]
    sorted_keys = np.empty(m, dtype=np.float64)
    sorted_idx = np.empty(m, dtype=np.int64)
    for j in range(m):
        at = count[bucket[j]]
        sorted_keys[at] = keys[j]
        sorted_idx[at] = idx[j]
        count[bucket[j]] = at + 1
    _insertion_sort(sorted_keys, sorted_idx, m * m)  # at most m(m-1)/2 moves: never over budget
    keys[:] = sorted_keys
    idx[:] = sorted_idx


def canonical_order(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The scan's canonical point order ((N,) int64 permutation): by ring, then by azimuth counter-clockwise from
    the +x axis (ties keep their input order). Clustering sorts each ring the same way, so a scan in this order
    clusters like the same scan in firing order."""
    return in_canonical_order(points, ring)[0]


def in_canonical_order(points: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`canonical_order`, with the points (float32, N x C) and their rings (uint16) put in that order."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    ring = np.ascontiguousarray(ring, dtype=np.uint16)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64), pts.copy(), ring.copy()
    order, work_ring = _canonical_kernel(pts, ring, int(ring.max()) + 1)
    return order, np.take(pts, order, axis=0), work_ring  # take: a tenth of pts[order]'s time on rows


def cluster_scanlines(
    points: np.ndarray, ring: np.ndarray, use: np.ndarray, config: Stage1Config, pool: Executor | None = None
) -> tuple[np.ndarray, int]:
    """Cluster id per point ((N,) int32, -1 where `use` is False) and the cluster count, with `th_ring`, `th_prop`,
    `n_prev_rings` and `run_skip` from `config`; see the module docstring. With `pool` (an executor whose thread
    is free), a scan of TWO_THREADS_MIN_POINTS used points or more has its nearest-point search (most of the time)
    split between two threads, the upper rings on the pool's; runs are joined on one thread in ring order, so the
    labels are the same."""
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if len(pts) == 0 or not np.any(use):
        return np.full(len(pts), -1, dtype=np.int32), 0
    ring = np.ascontiguousarray(ring, dtype=np.uint16)
    n_rings = int(ring.max()) + 1
    th_ring, th_prop = float(config.th_ring), float(config.th_prop)
    idx, keys, start, q, joins = _prepare(pts, ring, np.ascontiguousarray(use, dtype=np.bool_), n_rings, th_ring)
    m = len(idx)
    near = np.empty(m, dtype=np.int64)
    search = (q, keys, start)
    split = n_rings  # the rings from `split` on are searched on the pool's thread
    if pool is not None and m >= TWO_THREADS_MIN_POINTS and n_rings >= 2:
        split = int(np.clip(np.searchsorted(start, round(LOWER_SHARE * m)), 1, n_rings - 1))
    upper = None
    if split < n_rings:
        upper = pool.submit(_search_rings, *search, split, n_rings, near, th_ring, th_prop, int(config.n_prev_rings))
    _search_rings(*search, 0, split, near, th_ring, th_prop, int(config.n_prev_rings))
    if upper is not None:
        upper.result()
    return _join_runs(idx, len(pts), q, start, joins, near, th_ring, int(config.run_skip))


def warm_up() -> None:
    """Compile the clustering kernels on a tiny two-ring scan."""
    az = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    pts = np.zeros((64, 4), dtype=np.float32)
    pts[:, 0] = np.tile(5.0 * np.cos(az), 2)
    pts[:, 1] = np.tile(5.0 * np.sin(az), 2)
    pts[32:, 2] = -0.1
    ring = np.repeat(np.arange(2), 32).astype(np.uint16)
    cluster_scanlines(pts, ring, np.ones(64, dtype=bool), Stage1Config())
    canonical_order(pts[::-1], ring)
