"""Stage 2 canonical frame: per-proposal box from its member points, the 8 box views, N-point sampling.

The box of a proposal is fitted here, from the member points alone (minimal-area rectangle in x-y, z from
min to max), so the ROS node and the offline tools build exactly the same input for the network.

Views: a view puts the origin at one bottom vertex of the box with the axes along the box edges, the box in
the first octant. Views 0..3 are the four right-handed frames (origin at vertex 0..3: the 4 rotations),
views 4..7 are their mirror images (x and y swapped, left-handed). Training draws any of the 8; inference
uses the right-handed view at the vertex nearest the sensor, and a generator seeded from the proposal's
point count for the N-point sample, so a proposal's input depends on its points alone.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

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


def _best_angles(xy_t: np.ndarray, starts: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Per group, the candidate of `angles` (A,) giving the smallest rectangle; xy_t is (2, M) (centred)."""
    both = np.concatenate([angles, angles + np.pi / 2])
    proj = np.stack([np.cos(both), np.sin(both)], axis=1) @ xy_t
    ext = np.maximum.reduceat(proj, starts, axis=1) - np.minimum.reduceat(proj, starts, axis=1)
    return angles[np.argmin(ext[: len(angles)] * ext[len(angles) :], axis=0)]


def _rotate_t(xy_t: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Coordinates (2, M) of points xy_t (2, M) in axes turned by `angle` (M,)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([xy_t[0] * c + xy_t[1] * s, xy_t[1] * c - xy_t[0] * s])


def fit_boxes(xyz: np.ndarray, offsets: np.ndarray, chunk_points: int = 200_000) -> Boxes:
    """Minimal-area oriented boxes of P point groups: group p is xyz[offsets[p]:offsets[p+1]] (non-empty).

    Vectorised over all groups: a coarse search over [0, 90) degrees, then two finer searches around the
    best angle so far (to about 0.02 degrees). Groups go in chunks of about `chunk_points` points, which
    bounds the memory (the coarse search holds 60 projections per point).
    """
    xyz = np.asarray(xyz)
    offsets = np.asarray(offsets, dtype=np.int64)
    cuts = [0]  # group indices where chunks start; a group larger than chunk_points is a chunk of its own
    while cuts[-1] < len(offsets) - 1:
        end = int(np.searchsorted(offsets, offsets[cuts[-1]] + chunk_points, side="right")) - 1
        cuts.append(max(end, cuts[-1] + 1))
    if len(cuts) <= 2:
        return _fit_boxes(np.asarray(xyz[offsets[0] : offsets[-1]], dtype=np.float64), offsets - offsets[0])
    parts = [
        _fit_boxes(np.asarray(xyz[offsets[a] : offsets[b]], dtype=np.float64), offsets[a : b + 1] - offsets[a])
        for a, b in itertools.pairwise(cuts)
    ]
    return Boxes(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("center", "size", "yaw", "zmin")))


def _fit_boxes(xyz: np.ndarray, offsets: np.ndarray) -> Boxes:
    """fit_boxes on one chunk (offsets start at 0)."""
    starts = offsets[:-1]
    counts = np.diff(offsets)
    num = len(counts)
    if num == 0:
        return Boxes(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    if np.any(counts <= 0):
        raise ValueError("fit_boxes: every group needs at least one point")
    seg = np.repeat(np.arange(num), counts)
    mean = np.add.reduceat(xyz[:, :2], starts, axis=0) / counts[:, None]
    xy_t = (xyz[:, :2] - mean[seg]).T

    best = _best_angles(xy_t, starts, np.arange(0.0, np.pi / 2, _COARSE_STEP))
    span = _COARSE_STEP
    for step in _REFINE_STEPS:
        turned = _rotate_t(xy_t, best[seg])
        best = best + _best_angles(turned, starts, np.arange(-span, span + step / 2, step))
        span = step
    best = np.mod(best, np.pi / 2)

    pu, pv = _rotate_t(xy_t, best[seg])
    lo_u, hi_u = np.minimum.reduceat(pu, starts), np.maximum.reduceat(pu, starts)
    lo_v, hi_v = np.minimum.reduceat(pv, starts), np.maximum.reduceat(pv, starts)
    zmin, zmax = np.minimum.reduceat(xyz[:, 2], starts), np.maximum.reduceat(xyz[:, 2], starts)
    ext_u, ext_v = hi_u - lo_u, hi_v - lo_v
    mid_u, mid_v = (hi_u + lo_u) / 2, (hi_v + lo_v) / 2
    cb, sb = np.cos(best), np.sin(best)
    center = mean + np.stack([mid_u * cb - mid_v * sb, mid_u * sb + mid_v * cb], axis=1)
    u_longer = ext_u >= ext_v
    length = np.where(u_longer, ext_u, ext_v)
    width = np.where(u_longer, ext_v, ext_u)
    yaw = np.where(u_longer, best, best + np.pi / 2)
    yaw = np.where(yaw > np.pi / 2, yaw - np.pi, yaw)
    return Boxes(center, np.stack([length, width, zmax - zmin], axis=1), yaw, zmin)


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


def to_canonical(xyz: np.ndarray, boxes: Boxes, box_index: np.ndarray, views: np.ndarray) -> np.ndarray:
    """Local coordinates (M, 3) float64 of points `xyz` (M, 3) in the view `views[box_index]` of their box.

    The box spans [0, a] x [0, b] x [0, height] with (a, b) = (length, width) or (width, length).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    box_index = np.asarray(box_index, dtype=np.int64)
    v = np.asarray(views, dtype=np.int64)[box_index]
    c, s = np.cos(boxes.yaw)[box_index], np.sin(boxes.yaw)[box_index]
    d = xyz[:, :2] - boxes.center[box_index]
    lx = d[:, 0] * c + d[:, 1] * s
    ly = d[:, 1] * c - d[:, 0] * s
    signs = _VERTEX_SIGNS[v % 4]
    half = boxes.size[box_index, :2] / 2
    dx = half[:, 0] - signs[:, 0] * lx
    dy = half[:, 1] - signs[:, 1] * ly
    # Right-handed frames at vertices with sx * sy = -1 need x along the width; mirror views flip that.
    swap = (signs[:, 0] * signs[:, 1] < 0) ^ (v >= 4)
    out = np.empty((len(xyz), 3), dtype=np.float64)
    out[:, 0] = np.where(swap, dy, dx)
    out[:, 1] = np.where(swap, dx, dy)
    out[:, 2] = xyz[:, 2] - boxes.zmin[box_index]
    return np.maximum(out, 0.0)


def sample_indices(count: int, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly `num_points` indices into `count` points: a random choice without repeats if there are
    enough, else every point once plus random repeats."""
    if count <= 0:
        raise ValueError("sample_indices: empty proposal")
    if count >= num_points:
        return rng.choice(count, num_points, replace=False)
    return np.concatenate([np.arange(count), rng.integers(0, count, num_points - count)])


def inference_rng(count: int) -> np.random.Generator:
    """The deterministic per-proposal generator of inference, seeded from the proposal's point count."""
    return np.random.default_rng(count)


def n_feature(count: int | np.ndarray, num_points: int, mode: str = "ratio") -> float | np.ndarray:
    """The point-count feature: the paper's n = (NUM - N) / N ("ratio"), or log(NUM / N) ("log"), bounded
    to a few units for any proposal size."""
    count = np.asarray(count, dtype=np.float64)
    if mode == "ratio":
        return (count - num_points) / num_points
    if mode == "log":
        return np.log(np.maximum(count, 1.0) / num_points)
    raise ValueError(f"unknown n feature mode {mode!r}: ratio or log")
