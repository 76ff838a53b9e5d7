"""Numba kernels of PointNet++'s sampling, grouping and interpolation for CPU inference: one call per step
instead of many small torch kernels, and no (B, N, N) distance matrix.

Distances: `pointnet2.lift_points` gives rows l = (a, |a|^2, 1) and r = (-2b, 1, |b|^2) whose dot product is
|a - b|^2; `pairwise_sq_dist` takes them through torch.bmm, which on an FMA CPU (MKL) sums the 5 products as a
chain of fused multiply-adds (for matrices of 400 products or more; stage 2's are far larger). `_sq_dist` does
the same chain with explicit FMAs, so the kernels see the same float32 distances, bit for bit, and make the
same choices as the torch code of `pointnet2`: the same FPS centres, ball members and 3 nearest neighbours,
ties to the lower index (test_pointnet2_cpu checks this). Sums of features may round differently (float noise).
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.stage2.fma import fma32

_ZERO = np.float32(0.0)
_ONE = np.float32(1.0)
_MINUS_TWO = np.float32(-2.0)
_EPS = np.float32(1e-8)  # three_nn's inverse-distance guard, a float32 as in the torch code
_FMA = {"contract"}  # feature sums: fused multiply-adds allowed, nothing else (no reassociation, NaN / inf kept)


@nb.njit(cache=True, nogil=True)
def lift_points(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`pointnet2.lift_points` channels first: (a, |a|^2, 1) as (B, 5, P) and (-2b, 1, |b|^2) as (B', 5, Q), for
    a (B, P, 3) and b (B', Q, 3); |a|^2 summed in torch's order, no fused multiply-add (bit-identical rows)."""
    left = np.empty((a.shape[0], 5, a.shape[1]), dtype=np.float32)
    right = np.empty((b.shape[0], 5, b.shape[1]), dtype=np.float32)
    for i in range(a.shape[0]):
        for p in range(a.shape[1]):
            x, y, z = a[i, p, 0], a[i, p, 1], a[i, p, 2]
            left[i, 0, p], left[i, 1, p], left[i, 2, p] = x, y, z
            left[i, 3, p] = (x * x + y * y) + z * z
            left[i, 4, p] = _ONE
    for i in range(b.shape[0]):
        for q in range(b.shape[1]):
            x, y, z = b[i, q, 0], b[i, q, 1], b[i, q, 2]
            right[i, 0, q], right[i, 1, q], right[i, 2, q] = _MINUS_TWO * x, _MINUS_TWO * y, _MINUS_TWO * z
            right[i, 3, q] = _ONE
            right[i, 4, q] = (x * x + y * y) + z * z
    return left, right


@nb.njit(cache=True, nogil=True)
def _sq_dist(left: np.ndarray, i: int, p: int, right: np.ndarray, k: int, q: int) -> np.float32:
    """left[i, :, p] . right[k, :, q] (5 values each, channels first) as the multiply-add chain of MKL's
    sgemm, unclamped."""
    acc = left[i, 0, p] * right[k, 0, q]
    for m in range(1, 5):
        acc = fma32(left[i, m, p], right[k, m, q], acc)
    return acc


@nb.njit(cache=True, nogil=True)
def farthest_point_sample(left: np.ndarray, right: np.ndarray, count: int, start: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Farthest point sampling of B point sets from point start[b], from their lifted rows left, right (B, 5, N),
    channels first: centre indices (B, count) and the centres' squared distances to every point (B, count, N),
    unclamped. Ties go to the lowest index, as torch's argmax gives them."""
    b, n = left.shape[0], left.shape[2]
    idx = np.zeros((b, count), dtype=np.int64)
    d2 = np.empty((b, count, n), dtype=np.float32)
    dist = np.empty(n, dtype=np.float32)
    for i in range(b):
        dist[:] = np.inf
        last = start[i]
        for k in range(count):
            idx[i, k] = last
            for j in range(n):
                d2[i, k, j] = _sq_dist(left, i, last, right, i, j)
            if k + 1 == count:
                break
            # One pass: lower each point's distance to the centres by the newest one's, find the farthest.
            best = -np.inf
            for j in range(n):
                v = min(dist[j], max(d2[i, k, j], _ZERO))
                dist[j] = v
                if v > best:
                    best = v
                    last = j
    return idx, d2


@nb.njit(cache=True, nogil=True)
def ball_query(d2: np.ndarray, r2: np.float32, nsample: int) -> np.ndarray:
    """(B, S, nsample): per row of d2 (B, S, N), the first nsample columns with d2 <= r2 (clamped or not: the
    same) in index order, padded with the first one found (with N where none is)."""
    b, s, n = d2.shape
    out = np.empty((b, s, nsample), dtype=np.int64)
    found = np.empty(nsample + 1, dtype=np.int64)
    for i in range(b):
        for c in range(s):
            k = 0
            for j in range(n):
                # Branch-free append (whether a point is inside is unpredictable): write, then advance or not.
                found[k] = j
                k += d2[i, c, j] <= r2
                if k == nsample:
                    break
            pad = found[0] if k > 0 else n
            for m in range(nsample):
                out[i, c, m] = found[m] if m < k else pad
    return out


@nb.njit(cache=True, nogil=True)
def _kth_smallest(a: np.ndarray, m: int, k: int) -> np.float32:
    """The k-th smallest (0-based) of a[:m], by Hoare selection in place (a[:m] is reordered)."""
    lo, hi = 0, m - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return a[k]
    return a[k]


@nb.njit(cache=True, nogil=True)
def ball_query_nearest(d2: np.ndarray, r2: np.float32, nsample: int) -> np.ndarray:
    """(B, S, nsample): per row of d2 (B, S, N), the nsample columns with d2 <= r2 nearest (d2 clamped at 0, ties
    to the lower index), listed in index order as `pointnet2.ball_query(nearest=True)` lists them, padded with the
    first (with N where none is). A ball holding at most nsample points takes them all in one pass; a fuller one
    finds the nsample-th distance by selection, not a sort."""
    b, s, n = d2.shape
    out = np.empty((b, s, nsample), dtype=np.int64)
    near = np.empty(n, dtype=np.float32)
    work = np.empty(n, dtype=np.float32)
    index = np.empty(n, dtype=np.int64)
    for i in range(b):
        for c in range(s):
            m = 0
            for j in range(n):
                v = d2[i, c, j]
                if v <= r2:
                    near[m], index[m] = max(v, _ZERO), j
                    m += 1
            k = 0
            if m <= nsample:
                for q in range(m):
                    out[i, c, q] = index[q]
                k = m
            else:
                work[:m] = near[:m]
                cut = _kth_smallest(work, m, nsample - 1)
                ties = nsample
                for q in range(m):
                    if near[q] < cut:
                        ties -= 1
                for q in range(m):
                    v = near[q]
                    if v < cut:
                        out[i, c, k] = index[q]
                        k += 1
                    elif v == cut and ties > 0:
                        ties -= 1
                        out[i, c, k] = index[q]
                        k += 1
            pad = out[i, c, 0] if k > 0 else n
            for q in range(k, nsample):
                out[i, c, q] = pad
    return out


@nb.njit(cache=True, nogil=True)
def group_relative(values: np.ndarray, idx: np.ndarray, centres: np.ndarray, relu: bool) -> np.ndarray:
    """(B, S, K, C) = values[b, idx[b, s, k]] - centres[b, s] (then ReLU if `relu`); values (B, N, C),
    idx (B, S, K), centres (B, S, C)."""
    b, s, k = idx.shape
    c = values.shape[2]
    out = np.empty((b, s, k, c), dtype=values.dtype)
    for i in range(b):
        for j in range(s):
            for m in range(k):
                src = idx[i, j, m]
                for ch in range(c):
                    v = values[i, src, ch] - centres[i, j, ch]
                    out[i, j, m, ch] = max(v, _ZERO) if relu else v
    return out


class _Nearest(NamedTuple):
    """Work arrays for the 3 nearest sources of the Q queries of one block."""

    d2: np.ndarray  # (S, Q) float32: the block's squared distances, transposed, clamped at 0
    n0: np.ndarray  # (Q,) float32: nearest squared distance (inf: none), then the 2nd and 3rd nearest
    n1: np.ndarray
    n2: np.ndarray
    i0: np.ndarray  # (Q,) int32: their source indices
    i1: np.ndarray
    i2: np.ndarray


@nb.njit(cache=True, nogil=True)
def _nearest_work(q: int, s: int) -> _Nearest:
    """Work arrays for blocks of q queries and s sources."""
    dist = [np.empty(q, dtype=np.float32) for _ in range(3)]
    index = [np.empty(q, dtype=np.int32) for _ in range(3)]
    return _Nearest(np.empty((s, q), dtype=np.float32), dist[0], dist[1], dist[2], index[0], index[1], index[2])


@nb.njit(cache=True, nogil=True)
def _nearest3(left: np.ndarray, i: int, right: np.ndarray, k: int, work: _Nearest) -> None:
    """The 3 nearest sources right[k] (5, S) of each query left[i] (5, Q) into work, ascending, ties to the
    lower index (as torch's repeated argmin). Queries go in the inner loop, as vectorised selects: per query
    the order of the distances is random, so a scalar insertion would mispredict branches."""
    q, s = left.shape[2], right.shape[2]
    buf, n0, n1, n2, i0, i1, i2 = work
    for j in range(s):
        for p in range(q):
            buf[j, p] = max(_sq_dist(left, i, p, right, k, j), _ZERO)
    n0[:] = np.inf
    n1[:] = np.inf
    n2[:] = np.inf
    i0[:] = 0
    i1[:] = 0
    i2[:] = 0
    for j in range(s):
        for p in range(q):
            v = buf[j, p]
            a0, a1, a2 = n0[p], n1[p], n2[p]
            b0, b1, b2 = i0[p], i1[p], i2[p]
            c0, c1, c2 = v < a0, v < a1, v < a2
            n2[p] = a1 if c1 else (v if c2 else a2)
            i2[p] = b1 if c1 else (j if c2 else b2)
            n1[p] = a0 if c0 else (v if c1 else a1)
            i1[p] = b0 if c0 else (j if c1 else b1)
            n0[p] = v if c0 else a0
            i0[p] = j if c0 else b0


@nb.njit(cache=True, nogil=True, fastmath=_FMA)
def interpolate_project(
    left: np.ndarray, right: np.ndarray, source_batch: np.ndarray, source_feat: np.ndarray, skip: np.ndarray,
    skip_weight: np.ndarray, bias: np.ndarray, relu: bool,
) -> np.ndarray:
    """(B, Q, C): 3-NN inverse-distance interpolation of source_feat[source_batch[b]] (P, S, C) at the sources
    right[source_batch[b]] (P, 5, S) onto the queries left (B, 5, Q) (lifted rows, channels first), plus
    skip (B, Q, F) @ skip_weight (F, C) (with no skip_weight rows: skip is that product, (B, Q, C)), plus
    bias (C,); then ReLU if `relu`. Fewer than 3 sources: the missing ones weigh 0."""
    b, q = left.shape[0], left.shape[2]
    c = source_feat.shape[2]
    f = skip.shape[2]
    out = np.empty((b, q, c), dtype=np.float32)
    lin = np.empty(c, dtype=np.float32)
    work = _nearest_work(q, right.shape[2])
    for i in range(b):
        src = source_batch[i]
        _nearest3(left, i, right, src, work)
        for p in range(q):
            # Normalised inverse-distance weights, in float32 as the torch code computes them; a missing
            # neighbour is at inf: weight 0, index 0, it adds exactly 0.
            w0 = _ONE / (work.n0[p] + _EPS)
            w1 = _ONE / (work.n1[p] + _EPS)
            w2 = _ONE / (work.n2[p] + _EPS)
            total = (w0 + w1) + w2
            w0, w1, w2 = w0 / total, w1 / total, w2 / total
            i0, i1, i2 = work.i0[p], work.i1[p], work.i2[p]
            if skip_weight.shape[0] == 0:
                for ch in range(c):
                    lin[ch] = skip[i, p, ch]
            else:
                x = skip[i, p, 0]
                for ch in range(c):
                    lin[ch] = x * skip_weight[0, ch]
                for m in range(1, f):
                    x = skip[i, p, m]
                    for ch in range(c):
                        lin[ch] += x * skip_weight[m, ch]
            for ch in range(c):
                v = ((w0 * source_feat[src, i0, ch] + w1 * source_feat[src, i1, ch]) + w2 * source_feat[src, i2, ch]
                     + lin[ch]) + bias[ch]
                out[i, p, ch] = max(v, _ZERO) if relu else v
    return out


@nb.njit(cache=True, nogil=True, fastmath=_FMA)
def relu_linear_t(hidden_t: np.ndarray, hidden_bias: np.ndarray, weight: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """(K, R) = weight (K, C) @ relu(hidden_t + hidden_bias) + bias, for features hidden_t (C, R) stored channels
    first: a narrow Linear (K = 4 classes) with the previous layer's bias and ReLU in one pass over them."""
    c, r = hidden_t.shape
    k = weight.shape[0]
    out = np.zeros((k, r), dtype=np.float32)
    row = np.empty(r, dtype=np.float32)
    for ch in range(c):
        b = hidden_bias[ch]
        for p in range(r):
            row[p] = max(hidden_t[ch, p] + b, _ZERO)
        for m in range(k):
            w = weight[m, ch]
            for p in range(r):
                out[m, p] += w * row[p]
    for m in range(k):
        for p in range(r):
            out[m, p] += bias[m]
    return out


def warm_up() -> None:
    """Compile every kernel (from numba's on-disk cache after the first time) on tiny float32 inputs."""
    xyz = np.random.default_rng(0).random((1, 8, 3)).astype(np.float32)
    left, right = lift_points(xyz, xyz)
    _, d2 = farthest_point_sample(left, right, 4, np.zeros(1, dtype=np.int64))
    idx = ball_query(d2, np.float32(0.25), 4)
    ball_query_nearest(d2, np.float32(0.25), 4)
    feat = np.ones((1, 8, 2), dtype=np.float32)
    group_relative(feat, idx, np.ones((1, 4, 2), dtype=np.float32), True)
    weight, bias = np.ones((2, 2), dtype=np.float32), np.zeros(2, dtype=np.float32)
    interpolate_project(left, right, np.zeros(1, dtype=np.int64), feat, feat, weight, bias, True)
    relu_linear_t(np.ones((2, 3), dtype=np.float32), bias, weight, bias)
