"""Stage 1 under other point orders and sensors: firing-order fast path, camera crops, laser tables, line
recovery of a 32-laser scan, the reported fallback, and the benchmark's reordering helpers."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from helpers.scans import no_laser_lines_scan

from pass3d_ros.bench.stage1 import reorder, same_partition
from pass3d_ros.core.stage1 import Stage1Config, ground, lasers, propose, ring, scanline, synthetic_scan


def kitti_scan(root: Path) -> np.ndarray:
    """The first real KITTI object frame of the kitti_dev fixture."""
    return np.fromfile(root / "object" / "training" / "velodyne" / "000000.bin", dtype=np.float32).reshape(-1, 4)


def test_laser_tables_descend_and_have_their_laser_counts():
    counts = {"hdl64e": 64, "hdl32e": 32, "vlp16": 16, "vlp32c": 32, "os1-64": 64, "os1-128": 128, "pandar64": 64}
    for name, count in counts.items():
        elev = lasers.laser_elevations(name)
        assert len(elev) == count and np.all(np.diff(elev) < 0.0)
    with pytest.raises(ValueError, match="unknown sensor"):
        lasers.laser_elevations("hdl128")
    with pytest.raises(ValueError, match="sensor"):
        Stage1Config(sensor="hdl128")


def test_same_partition_ignores_label_names():
    assert same_partition(np.array([0, 0, 1, -1]), np.array([5, 5, 2, -1]))
    assert not same_partition(np.array([0, 0, 1, -1]), np.array([5, 2, 2, -1]))
    assert not same_partition(np.array([0, 0, 1, -1]), np.array([0, 0, 1, 1]))


def test_reorder_column_major_lists_each_column_top_down():
    pts = synthetic_scan(n_rings=8, points_per_ring=90)
    rings = np.repeat(np.arange(8), 90)
    order = reorder(pts, rings, "column")
    assert sorted(order.tolist()) == list(range(len(pts)))
    assert np.array_equal(rings[order][:8], np.arange(8))


def test_firing_order_path_unchanged_and_reported():
    pts = synthetic_scan(points_per_ring=900)
    result = propose(pts)
    assert result.ring_source == "azimuth_wrap"
    assert np.array_equal(result.ring, np.repeat(np.arange(64), 900))


def test_fallback_is_reported_when_rings_cannot_be_recovered():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-20.0, 20.0, size=(5000, 4)).astype(np.float32)
    result = ring.recover_rings(pts, Stage1Config())
    assert result.source == "elevation_bins"
    assert propose(pts).ring_source == "elevation_bins"


def test_laser_table_gives_the_table_ring_count_where_the_order_does_not():
    """A named table's lasers when the point order cannot give the rings (shuffled points); a scan in firing order
    keeps its exact rings from the order, held to the table's laser count."""
    keep = np.repeat(np.arange(64), 900) % 2 == 0
    pts = synthetic_scan(points_per_ring=900)[keep]
    truth = np.repeat(np.arange(64), 900)[keep] // 2
    in_order = ring.recover_rings(pts, Stage1Config(sensor="hdl32e"))
    assert in_order.source == "azimuth_wrap" and in_order.n_rings == 32
    np.testing.assert_array_equal(in_order.ring, truth)
    shuffled = pts[np.random.default_rng(3).permutation(len(pts))]
    result = ring.recover_rings(shuffled, Stage1Config(sensor="hdl32e"))
    assert result.source == "laser_table" and result.n_rings == 32
    assert result.ring.max() <= 31


def test_every_other_ring_scan_shuffled_recovers_32_rings():
    """A 32-laser scan (every other ring of a synthetic HDL-64E frame), shuffled: 32 lines, rings in order."""
    full = synthetic_scan(points_per_ring=900)
    truth = np.repeat(np.arange(64), 900)
    keep = truth % 2 == 0
    pts, truth = full[keep], truth[keep] // 2
    perm = np.random.default_rng(0).permutation(len(pts))
    result = ring.recover_rings(pts[perm], Stage1Config())
    assert result.source == "elevation_lines" and result.n_rings == 32
    assert np.mean(result.ring == truth[perm]) > 0.99


def test_real_camera_crop_keeps_the_full_scans_rings(kitti_dev):
    pts = kitti_scan(kitti_dev)
    full = ring.recover_rings(pts, Stage1Config())
    az = np.degrees(np.arctan2(pts[:, 1], pts[:, 0]))
    crop = (pts[:, 0] > 0.0) & (np.abs(az) < 45.0)
    cropped = ring.recover_rings(pts[crop], Stage1Config())
    assert cropped.source in ring.FIRING_ORDER_SOURCES
    for k in range(64):
        assert np.array_equal(cropped.ring[full.ring[crop] == k], np.full(np.sum(full.ring[crop] == k), k))


def test_real_scan_reordered_is_not_silently_wrong(kitti_dev):
    """Column-major and shuffled real scans never pass for firing order: their ring source says how rings were
    found."""
    pts = kitti_scan(kitti_dev)
    base = propose(pts)
    for how in ("column", "shuffled"):
        result = propose(np.ascontiguousarray(pts[reorder(pts, base.ring, how)]))
        assert result.ring_source in ("elevation_lines", "elevation_bins")


def _proposals_in_every_order(pts: np.ndarray) -> dict[str, tuple]:
    """Stage 1 of one scan in firing, column-major and shuffled order, results put back in firing order."""
    base = propose(pts)
    out = {}
    for how in ("firing", "column", "shuffled"):
        order = reorder(pts, base.ring, how)
        result = propose(np.ascontiguousarray(pts[order]))
        back = np.empty(len(pts), dtype=np.int64)
        back[order] = np.arange(len(pts))
        out[how] = (result, result.cluster_id[back], result.ring[back], result.ground[back])
    return out


def test_synthetic_scan_gives_the_same_proposals_in_any_order():
    pts = synthetic_scan(points_per_ring=900)
    runs = _proposals_in_every_order(pts)
    firing = runs["firing"]
    for how in ("column", "shuffled"):
        result, cluster_id, rings, ground = runs[how]
        assert result.ring_source == "elevation_lines"
        assert np.array_equal(rings, firing[2])
        assert np.array_equal(ground, firing[3])
        assert same_partition(cluster_id, firing[1]) and result.n_proposals == firing[0].n_proposals


def test_real_scan_gives_the_same_proposals_in_any_order(kitti_dev):
    """A real KITTI frame reordered: rings recovered from its laser lines (nearly all as in firing order), then the
    canonical order makes the ground fit and clustering read the points as in firing order."""
    runs = _proposals_in_every_order(kitti_scan(kitti_dev))
    firing = runs["firing"]
    for how in ("column", "shuffled"):
        result, cluster_id, rings, ground = runs[how]
        assert result.ring_source == "elevation_lines" and result.n_proposals == firing[0].n_proposals
        assert np.mean(rings == firing[2]) > 0.99
        assert np.mean(ground != firing[3]) < 1e-3
        assert np.mean((cluster_id >= 0) != (firing[1] >= 0)) < 1e-3


def test_two_shuffles_give_exactly_the_same_result():
    """The canonical order, the line search sample and the ground fit's sample depend on the points only: the same
    rings, ground and proposals exactly, and the same ground planes up to the order of the fit's sums (the fit reads
    the points as they come)."""
    pts = synthetic_scan(points_per_ring=900)
    base = propose(pts)
    results, labels = [], []
    for seed in (1, 2):
        order = reorder(pts, base.ring, "shuffled", seed=seed)
        result = propose(np.ascontiguousarray(pts[order]))
        back = np.empty(len(pts), dtype=np.int64)
        back[order] = np.arange(len(pts))
        results.append(result)
        labels.append((result.cluster_id[back], result.ring[back], result.ground[back]))
    assert np.array_equal(labels[0][1], labels[1][1]) and np.array_equal(labels[0][2], labels[1][2])
    assert same_partition(labels[0][0], labels[1][0])
    np.testing.assert_allclose(results[0].ground_planes, results[1].ground_planes, rtol=1e-12, atol=1e-12)


def test_canonical_order_lists_rings_then_azimuth():
    pts = synthetic_scan(n_rings=8, points_per_ring=90)
    rings = np.repeat(np.arange(8), 90).astype(np.uint16)
    perm = np.random.default_rng(3).permutation(len(pts))
    order = scanline.canonical_order(pts[perm], rings[perm])
    assert np.array_equal(np.sort(order), np.arange(len(pts)))
    assert np.array_equal(perm[order], np.arange(len(pts)))


def test_ring_field_in_any_order_gives_the_same_proposals():
    """A ring field whose points are not ring after ring (a driver's firing blocks) is read in canonical order."""
    pts = synthetic_scan(points_per_ring=900)
    rings = np.repeat(np.arange(64), 900).astype(np.uint16)
    base = propose(pts, rings)
    order = reorder(pts, rings, "column")
    result = propose(np.ascontiguousarray(pts[order]), rings[order])
    assert result.ring_source == "field"
    assert same_partition(result.cluster_id, base.cluster_id[order])
    assert np.array_equal(result.ground, base.ground[order])


@pytest.mark.parametrize("speed", [0.5, 1.0])
def test_motion_corrected_scan_recovers_its_rings(speed):
    """A scan corrected for the car's motion (origin moving `speed` metres per revolution along x, zero facing
    forward), shuffled: the motion is found and the rings come back exactly."""
    pts = synthetic_scan(points_per_ring=900)
    truth = np.repeat(np.arange(64), 900)
    pts[:, 0] += speed * np.arctan2(pts[:, 1], pts[:, 0]) / (2.0 * np.pi)
    perm = np.random.default_rng(0).permutation(len(pts))
    result = ring.recover_rings(pts[perm], Stage1Config())
    assert result.source == "elevation_lines_moving" and result.n_rings == 64
    assert np.array_equal(result.ring, truth[perm])
    vx, vy = ring.estimate_motion(ring.search_sample(pts))
    assert abs(vx - speed) < 0.05 and abs(vy) < 0.05


def test_ring_sources_are_listed():
    assert set(ring.FIRING_ORDER_SOURCES) <= set(ring.RING_SOURCES)
    for source in ("laser_table_moving", "elevation_lines_moving", "elevation_bins"):
        assert source in ring.RING_SOURCES


def test_laser_lines_of_one_scan_give_the_next_scans_rings_without_a_search(monkeypatch):
    """A stream of one sensor: the second scan, shuffled, reads its rings off the first scan's lines (no search) and
    clusters exactly as when it searches its own."""
    first = synthetic_scan(points_per_ring=900)
    second = synthetic_scan(points_per_ring=1000)
    lines = propose(np.ascontiguousarray(first[::-1])).lines
    assert lines is not None and len(lines.a) == 64
    shuffled = np.ascontiguousarray(second[np.random.default_rng(4).permutation(len(second))])
    searched = propose(shuffled)

    def no_search(*args, **kwargs):
        raise AssertionError("the line search or the firing-order count ran although the stream's lines fit")

    monkeypatch.setattr(ring, "rings_from_lines", no_search)
    monkeypatch.setattr(ring, "_ring_starts", no_search)
    streamed = propose(shuffled, lines=lines)
    assert streamed.ring_source == "elevation_lines" and streamed.lines is not None
    assert np.mean(streamed.ring == searched.ring) > 0.999
    assert same_partition(streamed.cluster_id, searched.cluster_id)


def test_held_lines_assign_half_the_points_on_the_helper_thread_with_the_same_rings():
    """Under held lines the ground thread assigns the second half of the points: the same rings and line quality as
    one thread, and the proposals as without the ground thread."""
    pts = synthetic_scan(points_per_ring=900)
    lines = propose(np.ascontiguousarray(pts[::-1])).lines
    shuffled = np.ascontiguousarray(pts[np.random.default_rng(5).permutation(len(pts))])
    tol = ring._close_tolerance(lines.a, 0.25)
    alone = ring._assign_known_lines(shuffled, lines.a, lines.b, 0.0, 0.0, tol, 5.0)
    with ThreadPoolExecutor(max_workers=1) as helper:
        halves = ring._assign_known_lines(shuffled, lines.a, lines.b, 0.0, 0.0, tol, 5.0, helper)
        submitted = []
        counting = _CountingExecutor(helper, submitted)
        ring._assign_known_lines(shuffled, lines.a, lines.b, 0.0, 0.0, tol, 5.0, counting)
    assert len(submitted) == 1 and len(shuffled) >= ring._SPLIT_POINTS
    np.testing.assert_array_equal(halves[0], alone[0])
    assert halves[1] == alone[1] > 0.97
    on_two = propose(shuffled, lines=lines)
    on_one = propose(shuffled, config=Stage1Config(ground_thread=False), lines=lines)
    np.testing.assert_array_equal(on_two.ring, on_one.ring)
    np.testing.assert_array_equal(on_two.cluster_id, on_one.cluster_id)


def test_unordered_variants_give_the_same_keys_sample_and_ground():
    """The branch-free pseudo-azimuth and ground sample for points in no scan order give the same values as the
    scan-order ones, on the axes and at the origin too."""
    pts = synthetic_scan(points_per_ring=900)
    shuffled = np.ascontiguousarray(pts[np.random.default_rng(6).permutation(len(pts))])
    corners = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [-1, -1], [2, -3], [-0.0, -0.0]], np.float32)
    for x, y in np.concatenate([corners, shuffled[:2000, :2]]):
        assert scanline.pseudo_azimuth_unordered(x, y) == scanline.pseudo_azimuth(x, y), (x, y)
    np.testing.assert_array_equal(ground._sample(shuffled, 4, False), ground._sample(shuffled, 4, True))
    config = Stage1Config()
    fast, plain = ground.fit_ground(shuffled, config, in_scan_order=False), ground.fit_ground(shuffled, config)
    np.testing.assert_array_equal(fast.ground, plain.ground)
    np.testing.assert_array_equal(fast.planes, plain.planes)


class _CountingExecutor:
    """An executor that records what is submitted to it."""

    def __init__(self, inner: ThreadPoolExecutor, log: list) -> None:
        self.inner, self.log = inner, log

    def submit(self, fn, *args):
        self.log.append(fn)
        return self.inner.submit(fn, *args)


def test_held_lines_read_a_firing_order_scan_as_its_firing_order_does():
    """Held lines are tried before the firing order: a scan that is in firing order after all gets the same rings
    and proposals from them."""
    pts = synthetic_scan(points_per_ring=900)
    lines = propose(np.ascontiguousarray(pts[::-1])).lines
    base = propose(pts)
    streamed = propose(pts, lines=lines)
    assert base.ring_source in ring.FIRING_ORDER_SOURCES and streamed.ring_source == "elevation_lines"
    assert np.mean(streamed.ring == base.ring) > 0.999
    assert same_partition(streamed.cluster_id, base.cluster_id)


def test_a_failed_line_search_is_held_and_not_repeated(monkeypatch):
    """A scan whose line search finds nothing says so (NO_LINES, rings binned by elevation); given that, the next
    scan skips the search and bins at once, with the same proposals."""
    pts = no_laser_lines_scan()
    searched = propose(pts)
    assert searched.ring_source == "elevation_bins" and searched.lines is not None and searched.lines.empty

    def no_search(*args, **kwargs):
        raise AssertionError("a line search ran although this stream's search found none")

    monkeypatch.setattr(ring, "rings_from_lines", no_search)
    assert ring.rings_from_known_lines(pts, ring.NO_LINES, "elevation_lines") is None
    held = propose(pts, lines=ring.NO_LINES)
    assert held.ring_source == "elevation_bins" and held.lines is ring.NO_LINES
    np.testing.assert_array_equal(held.ring, searched.ring)
    assert same_partition(held.cluster_id, searched.cluster_id)


def test_laser_lines_of_another_sensor_are_refused():
    """Lines that do not fit the scan (another sensor's) fail the quality check: the scan is searched instead."""
    vlp = synthetic_scan(n_rings=16, points_per_ring=900)
    wrong = propose(np.ascontiguousarray(vlp[::-1]), config=Stage1Config(n_rings=16)).lines
    assert wrong is not None and ring.standard_ring_count(len(wrong.a)) == 16
    pts = synthetic_scan(points_per_ring=900)
    shuffled = np.ascontiguousarray(pts[np.random.default_rng(5).permutation(len(pts))])
    result = propose(shuffled, lines=wrong)
    assert result.n_proposals == propose(shuffled).n_proposals
    assert result.lines is not None and len(result.lines.a) == 64


def test_real_stream_keeps_its_lines_through_motion(kitti_dev):
    """Motion-corrected real scans (SemanticKITTI): the lines of one scan, given to another whose motion differs,
    are taken under that scan's own motion, and label its rings as its firing order does."""
    root = kitti_dev / "semantickitti"
    scans = sorted(root.rglob("velodyne/*.bin"))[:2]
    assert len(scans) == 2
    first, second = (np.fromfile(p, dtype=np.float32).reshape(-1, 4) for p in scans)
    lines = propose(np.ascontiguousarray(first[::-1])).lines
    assert lines is not None
    base = propose(second)
    order = np.random.default_rng(6).permutation(len(second))
    result = propose(np.ascontiguousarray(second[order]), lines=lines._replace(motion=(0.0, 0.0)))
    assert result.ring_source == "elevation_lines_moving" and result.lines.motion != (0.0, 0.0)
    assert np.mean(result.ring == base.ring[order]) > 0.99
