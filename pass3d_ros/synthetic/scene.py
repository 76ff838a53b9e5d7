"""Random KITTI-like street scenes built from ray-castable primitives.

A scene is a road (lanes, parking lanes, crown, gentle slope changes and bumps, optionally a cross street)
with curbs, sidewalks and terrain, lined with buildings, walls, fences, hedges, trees, bushes, poles and
signs, and populated with parked and moving cars, vans, trucks, pedestrians (alone and in groups) and
cyclists. Objects are built in their own frame (x forward, z up from the ground contact) and placed on the
ground; foreground objects keep a clearance from everything else, so their boxes hold no foreign points,
while still standing close to each other, to walls and under trees (the hard cases PASS3D names).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M

# Materials: how a surface reflects (used by the dataset's intensity and dropout model).
(M_BUILDING, M_WALL, M_FENCE, M_VEGETATION, M_TRUNK, M_POLE, M_SIGN, M_PAINT, M_CABIN, M_TIRE, M_CLOTH,
 M_SKIN, M_METAL, M_OTHER) = range(14)
POROUS_MATERIALS = (M_VEGETATION,)  # rays reach some way into foliage before they return
FOREGROUND_GAP_M = 0.25  # clearance between a foreground object's footprint and anything else (> 2 x noise bound)
U_MAX = 130.0  # farthest road coordinate a ray can reach the ground at (bounds the slope term)
# The ego car (a VW Passat under the sensor) as a footprint nothing may overlap: cx, cy, hx, hy, yaw, z range.
EGO_FOOTPRINT = (-0.3, 0.0, 2.45, 0.95, 0.0, -MOUNT_HEIGHT_M, 0.0, 1.0, 0.0)


@dataclass
class Part:
    """One primitive in its object's frame: rows of `rot` are the primitive's axes."""

    ptype: int
    center: np.ndarray
    rot: np.ndarray
    size: np.ndarray  # 6 values, see raycast
    material: int
    rho: float


@dataclass
class SceneObject:
    """A placed object: pose, class, primitive range and extents in its own frame."""

    label: int
    kind: str
    x: float
    y: float
    z: float
    yaw: float
    first: int = 0
    count: int = 0
    local_min: np.ndarray = field(default_factory=lambda: np.zeros(3))
    local_max: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def boxed(self) -> bool:
        """Whether the object gets a box (cars, vans, trucks, pedestrians, cyclists)."""
        return bool(self.kind)


@dataclass
class Scene:
    """Everything the ray caster and the labeller need: ground parameters, primitives, objects."""

    ground: np.ndarray
    bumps: np.ndarray
    waves: np.ndarray
    ptype: np.ndarray
    prot: np.ndarray
    pcenter: np.ndarray
    psize: np.ndarray
    pmaterial: np.ndarray
    prho: np.ndarray
    pobject: np.ndarray
    objects: list[SceneObject]
    lane_lines: np.ndarray  # v of painted lines on the road
    dark_patches: np.ndarray  # (K, 4) u0, u1, v0, v1 of dark asphalt repairs on the road
    road_rho: float
    walk_rho: float
    terrain_rho: float

    def ground_at(self, xy: np.ndarray) -> np.ndarray:
        """Ground height under sensor-frame points (N x 2)."""
        return rc.ground_height_at(self.ground, self.bumps, self.waves, np.ascontiguousarray(xy, dtype=np.float64))

    def to_road(self, xy: np.ndarray) -> np.ndarray:
        """Road coordinates (u along, v across) of sensor-frame points (N x 2)."""
        c, s = self.ground[rc.G_COS], self.ground[rc.G_SIN]
        u = c * xy[:, 0] + s * xy[:, 1]
        v = -s * xy[:, 0] + c * xy[:, 1] + self.ground[rc.G_VEGO]
        return np.stack([u, v], axis=1)


# ----------------------------------------------------------------------------------------------- geometry
def rot_z(yaw: float) -> np.ndarray:
    """Rotation matrix about z (object -> world)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation matrix about y."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def axis_frame(axis: np.ndarray) -> np.ndarray:
    """Rows: an orthonormal frame whose third row is `axis` (the local z of a cylinder)."""
    z = np.asarray(axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def box(center, half, material: int, rho: float, rot: np.ndarray | None = None,
        rounding: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Part:
    """Oriented box; `rounding` > 0 intersects it with an ellipsoid that many half-extents wide."""
    return Part(rc.BOX, np.asarray(center, float), np.eye(3) if rot is None else rot,
                np.array([*half, *rounding], dtype=float), material, rho)


def ellipsoid(center, semi, material: int, rho: float, rot: np.ndarray | None = None) -> Part:
    """Ellipsoid with semi-axes `semi` along its rows of `rot`."""
    return Part(rc.ELLIPSOID, np.asarray(center, float), np.eye(3) if rot is None else rot,
                np.array([*semi, 0.0, 0.0, 0.0], dtype=float), material, rho)


def cylinder(p: np.ndarray, q: np.ndarray, radius: float, material: int, rho: float, inner: float = 0.0) -> Part:
    """Cylinder (tube if `inner` > 0) from point p to point q."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    half = 0.5 * float(np.linalg.norm(q - p))
    return Part(rc.CYLINDER, 0.5 * (p + q), axis_frame(q - p),
                np.array([radius, radius, half, inner, 0.0, 0.0]), material, rho)


def disc(center, axis, radius: float, half_width: float, material: int, rho: float, inner: float = 0.0) -> Part:
    """Short cylinder (wheel, round sign) centred at `center` around `axis`."""
    return Part(rc.CYLINDER, np.asarray(center, float), axis_frame(np.asarray(axis, float)),
                np.array([radius, radius, half_width, inner, 0.0, 0.0]), material, rho)


def part_extent(part: Part) -> np.ndarray:
    """Half extent of a part along the axes of the frame it is given in."""
    m = part.rot
    a, b, c = part.size[:3]
    if part.ptype == rc.BOX:
        return np.abs(m.T) @ np.array([a, b, c])
    if part.ptype == rc.ELLIPSOID:
        return np.sqrt((m.T ** 2) @ np.array([a * a, b * b, c * c]))
    axis = m[2]
    return np.abs(axis) * c + a * np.sqrt(np.clip(1.0 - axis * axis, 0.0, 1.0))


# ----------------------------------------------------------------------------------------------- materials
def paint_rho(rng: np.random.Generator) -> float:
    """Car paint reflectivity: many dark cars (KITTI car points are often intensity 0), some bright."""
    kind = rng.random()
    if kind < 0.45:
        return float(rng.uniform(0.0, 0.01))
    if kind < 0.85:
        return float(rng.uniform(0.15, 0.5))
    return float(rng.uniform(0.4, 0.7))


def cloth_rho(rng: np.random.Generator) -> float:
    """Clothing reflectivity: anything from dark to bright."""
    return float(rng.uniform(0.05, 0.55))


# ----------------------------------------------------------------------------------------------- objects
WHEEL_ROT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # cylinder axis along object y


def _wheels(xs: list[float], half_track: float, radius: float, rho: float, width: float = 0.1) -> list[Part]:
    return [Part(rc.CYLINDER, np.array([x, side * half_track, radius]), WHEEL_ROT,
                 np.array([radius, radius, width, 0.0, 0.0, 0.0]), M_TIRE, rho)
            for x in xs for side in (1.0, -1.0)]


def car_parts(rng: np.random.Generator) -> list[Part]:
    """Passenger car: rounded body, rounded cabin (glass sides, painted roof), four wheels; varied styles."""
    style = rng.choice(4, p=[0.4, 0.25, 0.15, 0.2])  # sedan, hatchback, wagon, SUV
    if style == 3:
        length, width, height = rng.uniform(4.1, 4.9), rng.uniform(1.75, 1.95), rng.uniform(1.6, 1.85)
        clearance, wheel_r = rng.uniform(0.2, 0.27), rng.uniform(0.34, 0.38)
    else:
        length = rng.uniform(3.6, 4.2) if style == 1 else rng.uniform(4.2, 4.9)
        width, height = rng.uniform(1.6, 1.85), rng.uniform(1.38, 1.58)
        clearance, wheel_r = rng.uniform(0.13, 0.2), rng.uniform(0.29, 0.34)
    rho = paint_rho(rng)
    body_top = clearance + (height - clearance) * rng.uniform(0.48, 0.56)
    cabin_len = length * (0.5, 0.56, 0.64, 0.62)[style] * rng.uniform(0.95, 1.05)
    rear_gap = (None, 0.2, 0.12, 0.15)[style]
    cabin_x = -0.06 * length if rear_gap is None else -(length / 2 - cabin_len / 2 - rear_gap)
    cabin_bottom = body_top - 0.06
    parts = [
        box([0.0, 0.0, 0.5 * (clearance + body_top)], [length / 2, width / 2, 0.5 * (body_top - clearance)],
            M_PAINT, rho, rounding=(1.12, 1.6, 2.6)),
        # Centred on the belt line: the rounding ellipsoid then gives a domed roof and sloped pillars.
        box([cabin_x, 0.0, cabin_bottom], [cabin_len / 2, 0.46 * width, height - cabin_bottom],
            M_CABIN, rho, rounding=(rng.uniform(1.1, 1.2), 1.3, rng.uniform(1.12, 1.22))),
    ]
    axle = length / 2 - rng.uniform(0.72, 0.95)
    parts += _wheels([axle, -axle], width / 2 - 0.13, wheel_r, float(rng.uniform(0.02, 0.08)))
    plate_z = clearance + 0.35 * (body_top - clearance)
    parts += [box([end * (length / 2 + 0.005), 0.0, plate_z], [0.012, 0.26, 0.06], M_SIGN, 0.95) for end in (1.0, -1.0)]
    return parts


def van_parts(rng: np.random.Generator) -> list[Part]:
    """Van: tall rounded box with a short bonnet, four wheels (background class, KITTI 'Van')."""
    length, width, height = rng.uniform(4.5, 5.5), rng.uniform(1.85, 2.05), rng.uniform(1.95, 2.5)
    clearance, wheel_r = rng.uniform(0.18, 0.25), rng.uniform(0.32, 0.36)
    rho = paint_rho(rng)
    nose = rng.uniform(0.6, 1.0)
    parts = [
        box([-nose / 2, 0.0, 0.5 * (clearance + height)], [(length - nose) / 2, width / 2, 0.5 * (height - clearance)],
            M_PAINT, rho, rounding=(1.08, 1.25, 1.35)),
        box([length / 2 - nose / 2 - 0.05, 0.0, clearance + 0.45], [nose / 2 + 0.05, width / 2 - 0.03, 0.45],
            M_PAINT, rho, rounding=(1.2, 1.4, 1.6)),
    ]
    axle = length / 2 - rng.uniform(0.75, 0.95)
    parts += _wheels([axle, -axle + 0.1], width / 2 - 0.14, wheel_r, 0.05)
    return parts


def truck_parts(rng: np.random.Generator) -> list[Part]:
    """Truck: cab and cargo box, two or three axles (background class, KITTI 'Truck')."""
    length, width, height = rng.uniform(6.5, 10.0), rng.uniform(2.3, 2.5), rng.uniform(2.9, 3.6)
    cab_len, cab_h, clearance, wheel_r = rng.uniform(1.9, 2.3), rng.uniform(2.5, 2.9), 0.35, rng.uniform(0.48, 0.53)
    rho_cab, rho_box = paint_rho(rng), float(rng.uniform(0.2, 0.6))
    cargo_len = length - cab_len - 0.15
    parts = [
        box([length / 2 - cab_len / 2, 0.0, 0.5 * (clearance + cab_h)],
            [cab_len / 2, width / 2 - 0.03, 0.5 * (cab_h - clearance)], M_PAINT, rho_cab, rounding=(1.15, 1.3, 1.4)),
        box([-length / 2 + cargo_len / 2, 0.0, 0.5 * (0.9 + height)], [cargo_len / 2, width / 2, 0.5 * (height - 0.9)],
            M_PAINT, rho_box),
        box([-length / 2 + cargo_len / 2, 0.0, 0.7], [cargo_len / 2 - 0.3, width / 2 - 0.3, 0.2], M_METAL, 0.1),
    ]
    front = length / 2 - 1.1
    axles = [front, -length / 2 + 1.3] + ([-length / 2 + 2.5] if length > 8.0 else [])
    parts += _wheels(axles, width / 2 - 0.25, wheel_r, 0.04, width=0.25)
    return parts


def pedestrian_parts(rng: np.random.Generator) -> list[Part]:
    """Pedestrian: legs, pelvis, torso, arms and head, walking or standing, child or adult, maybe a backpack."""
    height = rng.uniform(1.05, 1.4) if rng.random() < 0.1 else float(np.clip(rng.normal(1.72, 0.09), 1.5, 1.95))
    s = height / 1.75
    stride = rng.uniform(0.12, 0.42) * math.sin(rng.uniform(0, 2 * math.pi)) if rng.random() < 0.7 else 0.0
    leg_len = 0.5 * height
    hip_z = leg_len * math.cos(abs(stride)) + 0.01
    shoulder_z = hip_z + 0.3 * height
    girth = rng.uniform(0.85, 1.2)
    rho_legs, rho_top = cloth_rho(rng), cloth_rho(rng)
    parts = []
    for side, angle in ((1.0, stride), (-1.0, -stride)):
        hip = np.array([0.0, side * 0.09 * s, hip_z])
        foot = hip + leg_len * np.array([math.sin(angle), 0.0, -math.cos(angle)])
        parts.append(cylinder(hip, foot, 0.065 * s * girth, M_CLOTH, rho_legs))
    parts.append(ellipsoid([0.0, 0.0, hip_z], [0.1 * s * girth, 0.17 * s * girth, 0.1 * s], M_CLOTH, rho_legs))
    lean = rng.uniform(-0.05, 0.12)
    torso_half = 0.5 * (shoulder_z - hip_z) + 0.04 * s
    torso_c = np.array([math.sin(lean) * torso_half, 0.0, 0.5 * (hip_z + shoulder_z) + 0.02])
    parts.append(ellipsoid(torso_c, [0.12 * s * girth, 0.2 * s * girth, torso_half], M_CLOTH, rho_top, rot_y(-lean)))
    arm_len = 0.42 * height
    for side, angle in ((1.0, -0.8 * stride), (-1.0, 0.8 * stride)):
        shoulder = np.array([math.sin(lean) * 0.3 * height, side * (0.2 * girth + 0.04) * s, shoulder_z - 0.03])
        spread = rng.uniform(0.04, 0.15)
        hand = shoulder + arm_len * np.array([math.sin(angle), side * math.sin(spread), -math.cos(angle)])
        parts.append(cylinder(shoulder, hand, 0.045 * s, M_CLOTH, rho_top))
    head_c = np.array([math.sin(lean) * 0.35 * height, 0.0, shoulder_z + 0.17 * s])
    parts.append(ellipsoid(head_c, [0.1 * s, 0.08 * s, 0.115 * s], M_SKIN, float(rng.uniform(0.1, 0.5))))
    if rng.random() < 0.25:
        parts.append(box(torso_c + np.array([-0.12 * s * girth - 0.07, 0.0, 0.05]), [0.08, 0.15 * s, 0.2 * s],
                         M_CLOTH, cloth_rho(rng), rounding=(1.3, 1.3, 1.3)))
    return parts


def _shift(p: np.ndarray, dx: float, dy: float, dz: float) -> np.ndarray:
    return p + np.array([dx, dy, dz])


def _knee(hip: np.ndarray, foot: np.ndarray, thigh: float, shin: float) -> np.ndarray:
    """Knee of a two-link leg in its x-z plane, bent forward."""
    d = foot - hip
    dist = float(np.linalg.norm(d))
    if dist >= thigh + shin - 1e-6:
        return hip + d * (thigh / (thigh + shin))
    along = (thigh * thigh - shin * shin + dist * dist) / (2 * dist)
    up = math.sqrt(max(thigh * thigh - along * along, 0.0))
    unit = d / dist
    perp = np.array([-unit[2], 0.0, unit[0]])  # in the x-z plane
    if perp[0] < 0:
        perp = -perp
    return hip + unit * along + perp * up


def cyclist_parts(rng: np.random.Generator) -> list[Part]:
    """Cyclist: bicycle (tube wheels, frame, handlebar) and a rider leaning on it, pedals at a random phase."""
    s = rng.uniform(0.92, 1.08)
    wheel_r, base = rng.uniform(0.32, 0.36), rng.uniform(1.0, 1.12)
    rho_bike, rho_tire = float(rng.uniform(0.1, 0.55)), float(rng.uniform(0.02, 0.1))
    rear, front = np.array([-base / 2, 0.0, wheel_r]), np.array([base / 2, 0.0, wheel_r])
    bb = np.array([-base / 2 + 0.43, 0.0, 0.3])
    saddle = bb + np.array([-0.2, 0.0, 0.55 * s + 0.05])
    head_tube = np.array([base / 2 - 0.12, 0.0, 0.55 * s + 0.28])
    bar = head_tube + np.array([-0.05, 0.0, rng.uniform(0.08, 0.2)])
    parts = [
        disc(rear, [0, 1, 0], wheel_r, 0.025, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        disc(front, [0, 1, 0], wheel_r, 0.025, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        cylinder(bb, saddle, 0.02, M_METAL, rho_bike),
        cylinder(bb, head_tube, 0.025, M_METAL, rho_bike),
        cylinder(saddle, head_tube, 0.02, M_METAL, rho_bike),
        cylinder(bb, rear, 0.015, M_METAL, rho_bike),
        cylinder(saddle, rear, 0.015, M_METAL, rho_bike),
        cylinder(_shift(head_tube, 0.0, 0.0, 0.05), front, 0.02, M_METAL, rho_bike),
        cylinder(_shift(bar, 0.0, -0.27, 0.0), _shift(bar, 0.0, 0.27, 0.0), 0.015, M_METAL, rho_bike),
    ]
    lean = rng.uniform(0.55, 1.05)  # torso angle from vertical
    hip = saddle + np.array([-0.02, 0.0, 0.08])
    torso_len = 0.55 * s
    shoulder = hip + torso_len * np.array([math.sin(lean), 0.0, math.cos(lean)])
    rho_top, rho_legs = cloth_rho(rng), cloth_rho(rng)
    parts.append(ellipsoid(0.5 * (hip + shoulder), [0.11 * s, 0.19 * s, torso_len / 2 + 0.04], M_CLOTH, rho_top,
                           rot_y(-lean)))
    head = shoulder + 0.22 * s * np.array([math.sin(0.5 * lean), 0.0, math.cos(0.5 * lean)])
    parts.append(ellipsoid(head, [0.11 * s, 0.09 * s, 0.12 * s], M_SKIN, float(rng.uniform(0.05, 0.6))))
    for side in (1.0, -1.0):
        parts.append(cylinder(_shift(shoulder, 0.0, side * 0.19 * s, 0.0), _shift(bar, 0.0, side * 0.22, 0.02),
                              0.04 * s, M_CLOTH, rho_top))
    phase = rng.uniform(0, 2 * math.pi)
    for side, ph in ((1.0, phase), (-1.0, phase + math.pi)):
        pedal = bb + 0.17 * np.array([math.cos(ph), 0.0, math.sin(ph)])
        hip_side = _shift(hip, 0.0, side * 0.1 * s, 0.0)
        foot = _shift(pedal, 0.0, side * 0.13, 0.0)
        knee = _knee(hip_side, foot, 0.45 * s, 0.47 * s)
        parts.append(cylinder(hip_side, knee, 0.07 * s, M_CLOTH, rho_legs))
        parts.append(cylinder(knee, foot, 0.05 * s, M_CLOTH, rho_legs))
    return parts


def tree_parts(rng: np.random.Generator, min_base: float = 1.8) -> tuple[list[Part], float, float, float]:
    """Tree: trunk and an irregular crown of ellipsoids; returns (parts, trunk radius, crown base, crown radius)."""
    trunk_r = rng.uniform(0.1, 0.35)
    base = rng.uniform(min_base, max(min_base + 0.5, 4.5))
    crown_r = rng.uniform(1.3, 3.6)
    top = base + rng.uniform(2.0, 7.0)
    rho_leaf = float(rng.uniform(0.35, 0.6))
    parts = [cylinder([0.0, 0.0, -0.2], [0.0, 0.0, base + 0.6], trunk_r, M_TRUNK, float(rng.uniform(0.25, 0.5)))]
    conifer = rng.random() < 0.2
    n = int(rng.integers(4, 9))
    for i in range(n):
        if conifer:
            f = i / max(n - 1, 1)
            cz = base + (top - base) * (0.15 + 0.7 * f)
            radius = crown_r * (1.0 - 0.75 * f)
            cx = cy = 0.0
            semi = np.array([radius, radius, (top - base) / n + 0.3])
        else:
            ang, rad = rng.uniform(0, 2 * math.pi), crown_r * 0.55 * math.sqrt(rng.random())
            cx, cy = rad * math.cos(ang), rad * math.sin(ang)
            cz = base + (top - base) * rng.uniform(0.35, 0.65)
            semi = crown_r * rng.uniform(0.4, 0.75, size=3)
        semi[2] = min(semi[2], cz - base, top - cz) if semi[2] > 0.3 else semi[2]
        semi[2] = max(semi[2], 0.3)
        cz = max(cz, base + semi[2])
        semi[0] = min(semi[0], crown_r - math.hypot(cx, cy))
        semi[1] = min(semi[1], crown_r - math.hypot(cx, cy))
        semi[:2] = np.maximum(semi[:2], 0.3)
        parts.append(ellipsoid([cx, cy, cz], semi, M_VEGETATION, rho_leaf, rot_z(rng.uniform(0, math.pi)).T))
    return parts, trunk_r, base, crown_r


def bush_parts(rng: np.random.Generator) -> list[Part]:
    """Bush: a few overlapping low ellipsoids."""
    radius, height = rng.uniform(0.5, 1.6), rng.uniform(0.5, 1.6)
    rho = float(rng.uniform(0.35, 0.6))
    parts = []
    for _ in range(int(rng.integers(2, 6))):
        ang, rad = rng.uniform(0, 2 * math.pi), radius * 0.5 * math.sqrt(rng.random())
        semi = np.array([*(rng.uniform(0.35, 0.6, size=2) * radius), height * rng.uniform(0.35, 0.5)])
        semi[:2] = np.minimum(semi[:2], radius - rad)
        semi[:2] = np.maximum(semi[:2], 0.2)
        parts.append(ellipsoid([rad * math.cos(ang), rad * math.sin(ang), semi[2]], semi, M_VEGETATION, rho))
    return parts


# ----------------------------------------------------------------------------------------------- placement
class _Footprints:
    """Placed footprints (oriented rectangles with a z range) and the overlap test new objects must pass."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, ...]] = []
        self._array = np.zeros((0, 9))

    def _arr(self) -> np.ndarray:
        if len(self._array) != len(self.rows):
            self._array = np.array(self.rows, dtype=np.float64).reshape(-1, 9)
        return self._array

    def free(self, rects: list[tuple[float, ...]]) -> bool:
        """True when none of `rects` (cx, cy, hx, hy, yaw, zlo, zhi, fg, veg) overlaps a placed one."""
        arr = self._arr()
        if len(arr) == 0:
            return True
        for cx, cy, hx, hy, yaw, zlo, zhi, fg, veg in rects:
            gap = np.where((arr[:, 7] > 0) | (fg > 0), FOREGROUND_GAP_M, 0.0)
            check = ~((arr[:, 8] > 0) & (veg > 0))
            zgap = np.where((arr[:, 7] > 0) | (fg > 0), 0.1, 0.0)
            z_overlap = (arr[:, 5] < zhi + zgap) & (zlo < arr[:, 6] + zgap)
            cand = check & z_overlap
            if not cand.any():
                continue
            if _obb_overlap(np.array([cx, cy, hx, hy, yaw]), arr[cand, :5], gap[cand]).any():
                return False
        return True

    def add(self, rects: list[tuple[float, ...]]) -> None:
        """Record rectangles of a placed object."""
        self.rows.extend(rects)


def _obb_overlap(a: np.ndarray, b: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """Separating-axis test of rectangle `a` against rectangles `b` (cx, cy, hx, hy, yaw), each grown by gap/2."""
    ca, sa = math.cos(a[4]), math.sin(a[4])
    cb, sb = np.cos(b[:, 4]), np.sin(b[:, 4])
    d = b[:, :2] - a[:2]
    n = len(b)
    axes = [(np.full(n, ca), np.full(n, sa)), (np.full(n, -sa), np.full(n, ca)), (cb, sb), (-sb, cb)]
    ha, hb = a[2:4] + gap[:, None] / 2, b[:, 2:4] + gap[:, None] / 2
    separated = np.zeros(len(b), dtype=bool)
    for ax, ay in axes:
        dist = np.abs(d[:, 0] * ax + d[:, 1] * ay)
        ra = ha[:, 0] * np.abs(ca * ax + sa * ay) + ha[:, 1] * np.abs(-sa * ax + ca * ay)
        rb = hb[:, 0] * np.abs(cb * ax + sb * ay) + hb[:, 1] * np.abs(-sb * ax + cb * ay)
        separated |= dist > ra + rb
    return ~separated


class SceneBuilder:
    """Collects objects and their primitives, placing each object on the ground and refusing collisions."""

    def __init__(self, ground: np.ndarray, bumps: np.ndarray, waves: np.ndarray) -> None:
        self.ground, self.bumps, self.waves = ground, bumps, waves
        self.parts: list[tuple[Part, int]] = []
        self.objects: list[SceneObject] = []
        self.footprints = _Footprints()
        self.footprints.add([EGO_FOOTPRINT])
        c, s, v_ego = ground[rc.G_COS], ground[rc.G_SIN], ground[rc.G_VEGO]
        self._road_to_world = (c, s, v_ego)

    def world_xy(self, u: float, v: float) -> tuple[float, float]:
        """Sensor-frame (x, y) of road coordinates (u, v)."""
        c, s, v_ego = self._road_to_world
        return c * u - s * (v - v_ego), s * u + c * (v - v_ego)

    def road_yaw(self) -> float:
        """Heading of the road's u axis in the sensor frame."""
        return math.atan2(self.ground[rc.G_SIN], self.ground[rc.G_COS])

    def ground_z(self, x: float, y: float) -> float:
        """Ground height under a sensor-frame point."""
        return float(rc.ground_height_at(self.ground, self.bumps, self.waves, np.array([[x, y]]))[0])

    def place(self, parts: list[Part], u: float, v: float, yaw_road: float, label: int = BACKGROUND,
              kind: str = "", footprint: list[tuple[float, ...]] | None = None, veg: bool = False,
              z_offset: float = 0.0) -> bool:
        """Put `parts` at road coordinates (u, v), heading `yaw_road` relative to the road, unless it collides.

        The footprint defaults to the parts' extent; `footprint` rows are (cx, cy, hx, hy, zlo, zhi) in the
        object frame, for objects whose extent is a poor footprint (trees).
        """
        x, y = self.world_xy(u, v)
        yaw = self.road_yaw() + yaw_road
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for p in parts:
            ext = part_extent(p)
            lo = np.minimum(lo, p.center - ext)
            hi = np.maximum(hi, p.center + ext)
        fg = 1.0 if label != BACKGROUND else 0.0
        if footprint is None:
            footprint = [(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1]),
                          lo[2], hi[2])]
        c, s = math.cos(yaw), math.sin(yaw)
        z = self.ground_z(x, y) + z_offset
        rects = [(x + c * fx - s * fy, y + s * fx + c * fy, hx, hy, yaw, z + zlo, z + zhi, fg, 1.0 if veg else 0.0)
                 for fx, fy, hx, hy, zlo, zhi in footprint]
        if not self.footprints.free(rects):
            return False
        self.footprints.add(rects)
        index = len(self.objects)
        self.objects.append(SceneObject(label, kind, x, y, z, yaw, local_min=lo, local_max=hi))
        self.parts.extend((p, index) for p in parts)
        return True

    def build(self, lane_lines: np.ndarray, dark_patches: np.ndarray, road_rho: float, walk_rho: float,
              terrain_rho: float) -> Scene:
        """Freeze into the arrays the ray caster takes (primitives grouped by object)."""
        order = sorted(range(len(self.parts)), key=lambda i: self.parts[i][1])
        n = len(order)
        ptype = np.zeros(n, dtype=np.int32)
        prot = np.zeros((n, 3, 3))
        pcenter = np.zeros((n, 3))
        psize = np.zeros((n, 6))
        pmaterial = np.zeros(n, dtype=np.int16)
        prho = np.zeros(n)
        pobject = np.zeros(n, dtype=np.int32)
        for row, i in enumerate(order):
            part, obj_index = self.parts[i]
            obj = self.objects[obj_index]
            r = rot_z(obj.yaw)
            ptype[row] = part.ptype
            prot[row] = part.rot @ r.T
            pcenter[row] = r @ part.center + np.array([obj.x, obj.y, obj.z])
            psize[row] = part.size
            pmaterial[row] = part.material
            prho[row] = part.rho
            pobject[row] = obj_index
        counts = np.bincount(pobject, minlength=len(self.objects))
        firsts = np.cumsum(counts) - counts
        for obj, first, count in zip(self.objects, firsts, counts, strict=True):
            obj.first, obj.count = int(first), int(count)
        return Scene(self.ground, self.bumps, self.waves, ptype, prot, pcenter, psize, pmaterial, prho, pobject,
                     self.objects, lane_lines, dark_patches, road_rho, walk_rho, terrain_rho)


# ----------------------------------------------------------------------------------------------- layout
@dataclass
class RoadLayout:
    """Cross-section of the street in road coordinates (metres)."""

    lanes: int
    lane_width: float
    parking: tuple[bool, bool]  # right (v < 0), left (v > 0)
    half_width: float  # road edge at |v| = half_width (the curb)
    sidewalk: float
    frontage: float  # property line (|v|) where buildings may start
    cross: bool
    cross_u: float
    cross_half_width: float
    v_ego: float


def _road_layout(rng: np.random.Generator, style: str) -> RoadLayout:
    """Lanes, parking, sidewalks, yards, an optional cross street and where the ego car drives."""
    lanes = int(rng.choice([1, 2, 4], p=[0.15, 0.6, 0.25]))
    lane_width = rng.uniform(3.0, 3.6)
    p_park = {"urban": 0.7, "residential": 0.6, "open": 0.2}[style]
    parking = (bool(rng.random() < p_park), bool(rng.random() < p_park))
    park_w = rng.uniform(2.2, 2.8) if any(parking) else 0.3
    half_width = lanes * lane_width / 2 + park_w
    sidewalk = rng.uniform(1.5, 4.0) if style != "open" else rng.uniform(0.8, 2.0)
    yard = {"urban": rng.uniform(0.0, 1.5), "residential": rng.uniform(2.0, 8.0), "open": rng.uniform(4.0, 14.0)}[style]
    cross = bool(rng.random() < 0.3)
    cross_u = float(rng.choice([-1.0, 1.0], p=[0.3, 0.7]) * rng.uniform(14.0, 45.0))
    ego_lane = 0 if lanes < 4 else int(rng.choice(4, p=[0.45, 0.35, 0.1, 0.1]))
    v_ego = -lanes * lane_width / 2 + (ego_lane + 0.5) * lane_width if lanes > 1 else 0.0
    v_ego += rng.uniform(-0.3, 0.3)
    return RoadLayout(lanes, lane_width, parking, half_width, sidewalk, half_width + sidewalk + yard, cross, cross_u,
                      rng.uniform(4.0, 7.5), v_ego)


def _ground_params(rng: np.random.Generator, lay: RoadLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground parameter vector, bumps and terrain waves; the road under the sensor lies 1.73 m below it."""
    gp = np.zeros(rc.N_GROUND_PARAMS)
    yaw = rng.uniform(-0.06, 0.06)
    gp[rc.G_COS], gp[rc.G_SIN] = math.cos(yaw), math.sin(yaw)
    gp[rc.G_VEGO], gp[rc.G_W], gp[rc.G_S] = lay.v_ego, lay.half_width, lay.sidewalk
    gp[rc.G_CURB] = rng.uniform(0.08, 0.17)
    gp[rc.G_CROSS], gp[rc.G_XC], gp[rc.G_WC] = float(lay.cross), lay.cross_u, lay.cross_half_width
    gp[rc.G_CROWN] = rng.uniform(0.0, 0.08)
    gp[rc.G_KU] = rng.normal(0.0, 2.5e-4)
    gp[rc.G_TV] = rng.normal(0.0, 0.008)
    gp[rc.G_TERR] = rng.uniform(-0.1, 0.25)
    n_bumps = int(rng.integers(2, 7))
    bumps = np.stack([rng.uniform(-60, 60, n_bumps), rng.uniform(-30, 30, n_bumps),
                      rng.normal(0.0, 0.06, n_bumps), rng.uniform(4.0, 15.0, n_bumps)], axis=1)
    n_waves = 3
    wavelength = rng.uniform(2.0, 9.0, n_waves)
    direction = rng.uniform(0, 2 * math.pi, n_waves)
    waves = np.stack([2 * math.pi / wavelength * np.cos(direction), 2 * math.pi / wavelength * np.sin(direction),
                      rng.uniform(0, 2 * math.pi, n_waves), rng.uniform(0.01, 0.06, n_waves)], axis=1)
    # z0 puts the road under the sensor at -1.73 m.
    gp[rc.G_Z0] = 0.0
    gp[rc.G_Z0] = -MOUNT_HEIGHT_M - rc.ground_height(gp, bumps, waves, 0.0, lay.v_ego, rc.ROAD)
    bump_slope = float(np.sum(1.54 * np.abs(bumps[:, 2]) / bumps[:, 3]))
    base_l = abs(gp[rc.G_KU]) * U_MAX + abs(gp[rc.G_TV]) + bump_slope
    gp[rc.G_L_ROAD] = base_l + 2.0 * gp[rc.G_CROWN] / lay.half_width
    gp[rc.G_L_WALK] = base_l
    gp[rc.G_L_TERR] = base_l + float(np.sum(waves[:, 3] * np.hypot(waves[:, 0], waves[:, 1])))
    slope_hi = max(0.0, 0.5 * gp[rc.G_KU] * U_MAX**2) + abs(gp[rc.G_TV]) * U_MAX
    slope_lo = min(0.0, 0.5 * gp[rc.G_KU] * U_MAX**2) - abs(gp[rc.G_TV]) * U_MAX
    extra_hi = max(gp[rc.G_CROWN], gp[rc.G_CURB] + max(gp[rc.G_TERR], 0.0) + waves[:, 3].sum())
    extra_lo = min(0.0, gp[rc.G_CURB] + gp[rc.G_TERR] - waves[:, 3].sum())
    gp[rc.G_ZMAX] = gp[rc.G_Z0] + slope_hi + np.clip(bumps[:, 2], 0, None).sum() + extra_hi + 0.01
    gp[rc.G_ZMIN] = gp[rc.G_Z0] + slope_lo + np.clip(bumps[:, 2], None, 0).sum() + extra_lo - 0.01
    return gp, bumps, waves


def _in_cross(lay: RoadLayout, u: float, margin: float) -> bool:
    return lay.cross and abs(u - lay.cross_u) < lay.cross_half_width + lay.sidewalk + margin


def _add_roadside(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, style: str) -> None:
    """Buildings, walls, fences, hedges, trees, bushes, poles and signs along both sides of the street."""
    p_building = {"urban": 0.85, "residential": 0.55, "open": 0.15}[style]
    for side in (1.0, -1.0):
        u = -115.0 + rng.uniform(0, 10)
        while u < 115.0:
            lot = rng.uniform(8.0, 26.0)
            mid = u + lot / 2
            if not _in_cross(lay, mid, lot / 2 + 1.0):
                kind = rng.random()
                setback = rng.uniform(0.0, 2.5)
                if kind < p_building:
                    depth, height = rng.uniform(8.0, 16.0), rng.uniform(3.5, 20.0 if style == "urban" else 9.0)
                    width = lot - rng.uniform(0.0, 4.0 if style == "urban" else 8.0)
                    v = side * (lay.frontage + setback + depth / 2)
                    b.place([box([0, 0, height / 2 - 0.5], [width / 2, depth / 2, height / 2 + 0.5], M_BUILDING,
                                  float(rng.uniform(0.35, 0.6)))], mid, v, 0.0)
                    if rng.random() < 0.3:  # porch, bay or shop front
                        pw, pd, ph = rng.uniform(1.5, 5.0), rng.uniform(0.5, 2.0), rng.uniform(0.8, 3.0)
                        pv = side * (lay.frontage + setback - pd / 2 + 0.05)
                        b.place([box([0, 0, ph / 2 - 0.2], [pw / 2, pd / 2, ph / 2 + 0.2], M_BUILDING,
                                     float(rng.uniform(0.2, 0.6)))], mid + rng.uniform(-lot / 4, lot / 4), pv, 0.0)
                if kind >= p_building or rng.random() < 0.3:
                    _add_boundary(b, rng, lay, side, mid, lot)
                _add_yard_plants(b, rng, lay, side, mid, lot, style)
            u += lot
        _add_street_trees(b, rng, lay, side, style)
        _add_poles(b, rng, lay, side)
    if lay.cross:
        _add_cross_street_sides(b, rng, lay, p_building)


def _add_boundary(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float, mid: float,
                  lot: float) -> None:
    """A wall, fence or hedge along the property line of a lot."""
    v = side * (lay.frontage + rng.uniform(0.1, 1.0))
    length = lot - rng.uniform(0.0, 2.0)
    what = rng.random()
    if what < 0.35:
        height, thick = rng.uniform(0.8, 2.6), rng.uniform(0.2, 0.4)
        b.place([box([0, 0, height / 2 - 0.2], [length / 2, thick / 2, height / 2 + 0.2], M_WALL,
                     float(rng.uniform(0.25, 0.55)))], mid, v, 0.0)
    elif what < 0.7:
        height = rng.uniform(1.0, 2.0)
        rho = float(rng.uniform(0.2, 0.5))
        parts = [box([0, 0, height / 2], [length / 2, 0.02, height / 2], M_FENCE, rho)]
        n_posts = max(int(length / 2.5), 1)
        for x in np.linspace(-length / 2, length / 2, n_posts + 1):
            parts.append(cylinder([x, 0.0, -0.1], [x, 0.0, height + 0.05], 0.04, M_POLE, rho))
        b.place(parts, mid, v, 0.0)
    else:
        height, thick = rng.uniform(0.8, 2.2), rng.uniform(0.6, 1.3)
        b.place([box([0, 0, height / 2 - 0.1], [length / 2, thick / 2, height / 2 + 0.1], M_VEGETATION,
                     float(rng.uniform(0.35, 0.6)), rounding=(1.05, 1.5, 1.5))], mid, v, 0.0, veg=True)


def _tree_footprint(trunk_r: float, base: float, crown_r: float) -> list[tuple[float, ...]]:
    return [(0.0, 0.0, trunk_r, trunk_r, -0.2, base), (0.0, 0.0, crown_r, crown_r, base, base + 8.0)]


def _add_yard_plants(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float, mid: float,
                     lot: float, style: str) -> None:
    yard = lay.frontage - lay.half_width - lay.sidewalk
    n = int(rng.poisson({"urban": 1.5, "residential": 4.5, "open": 5.0}[style]))
    for _ in range(n):
        u = mid + rng.uniform(-lot / 2, lot / 2)
        v = side * (lay.half_width + lay.sidewalk + rng.uniform(0.3, max(yard, 0.5) + 6.0))
        if rng.random() < 0.6:
            parts, trunk_r, base, crown_r = tree_parts(rng)
            b.place(parts, u, v, 0.0, footprint=_tree_footprint(trunk_r, base, crown_r), veg=True)
        else:
            b.place(bush_parts(rng), u, v, 0.0, veg=True)


def _add_street_trees(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float, style: str) -> None:
    if rng.random() > {"urban": 0.6, "residential": 0.9, "open": 0.7}[style]:
        return
    spacing = rng.uniform(6.0, 16.0)
    v_line = side * (lay.half_width + min(0.9, lay.sidewalk * 0.4))
    for u in np.arange(-100.0 + rng.uniform(0, spacing), 100.0, spacing):
        if _in_cross(lay, u, 2.0) or rng.random() < 0.15:
            continue
        parts, trunk_r, base, crown_r = tree_parts(rng, min_base=2.6)
        b.place(parts, u + rng.uniform(-1, 1), v_line + side * rng.uniform(0.0, 0.3), 0.0,
                footprint=_tree_footprint(trunk_r, base, crown_r), veg=True)


def _add_poles(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float) -> None:
    """Street lamps near the curb and traffic signs (retro-reflective faces) here and there."""
    spacing = rng.uniform(18.0, 35.0)
    for u in np.arange(-100.0 + rng.uniform(0, spacing), 100.0, spacing):
        if _in_cross(lay, u, 0.5):
            continue
        height, radius = rng.uniform(5.0, 9.0), rng.uniform(0.06, 0.12)
        rho = float(rng.uniform(0.1, 0.35))
        arm = rng.uniform(0.8, 2.0)
        parts = [
            cylinder([0, 0, -0.2], [0, 0, height], radius, M_POLE, rho),
            cylinder([0, 0, height - 0.1], [0, -side * arm, height + 0.15], 0.04, M_POLE, rho),
            box([0, -side * arm, height + 0.05], [0.3, 0.15, 0.08], M_POLE, rho),
        ]
        b.place(parts, u, side * (lay.half_width + 0.4), 0.0)
    for _ in range(int(rng.integers(0, 5))):
        u = rng.uniform(-60, 80)
        height = rng.uniform(2.2, 3.2)
        rho_sign = float(rng.uniform(0.6, 0.95))
        parts = [cylinder([0, 0, -0.2], [0, 0, height], 0.035, M_POLE, 0.25)]
        if rng.random() < 0.5:
            parts.append(disc([0.05, 0, height - 0.1], [1, 0, 0], rng.uniform(0.3, 0.45), 0.01, M_SIGN, rho_sign))
        else:
            parts.append(box([0.05, 0, height - 0.2], [0.01, rng.uniform(0.3, 0.45), rng.uniform(0.3, 0.45)],
                             M_SIGN, rho_sign))
        yaw = 0.0 if side < 0 else math.pi
        b.place(parts, u, side * (lay.half_width + rng.uniform(0.3, 1.0)), yaw)


def _add_cross_street_sides(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, p_building: float) -> None:
    """Buildings and trees along the cross street, beyond the main street's frontage."""
    for side in (1.0, -1.0):
        u_line = lay.cross_u + side * (lay.cross_half_width + lay.sidewalk + rng.uniform(0.5, 4.0))
        for vside in (1.0, -1.0):
            v = lay.frontage + rng.uniform(0.0, 3.0)
            while v < 110.0:
                lot = rng.uniform(8.0, 25.0)
                if rng.random() < p_building:
                    depth, height = rng.uniform(8.0, 15.0), rng.uniform(3.5, 15.0)
                    b.place([box([0, 0, height / 2 - 0.5], [depth / 2, lot / 2 - 0.5, height / 2 + 0.5], M_BUILDING,
                                 float(rng.uniform(0.35, 0.6)))], u_line + side * depth / 2, vside * (v + lot / 2), 0.0)
                else:
                    parts, trunk_r, base, crown_r = tree_parts(rng)
                    b.place(parts, u_line + side * rng.uniform(1.0, 4.0), vside * (v + lot / 2), 0.0,
                            footprint=_tree_footprint(trunk_r, base, crown_r), veg=True)
                v += lot


def _distance_u(rng: np.random.Generator) -> float:
    """Road coordinate of an object: mostly 4-40 m away, more often ahead than behind."""
    dist = rng.uniform(3.0, 12.0) if rng.random() < 0.25 else rng.uniform(8.0, 45.0)
    return float(dist if rng.random() < 0.7 else -dist)


def _add_vehicles(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, style: str) -> None:
    """Parked rows (cars close to each other, some vans and trucks) and moving traffic in the lanes."""
    for side, has_parking in ((-1.0, lay.parking[0]), (1.0, lay.parking[1])):
        if not has_parking:
            continue
        occupancy = rng.uniform(0.2, 0.75)
        u = -60.0 + rng.uniform(0, 5)
        while u < 70.0:
            r = rng.random()
            kind, parts = ("Van", van_parts(rng)) if r < 0.1 else ("Truck", truck_parts(rng)) if r < 0.13 else \
                ("Car", car_parts(rng))
            length = max(abs(p.center[0]) + part_extent(p)[0] for p in parts) * 2
            if rng.random() < occupancy and not _in_cross(lay, u + length / 2, length / 2 + 1.0):
                flip = math.pi if rng.random() < 0.15 else 0.0
                v = side * (lay.half_width - 1.1 + rng.uniform(-0.15, 0.2))
                label = CAR if kind == "Car" else BACKGROUND
                b.place(parts, u + length / 2, v, flip + rng.normal(0.0, 0.04), label, kind)
            u += length + rng.uniform(0.35, 2.5)
    n_moving = int(rng.integers(1, 6))
    lane_edge = lay.lanes * lay.lane_width / 2
    for _ in range(n_moving):
        r = rng.random()
        kind, parts = ("Van", van_parts(rng)) if r < 0.1 else ("Truck", truck_parts(rng)) if r < 0.15 else \
            ("Car", car_parts(rng))
        label = CAR if kind == "Car" else BACKGROUND
        for _attempt in range(6):
            lane = int(rng.integers(0, lay.lanes))
            v = -lane_edge + (lane + 0.5) * lay.lane_width + rng.normal(0.0, 0.2)
            u = _distance_u(rng)
            if abs(v - lay.v_ego) < lay.lane_width / 2 and abs(u) < 9.0:
                continue
            heading = 0.0 if v < 0 or lay.lanes == 1 else math.pi
            if b.place(parts, u, v, heading + rng.normal(0.0, 0.03), label, kind):
                break
    if lay.cross:
        for _ in range(int(rng.integers(0, 3))):
            parts = car_parts(rng)
            v = rng.choice([-1.0, 1.0]) * rng.uniform(lay.half_width + 3.0, 40.0)
            u = lay.cross_u + rng.choice([-1.0, 1.0]) * lay.cross_half_width * 0.5
            b.place(parts, u, v, math.pi / 2 * rng.choice([-1.0, 1.0]) + rng.normal(0, 0.05), CAR, "Car")


def _add_people(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Pedestrians (alone, in groups, by walls, between parked cars, crossing) and cyclists."""
    n_ped = int(rng.choice(5, p=[0.2, 0.25, 0.25, 0.15, 0.15]))
    placed = 0
    while placed < n_ped:
        group = min(int(rng.choice([1, 2, 3], p=[0.6, 0.25, 0.15])), n_ped - placed)
        where = rng.random()
        side = float(rng.choice([-1.0, 1.0]))
        u = _distance_u(rng)
        if where < 0.5:  # sidewalk
            v = side * (lay.half_width + rng.uniform(0.3, max(lay.sidewalk - 0.3, 0.4)))
        elif where < 0.65:  # against the wall / building front
            v = side * (lay.frontage - rng.uniform(0.25, 0.6))
        elif where < 0.8:  # crossing or walking on the road edge, between parked cars
            v = side * rng.uniform(0.5, lay.half_width - 0.3)
        else:  # terrain, among trees and bushes
            v = side * (lay.half_width + lay.sidewalk + rng.uniform(0.3, 4.0))
        if rng.random() < 0.7:  # along the street, either way
            heading = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.3)
        else:
            heading = rng.uniform(-math.pi, math.pi)
        for member in range(group):
            for _attempt in range(12):
                du, dv = (0.0, 0.0) if member == 0 and _attempt == 0 else rng.normal(0.0, 0.9, size=2)
                yaw = heading + rng.normal(0.0, 0.25)
                if b.place(pedestrian_parts(rng), u + du, v + 0.4 * dv, yaw, PEDESTRIAN, "Pedestrian"):
                    break
            placed += 1
    n_cyc = int(rng.choice(5, p=[0.3, 0.3, 0.2, 0.12, 0.08]))
    lane_edge = lay.lanes * lay.lane_width / 2
    for _ in range(n_cyc):
        for _attempt in range(12):
            where = rng.random()
            side = float(rng.choice([-1.0, 1.0]))
            if where < 0.6:  # along the road, near the lane edge
                v = side * (lane_edge - rng.uniform(0.4, 1.2))
                yaw = (0.0 if side < 0 else math.pi) + rng.normal(0.0, 0.1)
            elif where < 0.8:  # on the sidewalk
                v = side * (lay.half_width + rng.uniform(0.5, max(lay.sidewalk - 0.4, 0.6)))
                yaw = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.2)
            else:  # crossing or turning
                v = side * rng.uniform(0.0, lay.half_width)
                yaw = rng.uniform(-math.pi, math.pi)
            if b.place(cyclist_parts(rng), _distance_u(rng), v, yaw, CYCLIST, "Cyclist"):
                break


def generate_scene(rng: np.random.Generator) -> Scene:
    """A random street scene; everything drawn from `rng`, so one seed gives one scene."""
    style = str(rng.choice(["urban", "residential", "open"], p=[0.45, 0.45, 0.1]))
    lay = _road_layout(rng, style)
    gp, bumps, waves = _ground_params(rng, lay)
    b = SceneBuilder(gp, bumps, waves)
    _add_roadside(b, rng, lay, style)
    _add_vehicles(b, rng, lay, style)
    _add_people(b, rng, lay)
    lane_edge = lay.lanes * lay.lane_width / 2
    lines = [-lane_edge + k * lay.lane_width for k in range(lay.lanes + 1)]
    n_patches = int(rng.integers(0, 9))
    u0 = rng.uniform(-40.0, 40.0, n_patches)
    v0 = rng.uniform(-lay.half_width, lay.half_width, n_patches)
    patches = np.stack([u0, u0 + rng.uniform(2.0, 15.0, n_patches), v0, v0 + rng.uniform(0.4, 3.0, n_patches)], axis=1)
    return b.build(np.array(lines), patches, float(rng.uniform(0.3, 0.42)), float(rng.uniform(0.42, 0.56)),
                   float(rng.uniform(0.5, 0.65)))
