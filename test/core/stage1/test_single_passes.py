"""Stage 1's single-pass helpers give exactly what the numpy forms they replaced gave (rule P,
docs/experiments/sensors.md: the proposals must not change, bit for bit, when a step gets faster)."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1 import Stage1Config, crowd, refinement, split
from pass3d_ros.core.stage1.ground import LOCAL_CELL_M, LocalGround, fit_ground, segments, with_local_ground
from pass3d_ros.data.frame import Box3D


def random_scan(seed: int, n: int = 4000, n_clusters: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Points (float32, N x 4) around a sensor and cluster labels (-1 for about a third)."""
    rng = np.random.default_rng(seed)
    pts = np.zeros((n, 4), dtype=np.float32)
    pts[:, :2] = rng.uniform(-40.0, 40.0, (n, 2))
    pts[:, 2] = rng.uniform(-2.0, 1.0, n)
    label = rng.integers(-1, n_clusters, n).astype(np.int32)
    label[rng.random(n) < 0.3] = -1
    return pts, label


def numpy_heights(points, label, chosen, surface, segment_edges) -> np.ndarray:
    """heights_above_ground as numpy wrote it before rule P."""
    height = np.full(len(points), np.nan)
    inside = np.flatnonzero((label >= 0) & chosen[np.maximum(label, 0)])
    if len(inside) == 0:
        return height
    planes = surface.planes if isinstance(surface, LocalGround) else surface
    pts = points[inside].astype(np.float64)
    a, b, c, d = planes[segments(pts[:, 0], segment_edges, len(planes))].T
    height[inside] = a * pts[:, 0] + b * pts[:, 1] + c * pts[:, 2] + d
    if isinstance(surface, LocalGround):
        where = label[inside]
        counts = np.bincount(where)
        present = np.flatnonzero(counts)
        centre = np.stack([np.bincount(where, weights=pts[:, k])[present] / counts[present] for k in (0, 1)], axis=1)
        offset = np.zeros(len(counts))
        offset[present] = surface.offsets(centre)
        height[inside] -= offset[where]
    return height


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("local", [False, True])
def test_heights_and_rise_match_the_numpy_forms(seed: int, local: bool) -> None:
    pts, label = random_scan(seed)
    fit = fit_ground(pts, Stage1Config())
    surface = fit.local if local else fit.planes
    assert surface is not None
    chosen = np.random.default_rng(seed + 10).random(60) < 0.5
    got = split.heights_above_ground(pts, label, chosen, surface, fit.segment_edges)
    want = numpy_heights(pts, label, chosen, surface, fit.segment_edges)
    np.testing.assert_array_equal(got, want)
    inside = np.flatnonzero(~np.isnan(want))
    top, bottom = np.full(60, -np.inf), np.full(60, np.inf)
    np.maximum.at(top, label[inside], want[inside])
    np.minimum.at(bottom, label[inside], want[inside])
    np.testing.assert_array_equal(split._shaped(got, label, chosen), chosen & (top - bottom >= split.PART_MIN_RISE_M))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_new_part_ids_match_a_sort_of_the_keys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_clusters, n_runs, m = 40, 90, 3000
    label = np.sort(rng.integers(0, n_clusters, m)).astype(np.int32)  # a cluster's points come in runs
    runs = rng.integers(0, n_runs, m).astype(np.int32)
    runs[label % 3 == 0] = label[label % 3 == 0]  # some clusters stay whole
    new_id, n_new, n_cut = split._new_part_ids(label, runs, n_clusters, n_runs)
    key = label.astype(np.int64) * n_runs + runs
    pairs, part = np.unique(key, return_inverse=True)
    parts_of = np.bincount(pairs // n_runs, minlength=n_clusters)
    cut = parts_of[pairs // n_runs] > 1
    want = np.full(len(pairs), -1)
    want[cut] = n_clusters + np.arange(int(cut.sum()))
    np.testing.assert_array_equal(new_id, want[part])
    assert (n_new, n_cut) == (int(cut.sum()), int(np.count_nonzero(parts_of > 1)))
    assert n_cut > 0 and n_cut < n_clusters


@pytest.mark.parametrize("seed", [0, 1])
def test_cluster_stats_crowd_members_and_part_sums_match_numpy(seed: int) -> None:
    pts, label = random_scan(seed)
    fit = fit_ground(pts, Stage1Config())
    count, sums, lo, hi, bottom, top = refinement._cluster_stats(pts, label, 60, fit.planes, fit.segment_edges)
    inside = label >= 0
    np.testing.assert_array_equal(count, np.bincount(label[inside], minlength=60))
    for k in range(3):
        want_lo, want_hi = np.full(60, np.inf), np.full(60, -np.inf)
        np.minimum.at(want_lo, label[inside], pts[inside, k].astype(np.float64))
        np.maximum.at(want_hi, label[inside], pts[inside, k].astype(np.float64))
        np.testing.assert_array_equal(lo[:, k], want_lo)
        np.testing.assert_array_equal(hi[:, k], want_hi)
    for k in (0, 1):
        np.testing.assert_array_equal(sums[:, k], np.bincount(label[inside], weights=pts[inside, k], minlength=60))
    every = numpy_heights(pts, label, np.ones(60, dtype=bool), fit.planes, fit.segment_edges)
    want_bottom, want_top = np.full(60, np.inf), np.full(60, -np.inf)
    np.minimum.at(want_bottom, label[inside], every[inside])
    np.maximum.at(want_top, label[inside], every[inside])
    np.testing.assert_array_equal(bottom, want_bottom)
    np.testing.assert_array_equal(top, want_top)
    height = np.where(inside, 0.5, np.nan)
    height[::7] = np.nan
    chosen = np.arange(60) % 2 == 0
    np.testing.assert_array_equal(crowd._with_height(label, chosen, height),
                                  np.flatnonzero(inside & chosen[np.maximum(label, 0)] & ~np.isnan(height)))
    part_count, part_sums = split._part_sums(pts, label, 30, 30)
    parts = label >= 30
    np.testing.assert_array_equal(part_count, np.bincount(label[parts] - 30, minlength=30))
    for k in (0, 1):
        np.testing.assert_array_equal(part_sums[:, k], np.bincount(label[parts] - 30, weights=pts[parts, k],
                                                                   minlength=30))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cluster_rects_match_each_clusters_own_rectangle(seed: int) -> None:
    pts, label = random_scan(seed)
    rng = np.random.default_rng(seed + 20)
    candidates = np.sort(rng.choice(60, 25, replace=False))
    candidates = np.concatenate([candidates[1:], candidates[:1], [60]])  # any order; cluster 60 has no points
    got = refinement._cluster_rects(pts, label, candidates)
    want = np.zeros((len(candidates), 5))
    for t, c in enumerate(candidates):
        mine = label == c
        if mine.any():
            want[t] = refinement.min_area_rectangle(pts[mine, :2].astype(np.float64))
    np.testing.assert_array_equal(got, want)
    assert refinement._cluster_rects(pts, label, np.zeros(0, dtype=np.int64)).shape == (0, 5)


def brute_membership(points, label, kept, boxes, margin, floors, gives_way) -> tuple[np.ndarray, np.ndarray]:
    """enlarged_membership point by point over every box, without a grid."""
    primary = np.full(len(points), -1, dtype=np.int32)
    secondary = np.full(len(points), -1, dtype=np.int32)
    own_of = {int(c): p for p, c in enumerate(kept)}
    for i, (x, y, z) in enumerate(points[:, :3].astype(np.float64)):
        first = own_of.get(int(label[i]), -1)
        second = -1
        for b, box in enumerate(boxes):
            cx, cy, cz, length, width, height, yaw = box
            half = (0.5 * length + margin[0], 0.5 * width + margin[1], 0.5 * height + margin[2])
            dx, dy = x - cx, y - cy
            c, s = np.cos(yaw), np.sin(yaw)
            if b in (first, second) or abs(dx * c + dy * s) > half[0] or abs(dy * c - dx * s) > half[1]:
                continue
            if abs(z - cz) > half[2] and not (floors[b] <= z <= cz):
                continue
            if first < 0:
                first = b
            elif second < 0 or (not gives_way[b] and gives_way[second]):
                second = b
            elif not gives_way[b] and gives_way[first]:
                first, second = second, b
        if first >= 0 and second >= 0 and gives_way[first] != gives_way[second]:
            first = second if gives_way[first] else first
            second = -1
        primary[i], secondary[i] = first, second
    return primary, secondary


@pytest.mark.parametrize("seed", [0, 1])
def test_enlarged_membership_matches_every_box_tested(seed: int) -> None:
    pts, label = random_scan(seed, n=3000)
    rng = np.random.default_rng(seed + 30)
    kept = np.sort(rng.choice(60, 20, replace=False))
    boxes = [Box3D(center=np.array([*rng.uniform(-30.0, 30.0, 2), rng.uniform(-1.5, 0.0)]),
                   size=np.array([rng.uniform(1.0, 8.0), rng.uniform(0.5, 4.0), rng.uniform(0.5, 2.0)]),
                   yaw=float(rng.uniform(-np.pi / 2, np.pi / 2))) for _ in kept]
    floors = np.where(rng.random(len(kept)) < 0.5, np.inf, rng.uniform(-3.0, -1.0, len(kept)))
    gives_way = rng.random(len(kept)) < 0.3
    margin = Stage1Config().enlarge
    got = refinement.enlarged_membership(pts, label, kept, boxes, margin, floors=floors, gives_way=gives_way)
    want = brute_membership(pts, label, kept, refinement.boxes_array(boxes), margin, floors, gives_way)
    assert (want[0] >= 0).sum() > (label >= 0).sum() * 20 / 60 and (want[1] >= 0).any()
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def numpy_with_local_ground(points: np.ndarray, fit, band: float) -> np.ndarray:
    """with_local_ground as numpy wrote it before its compiled passes (fifteenth session)."""
    local = fit.local
    rest = np.flatnonzero(~fit.ground)
    xyz = np.asarray(points[rest, :3], dtype=np.float64)
    n_cells = local.hist.shape[0]
    cell = np.floor((xyz[:, :2] - local.origin) / LOCAL_CELL_M).astype(np.int64)
    inside = np.all((cell >= 0) & (cell < n_cells), axis=1)
    rest, xyz, cell = rest[inside], xyz[inside], cell[inside]
    cells, which = np.unique(cell[:, 0] * n_cells + cell[:, 1], return_inverse=True)
    centres = local.origin + LOCAL_CELL_M * (np.column_stack([cells // n_cells, cells % n_cells]) + 0.5)
    a, b, c, d = local.planes[segments(xyz[:, 0], local.segment_edges, len(local.planes))].T
    height = (local.offsets(centres)[which] - a * xyz[:, 0] - b * xyz[:, 1] - d) / c  # LocalGround.heights, per cell
    ground = fit.ground.copy()
    ground[rest[np.abs(xyz[:, 2] - height) < band]] = True
    return ground


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_with_local_ground_matches_the_numpy_form(seed: int) -> None:
    """A tilted, bumpy road with objects and clutter on it, some of it past the local grid: the compiled passes mark
    the same points as numpy's unique-and-heights form did."""
    rng = np.random.default_rng(seed)
    n = 20000
    pts = np.zeros((n, 4), dtype=np.float32)
    pts[:, :2] = rng.uniform(-90.0, 90.0, (n, 2))
    road = rng.random(n) < 0.6
    pts[:, 2] = np.where(road, -1.73 + 0.04 * pts[:, 0] + 0.2 * np.sin(pts[:, 1] / 5.0) + rng.normal(0, 0.03, n),
                         rng.uniform(-2.0, 2.0, n))
    config = Stage1Config()
    fit = fit_ground(pts, config)
    assert fit.local is not None
    expected = numpy_with_local_ground(pts, fit, config.th_dist)
    assert np.count_nonzero(expected & ~fit.ground) > 100  # the local ground takes points the planes left
    np.testing.assert_array_equal(with_local_ground(pts, fit, config.th_dist), expected)
