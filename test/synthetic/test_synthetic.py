"""Synthetic HDL-64E scans: firing order and rings, exact labels and boxes, determinism, readers and writers, CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, IGNORE, PEDESTRIAN
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.data.kitti_object import read_kitti_object, write_kitti_object_frame
from pass3d_ros.data.semantickitti import read_semantickitti, write_semantickitti_frame
from pass3d_ros.data.spec import DatasetError, count_frames, open_dataset
from pass3d_ros.synthetic import parts as pt
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import Scene, SceneBuilder
from pass3d_ros.synthetic.dataset import cast_scene, generate_frame, mixed_pixel_share
from pass3d_ros.synthetic.materials import M_CABIN, M_OTHER, M_TIRE, M_WALL
from pass3d_ros.synthetic.scene import generate_scene
from pass3d_ros.synthetic.sensor import HDL64E, ray_bundle

SEEDS = [(0, 0), (1, 3), (2, 5)]
KIND_LABEL = {"Car": CAR, "Van": BACKGROUND, "Truck": BACKGROUND, "Pedestrian": PEDESTRIAN, "Cyclist": CYCLIST}


@pytest.fixture(scope="module")
def seeded_frames():
    return [generate_frame(seed, index) for seed, index in SEEDS]


def wrap_rings(points: np.ndarray) -> np.ndarray:
    """Independent ring recovery: a ring starts where the firing order crosses from quadrant 4 into quadrant 1."""
    q4 = (points[:, 0] > 0) & (points[:, 1] < 0)
    q1 = (points[:, 0] > 0) & (points[:, 1] >= 0)
    starts = q4[:-1] & q1[1:]
    return np.concatenate([[0], np.cumsum(starts)])


def test_quadrant_wraps_give_exactly_64_rings_top_laser_first(seeded_frames):
    for frame in seeded_frames:
        ring = wrap_rings(frame.points)
        assert ring[-1] + 1 == 64
        np.testing.assert_array_equal(ring, frame.ring.astype(np.int64))
        r = np.hypot(frame.points[:, 0], frame.points[:, 1])
        # Each laser's points lie on a cone z = offset + r tan(elevation): fit it ring by ring.
        slope = np.array([np.polyfit(r[ring == k], frame.points[ring == k, 2], 1)[0] for k in range(64)])
        assert np.all(np.diff(slope) < 0), "elevation must fall ring by ring"
        assert math.degrees(math.atan(slope[0])) == pytest.approx(1.94, abs=0.05)
        assert math.degrees(math.atan(slope[-1])) == pytest.approx(-25.0, abs=0.05)
        azimuth = np.arctan2(frame.points[:, 1], frame.points[:, 0]) % (2 * np.pi)
        for k in (0, 31, 63):
            assert np.all(np.diff(azimuth[ring == k]) > 0), "azimuth rises within a ring"


def test_stage1_ring_recovery_agrees(seeded_frames):
    ring_module = pytest.importorskip("pass3d_ros.core.stage1.ring")
    for frame in seeded_frames:
        rings = ring_module.recover_rings(frame.points, Stage1Config())
        assert rings.source == "azimuth_wrap"
        np.testing.assert_array_equal(rings.ring, frame.ring)


def test_every_labelled_point_is_inside_its_box(seeded_frames):
    for frame in seeded_frames:
        boxes = {b.instance: b for b in frame.boxes}
        fg = frame.labels != BACKGROUND
        assert fg.any()
        assert np.all(frame.instance[fg] >= 0) and np.all(frame.instance[~fg] == -1)
        for instance in np.unique(frame.instance[fg]):
            members = frame.instance == instance
            box = boxes[int(instance)]
            assert box.label != BACKGROUND and np.all(frame.labels[members] == box.label)
            assert box.contains(frame.points[members]).all()


def test_points_inside_a_foreground_box_carry_its_label(seeded_frames):
    for frame in seeded_frames:
        for box in frame.boxes:
            assert KIND_LABEL[box.kind] == box.label
            if box.label == BACKGROUND:
                continue
            inside = box.contains(frame.points) & ~frame.ground
            assert inside.any()
            assert np.all(frame.labels[inside] == box.label)
            assert np.all(frame.instance[inside] == box.instance)


def test_boxes_stand_on_the_ground_in_instance_order(seeded_frames):
    for frame in seeded_frames:
        assert [b.instance for b in frame.boxes] == list(range(len(frame.boxes)))
        assert np.all(np.array([b.size for b in frame.boxes]) > 0.2)
        ground = frame.points[frame.ground]
        for box in frame.boxes:
            near = np.hypot(*(ground[:, :2] - box.center[:2]).T) < max(box.size[0], 3.0)
            if near.sum() > 20:
                bottom = box.center[2] - box.size[2] / 2
                assert abs(bottom - np.median(ground[near, 2])) < 0.25
    # Every kind gets boxes; a scene holds no visible cyclist about a third of the time, so look a few frames further
    # when these three happen to lack one (a fixed list, so the test stays deterministic).
    kinds = {b.kind for frame in seeded_frames for b in frame.boxes}
    for index in range(4):
        if {"Car", "Pedestrian", "Cyclist"} <= kinds:
            break
        kinds |= {b.kind for b in generate_frame(3, index).boxes}
    assert {"Car", "Pedestrian", "Cyclist"} <= kinds


def test_ground_mask_and_point_counts(seeded_frames):
    for frame in seeded_frames:
        assert 100_000 <= len(frame.points) <= 130_000
        assert 0.3 < frame.ground.mean() < 0.85
        assert np.all(frame.labels[frame.ground] == BACKGROUND)
        below = frame.points[frame.ground, 2]
        assert np.median(below) < -1.3
        assert frame.points.dtype == np.float32 and frame.ring.dtype == np.uint16
        assert frame.labels.dtype == np.uint8 and frame.instance.dtype == np.int32


def test_intensity_is_kitti_like(seeded_frames):
    for frame in seeded_frames:
        intensity = frame.points[:, 3]
        assert intensity.min() >= 0.0 and intensity.max() <= 1.0
        assert 0.15 < intensity.mean() < 0.4
        np.testing.assert_allclose(intensity * 100, np.round(intensity * 100), atol=1e-3)
    everything = np.concatenate([f.points[:, 3] for f in seeded_frames])
    assert 0.02 < np.mean(everything == 0.0) < 0.2  # KITTI: about 9% read 0 (far, grazing, dark paint)
    cars = np.concatenate([f.points[f.labels == CAR, 3] for f in seeded_frames])
    assert cars.mean() < everything.mean()


def test_same_seed_same_bytes_other_seeds_differ(seeded_frames):
    again = generate_frame(*SEEDS[0])
    first = seeded_frames[0]
    assert again.points.tobytes() == first.points.tobytes()
    for key in ("ring", "labels", "ground", "instance"):
        assert getattr(again, key).tobytes() == getattr(first, key).tobytes()
    assert [(b.center.tobytes(), b.size.tobytes(), b.yaw) for b in again.boxes] == \
        [(b.center.tobytes(), b.size.tobytes(), b.yaw) for b in first.boxes]
    other_seed = generate_frame(SEEDS[0][0] + 100, SEEDS[0][1])
    other_index = generate_frame(SEEDS[0][0], SEEDS[0][1] + 1)
    assert other_seed.points.tobytes() != first.points.tobytes()
    assert other_index.points.tobytes() != first.points.tobytes()
    assert first.stamp_ns == SEEDS[0][1] * 100_000_000 and other_index.stamp_ns - first.stamp_ns == 100_000_000


def test_synthetic_spec_reader():
    spec = "synthetic:frames=2,seed=4,start=1"
    assert count_frames(spec) == 2
    read = list(open_dataset(spec))
    assert [f.name for f in read] == ["000001", "000002"]
    assert read[1].points.tobytes() == generate_frame(4, 2).points.tobytes()
    for bad in ("synthetic:frames=x", "synthetic:color=3", "synthetic:frames=-1"):
        with pytest.raises(DatasetError):
            list(open_dataset(bad))


def test_semantickitti_round_trip(seeded_frames, tmp_path):
    frame = seeded_frames[1]
    write_semantickitti_frame(tmp_path, frame)
    (back,) = list(read_semantickitti(tmp_path))
    assert back.points.tobytes() == frame.points.tobytes()
    np.testing.assert_array_equal(back.labels, frame.labels)
    np.testing.assert_array_equal(back.ground, frame.ground)
    np.testing.assert_array_equal(back.instance, frame.instance)


def test_kitti_object_round_trip(seeded_frames, tmp_path):
    frame = seeded_frames[2]
    write_kitti_object_frame(tmp_path, frame)
    (back,) = list(read_kitti_object(tmp_path))
    assert back.points.tobytes() == frame.points.tobytes()
    assert [b.kind for b in back.boxes] == [b.kind for b in frame.boxes]
    for a, b in zip(back.boxes, frame.boxes, strict=True):
        np.testing.assert_allclose(a.center, b.center, atol=1e-9)
        np.testing.assert_allclose(a.size, b.size, atol=1e-9)
        assert abs(math.remainder(a.yaw - b.yaw, 2 * math.pi)) < 1e-9
    # KITTI object labels come from boxes (SqueezeSeg's rule) and exist only in the front view: equal to ours
    # off the ground there, unknown (IGNORE) elsewhere.
    front = back.labels != IGNORE
    assert 0 < front.sum() < len(front)
    off_ground = ~frame.ground & front
    np.testing.assert_array_equal(back.labels[off_ground], frame.labels[off_ground])
    np.testing.assert_array_equal(back.instance[~frame.ground], frame.instance[~frame.ground])


# ------------------------------------------------------------------------------------------------ ray caster
def _flat_scene(parts_at: list[tuple[list[pt.Part], float, float, float]]) -> Scene:
    """A flat road (no slope, bumps, crown or curbs in reach) with the given objects at (u, v, yaw)."""
    gp = np.zeros(rc.N_GROUND_PARAMS)
    gp[rc.G_COS], gp[rc.G_W], gp[rc.G_S], gp[rc.G_Z0] = 1.0, 500.0, 1.0, -1.73
    gp[rc.G_ZMIN], gp[rc.G_ZMAX] = -1.74, -1.72
    b = SceneBuilder(gp, np.zeros((0, 4)), np.zeros((0, 4)))
    for parts, u, v, yaw in parts_at:
        assert b.place(parts, u, v, yaw)
    return b.build(np.zeros(0), np.zeros((0, 4)), 0.3, 0.4, 0.4)


def _cast(scene: Scene, dirs: np.ndarray, origin_z: float = 0.0):
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = np.zeros_like(dirs)
    origins[:, 2] = origin_z
    return cast_scene(scene, origins, dirs, 120.0)


def test_ray_hits_are_exact_and_first():
    wall = [pt.box([0, 0, 1.0], [0.5, 2.0, 3.0], M_WALL, 0.5)]
    ball = [pt.ellipsoid([0, 0, 1.73], [0.5, 0.5, 0.5], M_OTHER, 0.5)]
    scene = _flat_scene([(wall, 20.0, 0.0, 0.0), (ball, 10.0, 0.0, 0.0)])
    t, _, hit, normal, region = _cast(scene, np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, 0.0, -0.2]]))
    assert t[0] == pytest.approx(9.5, abs=1e-9)  # the ball hides the wall behind it
    assert scene.pobject[hit[0]] == 1
    np.testing.assert_allclose(normal[0], [-1.0, 0.0, 0.0], atol=1e-9)
    assert t[1] == pytest.approx(19.5 / math.cos(math.atan(0.1)), abs=1e-9)  # beside the ball: the wall
    assert hit[2] == rc.GROUND_HIT and region[2] == rc.ROAD
    assert t[2] * math.sin(math.atan(0.2)) == pytest.approx(1.73, abs=3e-3)


def test_tube_wheel_lets_rays_through_its_hole():
    wheel = [pt.disc([0, 0, 1.73], [1, 0, 0], 0.5, 0.03, M_TIRE, 0.1, inner=0.45)]
    scene = _flat_scene([(wheel, 5.0, 0.0, 0.0)])
    t, _, hit, _, _ = _cast(scene, np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.475 / 4.97]]))
    assert hit[0] == rc.NO_HIT  # through the hub: sky
    assert hit[1] >= 0 and t[1] == pytest.approx(math.hypot(4.97, 0.475), abs=2e-3)


def test_curb_face_is_hit_and_labelled_sidewalk():
    gp = np.zeros(rc.N_GROUND_PARAMS)
    gp[rc.G_COS], gp[rc.G_W], gp[rc.G_S], gp[rc.G_CURB], gp[rc.G_Z0] = 1.0, 4.0, 3.0, 0.15, -1.73
    gp[rc.G_ZMIN], gp[rc.G_ZMAX] = -1.74, -1.5
    scene = SceneBuilder(gp, np.zeros((0, 4)), np.zeros((0, 4))).build(np.zeros(0), np.zeros((0, 4)), 0.3, 0.4, 0.4)
    slope = 1.65 / 4.0  # reaches z = -1.65 (inside the 0.15 m curb) exactly at the curb line y = 4
    t, _, hit, normal, region = _cast(scene, np.array([[0.0, 1.0, -slope]]))
    assert hit[0] == rc.GROUND_HIT and region[0] == rc.SIDEWALK
    assert t[0] * math.cos(math.atan(slope)) == pytest.approx(4.0, abs=1e-6)
    np.testing.assert_allclose(normal[0], [0.0, -1.0, 0.0], atol=1e-9)


def test_azimuth_culling_matches_brute_force():
    rng = np.random.default_rng(np.random.SeedSequence([11, 0]))
    scene = generate_scene(rng)
    origins, dirs, _ = ray_bundle(HDL64E(), rng)
    pick = np.arange(0, len(dirs), 9)
    origins, dirs = origins[pick], dirs[pick]
    binned = cast_scene(scene, origins, dirs, 120.0)
    first = np.array([o.first for o in scene.objects], dtype=np.int32)
    count = np.array([o.count for o in scene.objects], dtype=np.int32)
    everything = np.arange(len(scene.objects), dtype=np.int32)
    one_bin = np.array([0, len(everything)], dtype=np.int64)
    huge = np.full((len(everything), 3), 0.0), np.full(len(everything), 1e4)  # spheres that never cull
    brute = rc.cast_rays(origins, dirs, 120.0, scene.ground, scene.bumps, scene.waves, scene.ptype, scene.prot,
                         scene.pcenter, scene.psize, first, count, huge[0], huge[1], one_bin, everything)
    np.testing.assert_array_equal(binned[2], brute[2])
    np.testing.assert_array_equal(binned[0], brute[0])


# ------------------------------------------------------------------------------------------------ CLI
def test_cli_writes_refuses_non_empty_and_reports(tmp_path, capsys):
    from pass3d_ros.tools.simulate import main

    out = tmp_path / "seq"
    assert main(["--frames", "2", "--seed", "5", "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "velodyne").iterdir()) == ["000000.bin", "000001.bin"]
    assert len(list((out / "labels").iterdir())) == 2
    assert main(["--frames", "1", "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["--frames", "1", "--seed", "5", "--out", str(out), "--force"]) == 0
    objects = tmp_path / "object"
    assert main(["--frames", "1", "--out", str(objects), "--format", "kitti_object"]) == 0
    assert (objects / "label_2" / "000000.txt").read_text().split()[0] in KIND_LABEL
    assert main(["--frames", "1", "--out", str(objects / "calib" / "000000.txt")]) == 2
    capsys.readouterr()
    assert main(["--report", "--frames", "1", "--seed", "5", "--real", f"semantickitti:{out}"]) == 0
    report = capsys.readouterr().out
    assert "points/ring median" in report and "semantickitti:seq" in report
    with pytest.raises(SystemExit):
        main(["--frames", "1"])


# ------------------------------------------------------------------------------------------------ street clutter
CLUTTER_MODELS = {"bollard", "post", "short_pole", "bin", "trunk", "parked_bicycle", "parked_motorbike", "bench",
                  "utility_box", "wall_fragment", "hedge_fragment", "bike_rack", "mailbox"}


def _front_proposal_shares(frame) -> tuple[int, int, int]:
    """(front-view proposals, background-only ones, mixed ones: >= 10% foreground and >= 10% background)."""
    from pass3d_ros.core.stage1 import proposal_members, propose

    res = propose(frame.points, frame.ring)
    n = bg_only = mixed = 0
    for box, idx in zip(res.boxes, proposal_members(res.cluster_id, res.cluster_id2, res.n_proposals), strict=True):
        if abs(math.atan2(box.center[1], box.center[0])) > math.pi / 4:
            continue
        fg = np.mean(frame.labels[idx[~res.ground[idx]]] != BACKGROUND) if (~res.ground[idx]).any() else 0.0
        n, bg_only, mixed = n + 1, bg_only + (fg == 0), mixed + (0.1 <= fg <= 0.9)
    return n, bg_only, mixed


def test_street_clutter_kinds_appear_and_fill_front_view_proposals():
    models = set()
    for seed in range(6):
        models |= {o.model for o in generate_scene(np.random.default_rng(seed)).objects}
    assert models >= CLUTTER_MODELS
    shares = np.array([_front_proposal_shares(generate_frame(5, index)) for index in range(12)])
    n, bg_only, mixed = shares.sum(axis=0)
    # Real front views hold many background proposals (64% in the count; 62.5% on the six dev frames).
    # Without the street clutter the synthetic share was 39-45% (synthetic:frames=30,seed=5); with it 56-62% over
    # 30-60 frames, 61% on these 12. The floor sits between, with room for the scatter of 12 frames.
    assert bg_only / n > 0.5
    assert mixed > 0  # lapsed clearance: some proposals hold foreground and background together


# ------------------------------------------------------------------------------------------------ object models
def _model_extents(fn, n: int, seed: int) -> np.ndarray:
    """(n, 3) extents L x W x H of n draws of an object model."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        parts = fn(rng)
        lo = np.min([p.center - pt.part_extent(p) for p in parts], axis=0)
        hi = np.max([p.center + pt.part_extent(p) for p in parts], axis=0)
        out.append(hi - lo)
    return np.array(out)


def test_vehicle_models_follow_kitti_class_boundaries():
    from pass3d_ros.synthetic.objects.vehicles import car_parts, truck_parts, van_parts

    cars, vans, trucks = (_model_extents(fn, 1500, 3) for fn in (car_parts, van_parts, truck_parts))
    # KITTI means (Frustum-PointNets): Car 3.88 x 1.63 x 1.53, Van 5.07 x 1.90 x 2.21, Truck 10.14 x 2.59 x 3.25.
    assert 3.6 <= cars[:, 0].mean() <= 4.3 and 1.55 <= cars[:, 1].mean() <= 1.75 and 1.45 <= cars[:, 2].mean() <= 1.62
    assert cars[:, 0].std() > 0.3 and cars[:, 2].std() > 0.1
    # Car and Van overlap in height as annotators draw them: tall SUVs / minivans are cars, small vans are vans.
    assert 0.02 < np.mean(cars[:, 2] > 1.9) < 0.15
    assert np.mean(vans[:, 2] < 1.95) > 0.1
    assert 4.7 <= vans[:, 0].mean() <= 5.4 and 2.0 <= vans[:, 2].mean() <= 2.4
    assert 8.5 <= trucks[:, 0].mean() <= 11.5 and trucks[:, 2].min() > 2.5


def _extent(parts) -> np.ndarray:
    """L x W x H of one object's parts."""
    lo = np.min([p.center - pt.part_extent(p) for p in parts], axis=0)
    hi = np.max([p.center + pt.part_extent(p) for p in parts], axis=0)
    return hi - lo


def _first_draws(seeds, lo: float, hi: float, skip: int = 0) -> list[int]:
    """The seeds whose generator's draw number `skip` (0: the first) lies in [lo, hi)."""
    return [s for s in seeds if lo <= np.random.default_rng(s).random(skip + 1)[skip] < hi]


def test_trucks_include_city_buses_labelled_background():
    """A truck whose first draw lies in [0.3, 0.45) is a city bus (12 m solo, 10.5 m midi) with a window band,
    and the street labels it background as every KITTI Truck."""
    from pass3d_ros.synthetic.objects.vehicles import truck_parts
    from pass3d_ros.synthetic.street import VEHICLE_LABEL, draw_vehicle

    seeds = _first_draws(range(200), 0.3, 0.45)
    assert len(seeds) >= 20
    buses = [truck_parts(np.random.default_rng(s)) for s in seeds]
    size = np.array([_extent(parts) for parts in buses])
    assert (size[:, 0] >= 10.5).all() and (size[:, 0] <= 12.2).all()
    assert (size[:, 1] >= 2.5).all() and (size[:, 1] <= 2.55).all()
    assert (size[:, 2] >= 3.05).all() and (size[:, 2] <= 3.35).all()
    assert all(any(p.material == M_CABIN for p in parts) for parts in buses)  # the window band
    assert all(sum(p.material == M_TIRE for p in parts) == 4 for parts in buses)  # two axles
    # The street's draw: van below 0.1, truck in [0.1, 0.15), then the truck's own first draw picks the bus.
    street = [s for s in _first_draws(range(3000), 0.1, 0.15) if 0.3 <= np.random.default_rng(s).random(2)[1] < 0.45]
    assert street
    for seed in street[:5]:
        kind, parts = draw_vehicle(np.random.default_rng(seed), 0.1, 0.05)
        assert kind == "Truck" and VEHICLE_LABEL[kind] == BACKGROUND
        assert 10.5 <= _extent(parts)[0] <= 12.2 and any(p.material == M_CABIN for p in parts)


def test_box_trucks_and_semis_draw_as_before_buses():
    """Outside the bus range a truck takes the same draws, in the same order, as before buses existed (first draw:
    semi below 0.3; then length, width, height, cab length, cab height, wheel radius, cab paint, cargo box), so
    scenes without a bus are unchanged object for object."""
    from pass3d_ros.synthetic.materials import paint_rho
    from pass3d_ros.synthetic.objects.vehicles import truck_parts

    kinds = set()
    for seed in [s for s in range(60) if s not in _first_draws(range(60), 0.3, 0.45)]:
        rng, replay = np.random.default_rng(seed), np.random.default_rng(seed)
        parts = truck_parts(rng)
        semi = replay.random() < 0.3
        length = replay.uniform(12.0, 16.5) if semi else replay.uniform(6.0, 10.0)
        width, height = replay.uniform(2.35, 2.55), replay.uniform(2.9, 3.9 if semi else 3.6)
        cab_len, cab_h, wheel_r = replay.uniform(1.9, 2.4), replay.uniform(2.5, 3.1), replay.uniform(0.48, 0.53)
        rho_cab, rho_box = paint_rho(replay), replay.uniform(0.2, 0.6)
        assert rng.random() == replay.random()  # the same number of draws
        cab, cargo = parts[0], parts[1]
        assert cab.center[0] == length / 2 - cab_len / 2 and cab.size[1] == width / 2 - 0.03
        assert cab.size[2] == 0.5 * (cab_h - 0.35) and cab.rho == rho_cab
        assert cargo.size[2] == 0.5 * (height - 1.0) and cargo.rho == rho_box
        wheels = [p for p in parts if p.material == M_TIRE]
        assert len(wheels) == (8 if semi else 4 + 2 * (length > 8.0)) and all(w.size[0] == wheel_r for w in wheels)
        assert not any(p.material == M_CABIN for p in parts)
        kinds.add(semi)
    assert kinds == {True, False}


def test_people_models_have_kitti_sizes():
    from pass3d_ros.synthetic.objects.people import cyclist_parts, pedestrian_parts

    peds, cyclists = _model_extents(pedestrian_parts, 1500, 4), _model_extents(cyclist_parts, 800, 5)
    # KITTI Pedestrian 0.84 x 0.66 x 1.76 (stride and arm swing in the box), Cyclist 1.76 x 0.60 x 1.74.
    assert 1.6 <= peds[:, 2].mean() <= 1.85 and peds[:, 2].min() < 1.4  # children too
    assert peds[:, 0].mean() > 0.5 and 0.55 <= peds[:, 1].mean() <= 0.85
    assert 1.6 <= cyclists[:, 0].mean() <= 1.9 and 1.6 <= cyclists[:, 2].mean() <= 1.85


def test_scene_objects_labelled_by_kitti_rules():
    cars, vans, models = [], [], {}
    for index in range(16):
        scene = generate_scene(np.random.default_rng(np.random.SeedSequence([77, index])))
        for o in scene.objects:
            size = o.local_max - o.local_min
            if o.kind == "Car":
                cars.append(size)
            elif o.kind == "Van":
                vans.append(size)
            models.setdefault(o.model, set()).add((o.label, o.kind))
    cars, vans = np.array(cars), np.array(vans)
    assert 3.6 <= cars[:, 0].mean() <= 4.3
    assert (cars[:, 2] > 1.9).any() and (vans[:, 2] < 1.95).any()
    # Seated people (KITTI Person_sitting), pushed bicycles and strollers are background and get no box.
    for model in ("person_sitting", "pushed_bicycle", "stroller"):
        assert models.get(model, {(BACKGROUND, "")}) == {(BACKGROUND, "")}
    assert "person_sitting" in models
    assert models["Pedestrian"] == {(PEDESTRIAN, "Pedestrian")} and models["Cyclist"] == {(CYCLIST, "Cyclist")}


def test_world_changes_can_be_left_out_for_an_ablation():
    """`without=` leaves out exactly the named change: nothing by default (same bytes), the clutter objects, the
    clutter standing against foreground objects, the dark surfaces, the mixed pixels."""
    assert generate_frame(3, 1, without=frozenset()).points.tobytes() == generate_frame(3, 1).points.tobytes()
    frames = {name: next(open_dataset(f"synthetic:frames=1,seed=3,start=1,without={name}"))
              for name in ("dark", "mixed_pixels")}
    full = generate_frame(3, 1)
    dark_share = {k: float(np.mean(f.points[:, 3] < 0.02)) for k, f in (("full", full), ("dark", frames["dark"]))}
    assert dark_share["dark"] < 0.7 * dark_share["full"]
    edges = {k: mixed_pixel_share(f.points, f.ring) for k, f in (("full", full), ("mixed", frames["mixed_pixels"]))}
    assert edges["mixed"] < 0.6 * edges["full"]

    def scene(without: frozenset) -> Scene:
        return generate_scene(np.random.default_rng(np.random.SeedSequence([3, 1])), without)

    clutter_models = {"utility_box", "bike_rack", "bus_shelter", "traffic_light", "trailer"}  # none stands "beside"
    assert any(o.model in clutter_models for o in scene(frozenset()).objects)
    assert not any(o.model in clutter_models for o in scene(frozenset({"clutter"})).objects)
    touching = [o for o in scene(frozenset()).objects if o.clearance is not None and o.label == BACKGROUND]
    assert len(touching) > len([o for o in scene(frozenset({"beside"})).objects
                                if o.clearance is not None and o.label == BACKGROUND])


def test_hidden_pedestrians_stand_behind_something_and_keep_the_rest_of_the_scene():
    """Without "hidden" the scene is the same but for the pedestrians placed behind parked cars and low things
    (drawn from their own stream); each of those stands farther from the sensor than something in its line of
    sight."""
    found = 0
    later = frozenset({"groups", "lone_people"})  # placed after the hidden pedestrians
    for seed in range(6):
        full = generate_scene(np.random.default_rng(np.random.SeedSequence([seed, 4])), later)
        plain = generate_scene(np.random.default_rng(np.random.SeedSequence([seed, 4])), later | {"hidden"})
        assert [(o.model, o.x, o.y) for o in full.objects[:len(plain.objects)]] == [
            (o.model, o.x, o.y) for o in plain.objects]
        for person in full.objects[len(plain.objects):]:
            assert person.label == PEDESTRIAN
            dist, ray = np.hypot(person.x, person.y), np.arctan2(person.y, person.x)
            in_front = [o for o in plain.objects if np.hypot(o.x, o.y) < dist - 0.3
                        and abs(np.angle(np.exp(1j * (np.arctan2(o.y, o.x) - ray)))) < 0.2]
            assert in_front, (seed, person.x, person.y)
            found += 1
    assert found >= 4


def test_partial_views_put_occluders_in_front_of_cars_and_keep_the_rest_of_the_scene():
    """Without "partial" the scene is the same but for the occluders (their own stream); each stands nearer to the
    sensor than a car in its line of sight."""
    found = 0
    for seed in range(10):  # about 1.8 occluders a scene, none in some
        def scene(without: frozenset, seed: int = seed) -> Scene:
            return generate_scene(np.random.default_rng(np.random.SeedSequence([seed, 2])), without)

        later = {"hidden", "groups", "lone_people"}  # placed after the occluders
        full, plain = scene(frozenset(later)), scene(frozenset(later | {"partial"}))
        assert [(o.model, o.x, o.y) for o in full.objects[:len(plain.objects)]] == [
            (o.model, o.x, o.y) for o in plain.objects]
        cars = [o for o in plain.objects if o.label == CAR]
        for occluder in full.objects[len(plain.objects):]:
            dist, ray = np.hypot(occluder.x, occluder.y), np.arctan2(occluder.y, occluder.x)
            behind = [c for c in cars if np.hypot(c.x, c.y) > dist + 1.0
                      and abs(np.angle(np.exp(1j * (np.arctan2(c.y, c.x) - ray)))) < 0.35]
            assert behind, (seed, occluder.model, occluder.x, occluder.y)
            found += 1
    assert found >= 4


def test_hard_negatives_add_car_sized_background_and_thin_out_posts():
    """"negatives" adds barriers, planters, low hedges and car-sized bushes (background, not touching foreground)
    and leaves out part of the posts, short poles and trunks; without it the street is drawn as before."""
    new_models = {"long_planter", "jersey_barrier", "low_hedge", "car_bush"}
    with_neg, without_neg = [], []
    for seed in range(4):
        rng_seed = np.random.SeedSequence([seed, 6])
        with_neg += generate_scene(np.random.default_rng(rng_seed), frozenset({"partial"})).objects
        without_neg += generate_scene(np.random.default_rng(rng_seed), frozenset({"partial", "negatives"})).objects
    assert {o.model for o in with_neg} >= new_models
    assert not new_models & {o.model for o in without_neg}
    assert all(o.label == BACKGROUND and o.clearance is None for o in with_neg if o.model in new_models)

    def thin(objects: list) -> int:
        return sum(o.model in ("post", "short_pole", "trunk") for o in objects)

    assert thin(with_neg) < 0.75 * thin(without_neg)


def test_unknown_world_change_is_refused():
    with pytest.raises(DatasetError, match=r"unknown world change.*known: clutter, beside, hidden, partial, negatives, "
                                           r"groups, lone_people, dark, mixed_pixels"):
        list(open_dataset("synthetic:frames=1,seed=0,without=clutter+rain"))
    with pytest.raises(ValueError, match="rain"):
        generate_frame(0, 0, without=frozenset({"rain"}))
