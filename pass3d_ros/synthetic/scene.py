"""Random KITTI-like street layouts: where the road, curbs and every object of a synthetic scene go.

A scene is a road (lanes, parking lanes, crown, gentle slope changes and bumps, optionally a cross street)
with curbs, sidewalks and terrain, lined with buildings, walls, fences, hedges, trees, bushes, poles and
signs, and populated with parked and moving cars, vans, trucks, pedestrians (alone and in groups) and
cyclists. The objects themselves are modelled in `synthetic.objects`; `SceneBuilder` sets them on the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import Scene, SceneBuilder
from pass3d_ros.synthetic.objects.people import cyclist_parts, pedestrian_parts
from pass3d_ros.synthetic.objects.street_furniture import sign_parts, street_lamp_parts
from pass3d_ros.synthetic.objects.structures import building_parts, fence_parts, porch_parts, wall_parts
from pass3d_ros.synthetic.objects.vegetation import bush_parts, hedge_parts, tree_parts
from pass3d_ros.synthetic.objects.vehicles import car_parts, truck_parts, van_parts
from pass3d_ros.synthetic.parts import part_extent
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M

U_MAX = 130.0  # farthest road coordinate a ray can reach the ground at (bounds the slope term)


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
                    b.place(building_parts(rng, width, depth, height), mid, v, 0.0)
                    if rng.random() < 0.3:
                        porch, pd = porch_parts(rng)
                        pv = side * (lay.frontage + setback - pd / 2 + 0.05)
                        b.place(porch, mid + rng.uniform(-lot / 4, lot / 4), pv, 0.0)
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
        b.place(wall_parts(rng, length), mid, v, 0.0)
    elif what < 0.7:
        b.place(fence_parts(rng, length), mid, v, 0.0)
    else:
        b.place(hedge_parts(rng, length), mid, v, 0.0, veg=True)


def _add_yard_plants(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float, mid: float,
                     lot: float, style: str) -> None:
    yard = lay.frontage - lay.half_width - lay.sidewalk
    n = int(rng.poisson({"urban": 1.5, "residential": 4.5, "open": 5.0}[style]))
    for _ in range(n):
        u = mid + rng.uniform(-lot / 2, lot / 2)
        v = side * (lay.half_width + lay.sidewalk + rng.uniform(0.3, max(yard, 0.5) + 6.0))
        if rng.random() < 0.6:
            parts, footprint = tree_parts(rng)
            b.place(parts, u, v, 0.0, footprint=footprint, veg=True)
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
        parts, footprint = tree_parts(rng, min_base=2.6)
        b.place(parts, u + rng.uniform(-1, 1), v_line + side * rng.uniform(0.0, 0.3), 0.0, footprint=footprint,
                veg=True)


def _add_poles(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float) -> None:
    """Street lamps near the curb and traffic signs (retro-reflective faces) here and there."""
    spacing = rng.uniform(18.0, 35.0)
    for u in np.arange(-100.0 + rng.uniform(0, spacing), 100.0, spacing):
        if _in_cross(lay, u, 0.5):
            continue
        b.place(street_lamp_parts(rng, -side), u, side * (lay.half_width + 0.4), 0.0)
    for _ in range(int(rng.integers(0, 5))):
        u = rng.uniform(-60, 80)
        parts = sign_parts(rng)
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
                    b.place(building_parts(rng, depth, lot - 1.0, height), u_line + side * depth / 2,
                            vside * (v + lot / 2), 0.0)
                else:
                    parts, footprint = tree_parts(rng)
                    b.place(parts, u_line + side * rng.uniform(1.0, 4.0), vside * (v + lot / 2), 0.0,
                            footprint=footprint, veg=True)
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
