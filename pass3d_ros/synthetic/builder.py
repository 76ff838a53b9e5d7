"""The scene container the ray caster takes, and the builder that places objects in it without collisions.

Objects arrive as parts in their own frame and are set on the ground at a pose; foreground objects keep a
clearance from everything else, so their boxes hold no foreign points, while still standing close to each
other, to walls and under trees (the hard cases PASS3D names). A placement may lower that clearance
(`SceneBuilder.place(..., clearance=...)`): real streets put people against poles and bikes against racks, and
stage 1 then proposes foreground and background in one cluster, which stage 2 must learn to split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.parts import Part, part_extent, rot_z
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M

FOREGROUND_GAP_M = 0.25  # clearance between a foreground object's footprint and anything else (> 2 x noise bound)
# The ego car (a VW Passat under the sensor) as a footprint nothing may overlap: cx, cy, hx, hy, yaw, z range.
# The smallest clearance that keeps foreign points out of a foreground object's labelled box: range noise up to
# 3 sigma = 0.06 m on either surface plus the 0.02 m box margin. Below it a box may hold background points too
# (checked: none in 24 frames even at 0.05 m, as most shapes sit well inside their footprints).
TOUCH_CLEARANCE_M = 0.15
EGO_FOOTPRINT = (-0.3, 0.0, 2.45, 0.95, 0.0, -MOUNT_HEIGHT_M, 0.0, 1.0, 0.0)


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
    model: str = ""  # what the object is ("bollard", "parked_bicycle", ...), for statistics and tests
    clearance: float | None = None  # the lowered clearance it was placed with, None: FOREGROUND_GAP_M

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
    u_offset: float = 0.0  # road u of the frame's origin (a drive's scan: where the sensor is along the road)

    def ground_at(self, xy: np.ndarray) -> np.ndarray:
        """Ground height under sensor-frame points (N x 2)."""
        return rc.ground_height_at(self.ground, self.bumps, self.waves, np.ascontiguousarray(xy, dtype=np.float64))

    def to_road(self, xy: np.ndarray) -> np.ndarray:
        """Road coordinates (u along, v across) of sensor-frame points (N x 2); u counts from the street's own
        origin (`u_offset` added), so lane markings and patches stay put while a drive's sensor moves."""
        c, s = self.ground[rc.G_COS], self.ground[rc.G_SIN]
        u = c * xy[:, 0] + s * xy[:, 1]
        if self.u_offset:
            u = u + self.u_offset
        v = -s * xy[:, 0] + c * xy[:, 1] + self.ground[rc.G_VEGO]
        return np.stack([u, v], axis=1)

    def primitive_extents(self) -> np.ndarray:
        """Half extents (P x 3) of every primitive's world-axis-aligned bounding box, about its centre."""
        rt = np.transpose(self.prot, (0, 2, 1))  # columns: primitive axes in world coordinates
        half = self.psize[:, :3]
        ext_box = np.einsum("pij,pj->pi", np.abs(rt), half)
        ext_ell = np.sqrt(np.einsum("pij,pj->pi", rt**2, half**2))
        axis = self.prot[:, 2, :]
        ext_cyl = np.abs(axis) * half[:, 2:3] + half[:, 0:1] * np.sqrt(np.clip(1.0 - axis**2, 0.0, 1.0))
        return np.where((self.ptype == rc.BOX)[:, None], ext_box,
                        np.where((self.ptype == rc.ELLIPSOID)[:, None], ext_ell, ext_cyl))


class _Footprints:
    """Placed footprints (oriented rectangles with a z range) and the overlap test new objects must pass."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, ...]] = []
        self._array = np.zeros((0, 9))

    def _arr(self) -> np.ndarray:
        if len(self._array) != len(self.rows):
            self._array = np.array(self.rows, dtype=np.float64).reshape(-1, 9)
        return self._array

    def free(self, rects: list[tuple[float, ...]], clearance: float | None = None) -> bool:
        """True when none of `rects` (cx, cy, hx, hy, yaw, zlo, zhi, fg, veg) overlaps a placed one.

        Pairs with a foreground object keep FOREGROUND_GAP_M apart (0.1 m in z), or `clearance` when given.
        """
        arr = self._arr()
        if len(arr) == 0:
            return True
        fg_gap = FOREGROUND_GAP_M if clearance is None else clearance
        fg_zgap = 0.1 if clearance is None else min(0.1, clearance)
        for cx, cy, hx, hy, yaw, zlo, zhi, fg, veg in rects:
            gap = np.where((arr[:, 7] > 0) | (fg > 0), fg_gap, 0.0)
            check = ~((arr[:, 8] > 0) & (veg > 0))
            zgap = np.where((arr[:, 7] > 0) | (fg > 0), fg_zgap, 0.0)
            z_overlap = (arr[:, 5] < zhi + zgap) & (zlo < arr[:, 6] + zgap)
            # Bounding circles first: only rectangles whose circles meet go through the separating-axis test.
            reach = np.hypot(arr[:, 2], arr[:, 3]) + math.hypot(hx, hy) + gap
            near = (arr[:, 0] - cx) ** 2 + (arr[:, 1] - cy) ** 2 < reach**2
            cand = check & z_overlap & near
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

    def road_uv(self, x: float, y: float) -> tuple[float, float]:
        """Road coordinates (u, v) of a sensor-frame point (x, y); the inverse of `world_xy`."""
        c, s, v_ego = self._road_to_world
        return c * x + s * y, -s * x + c * y + v_ego

    def road_yaw(self) -> float:
        """Heading of the road's u axis in the sensor frame."""
        return math.atan2(self.ground[rc.G_SIN], self.ground[rc.G_COS])

    def ground_z(self, x: float, y: float) -> float:
        """Ground height under a sensor-frame point."""
        return float(rc.ground_height_at(self.ground, self.bumps, self.waves, np.array([[x, y]]))[0])

    def area_free(self, u: float, v: float, yaw_road: float, half: tuple[float, float], height: float = 2.0,
                  margin: float = 0.0) -> bool:
        """Whether a foreground object of footprint half extents `half` (x along `yaw_road`), centred at road
        coordinates (u, v) and `height` tall, would keep FOREGROUND_GAP_M + `margin` from everything placed; places
        nothing (a group checks the room it needs before its members stand closer together)."""
        x, y = self.world_xy(u, v)
        z = self.ground_z(x, y)
        rect = (x, y, half[0] + margin, half[1] + margin, self.road_yaw() + yaw_road, z, z + height, 1.0, 0.0)
        return self.footprints.free([rect])

    def place(self, parts: list[Part], u: float, v: float, yaw_road: float, label: int = BACKGROUND,
              kind: str = "", footprint: list[tuple[float, ...]] | None = None, veg: bool = False,
              z_offset: float = 0.0, model: str = "", clearance: float | None = None,
              extent: tuple[np.ndarray, np.ndarray] | None = None) -> bool:
        """Put `parts` at road coordinates (u, v), heading `yaw_road` relative to the road, unless it collides.

        The footprint defaults to the parts' extent; `footprint` rows are (cx, cy, hx, hy, zlo, zhi) in the
        object frame, for objects whose extent is a poor footprint (trees). `model` names the object.
        `clearance` replaces FOREGROUND_GAP_M between this object and every foreground object (0: footprints
        may touch; negative: overlap that deep); objects placed later keep the full gap from it. Lower than
        TOUCH_CLEARANCE_M next to a foreground object, its labelled box takes in background points.
        `extent` (min, max corners in the object frame) widens the object's extent beyond its parts: the amodal
        extent its label box holds (a walker's whole stride), which the default footprint then keeps clear too.
        """
        x, y = self.world_xy(u, v)
        yaw = self.road_yaw() + yaw_road
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for p in parts:
            ext = part_extent(p)
            lo = np.minimum(lo, p.center - ext)
            hi = np.maximum(hi, p.center + ext)
        if extent is not None:
            lo, hi = np.minimum(lo, extent[0]), np.maximum(hi, extent[1])
        fg = 1.0 if label != BACKGROUND else 0.0
        if footprint is None:
            footprint = [(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1]),
                          lo[2], hi[2])]
        c, s = math.cos(yaw), math.sin(yaw)
        z = self.ground_z(x, y) + z_offset
        rects = [(x + c * fx - s * fy, y + s * fx + c * fy, hx, hy, yaw, z + zlo, z + zhi, fg, 1.0 if veg else 0.0)
                 for fx, fy, hx, hy, zlo, zhi in footprint]
        if not self.footprints.free(rects, clearance):
            return False
        self.footprints.add(rects)
        index = len(self.objects)
        self.objects.append(SceneObject(label, kind, x, y, z, yaw, local_min=lo, local_max=hi, model=model or kind,
                                        clearance=clearance))
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
