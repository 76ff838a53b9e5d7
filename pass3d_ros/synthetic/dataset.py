"""Synthetic KITTI-like scans with exact labels: `generate_frame(seed, index)` and the `synthetic:` reader.

A frame is one HDL-64E revolution ray-cast into a random street scene: points in firing order (ring after
ring, top laser first), per-point labels, instance ids, ground mask and ring, one box per car, van, truck,
pedestrian and cyclist that has points (instance id = the box's position in the list, foreground only), and
a 10 Hz stamp. Everything is drawn from SeedSequence([seed, index]), so a (seed, index) pair always gives the
same bytes. Spec: `synthetic:frames=N,seed=S[,start=K][,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG]
[,without=CHANGE+CHANGE]` yields frames K .. K+N-1 of seed S, generated on the fly (`height`: the sensor mounted H m
above the road instead of its model's; `without`: WORLD_CHANGES left out, for an ablation).

`roll` and `pitch` tilt the mount (REP-103: positive pitch points the sensor's x axis down, roll=180 is upside down):
the lasers are turned by the mount before they are cast, so a tilted sensor sees the road where a real one would, and
the points come back in the sensor's own frame (turned back by the mount), rings and point order the sensor's. The
per-point labels, ground and instances are those of the same points; Frame.boxes stay in the LEVEL frame at the
sensor's origin (z up, the road about `height` below; Box3D has a yaw only), not turned with the points. A spec without
roll or pitch gives the same bytes as before they existed. Another sensor
(`generate_frame(seed, index, sensor_model("vlp16"))`, names in
sensor.SENSOR_NAMES) scans the same scenes from the same mount height (unless its model says otherwise) and gives
its points in its ROS 2 driver's order (ring 0 still the top laser, intensity still in [0, 1]).

`synthetic:drive=N,seed=S[,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG]` is a drive instead: one street seen over N
scans 0.1 s apart while the ego car and the road users move, with persistent instance ids and Frame.pose
(`synthetic.drive`, `synthetic.motion`).

Mixed pixels (a return between the two surfaces of a depth edge) follow KITTI's box labels: one inside a car,
pedestrian or cyclist box takes that class and instance, any other is background (SemanticKITTI would give it the
nearer surface's class; the box rule is the one the paper's KITTI labels use). Intensity: see materials.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.data.frame import Box3D, Frame
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import Scene, SceneObject
from pass3d_ros.synthetic.materials import (
    DARK_CELL_EDGE_M,
    DARK_CELL_M,
    DARK_CELL_SHARE,
    DARK_RHO,
    GROUND_DARK_SHARE,
    M_CABIN,
    M_FENCE,
    POROUS_MATERIALS,
    dark_cells,
    darken,
)
from pass3d_ros.synthetic.scene import SCENE_CHANGES, generate_scene
from pass3d_ros.synthetic.sensor import (
    HDL64E,
    MOUNT_HEIGHT_M,
    LidarModel,
    driver_order,
    measured_intensity,
    ray_grid,
    return_probability,
    sensor_model,
    signal_to_noise,
)

# World changes an ablation can leave out (`synthetic:...,without=clutter+dark`): see generate_scene, simulate_scan.
WORLD_CHANGES: tuple[str, ...] = (*SCENE_CHANGES, "dark", "mixed_pixels")

FRAME_PERIOD_NS = 100_000_000  # 10 Hz
BOX_MARGIN_M = 0.02  # a box reaches at least this far beyond its object's outermost point
FOLIAGE_DEPTH_M = 0.25  # mean depth a ray reaches into foliage before it returns
GLASS_DROPOUT = 0.45  # side windows: share of rays with no return
FENCE_DROPOUT = 0.5  # mesh fences: share of rays that find a hole
MAX_ATTEMPTS = 8  # scenes redrawn when a ring would miss the +x axis (its start could not be recovered)
LANE_MARK_HALF_WIDTH = 0.07
# Mixed pixels: a beam that straddles a depth edge returns a range in between. Share of edges given one, fitted so
# that mixed_pixel_share() of generated scans matches the real HDL-64E scans (see mixed_pixel_share).
MIXED_EDGE_SHARE = 0.05
EDGE_JUMP_M = 1.0  # a depth edge: neighbouring beams of a ring differ by more than this (and 10 % of the range)
DEFAULT_SENSOR = HDL64E()
HEIGHT_RANGE_M = (0.3, 4.0)  # mount heights a spec's height= accepts: a small robot's deck to a truck's roof
MOUNT_ANGLE_RANGE_DEG = (-180.0, 180.0)  # roll= and pitch= of a spec (degrees, REP-103)


@dataclass
class Scan:
    """Per-point arrays of one simulated revolution, before they become a Frame."""

    points: np.ndarray
    ring: np.ndarray
    labels: np.ndarray
    ground: np.ndarray
    instance: np.ndarray
    boxes: list[Box3D]
    column: np.ndarray | None = None  # firing (column) of every point in the revolution


@dataclass
class Surfaces:
    """A drive's surfaces, the same in all its scans: the primitives' reflectivities (dark parts drawn once), the dark
    cells' salt, and the world-from-scan rotation and translation the cells are keyed in (so a dark patch of road or
    wall stays where it is while the sensor moves)."""

    prho: np.ndarray
    salt: int
    rotation: np.ndarray
    translation: np.ndarray


def _object_spheres(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Bounding sphere (centre, radius) of every object, from its primitives' world-axis extents."""
    ext = scene.primitive_extents()
    first = np.array([o.first for o in scene.objects], dtype=np.int64)
    lo = np.minimum.reduceat(scene.pcenter - ext, first, axis=0)
    hi = np.maximum.reduceat(scene.pcenter + ext, first, axis=0)
    return 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=1) + 1e-6


def cast_scene(scene: Scene, origins: np.ndarray, dirs: np.ndarray, max_range: float) -> tuple[np.ndarray, ...]:
    """First hits of the rays in the scene: (t, t_exit, hit, normal, region), see raycast.cast_rays."""
    center, radius = _object_spheres(scene)
    bin_start, bin_items = rc.azimuth_bins(center, radius)
    first = np.array([o.first for o in scene.objects], dtype=np.int32)
    count = np.array([o.count for o in scene.objects], dtype=np.int32)
    return rc.cast_rays(origins, dirs, max_range, scene.ground, scene.bumps, scene.waves, scene.ptype, scene.prot,
                        scene.pcenter, scene.psize, first, count, center, radius, bin_start, bin_items)


def _surface(scene: Scene, hit: np.ndarray, region: np.ndarray, xyz: np.ndarray,
             prho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(material, reflectivity) of every hit (primitives: `prho`); ground from the region and the lane markings."""
    on_prim = hit >= 0
    prim = np.where(on_prim, hit, 0)
    material = np.where(on_prim, scene.pmaterial[prim], -1).astype(np.int16)
    rho = np.where(on_prim, prho[prim], 0.0)
    ground_rho = np.array([0.0, scene.road_rho, scene.walk_rho, scene.terrain_rho])
    rho = np.where(on_prim, rho, ground_rho[region])
    road = region == rc.ROAD
    if road.any() and len(scene.lane_lines):
        uv = scene.to_road(xyz[road, :2])
        near_line = np.min(np.abs(uv[:, 1:2] - scene.lane_lines[None, :]), axis=1) < LANE_MARK_HALF_WIDTH
        outer = np.abs(np.abs(uv[:, 1]) - np.abs(scene.lane_lines).max()) < LANE_MARK_HALF_WIDTH
        dashed = (np.mod(uv[:, 0], 9.0) < 3.0) | outer
        rho[np.flatnonzero(road)[near_line & dashed]] = 0.6
        for u0, u1, v0, v1 in scene.dark_patches:
            inside = (uv[:, 0] >= u0) & (uv[:, 0] < u1) & (uv[:, 1] >= v0) & (uv[:, 1] < v1)
            rho[np.flatnonzero(road)[inside]] = 0.01
    return material, rho


def simulate_scan(scene: Scene, rng: np.random.Generator, sensor: HDL64E = DEFAULT_SENSOR,
                  without: frozenset[str] = frozenset(), surfaces: Surfaces | None = None,
                  ids: np.ndarray | None = None) -> Scan:
    """Cast one revolution into `scene` and turn the hits into noisy, labelled points in firing order.

    `without` leaves world changes out, for an ablation: "dark" (darkened parts and dark cells: every surface
    reads its material's reflectivity), "mixed_pixels" (no return inside a depth edge). A drive passes its fixed
    `surfaces` (else dark parts and cells are drawn from `rng`) and the instance id of every scene object (`ids`,
    see `_label`).
    """
    origins, dirs, ring, column = ray_grid(sensor, rng)
    lift = sensor.mount_height_m - MOUNT_HEIGHT_M  # scenes are built for a sensor MOUNT_HEIGHT_M above the road
    if lift:
        origins[:, 2] += lift
    t, t_exit, hit, normal, region = cast_scene(scene, origins, dirs, sensor.max_range_m)
    n = len(t)
    u_keep, u_glass, u_zero = rng.random(n), rng.random(n), rng.random(n)
    noise_r, noise_i, depth = rng.standard_normal(n), rng.standard_normal(n), rng.exponential(FOLIAGE_DEPTH_M, n)
    has_hit = hit != rc.NO_HIT
    t_hit = np.where(has_hit, t, 0.0)
    xyz = origins + t_hit[:, None] * dirs
    dark = "dark" not in without
    if dark:
        prho = darken(scene.prho, scene.pmaterial, scene.pobject, rng) if surfaces is None else surfaces.prho
    else:
        prho = scene.prho
    material, rho = _surface(scene, hit, region, xyz, prho)
    if dark:
        share = np.where(hit == rc.GROUND_HIT, GROUND_DARK_SHARE[region], DARK_CELL_SHARE[material])
        share[~has_hit] = 0.0
        xyz_world = xyz if surfaces is None else xyz @ surfaces.rotation.T + surfaces.translation
        xyz_cell = np.where((hit == rc.GROUND_HIT)[:, None], xyz_world * [1.0, 1.0, 0.0], xyz_world)
        edge = np.where(hit == rc.GROUND_HIT, DARK_CELL_M, DARK_CELL_EDGE_M[material])
        salt = int(rng.integers(2**31)) if surfaces is None else surfaces.salt
        rho = np.where(dark_cells(xyz_cell, share, salt, edge), 0.5 * DARK_RHO, rho)
    cos_inc = np.abs(np.einsum("ij,ij->i", normal, dirs))
    foliage = np.isin(material, POROUS_MATERIALS)
    t_hit = np.where(foliage, t_hit + np.minimum(depth, np.maximum(t_exit - t_hit, 0.0)), t_hit)
    cos_inc = np.where(foliage, 0.2 + 0.8 * u_glass, cos_inc)
    cos_inc = np.where(region == rc.TERRAIN, 0.3 + 0.7 * cos_inc, cos_inc)  # grass is rough: never quite grazing
    glass = (material == M_CABIN) & (np.abs(normal[:, 2]) < 0.6)
    snr = signal_to_noise(sensor, rho + 0.05, cos_inc, t_hit)
    keep = has_hit & (u_keep < return_probability(sensor, snr, t_hit))
    keep &= ~(glass & (u_glass < GLASS_DROPOUT))
    keep &= ~((material == M_FENCE) & (u_glass < FENCE_DROPOUT))
    if sensor.ray_drop > 0.0:
        keep &= rng.random(n) >= sensor.ray_drop
    idx = np.flatnonzero(keep)
    sigma = sensor.range_noise_m
    t_noisy = t_hit[idx] + np.clip(noise_r[idx] * sigma, -3 * sigma, 3 * sigma)
    mixed = np.zeros(0, np.int64)
    if "mixed_pixels" not in without:
        mixed, mixed_t = _mixed_pixels(t_noisy, ring[idx], rng)
        t_noisy[mixed] = mixed_t
    rho_read = np.where(glass[idx], 0.0, rho[idx])
    points = np.empty((len(idx), 4), dtype=np.float32)
    points[:, :3] = origins[idx] + t_noisy[:, None] * dirs[idx]
    points[:, 3] = measured_intensity(sensor, rho_read, cos_inc[idx], ring[idx], snr[idx], noise_i[idx], u_zero[idx],
                                      t_noisy)
    hit_kept = hit[idx]
    hit_kept[mixed] = rc.NO_HIT
    scan = _label(scene, points, ring[idx], hit_kept, ids)
    scan.column = column[idx]
    return scan


def _mixed_pixels(t: np.ndarray, ring: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(indices, new ranges) of mixed pixels: at MIXED_EDGE_SHARE of the depth edges between neighbouring returns
    of a ring, the farther return reads a range inside the gap (20-80 % of the way), as a beam whose footprint
    straddles the edge does."""
    near, far = t[:-1], t[1:]
    same = ring[:-1] == ring[1:]
    gap = np.abs(far - near)
    edge = np.flatnonzero(same & (gap > EDGE_JUMP_M) & (gap > 0.1 * np.minimum(near, far)))
    edge = edge[rng.random(len(edge)) < MIXED_EDGE_SHARE]
    far_idx = np.where(t[edge] > t[edge + 1], edge, edge + 1)
    near_t = np.minimum(t[edge], t[edge + 1])
    new_t = near_t + rng.uniform(0.2, 0.8, len(edge)) * (t[far_idx] - near_t)
    return far_idx, new_t


def mixed_pixel_share(points: np.ndarray, ring: np.ndarray) -> float:
    """Share of a scan's depth edges with a point in between: over triples of neighbouring points of a ring whose
    outer two differ by more than EDGE_JUMP_M (and 10 %), the share whose middle point lies inside the gap, at
    least a quarter of it from either side."""
    r = np.linalg.norm(np.asarray(points)[:, :3], axis=1)
    ring = np.asarray(ring)
    a, m, b = r[:-2], r[1:-1], r[2:]
    same = (ring[:-2] == ring[1:-1]) & (ring[1:-1] == ring[2:])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    edge = same & (hi - lo > EDGE_JUMP_M) & (hi - lo > 0.1 * lo)
    inside = (m > lo + 0.25 * (hi - lo)) & (m < hi - 0.25 * (hi - lo))
    return float(np.count_nonzero(edge & inside) / max(np.count_nonzero(edge), 1))


def _label(scene: Scene, points: np.ndarray, ring: np.ndarray, hit: np.ndarray, ids: np.ndarray | None = None) -> Scan:
    """Exact labels, ground, instances and boxes for the kept points (hit: primitive index, GROUND_HIT, or NO_HIT
    for a mixed pixel: not ground, background unless it lies in a foreground box, which it then belongs to).
    A box's instance id is its position in the list, or with `ids` its object's entry there (a drive's ids, the same
    in every scan)."""
    ground = hit == rc.GROUND_HIT
    obj = np.where(hit < 0, -1, scene.pobject[np.maximum(hit, 0)])
    obj_label = np.array([o.label for o in scene.objects] + [BACKGROUND], dtype=np.uint8)
    labels = obj_label[obj]
    instance = np.full(len(points), -1, dtype=np.int32)
    boxes: list[Box3D] = []
    counts = np.bincount(obj[obj >= 0], minlength=len(scene.objects))
    order = np.argsort(obj, kind="stable")
    starts = np.searchsorted(obj[order], np.arange(len(scene.objects)))
    for k, o in enumerate(scene.objects):
        if not o.boxed or counts[k] == 0:
            continue
        members = order[starts[k]:starts[k] + counts[k]]
        box = _fit_box(o, points[members, :3], len(boxes) if ids is None else int(ids[k]))
        if o.label != BACKGROUND:
            instance[members] = box.instance
        boxes.append(box)
    mixed = np.flatnonzero(hit == rc.NO_HIT)
    for box in boxes:  # box labels, as KITTI's: a mixed pixel inside a foreground box takes its class
        if box.label != BACKGROUND and len(mixed):
            inside = mixed[box.contains(points[mixed, :3])]
            labels[inside], instance[inside] = box.label, box.instance
    return Scan(points, ring.astype(np.uint16), labels, ground, instance, boxes)


def _fit_box(o: SceneObject, xyz: np.ndarray, instance: int) -> Box3D:
    """The object's box (its shape's extent, on the ground), grown where needed to hold all its noisy points."""
    c, s = np.cos(o.yaw), np.sin(o.yaw)
    d = xyz.astype(np.float64) - np.array([o.x, o.y, o.z])
    local = np.stack([d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c, d[:, 2]], axis=1)
    lo = np.minimum(o.local_min, local.min(axis=0) - BOX_MARGIN_M)
    hi = np.maximum(o.local_max, local.max(axis=0) + BOX_MARGIN_M)
    mid = 0.5 * (lo + hi)
    center = np.array([o.x + c * mid[0] - s * mid[1], o.y + s * mid[0] + c * mid[1], o.z + mid[2]])
    box = Box3D(center=center, size=hi - lo, yaw=float(o.yaw), label=o.label, instance=instance, kind=o.kind)
    if not box.contains(xyz).all():  # rounding at the faces: widen by a millimetre
        box.size = box.size + 2e-3
    return box


def rings_recoverable(points: np.ndarray, ring: np.ndarray, n_lasers: int) -> bool:
    """Every ring has points, starts in quadrant 1 and ends in quadrant 4 (so the +x crossing marks it)."""
    if len(ring) == 0:
        return False
    bounds = np.flatnonzero(np.diff(ring.astype(np.int64))) + 1
    firsts = np.concatenate([[0], bounds])
    lasts = np.concatenate([bounds - 1, [len(ring) - 1]])
    if len(firsts) != n_lasers:
        return False
    x, y = points[:, 0], points[:, 1]
    return bool(np.all((x[firsts] > 0) & (y[firsts] >= 0)) and np.all((x[lasts] > 0) & (y[lasts] < 0)))


def _usable(scan: Scan, sensor: LidarModel) -> bool:
    """Every ring has points (and, in KITTI's order, can be recovered from the azimuth wrap in the sensor's frame)."""
    if sensor.point_order == "kitti":
        rotation = sensor.mount_rotation()
        points = scan.points if rotation is None else scan.points[:, :3].astype(np.float64) @ rotation
        return rings_recoverable(points, scan.ring, sensor.n_lasers)
    return len(np.unique(scan.ring)) == sensor.n_lasers


def to_sensor_frame(scan: Scan, sensor: LidarModel) -> Scan:
    """Points in the driver's order, lowered into the sensor's frame when it is not mounted MOUNT_HEIGHT_M up, and
    turned back by the mount's rotation (the rays were cast turned by it); boxes are lowered, not turned: they stay
    in the level frame at the sensor's origin."""
    order = driver_order(sensor, scan.ring, scan.column)
    if order is not None:
        scan = Scan(scan.points[order], scan.ring[order], scan.labels[order], scan.ground[order],
                    scan.instance[order], scan.boxes, scan.column[order])
    lift = sensor.mount_height_m - MOUNT_HEIGHT_M
    if lift:
        scan.points[:, 2] -= np.float32(lift)
        for box in scan.boxes:
            box.center = box.center - np.array([0.0, 0.0, lift])
    rotation = sensor.mount_rotation()
    if rotation is not None:  # level -> sensor: R^T p, for row vectors p @ R
        scan.points[:, :3] = (scan.points[:, :3].astype(np.float64) @ rotation).astype(np.float32)
    return scan


def unknown_changes(without: frozenset[str]) -> str:
    """Why `without` cannot be applied (names outside WORLD_CHANGES), "" when it can."""
    unknown = sorted(set(without) - set(WORLD_CHANGES))
    return f"unknown world change(s) {', '.join(unknown)}; known: {', '.join(WORLD_CHANGES)}" if unknown else ""


def generate_frame(seed: int, index: int, sensor: LidarModel | str = DEFAULT_SENSOR,
                   without: frozenset[str] = frozenset()) -> Frame:
    """Frame `index` of the synthetic sequence `seed` seen by `sensor` (a model or a name of SENSOR_NAMES);
    the same pair and sensor always give the same bytes. `without`: WORLD_CHANGES left out (an ablation)."""
    problem = unknown_changes(without)
    if problem:
        raise ValueError(problem)
    if seed < 0 or index < 0:
        raise ValueError(f"seed and index must not be negative, got seed={seed}, index={index}")
    if isinstance(sensor, str):
        sensor = sensor_model(sensor)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))
    for _ in range(MAX_ATTEMPTS):
        scan = simulate_scan(generate_scene(rng, without), rng, sensor, without)
        if _usable(scan, sensor):
            break
    scan = to_sensor_frame(scan, sensor)
    return Frame(name=f"{index:06d}", points=scan.points, stamp_ns=index * FRAME_PERIOD_NS, ring=scan.ring,
                 labels=scan.labels, ground=scan.ground, instance=scan.instance, boxes=scan.boxes)
