"""Stage 2 canonical frame: per-proposal box from its member points, the 8 box views, N-point sampling.

The box of a proposal is fitted here, from the member points alone (minimal-area rectangle in x-y, z from
min to max), so the ROS node and the offline tools build exactly the same input for the network. Box fitting
and the canonical transform are numba kernels (a frame's ~30 proposals in about 1.5 ms on one core).

Views: a view puts the origin at one bottom vertex of the box with the axes along the box edges, the box in
the first octant. Views 0..3 are the four right-handed frames (origin at vertex 0..3: the 4 rotations),
views 4..7 are their mirror images (x and y swapped, left-handed). Training draws any of the 8; inference
uses the right-handed view at the vertex nearest the sensor and, for the shipped ("slot") weights,
`content_sample`: a proposal of more than N points gives the N points of smallest hash of their values (and a draw
index, 0 by default), the same points in any order; a smaller one is read whole in input order, as trained. The
count-seeded draw (`inference_sample`, `--sampling draw`, the former default) picks positions in the
members' list from a generator seeded by the point count, so its input depends on the points' order too.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba as nb
import numpy as np

from pass3d_ros.core.stage2.fma import fma64

NUM_VIEWS = 8
# Vertex k sits at (sx * L/2, sy * W/2) in the box frame; counter-clockwise order.
_VERTEX_SIGNS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
_COARSE_STEP = np.deg2rad(3.0)
_REFINE_STEPS = (np.deg2rad(0.25), np.deg2rad(0.02))


@dataclass
class Boxes:
    """Boxes of P proposals: x-y centre (P, 2), size (P, 3) = (length >= width, width, height), yaw (P,)
    of the length axis in (-pi/2, pi/2], bottom height zmin (P,)."""

    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    zmin: np.ndarray

    def __len__(self) -> int:
        return len(self.yaw)


def _direction_table(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate angles (A,) with the cosines and sines (2A,) of `angles` then `angles + pi/2`."""
    both = np.concatenate([angles, angles + np.pi / 2])
    return angles, np.cos(both), np.sin(both)


_COARSE = _direction_table(np.arange(0.0, np.pi / 2, _COARSE_STEP))
_REFINES = tuple(
    _direction_table(np.arange(-span, span + step / 2, step))
    for span, step in zip((_COARSE_STEP, *_REFINE_STEPS[:-1]), _REFINE_STEPS, strict=True)
)


@nb.njit(cache=True, nogil=True)
def _centre(xyz: np.ndarray, offsets: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """x-y coordinates (M, 2) float64 of group g's points xyz[offsets[g]:offsets[g+1]] minus mean[g]."""
    xy = np.empty((len(xyz), 2))
    for g in range(len(offsets) - 1):
        for i in range(offsets[g], offsets[g + 1]):
            xy[i, 0] = np.float64(xyz[i, 0]) - mean[g, 0]
            xy[i, 1] = np.float64(xyz[i, 1]) - mean[g, 1]
    return xy


@nb.njit(cache=True, nogil=True)
def _best_angles(
    xy: np.ndarray, offsets: np.ndarray, cb: np.ndarray, sb: np.ndarray, rotate: bool, dcos: np.ndarray,
    dsin: np.ndarray,
) -> np.ndarray:
    """Per group, the index of the candidate angle giving the smallest rectangle (the first on ties).

    Points are turned by the group's (cb, sb) first when `rotate`; candidate a's rectangle has the extents
    along directions a and a + A of (dcos, dsin) (2A,). A projection is fma(sin, y, cos * x), the rounding
    of the numpy matmul (OpenBLAS dgemm) this replaced, so near-equal areas compare as they did. The loop
    runs point-major: the per-direction min / max updates of one point vectorise.
    """
    num = len(offsets) - 1
    ndir = len(dcos)
    nang = ndir // 2
    lo = np.empty(ndir)
    hi = np.empty(ndir)
    out = np.zeros(num, dtype=np.int64)
    for g in range(num):
        lo[:] = np.inf
        hi[:] = -np.inf
        for i in range(offsets[g], offsets[g + 1]):
            x, y = xy[i, 0], xy[i, 1]
            if rotate:
                x, y = x * cb[g] + y * sb[g], y * cb[g] - x * sb[g]
            for d in range(ndir):
                p = fma64(dsin[d], y, dcos[d] * x)
                lo[d] = p if p < lo[d] else lo[d]
                hi[d] = p if p > hi[d] else hi[d]
        best_area = (hi[0] - lo[0]) * (hi[nang] - lo[nang])
        for a in range(1, nang):
            area = (hi[a] - lo[a]) * (hi[a + nang] - lo[a + nang])
            if area < best_area:
                best_area = area
                out[g] = a
    return out


@nb.njit(cache=True, nogil=True)
def _extents(xy: np.ndarray, xyz: np.ndarray, offsets: np.ndarray, cb: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """Per group, (min, max) of u, v (the x-y coordinates xy turned by (cb, sb)) and of z = xyz[:, 2]: (P, 6)."""
    num = len(offsets) - 1
    out = np.empty((num, 6))
    for g in range(num):
        lo_u, hi_u, lo_v, hi_v, lo_z, hi_z = np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf
        for i in range(offsets[g], offsets[g + 1]):
            x, y = xy[i, 0], xy[i, 1]
            u, v, h = x * cb[g] + y * sb[g], y * cb[g] - x * sb[g], np.float64(xyz[i, 2])
            lo_u, hi_u = min(lo_u, u), max(hi_u, u)
            lo_v, hi_v = min(lo_v, v), max(hi_v, v)
            lo_z, hi_z = min(lo_z, h), max(hi_z, h)
        out[g] = (lo_u, hi_u, lo_v, hi_v, lo_z, hi_z)
    return out


def fit_boxes(xyz: np.ndarray, offsets: np.ndarray) -> Boxes:
    """Minimal-area oriented boxes of P point groups: group p is xyz[offsets[p]:offsets[p+1]] (non-empty).

    A coarse search over [0, 90) degrees, then two finer searches around the best angle so far (to about
    0.02 degrees), in numba kernels that go through each group's points once per search: O(P) memory beyond
    the centred coordinates, and a group's box does not depend on the other groups.
    """
    xyz = np.asarray(xyz)
    if xyz.dtype not in (np.float32, np.float64):
        xyz = xyz.astype(np.float64)
    xyz = np.ascontiguousarray(xyz)
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    num = len(offsets) - 1
    if num <= 0:
        return Boxes(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    counts = np.diff(offsets)
    if np.any(counts <= 0):
        raise ValueError("fit_boxes: every group needs at least one point")
    if offsets[0] < 0 or offsets[-1] > len(xyz):
        raise ValueError(f"fit_boxes: offsets reach {offsets[-1]} but there are {len(xyz)} points")
    xyz, offsets = xyz[offsets[0] : offsets[-1]], offsets - offsets[0]
    # numpy's own (pairwise) sums as before: a kernel summing in another order moves float64 means by an ulp.
    mean = np.add.reduceat(xyz[:, :2], offsets[:-1], axis=0, dtype=np.float64) / counts[:, None]
    xy = _centre(xyz, offsets, mean)

    angles, dcos, dsin = _COARSE
    best = angles[_best_angles(xy, offsets, np.ones(num), np.zeros(num), False, dcos, dsin)]
    for angles, dcos, dsin in _REFINES:
        best = best + angles[_best_angles(xy, offsets, np.cos(best), np.sin(best), True, dcos, dsin)]
    best = np.mod(best, np.pi / 2)

    cb, sb = np.cos(best), np.sin(best)
    lo_u, hi_u, lo_v, hi_v, zmin, zmax = _extents(xy, xyz, offsets, cb, sb).T
    ext_u, ext_v = hi_u - lo_u, hi_v - lo_v
    mid_u, mid_v = (hi_u + lo_u) / 2, (hi_v + lo_v) / 2
    center = mean + np.stack([mid_u * cb - mid_v * sb, mid_u * sb + mid_v * cb], axis=1)
    u_longer = ext_u >= ext_v
    length = np.where(u_longer, ext_u, ext_v)
    width = np.where(u_longer, ext_v, ext_u)
    yaw = np.where(u_longer, best, best + np.pi / 2)
    yaw = np.where(yaw > np.pi / 2, yaw - np.pi, yaw)
    return Boxes(center, np.stack([length, width, zmax - zmin], axis=1), yaw, np.ascontiguousarray(zmin))


def fit_box_members(points: np.ndarray, members: list[np.ndarray]) -> Boxes:
    """Boxes of proposals given as index arrays into `points` (each non-empty)."""
    idx = np.concatenate(members) if members else np.zeros(0, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum([len(m) for m in members])])
    return fit_boxes(np.asarray(points)[idx, :3], offsets)


def vertices(boxes: Boxes) -> np.ndarray:
    """x-y coordinates (P, 4, 2) of the 4 bottom vertices, in view order."""
    c, s = np.cos(boxes.yaw), np.sin(boxes.yaw)
    half = boxes.size[:, None, :2] / 2 * _VERTEX_SIGNS[None]
    return boxes.center[:, None, :] + np.stack(
        [half[..., 0] * c[:, None] - half[..., 1] * s[:, None], half[..., 0] * s[:, None] + half[..., 1] * c[:, None]],
        axis=-1,
    )


def inference_views(boxes: Boxes, sensor_xy: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The fixed inference rule: origin at the bottom vertex nearest the sensor, right-handed (views 0..3)."""
    d2 = ((vertices(boxes) - np.asarray(sensor_xy, dtype=np.float64)) ** 2).sum(axis=-1)
    return np.argmin(d2, axis=1).astype(np.int64)


@nb.njit(cache=True, nogil=True)
def _canonical_kernel(
    xyz: np.ndarray, box_index: np.ndarray, center: np.ndarray, cos_yaw: np.ndarray, sin_yaw: np.ndarray,
    half: np.ndarray, zmin: np.ndarray, sign: np.ndarray, swap: np.ndarray,
) -> np.ndarray:
    """to_canonical's arithmetic point by point, from per-box rotations, half sizes, vertex signs and swaps."""
    out = np.empty((len(box_index), 3))
    for i in range(len(box_index)):
        b = box_index[i]
        dx0 = np.float64(xyz[i, 0]) - center[b, 0]
        dy0 = np.float64(xyz[i, 1]) - center[b, 1]
        lx = dx0 * cos_yaw[b] + dy0 * sin_yaw[b]
        ly = dy0 * cos_yaw[b] - dx0 * sin_yaw[b]
        dx = half[b, 0] - sign[b, 0] * lx
        dy = half[b, 1] - sign[b, 1] * ly
        dz = np.float64(xyz[i, 2]) - zmin[b]
        if swap[b]:
            dx, dy = dy, dx
        # np.maximum(v, 0.0): keeps v when v >= 0 (-0.0 too) or NaN.
        out[i, 0] = dx if dx >= 0.0 or dx != dx else 0.0
        out[i, 1] = dy if dy >= 0.0 or dy != dy else 0.0
        out[i, 2] = dz if dz >= 0.0 or dz != dz else 0.0
    return out


def to_canonical(xyz: np.ndarray, boxes: Boxes, box_index: np.ndarray, views: np.ndarray) -> np.ndarray:
    """Local coordinates (M, 3) float64 of points `xyz` (M, 3) in the view `views[box_index]` of their box.

    The box spans [0, a] x [0, b] x [0, height] with (a, b) = (length, width) or (width, length). Per-box
    terms are computed once, the per-point arithmetic in one numba pass.
    """
    xyz = np.asarray(xyz)
    if xyz.dtype not in (np.float32, np.float64):
        xyz = xyz.astype(np.float64)
    xyz = np.ascontiguousarray(xyz)
    box_index = np.ascontiguousarray(box_index, dtype=np.int64)
    v = np.asarray(views, dtype=np.int64)
    if xyz.ndim != 2 or xyz.shape[1] < 3 or box_index.shape != (len(xyz),):
        raise ValueError(f"to_canonical: points {xyz.shape} and box_index {box_index.shape} do not match")
    num = min(len(boxes), len(v))
    if len(box_index) and (box_index.min() < 0 or box_index.max() >= num):
        raise IndexError(f"to_canonical: a box index is outside [0, {num})")
    v = v[:num]
    signs = _VERTEX_SIGNS[v % 4]
    # Right-handed frames at vertices with sx * sy = -1 need x along the width; mirror views flip that.
    swap = (signs[:, 0] * signs[:, 1] < 0) ^ (v >= 4)
    return _canonical_kernel(
        xyz, box_index, np.ascontiguousarray(boxes.center[:num], dtype=np.float64),
        np.ascontiguousarray(np.cos(boxes.yaw)[:num], dtype=np.float64),
        np.ascontiguousarray(np.sin(boxes.yaw)[:num], dtype=np.float64),
        np.ascontiguousarray(boxes.size[:num, :2] / 2, dtype=np.float64),
        np.ascontiguousarray(boxes.zmin[:num], dtype=np.float64), signs, swap,
    )


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) the box and canonical kernels for float32 points, the
    type every caller passes, so a first frame does not pay for it."""
    xyz = np.random.default_rng(0).random((12, 3)).astype(np.float32)
    boxes = fit_boxes(xyz, np.array([0, 5, 12]))
    to_canonical(xyz, boxes, np.repeat(np.arange(2), [5, 7]), np.array([0, 5]))


def sample_indices(count: int, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly `num_points` indices into `count` points: a random choice without repeats if there are
    enough, else every point once plus random repeats."""
    if count <= 0:
        raise ValueError("sample_indices: empty proposal")
    if count >= num_points:
        return rng.choice(count, num_points, replace=False)
    return np.concatenate([np.arange(count), rng.integers(0, count, num_points - count)])


def inference_rng(count: int, draw: int = 0) -> np.random.Generator:
    """The per-proposal generator of the count-seeded draw (`--sampling draw`), seeded from the point count.

    Draw 0 is that sampler's default; draw d > 0 another fixed generator (seeded from (count, d)), for measuring
    how much the choice of sampled points moves the result.
    """
    if draw < 0:
        raise ValueError(f"inference_rng: draw must be >= 0, got {draw}")
    return np.random.default_rng(count) if draw == 0 else np.random.default_rng([count, draw])


@functools.lru_cache(maxsize=4096)
def inference_sample(count: int, num_points: int, draw: int = 0) -> np.ndarray:
    """`sample_indices` under `inference_rng(count, draw)`: the same for every proposal of `count` points, so drawn
    once (a generator and a draw cost tens of microseconds, a frame has ~30 proposals). Read-only."""
    indices = sample_indices(count, num_points, inference_rng(count, draw))
    indices.flags.writeable = False
    return indices


_HASH_MIX = np.array([0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0x27D4EB2F165667C5], np.uint64)


def point_hashes(points: np.ndarray, draw: int = 0) -> np.ndarray:
    """A 64-bit hash of each point's float32 values (x, y, z and intensity, or only the first three columns given)
    and the draw index (murmur3's 64-bit finalizer over a multiply-xor mix): a function of the point alone, so of no
    list order. A network that does not read intensity hashes x, y, z only, so its labels do not depend on it."""
    bits = np.ascontiguousarray(points[:, :4], dtype=np.float32).view(np.uint32)
    return _hash_kernel(bits, _HASH_MIX, np.uint64((0x94D049BB133111EB * (draw + 1)) % 2**64))


@nb.njit(cache=True, nogil=True)
def _hash_kernel(bits: np.ndarray, mix: np.ndarray, salt: np.uint64) -> np.ndarray:
    """point_hashes in one pass (uint64 arithmetic wraps, as numpy's)."""
    out = np.empty(bits.shape[0], dtype=np.uint64)
    for i in range(bits.shape[0]):
        h = np.uint64(bits[i, 0]) * mix[0]
        for k in range(1, bits.shape[1]):
            h ^= np.uint64(bits[i, k]) * mix[k]
        h ^= salt
        h ^= h >> np.uint64(33)
        h *= np.uint64(0xFF51AFD7ED558CCD)
        h ^= h >> np.uint64(33)
        h *= np.uint64(0xC4CEB9FE1A85EC53)
        out[i] = h ^ (h >> np.uint64(33))
    return out


def content_sample(points: np.ndarray, num_points: int, draw: int = 0) -> np.ndarray:
    """`num_points` positions into one proposal's `points` (count, 3 or 4). With more points than that, picked by
    their content, not their order: the `num_points` of smallest `point_hashes`, listed in hash order (a uniform
    random subset in random order, as `sample_indices`). With as many or fewer, every point in input order, as
    `sample_indices` lists them, and the repeats it would add drawn from a generator seeded by the proposal's content
    (the xor of its hashes), count and draw: the network reads a small proposal in scan order, as it was trained,
    and a new order per draw made its class a dice roll (measured: docs/experiments/trials-issue-37-sampling.md)."""
    return content_positions(point_hashes(points, draw), num_points, draw)


def content_positions(hashes: np.ndarray, num_points: int, draw: int = 0) -> np.ndarray:
    """`content_sample` from one proposal's `point_hashes` (hashed once for a whole frame)."""
    count = len(hashes)
    if count <= 0:
        raise ValueError("content_sample: empty proposal")
    if count > num_points:
        chosen = np.argpartition(hashes, num_points - 1)[:num_points]
        return chosen[np.argsort(hashes[chosen], kind="stable")]
    if count == num_points:
        return np.arange(count)
    return sample_indices(count, num_points, np.random.default_rng([int(np.bitwise_xor.reduce(hashes)), count, draw]))


SAMPLINGS: tuple[str, ...] = ("draw", "coverage", "content")  # how inference picks each proposal's N points
COVERAGE_CELL_M = 0.001  # coverage sampling orders points on a Morton curve of their coordinates at this resolution
_COVERAGE_BITS = 14  # per axis: 16.4 m of extent at 1 mm (coordinates past it are clipped)


@nb.njit(cache=True, nogil=True)
def _morton(x: int, y: int, z: int, bits: int) -> np.uint64:
    """The 3-D Morton code of cell (x, y, z): bit b of x at 3b, of y at 3b + 1, of z at 3b + 2."""
    code = np.uint64(0)
    for b in range(bits):
        code |= np.uint64(((x >> b) & 1) << (3 * b)) | np.uint64(((y >> b) & 1) << (3 * b + 1)) | np.uint64(
            ((z >> b) & 1) << (3 * b + 2))
    return code


@nb.njit(cache=True, nogil=True)
def _coverage_kernel(xyz: np.ndarray, offsets: np.ndarray, num_points: int, cell: np.float32, bits: int
                     ) -> np.ndarray:
    """Per proposal, the middle position of each of num_points equal strata of its points' Morton order (cells of
    `cell` metres from the proposal's low corner, in float32, clipped to `bits` bits an axis; ties keep the input
    order)."""
    count = len(offsets) - 1
    out = np.empty((count, num_points), dtype=np.int64)
    top = (1 << bits) - 1
    for p in range(count):
        start, end = offsets[p], offsets[p + 1]
        size = end - start
        lx, ly, lz = xyz[start:end, 0].min(), xyz[start:end, 1].min(), xyz[start:end, 2].min()
        codes = np.empty(size, dtype=np.uint64)
        for q in range(size):
            cx = min(max(int((xyz[start + q, 0] - lx) / cell), 0), top)
            cy = min(max(int((xyz[start + q, 1] - ly) / cell), 0), top)
            cz = min(max(int((xyz[start + q, 2] - lz) / cell), 0), top)
            codes[q] = _morton(cx, cy, cz, bits)
        order = np.argsort(codes, kind="mergesort")
        for k in range(num_points):
            out[p, k] = start + order[int(np.floor((k + 0.5) / num_points * size))]
    return out


def coverage_sample(xyz: np.ndarray, offsets: np.ndarray, num_points: int) -> np.ndarray:
    """Per proposal (points xyz[offsets[p]:offsets[p + 1]]), `num_points` positions into xyz spread over it: the
    points ordered along a Morton curve of their coordinates, and the middle point of each of `num_points` equal
    strata of that order (fewer points: each once, the repeats spread evenly), listed in one fixed shuffled order
    (`_sample_order`). It depends on the coordinates alone,
    never on the points' order or a generator: the same proposal always gets the same sample. (P, num_points)."""
    counts = np.diff(offsets)
    if len(counts) == 0:
        return np.zeros((0, num_points), dtype=np.int64)
    if np.any(counts <= 0):
        raise ValueError("coverage_sample: empty proposal")
    positions = _coverage_kernel(np.ascontiguousarray(xyz, dtype=np.float32), np.asarray(offsets, dtype=np.int64),
                                 num_points, np.float32(COVERAGE_CELL_M), _COVERAGE_BITS)
    return positions[:, _sample_order(num_points)]


@functools.lru_cache(maxsize=8)
def _sample_order(num_points: int) -> np.ndarray:
    """One fixed shuffle of N sample slots: the network starts its farthest point sampling at slot 0 and its ball
    queries take the first points in slot order, so a sample listed along the curve would bias both to one corner."""
    return np.random.default_rng(0).permutation(num_points)


def n_feature(count: int | np.ndarray, num_points: int, mode: str = "ratio") -> float | np.ndarray:
    """The point-count feature: the paper's n = (NUM - N) / N ("ratio"), or log(NUM / N) ("log"), bounded
    to a few units for any proposal size."""
    count = np.asarray(count, dtype=np.float64)
    if mode == "ratio":
        return (count - num_points) / num_points
    if mode == "log":
        return np.log(np.maximum(count, 1.0) / num_points)
    raise ValueError(f"unknown n feature mode {mode!r}: ratio or log")
