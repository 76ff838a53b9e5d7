"""Stage 1 on constructed scans with known answers: rings, ground, scan-line runs, refinement, propose()."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest
from helpers.scans import SENSOR_HEIGHT, Solid, raycast
from scipy.spatial import ConvexHull

from pass3d_ros.core import stage1
from pass3d_ros.core.stage1 import Stage1Config, ground, proposal_members, propose, refinement, ring, scanline
from pass3d_ros.data.frame import Box3D

RUNS = Stage1Config(th_ring=0.5, th_prop=1.0)  # the paper's Th_ring and Th_prop, which the run tests rely on
CAR = (4.2, 1.8, 1.5)
PEDESTRIAN = (0.6, 0.6, 1.8)


def car_at(x: float, y: float, yaw: float = 0.0, slope: float = 0.0) -> Solid:
    return Solid((x, y, -SENSOR_HEIGHT + slope * x + CAR[2] / 2), CAR, yaw)


# ---------------------------------------------------------------- ring recovery


def test_rings_recovered_from_firing_order():
    points, rings, _ = raycast([car_at(10.0, 3.0)])
    result = ring.recover_rings(points, Stage1Config())
    assert result.source == "azimuth_wrap"
    assert np.array_equal(result.ring, rings)


def test_rings_recovered_on_camera_crop_in_firing_order():
    points, rings, _ = raycast([car_at(10.0, 3.0)])
    az = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    crop = (np.abs(az) < 40.0) & (points[:, 0] > 0.0)
    result = ring.recover_rings(points[crop], Stage1Config())
    assert len(np.unique(result.ring)) == 64
    assert np.array_equal(result.ring, rings[crop])


def test_rings_recovered_on_frontal_arcs_cut_behind_the_sensor():
    """Rings that are frontal arcs -40..40 degrees in firing order: no +x crossing starts them, a jump back does."""
    points, rings, _ = raycast([car_at(10.0, 3.0)])
    az = np.arctan2(points[:, 1], points[:, 0])
    order = np.lexsort((np.mod(az + np.pi, 2 * np.pi), rings))  # each ring from -180 to 180 degrees
    points, rings, az = points[order], rings[order], az[order]
    crop = np.abs(np.degrees(az)) < 40.0
    result = ring.recover_rings(points[crop], Stage1Config())
    assert result.source == "azimuth_jump"
    assert np.array_equal(result.ring, rings[crop])
    full = ring.recover_rings(points, Stage1Config())  # the whole scan cut behind: the -x crossing starts rings
    assert full.source == "azimuth_wrap" and np.array_equal(full.ring, rings)


def test_shuffled_scan_rings_come_from_laser_lines():
    points, rings, _ = raycast([])
    shuffled = np.random.default_rng(0).permutation(len(points))
    result = ring.recover_rings(points[shuffled], Stage1Config())
    assert result.source == "elevation_lines" and result.n_rings == 64
    assert result.ring.dtype == np.uint16 and result.ring.max() <= 63
    assert np.mean(result.ring == rings[shuffled]) > 0.99


def test_ring_fallback_is_reported():
    points = np.random.default_rng(0).uniform(-30.0, 30.0, size=(20000, 4)).astype(np.float32)
    result = ring.recover_rings(points, Stage1Config())
    assert result.source == "elevation_bins"
    assert result.ring.dtype == np.uint16 and result.ring.max() <= 63


def test_given_ring_field_is_used():
    points, rings, _ = raycast([car_at(10.0, 3.0)])
    result = propose(points, ring=rings.copy())
    assert result.ring_source == "field" and np.array_equal(result.ring, rings)
    assert result.ring_order.convention == "top_down"
    bottom_up = propose(points, ring=(63 - rings).astype(np.uint16))
    assert bottom_up.ring_order.convention == "bottom_up" and np.array_equal(bottom_up.ring, rings)
    with pytest.raises(ValueError, match="ring field"):
        propose(points, ring=rings[:-1])


# ---------------------------------------------------------------- ground


@pytest.mark.parametrize("slope", [0.0, 0.06])
def test_ground_found_under_boxes(slope: float):
    solids = [car_at(12.0, -4.0, 0.3, slope), car_at(-9.0, 5.0, 1.2, slope), car_at(25.0, 6.0, 0.0, slope)]
    points, _, hit = raycast(solids, slope=slope)
    fit = ground.fit_ground(points, Stage1Config())
    truth = hit == -1
    assert np.count_nonzero(fit.ground & truth) / np.count_nonzero(truth) > 0.99
    high = points[:, 2] > -SENSOR_HEIGHT + slope * points[:, 0] + 0.35  # box points above the ground band
    assert not np.any(fit.ground & (hit >= 0) & high)
    centre = fit.planes[1]
    assert abs(centre[0] / centre[2] + slope) < 0.01 and abs(centre[3] / centre[2] - SENSOR_HEIGHT) < 0.05


def test_ground_ignores_a_pit_and_reflections_below_the_road():
    points, _, hit = raycast([car_at(12.0, -4.0)])
    rng = np.random.default_rng(1)
    pit = np.column_stack([rng.uniform(4, 6, 300), rng.uniform(-8, -6, 300), rng.uniform(-3.2, -2.6, 300),
                           np.full(300, 0.5)]).astype(np.float32)
    fit = ground.fit_ground(np.concatenate([points, pit]), Stage1Config())
    truth = np.concatenate([hit == -1, np.zeros(300, dtype=bool)])
    assert np.count_nonzero(fit.ground & truth) / np.count_nonzero(truth) > 0.99
    assert abs(fit.planes[1, 3] - SENSOR_HEIGHT) < 0.05


def test_fit_stride_only_thins_the_plane_fits():
    """Every point or a quarter of them in the fits: the same ground (the final test reads every point either way),
    and planes whose heights over their own ground points differ by less than 1 cm (the planes' d is their height at
    the origin, up to 80 m from an outer segment's points, so it is not compared)."""
    points, _, _ = raycast([car_at(12.0, -4.0)])
    every = ground.fit_ground(points, Stage1Config(fit_stride=1))
    thinned = ground.fit_ground(points, Stage1Config(fit_stride=4))
    assert np.count_nonzero(every.ground != thinned.ground) < 1e-3 * len(points)
    segment = np.clip(np.searchsorted(every.segment_edges, points[:, 0]) - 1, 0, len(every.planes) - 1)
    height = [-(p[:, 0] * points[:, 0] + p[:, 1] * points[:, 1] + p[:, 3]) / p[:, 2]
              for p in (every.planes[segment], thinned.planes[segment])]
    assert np.abs(height[0] - height[1])[every.ground].max() < 0.01



@pytest.mark.parametrize("order", ["firing", "ring field", "shuffled", "shuffled ring field"])
def test_ground_thread_gives_the_same_result(order: str, monkeypatch: pytest.MonkeyPatch):
    """The ground planes are fitted on the ground thread for a scan in any order (rule P6: the final test is then
    shared) and give what the fit in line gives."""
    points, rings, _ = raycast([car_at(12.0, -4.0), Solid((8.0, 3.0, -0.83), PEDESTRIAN)])
    if order.startswith("shuffled"):
        perm = np.random.default_rng(0).permutation(len(points))
        points, rings = points[perm], rings[perm]
    ring_field = rings if order.endswith("ring field") else None
    threads: list[str] = []
    fit = ground.fit_planes

    def recording_fit(*args, **kwargs):
        threads.append(threading.current_thread().name)
        return fit(*args, **kwargs)

    monkeypatch.setattr(ground, "fit_planes", recording_fit)
    in_line = propose(points, ring_field, Stage1Config(ground_thread=False))
    assert threads == [threading.current_thread().name]
    threads.clear()
    beside = propose(points, ring_field, Stage1Config())
    assert len(threads) == 1 and threads[0].startswith("pass3d-ground")
    for key in ("ground", "cluster_id", "cluster_id2"):
        np.testing.assert_array_equal(getattr(in_line, key), getattr(beside, key))
    assert beside.n_proposals == in_line.n_proposals >= 2


def test_ground_fit_reads_the_same_points_in_any_order():
    """The LPR and plane fits read the points of every 4th azimuth sector: a shuffled scan gets the same planes (up to
    the order of the sums) and the same ground points."""
    points, _, _ = raycast([car_at(12.0, -4.0)], slope=0.03)
    perm = np.random.default_rng(3).permutation(len(points))
    fired = ground.fit_ground(points, Stage1Config())
    shuffled = ground.fit_ground(points[perm], Stage1Config())
    np.testing.assert_allclose(shuffled.planes, fired.planes, atol=1e-9)
    np.testing.assert_array_equal(shuffled.ground, fired.ground[perm])
    sample = ground._sample(points, 4)
    assert 0.2 < len(sample) / len(points) < 0.3
    np.testing.assert_array_equal(np.sort(perm[ground._sample(points[perm], 4)]), sample)


def test_plane_distance_reads_each_points_segment_and_the_end_segments_beyond():
    """The height above the ground plane that the ground mask and the gates read: the point's own segment's plane,
    the first or last segment's for x beyond the edges; `segments` gives the same segment over an array."""
    planes = np.array([[0.0, 0.0, 1.0, 1.7], [0.1, 0.0, 0.995, 1.8], [0.0, -0.05, 0.999, 1.6]])
    edges = np.array([-30.0, -10.0, 10.0, 30.0])
    xyz = np.array([[-50.0, 1.0, -1.0], [-15.0, 2.0, 0.5], [0.0, 3.0, -1.6], [12.0, -4.0, 0.2], [80.0, 0.0, 0.0]])
    want_segment = [0, 0, 1, 2, 2]
    np.testing.assert_array_equal(ground.segments(xyz[:, 0], edges, 3), want_segment)
    for (x, y, z), s in zip(xyz, want_segment, strict=True):
        a, b, c, d = planes[s]
        assert ground.plane_distance(planes, edges[0], edges[1] - edges[0], x, y, z) == a * x + b * y + c * z + d


def test_smallest_eigenvector_matches_numpy():
    rng = np.random.default_rng(2)
    for _ in range(50):
        a = rng.normal(size=(3, 3))
        cov = a @ a.T
        _, vecs = np.linalg.eigh(cov)
        assert abs(abs(ground.smallest_eigenvector(cov) @ vecs[:, 0]) - 1.0) < 1e-8


# ---------------------------------------------------------------- scan-line runs


def _arc(radius: float, z: float, y_from: float, y_to: float, step: float = 0.05) -> np.ndarray:
    """Points of one ring on a straight wall piece at x = radius between y_from and y_to."""
    y = np.arange(y_from, y_to + 1e-9, step)
    return np.column_stack([np.full_like(y, radius), y, np.full_like(y, z), np.full_like(y, 0.5)])


@pytest.mark.parametrize(("gap", "clusters"), [(0.3, 1), (0.8, 2)])
def test_runs_split_at_th_ring(gap: float, clusters: int):
    """One ring crosses two objects: a 0.3 m gap is inside Th_ring = 0.5 (one run), 0.8 m is not."""
    pts = np.concatenate([_arc(10.0, 0.0, -1.0, 0.0), _arc(10.0, 0.0, gap, gap + 1.0)]).astype(np.float32)
    label, n = scanline.cluster_scanlines(pts, np.zeros(len(pts), np.uint16), np.ones(len(pts), bool), RUNS)
    assert n == clusters
    assert len(np.unique(label)) == clusters


@pytest.mark.parametrize(("gap", "clusters"), [(0.8, 1), (1.2, 2)])
def test_previous_ring_joins_runs_within_th_prop(gap: float, clusters: int):
    """Ring 1 crosses two pieces `gap` apart, ring 0 above only the left one: the right run joins the left
    piece through ring 0 when its nearest ring-0 point is closer than Th_prop = 1.0 (0.8 m), not at 1.2 m."""
    upper = _arc(10.0, 0.0, -1.0, 0.0)
    lower = np.concatenate([_arc(10.0, -0.1, -1.0, 0.0), _arc(10.0, -0.1, gap, gap + 1.0)])
    pts = np.concatenate([upper, lower]).astype(np.float32)
    rings = np.repeat([0, 1], [len(upper), len(lower)]).astype(np.uint16)
    _, n = scanline.cluster_scanlines(pts, rings, np.ones(len(pts), bool), RUNS)
    assert n == clusters


def test_runs_merge_labels_smallest_wins_and_ring_closes():
    """A V: two upper pieces get labels 0 and 1, a lower run under both merges them; a full circle closes."""
    left = _arc(10.0, 0.0, -2.0, -1.0)
    right = _arc(10.0, 0.0, 1.0, 2.0)
    bottom = _arc(10.0, -0.1, -1.5, 1.5)
    pts = np.concatenate([left, right, bottom]).astype(np.float32)
    rings = np.repeat([0, 0, 1], [len(left), len(right), len(bottom)]).astype(np.uint16)
    label, n = scanline.cluster_scanlines(pts, rings, np.ones(len(pts), bool), RUNS)
    assert n == 1 and np.all(label == 0)
    az = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    circle = np.column_stack([5 * np.cos(az), 5 * np.sin(az), np.zeros(400), np.zeros(400)]).astype(np.float32)
    circle[150:170, :2] *= 3.0  # a break: without closing at the wrap the circle would be two runs
    label, n = scanline.cluster_scanlines(circle, np.zeros(400, np.uint16), np.ones(400, bool), RUNS)
    assert label[0] == label[-1] == label[100] and n == 2


@pytest.mark.parametrize("y_from", [0.5, -0.3])  # clear of the ring's start at azimuth 0, and across it
@pytest.mark.parametrize(("through", "run_skip", "clusters"), [(1, 0, 3), (1, 1, 2), (2, 1, 3), (2, 2, 2)])
def test_runs_bridge_points_seen_through_a_gap(through: int, run_skip: int, clusters: int, y_from: float):
    """One ring crosses a walker at 20 m, and `through` of its rays pass a gap (arm and body) to a wall 5 m behind:
    the walker's two pieces are one run when at most run_skip points lie between them; the wall points stay apart
    (they are not taken into the walker's run)."""
    walker = _arc(20.0, 0.0, y_from, y_from + 0.6, step=0.05)
    gap = np.arange(len(walker) // 2 - 1, len(walker) // 2 - 1 + through)
    wall = walker[gap].copy()
    wall[:, 0], wall[:, 1] = 25.0, walker[gap, 1] * 25.0 / 20.0  # the same rays, 5 m farther
    pts = np.concatenate([np.delete(walker, gap, axis=0), wall]).astype(np.float32)
    label, n = scanline.cluster_scanlines(pts, np.zeros(len(pts), np.uint16), np.ones(len(pts), bool),
                                          replace(RUNS, run_skip=run_skip))
    walker_labels = np.unique(label[: len(walker) - through])
    assert n == clusters
    assert len(walker_labels) == (1 if through <= run_skip else 2)
    assert not set(label[len(walker) - through:]) & set(walker_labels)


def test_clustering_uses_only_the_given_points():
    pts = _arc(10.0, 0.0, -1.0, 1.0).astype(np.float32)
    use = np.zeros(len(pts), bool)
    use[:10] = True
    label, n = scanline.cluster_scanlines(pts, np.zeros(len(pts), np.uint16), use, RUNS)
    assert n == 1 and np.all(label[:10] == 0) and np.all(label[10:] == -1)


# ---------------------------------------------------------------- refinement


def test_min_area_rectangle_recovers_rotated_rectangles():
    rng = np.random.default_rng(3)
    for _ in range(100):
        length, width = sorted(rng.uniform(0.2, 5.0, 2), reverse=True)
        yaw, centre = rng.uniform(-np.pi, np.pi), rng.uniform(-30, 30, 2)
        local = np.column_stack([rng.uniform(-length / 2, length / 2, 60), rng.uniform(-width / 2, width / 2, 60)])
        local[:4] = [[-length / 2, -width / 2], [length / 2, -width / 2], [length / 2, width / 2],
                     [-length / 2, width / 2]]
        c, s = np.cos(yaw), np.sin(yaw)
        xy = local @ np.array([[c, s], [-s, c]]) + centre
        cx, cy, got_l, got_w, got_yaw = refinement.min_area_rectangle(xy)
        assert got_l == pytest.approx(length, abs=1e-6) and got_w == pytest.approx(width, abs=1e-6)
        assert (cx, cy) == pytest.approx(tuple(centre), abs=1e-6)
        box = Box3D(np.array([cx, cy, 0.0]), np.array([got_l, got_w, 1.0]), got_yaw)
        assert box.contains(np.column_stack([xy, np.zeros(len(xy))]), margin=(1e-6, 1e-6, 0.0)).all()
    assert refinement.min_area_rectangle(np.ones((4, 2)))[2:4] == (0.0, 0.0)



def _large_clusters() -> dict[str, np.ndarray]:
    """Large clusters of the shapes stage 1 meets: a long noisy wall, a ring round the sensor, a car-sized blob with
    exact duplicates, points on a few x values, and a vertical line (one x: no inner hull)."""
    rng = np.random.default_rng(11)
    wall = np.column_stack([rng.uniform(-12.0, 12.0, 30000), 4.0 + rng.normal(0.0, 0.4, 30000)])
    angle = rng.uniform(0.0, 2.0 * np.pi, 20000)
    radius = rng.uniform(8.0, 9.0, 20000)
    blob = rng.normal(0.0, 1.0, (5000, 2)) * [2.0, 0.8]
    blob[::5] = blob[1::5][: len(blob[::5])]
    columns = np.column_stack([rng.integers(0, 4, 4000) * 0.5, rng.uniform(-2.0, 2.0, 4000)])
    line = np.column_stack([np.full(3000, 3.0), rng.uniform(-5.0, 5.0, 3000)])
    shapes = {"wall": wall, "ring": np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]),
              "blob": blob, "columns": columns, "line": line}
    return {name: xy.astype(np.float32).astype(np.float64) for name, xy in shapes.items()}


@pytest.mark.parametrize("shape", ["wall", "ring", "blob", "columns", "line"])
def test_binned_candidates_keep_every_hull_vertex_and_the_rectangle(shape: str):
    """A large cluster's binned inner-hull filter keeps every vertex of its convex hull, so its rectangle is the one
    the hull's vertices alone give (the octagon's path, under BINNED_MIN_POINTS points), bit for bit."""
    xy = _large_clusters()[shape]
    assert len(xy) >= refinement.BINNED_MIN_POINTS
    x, y = xy[:, 0].copy(), xy[:, 1].copy()
    kept = refinement._binned_candidates(x, y)
    if shape != "line":
        hull = ConvexHull(xy).vertices
        assert np.isin(hull, kept).all()
        if shape in ("wall", "blob"):
            assert len(kept) < len(xy) // 4  # the filter is worth its pass
        assert refinement._min_area_rect(x, y) == refinement._min_area_rect(x[np.sort(hull)], y[np.sort(hull)])
    assert refinement._min_area_rect(x, y) == refinement._min_area_rect(x[kept], y[kept])


def test_hull_order_is_argsorts_permutation_for_large_clusters():
    """The radix-sorted hull order equals np.argsort of the chain's key where no key is shared by different points
    (shared by duplicates: the same points, in any order); where one is, argsort itself orders them."""
    rng = np.random.default_rng(5)
    xy = rng.normal(0.0, 20.0, (5000, 2)).astype(np.float32).astype(np.float64)
    xy[::7] = xy[1::7][: len(xy[::7])]  # exact duplicates
    xy[3, 0] = -0.0
    key = xy[:, 0] + 1e-9 * xy[:, 1]
    order = refinement._hull_order(xy[:, 0].copy(), xy[:, 1].copy())
    assert np.array_equal(key[order], np.sort(key)) and np.array_equal(xy[order], xy[np.argsort(key)])
    assert np.array_equal(refinement._radix_argsort(key), np.argsort(key, kind="stable"))
    tied = xy.copy()
    tied[10] = [1.0, 0.0]
    tied[11] = [1.0 - 1e-9 * 2.0 ** -20, 2.0 ** -20]  # another point with the same key: argsort's order is kept
    key = tied[:, 0] + 1e-9 * tied[:, 1]
    assert key[10] == key[11]
    assert np.array_equal(key[refinement._hull_order(tied[:, 0].copy(), tied[:, 1].copy())], np.sort(key))
    assert len(xy) >= refinement.RADIX_MIN_POINTS  # the radix path was the one tested


# ---------------------------------------------------------------- propose()


@pytest.mark.parametrize("slope", [0.0, 0.05])
def test_propose_finds_each_object_once(slope: float):
    solids = [car_at(10.0, -4.0, 0.4, slope), car_at(-12.0, 6.0, -1.0, slope), car_at(20.0, 8.0, 0.0, slope),
              Solid((7.0, 5.0, -SENSOR_HEIGHT + slope * 7.0 + 0.9), PEDESTRIAN)]
    points, _, hit = raycast(solids, slope=slope)
    result = propose(points)
    assert result.ring_source == "azimuth_wrap"
    assert len(result.boxes) == len(solids)
    truth = hit == -1
    assert np.count_nonzero(result.ground & truth) / np.count_nonzero(truth) > 0.99
    covered = (result.cluster_id >= 0) | (result.cluster_id2 >= 0)
    for index, solid in enumerate(solids):
        mine = hit == index
        assert covered[mine].all(), f"object {index} not fully covered"
        ids = np.unique(result.cluster_id[mine & ~result.ground])
        assert len(ids) == 1  # one proposal per object
        box = result.boxes[ids[0]]  # minimal area: a car seen as an L may get a tighter, turned rectangle
        assert box.size[0] * box.size[1] <= solid.size[0] * solid.size[1] + 0.1
        assert box.size[0] >= 0.5 * solid.size[0] and box.size[2] <= solid.size[2]
        assert np.hypot(*(box.center[:2] - solid.center[:2])) < 1.0
    assert set(result.timings_ms) == set(stage1.STEPS)
    assert result.cluster_id.dtype == np.int32 and result.ring.dtype == np.uint16


def test_pedestrian_beside_wall_kept_wall_rejected():
    wall = Solid((12.0, 6.0, -SENSOR_HEIGHT + 1.5), (14.0, 0.3, 3.0))
    person = Solid((12.0, 4.45, -SENSOR_HEIGHT + 0.9), PEDESTRIAN)  # 1.3 m from the wall face
    points, _, hit = raycast([wall, person])
    result = propose(points)
    covered = (result.cluster_id >= 0) | (result.cluster_id2 >= 0)
    assert covered[hit == 1].all()
    assert covered[hit == 0].mean() < 0.05  # only the wall foot next to the person's enlarged box, if any
    assert len(result.boxes) == 1 and result.boxes[0].size[0] < 1.0


def test_enlarged_boxes_take_ground_points_and_overlap():
    """A person inside a U-shaped object (opening to the sensor), more than Th_prop from it: two proposals;
    the U's rectangle covers the person, whose points then carry both ids; the feet in the ground band join."""
    z = -SENSOR_HEIGHT + 1.1
    side_left = Solid((11.6, 1.5, z), (3.2, 0.2, 2.2))
    side_right = Solid((11.6, -1.5, z), (3.2, 0.2, 2.2))
    back = Solid((13.1, 0.0, z), (0.2, 3.2, 2.2))  # taller than the person: seen above its head, one piece
    person = Solid((11.4, 0.0, -SENSOR_HEIGHT + 0.9), PEDESTRIAN)
    points, _, hit = raycast([side_left, side_right, back, person], n_az=2400)
    hit = np.where(hit == 3, 2, np.where(hit >= 0, 0, hit))  # 0: the U, 2: the person
    result = propose(points)
    assert len(result.boxes) == 2
    own = np.unique(result.cluster_id[(hit == 2) & ~result.ground])
    assert len(own) == 1
    members = proposal_members(result.cluster_id, result.cluster_id2)
    person_points = np.flatnonzero(hit == 2)
    assert np.isin(person_points, members[own[0]]).all()
    assert np.isin(person_points, members[1 - own[0]]).all()  # inside the U's rectangle as well
    body = (hit == 2) & ~result.ground
    assert np.all(result.cluster_id[body] == own[0]) and np.all(result.cluster_id2[body] == 1 - own[0])
    feet = (hit == 2) & result.ground  # in no cluster: both boxes, the lower id first
    assert feet.any() and np.all(result.cluster_id[feet] == 0) and np.all(result.cluster_id2[feet] == 1)
    for k, box in enumerate(result.boxes):
        inside = box.contains(points[:, :3].astype(np.float64), margin=Stage1Config().enlarge)
        assert np.array_equal(np.flatnonzero(inside), members[k])


def test_proposal_members_from_the_two_fields():
    cid = np.array([0, 0, 1, -1, 2, 1], dtype=np.int32)
    cid2 = np.array([-1, 1, -1, 2, -1, 0], dtype=np.int32)
    members = proposal_members(cid, cid2)
    assert [m.tolist() for m in members] == [[0, 1, 5], [1, 2, 5], [3, 4]]
    assert [m.tolist() for m in proposal_members(cid, cid2, n_proposals=4)][3] == []
    assert proposal_members(np.full(3, -1), np.full(3, -1)) == []
    with pytest.raises(ValueError):
        proposal_members(cid, cid2[:-1])
    with pytest.raises(ValueError):
        proposal_members(cid, cid2, n_proposals=2)


@pytest.mark.parametrize("seed", range(4))
def test_proposal_members_match_a_sort_of_the_id_pairs(seed: int):
    """The counting sort gives what sorting (proposal id, point index) pairs gives: each proposal's points
    ascending, a point listed once per field that names the proposal (twice when both do)."""
    rng = np.random.default_rng(seed)
    n, k = 5000, 40
    first = np.where(rng.random(n) < 0.6, -1, rng.integers(0, k, n)).astype(np.int32)
    second = np.where(rng.random(n) < 0.9, -1, rng.integers(0, k, n)).astype(np.int32)
    second[:20] = first[:20]
    ids = np.concatenate([first, second]).astype(np.int64)
    index = np.concatenate([np.arange(n), np.arange(n)])
    keep = ids >= 0
    pairs = sorted(zip(ids[keep].tolist(), index[keep].tolist(), strict=True))
    expected = [[i for p, i in pairs if p == j] for j in range(k + 3)]
    members = proposal_members(first, second, n_proposals=k + 3)
    assert [m.tolist() for m in members] == expected


def test_size_gates_reject_what_is_not_a_road_user():
    solids = [Solid((25.0, 0.0, -SENSOR_HEIGHT + 4.0), (3.0, 3.0, 8.0)),  # a tower: too tall (seen to 2.6 m)
              Solid((-10.0, 8.0, -SENSOR_HEIGHT + 1.0), (12.0, 3.0, 2.0)),  # a bus-sized block: too long
              Solid((6.0, -8.0, -SENSOR_HEIGHT + 0.45), (1.0, 1.0, 0.2)),  # a flat slab in the ground band
              car_at(-6.0, -7.0)]
    points, _, hit = raycast(solids)
    result = propose(points)
    assert len(result.boxes) == 1
    assert np.all(result.cluster_id[hit == 3] >= 0)


def test_non_finite_points_take_no_part():
    points, rings, hit = raycast([car_at(10.0, -4.0)])
    clean = propose(points)
    holes = points.copy()
    holes[::7, 0] = np.nan
    holes[3::11, 2] = np.inf
    bad = ~np.isfinite(holes[:, :3]).all(axis=1)
    result = propose(holes, ring=rings)
    assert np.all(result.cluster_id[bad] == -1) and not result.ground[bad].any()
    assert len(result.boxes) == len(clean.boxes) == 1
    assert np.all(result.cluster_id[(hit == 0) & ~bad] == 0)
    assert np.array_equal(result.ring[~bad], rings[~bad])


def test_empty_and_tiny_scans():
    empty = propose(np.zeros((0, 4), np.float32))
    assert empty.boxes == [] and len(empty.cluster_id) == 0
    tiny = propose(np.array([[5.0, 0.0, -1.7, 0.5], [5.0, 0.1, -1.7, 0.5]], np.float32))
    assert tiny.boxes == [] and tiny.ground.all()
    with pytest.raises(ValueError):
        propose(np.zeros((5, 2), np.float32))


def test_config_checks_and_mapping():
    with pytest.raises(ValueError, match="th_dist"):
        Stage1Config(th_dist=-1.0)
    with pytest.raises(ValueError, match="unknown"):
        Stage1Config.from_mapping({"th_distance": 0.2})
    config = Stage1Config.from_mapping({"th_dist": 0.25, "enlarge": [0.2, 0.2, 0.5]})
    assert config.enlarge == (0.2, 0.2, 0.5) and config.to_dict()["th_dist"] == 0.25
    defaults = Stage1Config()
    paper = (defaults.n_seg, defaults.n_iter, defaults.n_lpr, defaults.th_seeds, defaults.th_dist,
             defaults.th_ring, defaults.th_prop, defaults.enlarge)
    assert paper == (3, 3, 20, 0.4, 0.3, 0.5, 1.0, (0.1, 0.1, 0.4))
    with pytest.raises(ValueError, match="fit_stride"):
        Stage1Config(fit_stride=0)


def test_warm_up_and_synthetic_scan_run():
    stage1.warm_up()
    result = propose(stage1.synthetic_scan())
    assert result.ring_source == "azimuth_wrap" and len(result.boxes) == 1


def test_effective_values_are_reported():
    """Every result names the resolution its scan showed and the th_num / th_prop it ran with; a scan half as dense
    as the HDL-64E in both directions runs with a quarter of the paper's th_num, and switching the scaling off
    gives the paper's values."""
    result = propose(stage1.synthetic_scan(n_rings=64, points_per_ring=2000))
    assert result.sensor is not None and result.sensor.density == 1.0 and result.sensor.th_num_near == 30.0
    sparse = stage1.synthetic_scan(n_rings=32, points_per_ring=1000)
    result = propose(sparse, config=Stage1Config(n_rings=32))
    assert result.sensor is not None and result.sensor.n_rings == 32
    assert 0.15 < result.sensor.density < 0.35 and result.sensor.th_num_near < 10.0
    plain = propose(sparse, config=Stage1Config(n_rings=32, sensor_scaling=False))
    assert plain.sensor is not None and plain.sensor.density == 1.0 and plain.sensor.th_num_near == 30.0
