"""The numba box fit and canonical transform give what the numpy code they replaced gave, and the shipped weights
label frames the same with either.

The reference below is the previous implementation, kept verbatim (renamed): same minimal-area search
(coarse 3 degrees, then 0.25 and 0.02 degrees around the best), same tie rule (first smallest area), same
canonical arithmetic. Boxes and local coordinates must agree to float rounding, labels of the shipped
weights exactly.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.bench.stage2 import constructed_frame
from pass3d_ros.core.stage1 import proposal_members, propose
from pass3d_ros.core.stage2 import canonical
from pass3d_ros.core.stage2.segmentation import Segmenter
from pass3d_ros.data.spec import open_dataset

ATOL = 1e-5

# ------------------------------------------------------------------------------------ reference (numpy)

_VERTEX_SIGNS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
_COARSE_STEP = np.deg2rad(3.0)
_REFINE_STEPS = (np.deg2rad(0.25), np.deg2rad(0.02))


def _ref_best_angles(xy_t: np.ndarray, starts: np.ndarray, angles: np.ndarray) -> np.ndarray:
    both = np.concatenate([angles, angles + np.pi / 2])
    proj = np.stack([np.cos(both), np.sin(both)], axis=1) @ xy_t
    ext = np.maximum.reduceat(proj, starts, axis=1) - np.minimum.reduceat(proj, starts, axis=1)
    return angles[np.argmin(ext[: len(angles)] * ext[len(angles) :], axis=0)]


def _ref_rotate_t(xy_t: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([xy_t[0] * c + xy_t[1] * s, xy_t[1] * c - xy_t[0] * s])


def ref_fit_boxes(xyz: np.ndarray, offsets: np.ndarray, chunk_points: int = 200_000) -> canonical.Boxes:
    xyz = np.asarray(xyz)
    offsets = np.asarray(offsets, dtype=np.int64)
    cuts = [0]
    while cuts[-1] < len(offsets) - 1:
        end = int(np.searchsorted(offsets, offsets[cuts[-1]] + chunk_points, side="right")) - 1
        cuts.append(max(end, cuts[-1] + 1))
    if len(cuts) <= 2:
        return _ref_fit_boxes(np.asarray(xyz[offsets[0] : offsets[-1]], dtype=np.float64), offsets - offsets[0])
    parts = [
        _ref_fit_boxes(np.asarray(xyz[offsets[a] : offsets[b]], dtype=np.float64), offsets[a : b + 1] - offsets[a])
        for a, b in itertools.pairwise(cuts)
    ]
    return canonical.Boxes(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("center", "size", "yaw", "zmin")))


def _ref_fit_boxes(xyz: np.ndarray, offsets: np.ndarray) -> canonical.Boxes:
    starts = offsets[:-1]
    counts = np.diff(offsets)
    num = len(counts)
    if num == 0:
        return canonical.Boxes(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    if np.any(counts <= 0):
        raise ValueError("fit_boxes: every group needs at least one point")
    seg = np.repeat(np.arange(num), counts)
    mean = np.add.reduceat(xyz[:, :2], starts, axis=0) / counts[:, None]
    xy_t = (xyz[:, :2] - mean[seg]).T

    best = _ref_best_angles(xy_t, starts, np.arange(0.0, np.pi / 2, _COARSE_STEP))
    span = _COARSE_STEP
    for step in _REFINE_STEPS:
        turned = _ref_rotate_t(xy_t, best[seg])
        best = best + _ref_best_angles(turned, starts, np.arange(-span, span + step / 2, step))
        span = step
    best = np.mod(best, np.pi / 2)

    pu, pv = _ref_rotate_t(xy_t, best[seg])
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
    return canonical.Boxes(center, np.stack([length, width, zmax - zmin], axis=1), yaw, zmin)


def ref_to_canonical(xyz: np.ndarray, boxes: canonical.Boxes, box_index: np.ndarray, views: np.ndarray) -> np.ndarray:
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
    swap = (signs[:, 0] * signs[:, 1] < 0) ^ (v >= 4)
    out = np.empty((len(xyz), 3), dtype=np.float64)
    out[:, 0] = np.where(swap, dy, dx)
    out[:, 1] = np.where(swap, dx, dy)
    out[:, 2] = xyz[:, 2] - boxes.zmin[box_index]
    return np.maximum(out, 0.0)


# ------------------------------------------------------------------------------------------- helpers


def assert_same_boxes(got: canonical.Boxes, want: canonical.Boxes) -> None:
    assert len(got) == len(want)
    for field in ("center", "size", "yaw", "zmin"):
        a, b = getattr(got, field), getattr(want, field)
        assert a.shape == b.shape, field
        assert np.allclose(a, b, rtol=0, atol=ATOL), (field, np.abs(a - b).max())


def assert_same_canonical(xyz: np.ndarray, boxes: canonical.Boxes, offsets: np.ndarray) -> None:
    """to_canonical against the reference in every view and in the inference views."""
    batch = np.repeat(np.arange(len(boxes)), np.diff(offsets))
    for views in [np.full(len(boxes), v) for v in range(canonical.NUM_VIEWS)] + [canonical.inference_views(boxes)]:
        got = canonical.to_canonical(xyz, boxes, batch, views)
        want = ref_to_canonical(xyz, boxes, batch, views)
        assert got.dtype == np.float64 and got.shape == want.shape
        assert np.allclose(got, want, rtol=0, atol=ATOL), np.abs(got - want).max()


def random_clouds(rng: np.random.Generator) -> list[np.ndarray]:
    """Point groups (K, 3) of awkward shapes: tiny, collinear, duplicated, gridded (area ties), box-like."""
    line = np.linspace(-2, 2, 40)
    groups = [
        rng.normal(size=(1, 3)),
        rng.normal(size=(2, 3)),
        rng.normal(size=(3, 3)),
        np.repeat(rng.normal(size=(1, 3)), 7, axis=0),  # one point seven times
        np.repeat(rng.normal(size=(5, 3)), 3, axis=0),  # duplicates
        np.column_stack([line, np.zeros(40), rng.normal(size=40)]),  # collinear along x
        np.column_stack([np.zeros(40), line, rng.normal(size=40)]),  # collinear along y
        np.column_stack([line + 7, 0.6 * line - 3, np.zeros(40)]),  # collinear, oblique
        np.column_stack([np.full(9, 2.5), np.full(9, -1.0), np.arange(9.0)]),  # a vertical line
        np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64),  # a square
        np.array([[x, y, 0.0] for x in range(5) for y in range(3)]),  # a grid
    ]
    for count in (5, 50, 500, 3000):
        size = rng.uniform([0.3, 0.3, 0.5], [5, 2, 2])
        yaw = rng.uniform(-np.pi, np.pi)
        local = rng.uniform(-size / 2, size / 2, (count, 3))
        c, s = np.cos(yaw), np.sin(yaw)
        xy = local[:, :2] @ np.array([[c, s], [-s, c]]) + rng.uniform(-40, 40, 2)
        groups.append(np.column_stack([xy, local[:, 2] - 1.5]))
    groups.append(rng.normal(size=(400, 3)) * [3.0, 0.4, 1.0])
    return groups


def frame_groups(points: np.ndarray, members: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Member xyz (M, 3) float32 of a frame's proposals and their offsets, as prepare_proposals builds them."""
    index = np.concatenate(members).astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum([len(m) for m in members])])
    return np.asarray(points, dtype=np.float32)[index, :3], offsets


def stage1_frames(spec: str, count: int) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    frames = []
    for frame in itertools.islice(open_dataset(spec), count):
        result = propose(frame.points, ring=frame.ring)
        frames.append((frame.points, proposal_members(result.cluster_id, result.cluster_id2)))
    return frames


# --------------------------------------------------------------------------------------------- tests


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_fit_boxes_matches_reference_group_by_group(dtype):
    rng = np.random.default_rng(10)
    for group in random_clouds(rng):
        xyz = group.astype(dtype)
        offsets = np.array([0, len(xyz)])
        assert_same_boxes(canonical.fit_boxes(xyz, offsets), ref_fit_boxes(xyz, offsets))


def test_fit_boxes_matches_reference_on_many_groups_and_offsets():
    rng = np.random.default_rng(11)
    groups = random_clouds(rng)
    xyz = np.concatenate([rng.normal(size=(13, 3)), *groups, rng.normal(size=(5, 3))])
    offsets = 13 + np.concatenate([[0], np.cumsum([len(g) for g in groups])])  # groups start after 13 points
    want = ref_fit_boxes(xyz, offsets)
    assert_same_boxes(canonical.fit_boxes(xyz, offsets), want)
    assert_same_boxes(canonical.fit_boxes(xyz[:, :3].copy(order="F"), offsets), want)  # any layout
    assert_same_boxes(canonical.fit_boxes(np.column_stack([xyz, xyz[:, :1]])[:, :3], offsets), want)
    assert_same_canonical(xyz[13:-5], want, offsets - 13)


def test_a_groups_box_does_not_depend_on_the_other_groups():
    """Integer clouds tie in area at several angles; each group's choice is its own, bit for bit. (The numpy
    reference broke some of these ties differently by the group's column in the big matmul.)"""
    rng = np.random.default_rng(19)
    groups = [np.round(rng.normal(size=(int(rng.integers(1, 8)), 3)) * 3) for _ in range(200)]
    offsets = np.concatenate([[0], np.cumsum([len(g) for g in groups])])
    together = canonical.fit_boxes(np.concatenate(groups), offsets)
    for p, group in enumerate(groups):
        alone = canonical.fit_boxes(group, np.array([0, len(group)]))
        for field in ("center", "size", "yaw", "zmin"):
            assert np.array_equal(getattr(alone, field)[0], getattr(together, field)[p]), (p, field)


def test_warm_up_runs():
    canonical.warm_up()


def test_fit_boxes_empty_and_bad_groups_like_reference():
    assert len(canonical.fit_boxes(np.zeros((0, 3)), np.array([0]))) == 0
    with pytest.raises(ValueError):
        canonical.fit_boxes(np.zeros((4, 3)), np.array([0, 2, 2, 4]))
    with pytest.raises(ValueError):
        canonical.fit_boxes(np.zeros((4, 3)), np.array([0, 2, 6]))


def test_to_canonical_rejects_box_index_out_of_range():
    xyz = np.random.default_rng(12).normal(size=(10, 3))
    boxes = canonical.fit_boxes(xyz, np.array([0, 10]))
    with pytest.raises(IndexError):
        canonical.to_canonical(xyz, boxes, np.ones(10, dtype=np.int64), np.array([0]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constructed_frame_boxes_and_canonical_match_reference(seed):
    xyz, offsets = frame_groups(*constructed_frame(30, seed=seed))
    boxes = canonical.fit_boxes(xyz, offsets)
    assert_same_boxes(boxes, ref_fit_boxes(xyz, offsets))
    assert_same_canonical(xyz, boxes, offsets)


def test_stage1_proposals_match_reference():
    for points, members in stage1_frames("synthetic:frames=2,seed=7", 2):
        xyz, offsets = frame_groups(points, members)
        boxes = canonical.fit_boxes(xyz, offsets)
        assert_same_boxes(boxes, ref_fit_boxes(xyz, offsets))
        assert_same_canonical(xyz, boxes, offsets)


def test_real_kitti_proposals_match_reference(kitti_dev: Path):
    for points, members in stage1_frames(f"semantickitti:{kitti_dev}/semantickitti/sequences/00", 2):
        xyz, offsets = frame_groups(points, members)
        boxes = canonical.fit_boxes(xyz, offsets)
        assert_same_boxes(boxes, ref_fit_boxes(xyz, offsets))
        assert_same_canonical(xyz, boxes, offsets)


def assert_same_labels(segmenter: Segmenter, frames: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """segment() with the new kernels and with the reference functions patched in gives the same labels."""
    got = [segmenter.segment(points, members) for points, members in frames]
    with monkeypatch.context() as patch:
        patch.setattr(canonical, "fit_boxes", ref_fit_boxes)
        patch.setattr(canonical, "to_canonical", ref_to_canonical)
        want = [segmenter.segment(points, members) for points, members in frames]
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.labels, b.labels)
        assert np.array_equal(a.proposal_class, b.proposal_class)
        assert np.allclose(a.confidence, b.confidence, atol=1e-5)


def test_shipped_weights_label_the_same(shipped, monkeypatch):
    frames = [constructed_frame(30, seed=s) for s in (0, 1)] + stage1_frames("synthetic:frames=2,seed=99", 2)
    assert_same_labels(shipped, frames, monkeypatch)


def test_shipped_weights_label_real_frames_the_same(shipped, kitti_dev: Path, monkeypatch):
    assert_same_labels(shipped, stage1_frames(f"semantickitti:{kitti_dev}/semantickitti/sequences/00", 2), monkeypatch)
