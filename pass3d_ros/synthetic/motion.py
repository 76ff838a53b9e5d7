"""What moves in a synthetic drive, and how: the ego car's path and every road user's velocity over the drive.

A drive is one street scene (`synthetic.scene.generate_scene`) seen over `n_scans` scans 0.1 s apart. Its world frame
is the scene's own (the frame of a single synthetic frame's sensor). In it:
- the ego car drives down the middle of its lane at 5-15 m/s (drawn per drive), the way its lane's traffic goes (+u
  on the right-hand side of the road, -u on the left), its path centred on the scene's origin (scan 0 behind, the
  last scan ahead), level, the sensor MOUNT_HEIGHT_M above the road under it;
- cars, vans and trucks in the traffic lanes drive along their lane the way they face, one speed per lane (3-16 m/s
  in the others, the ego's speed in the ego's lane: no car drives through another), turned square to the road, when
  they stand within `LANE_KEEP_M` of the lane's centre line; one further off (across a lane line: a car
  `synthetic.occlusion.add_partial_views` put a hand's breadth beside the car it hides) is taken out of the drive;
  cars on a cross street drive along it (4-10 m/s);
- pedestrians, alone or in a group (people standing within `GROUP_REACH_M` of each other, with the bicycle or
  stroller one pushes), walk along the pavement or cross the street, whichever way the group's first member faces,
  at 0.8-1.7 m/s, the group turned as one to its heading; `STAND_SHARE` of the groups stand still; riders ride the
  way they face (along or across) at 2.5-6 m/s, `RIDER_STAND_SHARE` wait. Where something standing is in the way
  they go slower (a half, a quarter), or the other way (along the street: the opposite way; crossing: along it);
- everything else stands still: parked cars, riders' and pedestrians' neighbours of other kinds, all background;
  background in the traffic lanes (clutter a single frame stands beside a car there) is taken out of the drive.
Every moving thing keeps a constant velocity, its heading along it. A mover whose path would run into something
standing, or into another mover or the ego car at some scan, stands still instead (at the pose the scene placed it,
repeated until nothing collides); anything standing in the ego car's path is taken out of the drive.
Collisions are tested between footprints (oriented rectangles with a height range above the local ground) and the
world-axis boxes of the primitives in the way, every `STEP_M` of travel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import EGO_FOOTPRINT, Scene
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M

SCAN_PERIOD_S = 0.1  # 10 Hz
MAX_DRIVE_SCANS = 100  # 10 s: at 15 m/s the ego car covers 150 m; the street's buildings reach +-115 m
EGO_SPEED_MPS = (5.0, 15.0)
LANE_SPEED_MPS = (3.0, 16.0)
CROSS_SPEED_MPS = (4.0, 10.0)
WALK_SPEED_MPS = (0.8, 1.7)
RIDE_SPEED_MPS = (2.5, 6.0)
STAND_SHARE = 0.3
RIDER_STAND_SHARE = 0.1
GROUP_REACH_M = 1.6  # people whose origins stand closer than this walk together
COMPANION_REACH_M = 2.0  # a pushed bicycle or stroller goes with the nearest pedestrian this close
COMPANIONS = ("pushed_bicycle", "stroller")
STEP_M = 0.25  # collision tests every this much travel against standing things
MOVER_GAP_M = 0.1  # movers' footprints keep this apart at every scan (and half-way between scans)
STATIC_GAP_M = 0.05  # a mover's footprint from standing primitives' boxes
VEHICLE_KINDS = ("Car", "Van", "Truck")
# A vehicle drives its lane only this near the lane's centre line: the scene's traffic stands within 0.52 m of it (40
# drives' lane movers), the cars placed to hide another up to 1.75 m off; driven, they passed 0.2 m from parked cars.
LANE_KEEP_M = 0.6
EGO_CLEAR_M = 2.1  # height above the road the ego car's path is cleared to (roof and sensor head)


@dataclass
class EgoPath:
    """The ego car's straight drive down its lane: road coordinate u at time t, world pose."""

    u_start: float
    v: float
    direction: float  # +1 along the road's u axis, -1 against it
    speed: float

    def u(self, t: float) -> float:
        return self.u_start + self.direction * self.speed * t


@dataclass
class Motions:
    """Start pose and constant velocity of every scene object over a drive (world frame, metres and m/s)."""

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    velocity: np.ndarray  # (n, 2)
    removed: np.ndarray  # (n,) bool: taken out of the drive (it stood in the ego car's path)
    mode: list[str]  # per object: static, lane, cross_street, walk, cross, ride, stand, blocked, removed


def road_frame(scene: Scene) -> tuple[float, float, float]:
    """(cos, sin) of the road's heading in the world and the world origin's road v."""
    return float(scene.ground[rc.G_COS]), float(scene.ground[rc.G_SIN]), float(scene.ground[rc.G_VEGO])


def world_xy(scene: Scene, u: np.ndarray | float, v: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) of road coordinates (u, v)."""
    c, s, v0 = road_frame(scene)
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    return c * u - s * (v - v0), s * u + c * (v - v0)


def ego_path(scene: Scene, rng: np.random.Generator, n_scans: int) -> EgoPath:
    """The ego car's speed and direction (its lane's), its path centred on the world origin."""
    speed = float(rng.uniform(*EGO_SPEED_MPS))
    v = float(scene.ground[rc.G_VEGO])
    direction = 1.0 if (v < 0.0 or len(scene.lane_lines) <= 2) else -1.0
    travel = speed * SCAN_PERIOD_S * max(n_scans - 1, 0)
    return EgoPath(-direction * travel / 2, v, direction, speed)


def ego_pose(scene: Scene, path: EgoPath, t: float) -> tuple[float, np.ndarray]:
    """(yaw, position) in the world of the ego car's sensor point (MOUNT_HEIGHT_M above the road under it) at t."""
    u = path.u(t)
    x, y = world_xy(scene, u, path.v)
    z = rc.ground_height(scene.ground, scene.bumps, scene.waves, u, path.v, rc.ROAD) + MOUNT_HEIGHT_M
    c, s, _ = road_frame(scene)
    yaw = math.atan2(s, c) + (0.0 if path.direction > 0 else math.pi)
    return yaw, np.array([float(x), float(y), float(z)])


def _overlap(a: np.ndarray, b: np.ndarray, gap: float) -> np.ndarray:
    """Elementwise separating-axis test of rectangles a and b (..., 5: cx, cy, hx, hy, yaw), each grown by gap/2."""
    ca, sa, cb, sb = np.cos(a[..., 4]), np.sin(a[..., 4]), np.cos(b[..., 4]), np.sin(b[..., 4])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    hax, hay = a[..., 2] + gap / 2, a[..., 3] + gap / 2
    hbx, hby = b[..., 2] + gap / 2, b[..., 3] + gap / 2
    separated = np.zeros(np.broadcast(dx, hax).shape, dtype=bool)
    for ax, ay in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        dist = np.abs(dx * ax + dy * ay)
        ra = hax * np.abs(ca * ax + sa * ay) + hay * np.abs(-sa * ax + ca * ay)
        rb = hbx * np.abs(cb * ax + sb * ay) + hby * np.abs(-sb * ax + cb * ay)
        separated |= dist > ra + rb
    return ~separated


@dataclass
class _Body:
    """A moving footprint: start (x, y, yaw), extent lo/hi in its own frame (z above the local ground), velocity."""

    x: float
    y: float
    yaw: float
    lo: np.ndarray
    hi: np.ndarray
    velocity: np.ndarray

    def rects(self, times: np.ndarray) -> np.ndarray:
        """(T, 5) footprint rectangles at `times`."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        mx, my = 0.5 * (self.lo[0] + self.hi[0]), 0.5 * (self.lo[1] + self.hi[1])
        out = np.empty((len(times), 5))
        out[:, 0] = self.x + c * mx - s * my + self.velocity[0] * times
        out[:, 1] = self.y + s * mx + c * my + self.velocity[1] * times
        out[:, 2] = 0.5 * (self.hi[0] - self.lo[0])
        out[:, 3] = 0.5 * (self.hi[1] - self.lo[1])
        out[:, 4] = self.yaw
        return out


class _Obstacles:
    """The scene's primitives as world-axis boxes (with their height above the local ground), by object."""

    def __init__(self, scene: Scene) -> None:
        ext = scene.primitive_extents()
        self.center = scene.pcenter[:, :2]
        self.half = ext[:, :2]
        ground = scene.ground_at(scene.pcenter[:, :2])
        self.zlo = scene.pcenter[:, 2] - ext[:, 2] - ground
        self.zhi = scene.pcenter[:, 2] + ext[:, 2] - ground
        self.obj = scene.pobject
        self.radius = np.hypot(self.half[:, 0], self.half[:, 1])

    def hits(self, body: _Body, duration: float) -> set[int]:
        """Objects with a primitive in `body`'s way at some time in [0, duration] (every STEP_M of travel)."""
        speed = float(np.hypot(*body.velocity))
        n = max(2, math.ceil(speed * duration / STEP_M) + 1)
        times = np.linspace(0.0, duration, n)
        rects = body.rects(times[[0, -1]])
        a, d = rects[0, :2], rects[1, :2] - rects[0, :2]
        length2 = float(d @ d)
        rel = self.center - a
        f = np.clip(rel @ d / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(rel))
        dist = np.hypot(*(rel - f[:, None] * d).T)
        near = dist < self.radius + math.hypot(rects[0, 2], rects[0, 3]) + STATIC_GAP_M
        near &= (self.zhi > body.lo[2] + 0.05) & (self.zlo < body.hi[2])
        cand = np.flatnonzero(near)
        if len(cand) == 0:
            return set()
        boxes = np.zeros((len(cand), 5))
        boxes[:, :2], boxes[:, 2:4] = self.center[cand], self.half[cand]
        hit = _overlap(body.rects(times)[:, None, :], boxes[None, :, :], STATIC_GAP_M).any(axis=0)
        return {int(o) for o in self.obj[cand[hit]]}


def _body(scene: Scene, k: int, x: float, y: float, yaw: float, velocity: np.ndarray) -> _Body:
    o = scene.objects[k]
    base = o.z - float(scene.ground_at(np.array([[o.x, o.y]]))[0])
    lo, hi = o.local_min.copy(), o.local_max.copy()
    lo[2] += base
    hi[2] += base
    return _Body(x, y, yaw, lo, hi, np.asarray(velocity, dtype=np.float64))


def _ego_body(scene: Scene, path: EgoPath) -> _Body:
    yaw, start = ego_pose(scene, path, 0.0)
    cx, _, hx, hy = EGO_FOOTPRINT[:4]
    lo = np.array([cx - hx, -hy, 0.0])
    hi = np.array([cx + hx, hy, EGO_CLEAR_M])
    return _Body(float(start[0]), float(start[1]), yaw, lo, hi, path.speed * np.array([math.cos(yaw), math.sin(yaw)]))


def _units(scene: Scene) -> list[list[int]]:
    """Groups of people (pedestrians and riders within GROUP_REACH_M of each other) with what they push."""
    people = [k for k, o in enumerate(scene.objects) if o.label in (PEDESTRIAN, CYCLIST)]
    parent = {k: k for k in people}

    def find(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    xy = np.array([[scene.objects[k].x, scene.objects[k].y] for k in people]).reshape(-1, 2)
    for i in range(len(people)):
        for j in range(i + 1, len(people)):
            if np.hypot(*(xy[i] - xy[j])) < GROUP_REACH_M:
                parent[find(people[j])] = find(people[i])
    groups: dict[int, list[int]] = {}
    for k in people:
        groups.setdefault(find(k), []).append(k)
    walkers = [k for k in people if scene.objects[k].label == PEDESTRIAN]
    for k, o in enumerate(scene.objects):
        if o.model in COMPANIONS and walkers:
            dist = [math.hypot(o.x - scene.objects[w].x, o.y - scene.objects[w].y) for w in walkers]
            w = walkers[int(np.argmin(dist))]
            if min(dist) < COMPANION_REACH_M:
                groups[find(w)].append(k)
    return sorted(groups.values())


def _walking(scene: Scene, unit: list[int]) -> bool:
    return any(scene.objects[k].label == PEDESTRIAN for k in unit)


def _turned(scene: Scene, unit: list[int], lead: int, heading: float,
            speed: float) -> dict[int, tuple[float, float, float, np.ndarray]]:
    """(x, y, yaw, velocity) of every member of a group turned as one about its lead to `heading`."""
    o = scene.objects[lead]
    turn = heading - o.yaw
    ct, st = math.cos(turn), math.sin(turn)
    velocity = speed * np.array([math.cos(heading), math.sin(heading)])
    out = {}
    for k in unit:
        m = scene.objects[k]
        dx, dy = m.x - o.x, m.y - o.y
        out[k] = (o.x + ct * dx - st * dy, o.y + st * dx + ct * dy, m.yaw + turn, velocity)
    return out


def plan_motions(scene: Scene, rng: np.random.Generator, path: EgoPath, n_scans: int) -> Motions:
    """Velocities of the scene's road users over a drive of `n_scans` scans (see the module's notes)."""
    n = len(scene.objects)
    c, s, _ = road_frame(scene)
    road_yaw = math.atan2(s, c)
    x = np.array([o.x for o in scene.objects])
    y = np.array([o.y for o in scene.objects])
    yaw = np.array([o.yaw for o in scene.objects])
    velocity = np.zeros((n, 2))
    mode = ["static"] * n
    uv = scene.to_road(np.stack([x, y], axis=1)) if n else np.zeros((0, 2))
    lines = scene.lane_lines
    lanes, lane_edge = len(lines) - 1, float(np.abs(lines).max()) if len(lines) else 0.0
    lane_width = 2 * lane_edge / max(lanes, 1)
    ego_lane = int(np.clip((path.v + lane_edge) // lane_width, 0, lanes - 1))
    lane_speed = rng.uniform(*LANE_SPEED_MPS, size=max(lanes, 1))
    lane_speed[ego_lane] = path.speed
    units: list[list[int]] = []
    astray = np.zeros(n, dtype=bool)  # vehicles across a lane line: out of the drive, as background in the lanes
    for k, o in enumerate(scene.objects):  # vehicles
        if o.kind not in VEHICLE_KINDS:
            continue
        rel = o.yaw - road_yaw
        if abs(uv[k, 1]) < lane_edge and abs(math.sin(rel)) < 0.3:
            if _lane_offset(uv[k, 1], lane_edge, lane_width) > LANE_KEEP_M:
                astray[k] = True
                continue
            heading = road_yaw + (0.0 if math.cos(rel) > 0 else math.pi)
            speed = lane_speed[int(np.clip((uv[k, 1] + lane_edge) // lane_width, 0, lanes - 1))]
            mode[k] = "lane"
        elif (o.kind == "Car" and scene.ground[rc.G_CROSS] > 0.5 and abs(math.cos(rel)) < 0.3
              and abs(uv[k, 0] - scene.ground[rc.G_XC]) < scene.ground[rc.G_WC]):
            heading = road_yaw + math.copysign(math.pi / 2, math.sin(rel))
            speed = float(rng.uniform(*CROSS_SPEED_MPS))
            mode[k] = "cross_street"
        else:
            continue
        yaw[k] = heading
        velocity[k] = speed * np.array([math.cos(heading), math.sin(heading)])
        units.append([k])
    in_lanes = np.array([not o.boxed and abs(v) < lane_edge for o, v in zip(scene.objects, uv[:, 1], strict=True)],
                        dtype=bool) | astray
    groups = _units(scene)
    people = [unit for unit in groups if rng.random() >= (STAND_SHARE if _walking(scene, unit) else RIDER_STAND_SHARE)]
    for unit in groups:
        if unit not in people:
            for k in unit:
                mode[k] = "stand"
    obstacles = _Obstacles(scene)
    fixed = ~in_lanes  # what stands still whatever the others do
    for unit in units + people:
        fixed[unit] = False
    duration = SCAN_PERIOD_S * max(n_scans - 1, 0)
    for unit in people:
        lead = next(k for k in unit if scene.objects[k].label in (PEDESTRIAN, CYCLIST))
        walking = _walking(scene, unit)
        rel = yaw[lead] - road_yaw
        along = abs(math.cos(rel)) >= abs(math.sin(rel))
        forward = road_yaw + (0.0 if math.cos(rel) > 0 else math.pi)
        across = road_yaw + math.copysign(math.pi / 2, math.sin(rel))
        speed = float(rng.uniform(*(WALK_SPEED_MPS if walking else RIDE_SPEED_MPS)))
        # The way it faces first; then slower, the other way, along the pavement: the first way nothing stands in.
        options = [(forward, "walk"), (forward + math.pi, "walk")] if along else [(across, "cross"), (forward, "walk")]
        tries = [(h, what, f) for h, what in options for f in (1.0, 0.5, 0.25)]
        for heading, what_try, factor in tries:
            what = what_try
            turned = _turned(scene, unit, lead, heading, speed * factor)
            if not any(fixed[h] for k in unit for h in obstacles.hits(_body(scene, k, *turned[k]), duration)
                       if h not in unit):
                break
        for k in unit:
            x[k], y[k], yaw[k], velocity[k] = *turned[k][:3], turned[k][3]
            mode[k] = what if walking else "ride"
        units.append(unit)
    removed = _resolve(scene, obstacles, path, n_scans, units, x, y, yaw, velocity, mode, in_lanes)
    return Motions(x, y, yaw, velocity, removed, mode)


def _lane_offset(v: float, lane_edge: float, lane_width: float) -> float:
    """How far road coordinate v lies from the centre line of the lane it is in (lanes `lane_width` wide from
    -`lane_edge`)."""
    return abs((v + lane_edge) % lane_width - 0.5 * lane_width)


def _resolve(scene: Scene, obstacles: _Obstacles, path: EgoPath, n_scans: int, units: list[list[int]],
             x: np.ndarray, y: np.ndarray, yaw: np.ndarray, velocity: np.ndarray, mode: list[str],
             in_lanes: np.ndarray) -> np.ndarray:
    """Stop the movers that would collide (back to their placed pose), take what stands in the ego car's way or
    (`in_lanes`) in the traffic lanes out of the drive; `x`, `y`, `yaw`, `velocity` and `mode` are updated in place.
    Returns the removed mask."""
    n = len(scene.objects)
    duration = SCAN_PERIOD_S * max(n_scans - 1, 0)
    ego = _ego_body(scene, path)
    in_ego_path = obstacles.hits(ego, duration)
    bodies = {k: _body(scene, k, x[k], y[k], yaw[k], velocity[k]) for unit in units for k in unit}
    hits = [set().union(*(obstacles.hits(bodies[k], duration) for k in unit)) - set(unit) for unit in units]
    times = np.arange(0.0, duration + 1e-9, SCAN_PERIOD_S / 2)
    rects = [np.stack([bodies[k].rects(times) for k in unit], axis=1) for unit in units]  # (T, members, 5)
    ego_rects = ego.rects(times)[:, None, :]

    def clash(a: np.ndarray, b: np.ndarray) -> bool:
        return bool(_overlap(a[:, :, None, :], b[:, None, :, :], MOVER_GAP_M).any())

    conflict = np.zeros((len(units), len(units)), dtype=bool)
    hits_ego = np.array([clash(r, ego_rects) for r in rects], dtype=bool)
    for i in range(len(units)):
        for j in range(i + 1, len(units)):
            lo_i, hi_i = rects[i][..., :2].min(axis=(0, 1)) - 6.0, rects[i][..., :2].max(axis=(0, 1)) + 6.0
            lo_j, hi_j = rects[j][..., :2].min(axis=(0, 1)), rects[j][..., :2].max(axis=(0, 1))
            if np.all(lo_j < hi_i) and np.all(lo_i < hi_j):
                conflict[i, j] = conflict[j, i] = clash(rects[i], rects[j])
    moving = np.ones(len(units), dtype=bool)
    mover = np.zeros(n, dtype=bool)
    for unit in units:
        mover[unit] = True
    removed = in_lanes.copy()
    removed[[k for k in in_ego_path if not mover[k]]] = True
    standing = ~mover & ~removed
    changed = True
    while changed:
        changed = False
        for i, unit in enumerate(units):
            if not moving[i]:
                continue
            if hits_ego[i] or conflict[i, moving].any() or any(standing[k] for k in hits[i]):
                moving[i] = False
                changed = True
                for k in unit:  # back where the scene placed it
                    o = scene.objects[k]
                    x[k], y[k], yaw[k] = o.x, o.y, o.yaw
                    velocity[k] = 0.0
                    mode[k] = "blocked"
                    gone = k in in_ego_path
                    removed[k], standing[k] = gone, not gone
    for k in np.flatnonzero(removed):
        mode[k] = "removed"
    return removed
