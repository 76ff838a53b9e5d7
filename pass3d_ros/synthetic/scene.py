"""Random KITTI-like street layouts: where the road, curbs and every object of a synthetic scene go.

A scene is a road (lanes, parking lanes, crown, gentle slope changes and bumps, optionally a cross street)
with curbs, sidewalks and terrain, lined with buildings, walls, fences, hedges, trees, bushes, poles and
signs, barriers, planters and car-sized bushes, and populated with parked and moving cars, vans, trucks,
pedestrians (alone, in groups, and standing behind parked cars and low things) and cyclists; some cars are seen
only in part, behind nearer road users, trees, boxes, hedges and low things in the sensor's line of sight. The
objects themselves are modelled in `synthetic.objects`; `SceneBuilder` sets them on the ground. The street's
cross-section is `synthetic.street`; the world changes that show things in part ("hidden", "partial") are
`synthetic.occlusion`, the car-sized background and thinned posts ("negatives") `synthetic.hard_negatives`, the
groups a hand's breadth apart, pedestrians beside riders ("groups") and lone far pedestrians with loads
("lone_people") `synthetic.crowds`.
"""

from __future__ import annotations

import math

import numpy as np

from pass3d_ros.classes import CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import TOUCH_CLEARANCE_M, Scene, SceneBuilder
from pass3d_ros.synthetic.crowds import add_groups, add_lone_pedestrians
from pass3d_ros.synthetic.hard_negatives import add_hard_negatives, thinned_out
from pass3d_ros.synthetic.objects import parked as pk
from pass3d_ros.synthetic.objects import street_furniture as sf
from pass3d_ros.synthetic.objects import structures as st
from pass3d_ros.synthetic.objects import vegetation as vg
from pass3d_ros.synthetic.objects.people import (
    bicycle_parts,
    cyclist_parts,
    pedestrian,
    seated_person_parts,
    stroller_parts,
)
from pass3d_ros.synthetic.objects.street_furniture import sign_parts, street_lamp_parts
from pass3d_ros.synthetic.objects.structures import building_parts, fence_parts, porch_parts, wall_parts
from pass3d_ros.synthetic.objects.vegetation import bush_parts, hedge_parts, tree_parts
from pass3d_ros.synthetic.objects.vehicles import car_parts
from pass3d_ros.synthetic.occlusion import add_hidden_pedestrians, add_partial_views
from pass3d_ros.synthetic.parts import Part, part_extent
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M
from pass3d_ros.synthetic.street import VEHICLE_LABEL, PartsFn, RoadLayout, draw_vehicle, in_cross, road_layout

U_MAX = 130.0  # farthest road coordinate a ray can reach the ground at (bounds the slope term)




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
    set_ground_bounds(gp, bumps, waves)
    return gp, bumps, waves



def set_ground_bounds(gp: np.ndarray, bumps: np.ndarray, waves: np.ndarray, u_max: float = U_MAX) -> None:
    """The ray caster's Lipschitz bounds and height range of the ground `gp` (in place), for rays that reach it
    within `u_max` of the origin along the road."""
    bump_slope = float(np.sum(1.54 * np.abs(bumps[:, 2]) / bumps[:, 3]))
    base_l = abs(gp[rc.G_KU]) * u_max + abs(gp[rc.G_TU]) + abs(gp[rc.G_TV]) + bump_slope
    gp[rc.G_L_ROAD] = base_l + 2.0 * gp[rc.G_CROWN] / gp[rc.G_W]
    gp[rc.G_L_WALK] = base_l
    gp[rc.G_L_TERR] = base_l + float(np.sum(waves[:, 3] * np.hypot(waves[:, 0], waves[:, 1])))
    slope_hi = max(0.0, 0.5 * gp[rc.G_KU] * u_max**2) + abs(gp[rc.G_TU]) * u_max + abs(gp[rc.G_TV]) * u_max
    slope_lo = min(0.0, 0.5 * gp[rc.G_KU] * u_max**2) - abs(gp[rc.G_TU]) * u_max - abs(gp[rc.G_TV]) * u_max
    extra_hi = max(gp[rc.G_CROWN], gp[rc.G_CURB] + max(gp[rc.G_TERR], 0.0) + waves[:, 3].sum())
    extra_lo = min(0.0, gp[rc.G_CURB] + gp[rc.G_TERR] - waves[:, 3].sum())
    gp[rc.G_ZMAX] = gp[rc.G_Z0] + slope_hi + np.clip(bumps[:, 2], 0, None).sum() + extra_hi + 0.01
    gp[rc.G_ZMIN] = gp[rc.G_Z0] + slope_lo + np.clip(bumps[:, 2], None, 0).sum() + extra_lo - 0.01


def _add_roadside(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, style: str, clutter: bool = True,
                  thin_rng: np.random.Generator | None = None) -> None:
    """Buildings, walls, fences, hedges, trees, bushes, poles and signs along both sides of the street, and (with
    `clutter`) the street clutter."""
    p_building = {"urban": 0.85, "residential": 0.55, "open": 0.15}[style]
    for side in (1.0, -1.0):
        u = -115.0 + rng.uniform(0, 10)
        while u < 115.0:
            lot = rng.uniform(8.0, 26.0)
            mid = u + lot / 2
            if not in_cross(lay, mid, lot / 2 + 1.0):
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
        if clutter:
            _add_street_clutter(b, rng, lay, side, style, thin_rng)
    if clutter:
        _add_lane_clutter(b, rng, lay)
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
        if in_cross(lay, u, 2.0) or rng.random() < 0.15:
            continue
        parts, footprint = tree_parts(rng, min_base=2.6)
        b.place(parts, u + rng.uniform(-1, 1), v_line + side * rng.uniform(0.0, 0.3), 0.0, footprint=footprint,
                veg=True)


def _add_poles(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float) -> None:
    """Street lamps near the curb and traffic signs (retro-reflective faces) here and there."""
    spacing = rng.uniform(18.0, 35.0)
    for u in np.arange(-100.0 + rng.uniform(0, spacing), 100.0, spacing):
        if in_cross(lay, u, 0.5):
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


# Street clutter that stage 1 lets through (0.9-2.3 m tall, car-sized or smaller): (model, parts function, weight).
# Kerb line: within a metre of the curb; sidewalk: along its back half; frontage: at the property line.
_KERB_CLUTTER = (("bollard", sf.bollard_parts, 3.0), ("post", sf.post_parts, 2.5),
                 ("short_pole", sf.short_pole_parts, 3.0), ("hydrant", sf.hydrant_parts, 0.7),
                 ("bin", sf.bin_parts, 1.2), ("trunk", vg.trunk_parts, 1.5),
                 ("parked_bicycle", pk.parked_bicycle_parts, 1.0))
_SIDEWALK_CLUTTER = (("bench", sf.bench_parts, 1.0), ("mailbox", sf.mailbox_parts, 0.6),
                     ("utility_box", sf.utility_box_parts, 1.2), ("bin", sf.bin_parts, 1.5),
                     ("planter", sf.planter_parts, 0.8), ("parked_bicycle", pk.parked_bicycle_parts, 1.5),
                     ("parked_motorbike", pk.parked_motorbike_parts, 0.6), ("post", sf.post_parts, 1.0))
_FRONTAGE_CLUTTER = (("wall_fragment", st.wall_fragment_parts, 2.0), ("hedge_fragment", vg.hedge_fragment_parts, 2.0),
                     ("building_corner", st.building_corner_parts, 1.0), ("trunk", vg.trunk_parts, 1.0),
                     ("parked_bicycle", pk.parked_bicycle_parts, 1.0), ("bin", sf.bin_parts, 1.0))
_CLUTTER_SPACING_M = {"urban": 3.5, "residential": 4.5, "open": 9.0}  # mean kerb length per clutter item


# What generate_scene(without=...) leaves out.
SCENE_CHANGES = ("clutter", "beside", "hidden", "partial", "negatives", "groups", "lone_people")


def _pick(rng: np.random.Generator, table: tuple[tuple[str, PartsFn, float], ...]) -> tuple[str, PartsFn]:
    """A (model, parts function) drawn from a clutter table by weight."""
    weights = np.array([w for _, _, w in table])
    name, fn, _ = table[int(rng.choice(len(table), p=weights / weights.sum()))]
    return name, fn


def _add_street_clutter(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, side: float, style: str,
                        thin_rng: np.random.Generator | None = None) -> None:
    """Posts, bollard rows, short poles, bins, benches, parked bikes, wall and hedge fragments along one side.

    Real KITTI streets hold many such proposal-sized background objects (64% of real front-view proposals are
    background only); they stand on the kerb line, the sidewalk and the property line, about every 3.5-9 m.
    With `thin_rng` (the "negatives" change), some posts, short poles and trunks are drawn from `rng` as before
    but not placed (`hard_negatives.thinned_out` decides, from `thin_rng`, so `rng`'s stream is the same either way).
    """

    def place_thin(name: str, parts: list[Part], u: float, v: float, yaw: float) -> None:
        if thinned_out(name, thin_rng):
            return
        b.place(parts, u, v, yaw, model=name)

    walk_in = lay.half_width + 0.25
    walk_out = lay.half_width + lay.sidewalk
    u = -70.0 + rng.exponential(_CLUTTER_SPACING_M[style])
    while u < 95.0:
        if not in_cross(lay, u, 0.5):
            where = rng.random()
            yaw = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.1)
            if where < 0.5:
                name, fn = _pick(rng, _KERB_CLUTTER)
                v = walk_in + rng.uniform(0.05, min(0.8, max(lay.sidewalk - 0.5, 0.1)))
                if name == "bollard" and rng.random() < 0.35:  # a row of bollards along the kerb
                    step = rng.uniform(1.2, 2.2)
                    for k in range(int(rng.integers(3, 9))):
                        b.place(sf.bollard_parts(rng), u + k * step, side * v, 0.0, model="bollard")
                    u += 8 * step
                elif name == "parked_bicycle":
                    b.place(fn(rng), u, side * v, math.pi / 2 + rng.normal(0.0, 0.3), model=name)
                else:
                    place_thin(name, fn(rng), u, side * v, yaw)
            elif where < 0.82:
                name, fn = _pick(rng, _SIDEWALK_CLUTTER)
                v = walk_out - rng.uniform(0.3, max(0.5, lay.sidewalk / 2))
                if name == "parked_bicycle" and rng.random() < 0.5:  # a rack full of bikes
                    _add_bike_rack(b, rng, u, side * v)
                else:
                    place_thin(name, fn(rng), u, side * v, yaw)
            else:
                name, fn = _pick(rng, _FRONTAGE_CLUTTER)
                v = lay.frontage + rng.uniform(-0.8, 0.8)
                facing = yaw if name != "building_corner" else (0.0 if side > 0 else math.pi)
                place_thin(name, fn(rng), u, side * v, facing)
        u += rng.exponential(_CLUTTER_SPACING_M[style])
    u_stop = rng.uniform(5.0, 60.0)
    if rng.random() < 0.3 and not in_cross(lay, u_stop, 4.0):
        b.place(sf.bus_shelter_parts(rng), u_stop, side * (walk_out - 1.2), 0.0 if side > 0 else math.pi,
                model="bus_shelter")


def _add_bike_rack(b: SceneBuilder, rng: np.random.Generator, u: float, v: float) -> None:
    """A bike rack along the sidewalk with parked bicycles standing in it (background beside background: no gap)."""
    length = rng.uniform(2.0, 6.0)
    if not b.place(sf.bike_rack_parts(rng, length), u, v, 0.0, model="bike_rack"):
        return
    for x in np.arange(-length / 2, length / 2 + 1e-6, 0.9):
        if rng.random() < 0.6:
            b.place(pk.parked_bicycle_parts(rng), u + x + rng.uniform(-0.1, 0.1), v, math.pi / 2 + rng.normal(0, 0.1),
                    model="parked_bicycle")


def _add_lane_clutter(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Trailers and motorbikes in the parking lanes, traffic lights at the cross street (placed before the cars)."""
    for side, has_parking in ((-1.0, lay.parking[0]), (1.0, lay.parking[1])):
        if not has_parking:
            continue
        for _ in range(int(rng.poisson(0.8))):
            trailer = rng.random() < 0.4
            name, fn = ("trailer", pk.trailer_parts) if trailer else ("parked_motorbike", pk.parked_motorbike_parts)
            b.place(fn(rng), rng.uniform(-40.0, 60.0), side * (lay.half_width - 1.1 + rng.uniform(-0.2, 0.4)),
                    float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.05), model=name)
    if lay.cross:
        for su in (-1.0, 1.0):
            for sv in (-1.0, 1.0):
                if rng.random() < 0.7:
                    u = lay.cross_u + su * (lay.cross_half_width + rng.uniform(0.3, 0.8))
                    b.place(sf.traffic_light_parts(rng, -sv), u, sv * (lay.half_width + rng.uniform(0.3, 0.7)),
                            0.0 if su < 0 else math.pi, model="traffic_light")


# Lapsed clearance: the share of foreground objects that get a background object against them, and what it is.
_BESIDE = {PEDESTRIAN: (0.3, (("short_pole", sf.short_pole_parts, 2.0), ("post", sf.post_parts, 2.0),
                              ("bin", sf.bin_parts, 1.0),
                              ("bollard", sf.bollard_parts, 1.0), ("trunk", vg.trunk_parts, 1.5),
                              ("wall_fragment", st.wall_fragment_parts, 1.0))),
           CYCLIST: (0.25, (("parked_bicycle", pk.parked_bicycle_parts, 2.0), ("post", sf.post_parts, 1.0),
                            ("short_pole", sf.short_pole_parts, 1.0))),
           CAR: (0.35, (("bollard", sf.bollard_parts, 2.0), ("post", sf.post_parts, 1.5), ("bin", sf.bin_parts, 1.0),
                       ("short_pole", sf.short_pole_parts, 1.0), ("hedge_fragment", vg.hedge_fragment_parts, 1.0),
                       ("parked_motorbike", pk.parked_motorbike_parts, 0.7), ("trunk", vg.trunk_parts, 1.0)))}


def _add_clutter_beside_foreground(b: SceneBuilder, rng: np.random.Generator) -> None:
    """Stand a post, bin, trunk or bike right beside some cars, pedestrians and cyclists (clearance lapsed).

    On real scans stage 1 often proposes a person and a pole, or a car and a bollard, as one cluster (about 9% of
    real car proposals are mixed); synthetic foreground keeps FOREGROUND_GAP_M from everything and never does.
    The clearance is TOUCH_CLEARANCE_M, so the labelled boxes stay clean while stage 1's clusters merge.
    """
    for obj in [o for o in b.objects if o.label in _BESIDE]:
        share, table = _BESIDE[obj.label]
        if rng.random() >= share:
            continue
        name, fn = _pick(rng, table)
        parts = fn(rng)
        half = max(max(abs(p.center[0]) + part_extent(p)[0], abs(p.center[1]) + part_extent(p)[1]) for p in parts)
        for _attempt in range(6):
            ang = float(rng.choice([0.0, 0.5, 1.0, 1.5])) * math.pi + rng.normal(0.0, 0.15)
            ex = obj.local_max[0] if math.cos(ang) >= 0 else -obj.local_min[0]
            ey = obj.local_max[1] if math.sin(ang) >= 0 else -obj.local_min[1]
            reach = abs(ex * math.cos(ang)) + abs(ey * math.sin(ang))
            dist = reach + half + TOUCH_CLEARANCE_M + rng.uniform(0.02, 0.2)
            lx, ly = dist * math.cos(ang), dist * math.sin(ang)
            c, s = math.cos(obj.yaw), math.sin(obj.yaw)
            u, v = b.road_uv(obj.x + c * lx - s * ly, obj.y + s * lx + c * ly)
            if obj.label == CAR and abs(v) < abs(b.road_uv(obj.x, obj.y)[1]):
                continue  # on the kerb side of a car, not in the traffic lane
            if b.place(parts, u, v, obj.yaw - b.road_yaw() + rng.normal(0.0, 0.2), model=name,
                       clearance=TOUCH_CLEARANCE_M):
                break




def _distance_u(rng: np.random.Generator) -> float:
    """Road coordinate of an object: mostly 4-40 m away, more often ahead than behind."""
    dist = rng.uniform(3.0, 12.0) if rng.random() < 0.25 else rng.uniform(8.0, 45.0)
    return float(dist if rng.random() < 0.7 else -dist)


def _add_vehicles(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, style: str) -> None:
    """Parked rows, off-street parking and moving traffic (queues), cars mixed with vans and trucks.

    Parked rows are dense (cars bumper to bumper, as on KITTI's Karlsruhe streets) and off-street lots put cars
    behind the parked row, so near cars are often partly hidden: real cars within 20 m carry about half the
    points of isolated synthetic ones. Cars, vans and trucks overlap in size as KITTI labels them
    (see `synthetic.objects.vehicles`).
    """
    for side, has_parking in ((-1.0, lay.parking[0]), (1.0, lay.parking[1])):
        if not has_parking:
            continue
        occupancy = rng.uniform(0.2, 0.7)  # KITTI: ~4 labelled cars in the front 90 deg of a frame, not 6-7
        u = -60.0 + rng.uniform(0, 5)
        while u < 70.0:
            kind, parts = draw_vehicle(rng, 0.1, 0.03)
            length = max(abs(p.center[0]) + part_extent(p)[0] for p in parts) * 2
            if rng.random() < occupancy and not in_cross(lay, u + length / 2, length / 2 + 1.0):
                flip = math.pi if rng.random() < 0.15 else 0.0
                v = side * (lay.half_width - 1.1 + rng.uniform(-0.15, 0.2))
                b.place(parts, u + length / 2, v, flip + rng.normal(0.0, 0.04), VEHICLE_LABEL[kind], kind)
            u += length + (rng.uniform(0.3, 1.5) if rng.random() < 0.7 else rng.uniform(1.5, 4.0))
    if style != "urban" or rng.random() < 0.3:
        _add_parking_lot(b, rng, lay)
    lane_edge = lay.lanes * lay.lane_width / 2
    for _ in range(int(rng.integers(0, 5))):  # moving vehicles, each maybe leading a queue
        kind, parts = draw_vehicle(rng, 0.1, 0.05)
        for _attempt in range(6):
            lane = int(rng.integers(0, lay.lanes))
            v = -lane_edge + (lane + 0.5) * lay.lane_width + rng.normal(0.0, 0.2)
            u = _distance_u(rng)
            if abs(v - lay.v_ego) < lay.lane_width / 2 and abs(u) < 9.0:
                continue
            heading = 0.0 if v < 0 or lay.lanes == 1 else math.pi
            if b.place(parts, u, v, heading + rng.normal(0.0, 0.03), VEHICLE_LABEL[kind], kind):
                length = max(abs(p.center[0]) + part_extent(p)[0] for p in parts) * 2
                for _k in range(int(rng.choice(3, p=[0.5, 0.3, 0.2]))):  # a queue behind it, one lane, same way
                    u += math.copysign(length / 2 + rng.uniform(1.5, 5.0), u if u != 0 else 1.0)
                    kind, parts = draw_vehicle(rng, 0.08, 0.03)
                    length = max(abs(p.center[0]) + part_extent(p)[0] for p in parts) * 2
                    u += math.copysign(length / 2, u)
                    b.place(parts, u, v + rng.normal(0.0, 0.15), heading + rng.normal(0.0, 0.03),
                            VEHICLE_LABEL[kind], kind)
                break
    if lay.cross:
        for _ in range(int(rng.integers(0, 3))):
            parts = car_parts(rng)
            v = rng.choice([-1.0, 1.0]) * rng.uniform(lay.half_width + 3.0, 40.0)
            u = lay.cross_u + rng.choice([-1.0, 1.0]) * lay.cross_half_width * 0.5
            b.place(parts, u, v, math.pi / 2 * rng.choice([-1.0, 1.0]) + rng.normal(0, 0.05), CAR, "Car")




def _add_parking_lot(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """A row of cars parked nose-in beyond the sidewalk (a lot, driveways): cars behind cars, seen through gaps."""
    side = float(rng.choice([-1.0, 1.0]))
    u = rng.uniform(-35.0, 35.0)
    spacing = rng.uniform(2.4, 3.0)
    for k in range(int(rng.integers(2, 8))):
        if rng.random() > 0.8:
            continue
        kind, parts = draw_vehicle(rng, 0.08, 0.0)
        length = max(abs(p.center[0]) + part_extent(p)[0] for p in parts) * 2
        v = side * (lay.half_width + lay.sidewalk + 0.6 + length / 2 + rng.uniform(0.0, 0.5))
        yaw = side * math.pi / 2 + (math.pi if rng.random() < 0.4 else 0.0) + rng.normal(0.0, 0.05)
        uk = u + k * spacing
        if not in_cross(lay, uk, 2.0):
            b.place(parts, uk, v, yaw, VEHICLE_LABEL[kind], kind)


def _lateral(heading: float, d: float) -> tuple[float, float]:
    """Road-coordinate offset `d` metres to the left of a heading."""
    return -math.sin(heading) * d, math.cos(heading) * d


def _add_people(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Pedestrians (alone, pairs and groups shoulder to shoulder, pushing bikes or strollers), seated people and
    cyclists.

    Class rules (see `synthetic.objects.people`): a rider is a Cyclist; a person walking a bicycle is a Pedestrian
    and the bicycle background; seated people (KITTI's Person_sitting) and strollers are background. Group
    members walk TOUCH_CLEARANCE_M apart, close enough that stage 1 proposes a pair as one cluster (real
    pedestrian proposals are 0.85 x 0.52 m, wider than one person) while each labelled box stays clean.
    """
    n_ped = int(rng.choice(6, p=[0.15, 0.22, 0.23, 0.16, 0.14, 0.1]))
    placed = 0
    while placed < n_ped:
        group = min(int(rng.choice([1, 2, 3, 4], p=[0.5, 0.3, 0.13, 0.07])), n_ped - placed)
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
        if group == 1 and rng.random() < 0.12:
            _add_pedestrian_with(b, rng, u, v, heading)
            placed += 1
            continue
        pose = "walk" if rng.random() < 0.75 else "stand"
        offset = 0.0
        for member in range(group):
            for _attempt in range(8):
                if member == 0:
                    du, dv = (0.0, 0.0) if _attempt == 0 else tuple(rng.normal(0.0, 0.5, size=2))
                else:  # shoulder to shoulder, or a step behind; farther out on each retry
                    offset_try = offset + rng.uniform(0.75, 0.95) + 0.12 * _attempt
                    du, dv = _lateral(heading, offset_try)
                    du += rng.normal(0.0, 0.15) + math.cos(heading) * rng.uniform(-0.3, 0.3)
                yaw = heading + rng.normal(0.0, 0.15)
                parts, lo, hi = pedestrian(rng, pose)
                if b.place(parts, u + du, v + dv, yaw, PEDESTRIAN, "Pedestrian",
                           clearance=TOUCH_CLEARANCE_M if member else None, extent=(lo, hi)):
                    if member:
                        offset = offset_try
                    break
            placed += 1
    _add_seated_people(b, rng, lay)
    _add_cyclists(b, rng, lay)


def _add_pedestrian_with(b: SceneBuilder, rng: np.random.Generator, u: float, v: float, heading: float) -> None:
    """A pedestrian pushing a bicycle at their left or a stroller ahead (the bicycle and stroller background)."""
    bike = rng.random() < 0.65
    reach = rng.uniform(0.1, 0.2) if bike else 0.0
    parts, lo, hi = pedestrian(rng, "walk" if rng.random() < 0.8 else "stand", reach=reach)
    if not b.place(parts, u, v, heading + rng.normal(0.0, 0.05), PEDESTRIAN, "Pedestrian", extent=(lo, hi)):
        return
    person_hi = hi  # the amodal extent: the footprint it keeps clear
    if bike:
        thing = bicycle_parts(rng)
        half_w = max(abs(p.center[1]) + part_extent(p)[1] for p in thing)
        du, dv = _lateral(heading, person_hi[1] + TOUCH_CLEARANCE_M + 0.03 + half_w)
        du += math.cos(heading) * rng.uniform(0.0, 0.3)
        model = "pushed_bicycle"
    else:
        thing = stroller_parts(rng)
        back = -min(p.center[0] - part_extent(p)[0] for p in thing)
        d = person_hi[0] + TOUCH_CLEARANCE_M + 0.03 + back
        du, dv = math.cos(heading) * d, math.sin(heading) * d
        model = "stroller"
    b.place(thing, u + du, v + dv, heading, model=model, clearance=TOUCH_CLEARANCE_M)


def _add_seated_people(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """People on benches, café chairs or a step (background: KITTI's Person_sitting), facing the street."""
    for _ in range(int(rng.choice(4, p=[0.45, 0.3, 0.15, 0.1]))):
        seat = str(rng.choice(["bench", "chair", "curb"], p=[0.45, 0.35, 0.2]))
        side = float(rng.choice([-1.0, 1.0]))
        if seat == "chair":  # café tables along the building front
            v = side * (lay.frontage - rng.uniform(0.6, 1.5))
        else:
            v = side * (lay.half_width + rng.uniform(0.6, max(lay.sidewalk - 0.3, 0.7)))
        facing = -math.pi / 2 if side > 0 else math.pi / 2
        b.place(seated_person_parts(rng, seat), _distance_u(rng), v, facing + rng.normal(0.0, 0.3),
                model="person_sitting")


def _add_cyclists(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Cyclists along the lane edge, on the sidewalk, and crossing or turning."""
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


def generate_scene(rng: np.random.Generator, without: frozenset[str] = frozenset()) -> Scene:
    """A random street scene; everything drawn from `rng`, so one seed gives one scene.

    `without` leaves world changes out, for an ablation: "clutter" (street and lane clutter), "beside" (clutter
    standing against foreground objects), "hidden" (pedestrians placed behind parked cars and low things),
    "partial" (occluders in front of cars: cars seen as pieces, `occlusion.add_partial_views`), "negatives"
    (car-sized low and leafy background, fewer thin posts: `hard_negatives.add_hard_negatives`), "groups" (2-4
    pedestrians a hand's breadth apart, pedestrians beside riders: `crowds.add_groups`), "lone_people" (lone
    pedestrians far away, some holding a suitcase, a box or bags: `crowds.add_lone_pedestrians`); the rest of the
    scene is drawn from the same stream, so it differs too (except without "hidden", "partial", "negatives", "groups"
    or "lone_people", drawn from their own; without one of these the objects placed after it may stand elsewhere:
    the hidden pedestrians after "negatives" and "partial", the lone pedestrians after those, "hidden" and "groups").
    "groups" and "lone_people" come last: without both, a seed gives the scene it gave before they were added, object
    for object.
    """
    style = str(rng.choice(["urban", "residential", "open"], p=[0.45, 0.45, 0.1]))
    lay = road_layout(rng, style)
    gp, bumps, waves = _ground_params(rng, lay)
    b = SceneBuilder(gp, bumps, waves)
    # "negatives", "partial", "groups" and "lone_people" draw from streams of their own, so leaving one out keeps
    # the rest of the scene.
    negatives_rng = np.random.Generator(rng.bit_generator.jumped(2))
    partial_rng = np.random.Generator(rng.bit_generator.jumped(3))
    groups_rng = np.random.Generator(rng.bit_generator.jumped(4))  # the crowds' people, placed last (see above)
    lone_rng = np.random.Generator(rng.bit_generator.jumped(5))
    negatives = "negatives" not in without
    _add_roadside(b, rng, lay, style, clutter="clutter" not in without, thin_rng=negatives_rng if negatives else None)
    _add_vehicles(b, rng, lay, style)
    _add_people(b, rng, lay)
    hidden_rng = np.random.Generator(rng.bit_generator.jumped())  # its own stream: the rest of the scene is kept
    if "beside" not in without:
        _add_clutter_beside_foreground(b, rng)
    lane_edge = lay.lanes * lay.lane_width / 2
    lines = [-lane_edge + k * lay.lane_width for k in range(lay.lanes + 1)]
    n_patches = int(rng.integers(0, 9))
    u0 = rng.uniform(-40.0, 40.0, n_patches)
    v0 = rng.uniform(-lay.half_width, lay.half_width, n_patches)
    patches = np.stack([u0, u0 + rng.uniform(2.0, 15.0, n_patches), v0, v0 + rng.uniform(0.4, 3.0, n_patches)], axis=1)
    rho = (float(rng.uniform(0.3, 0.42)), float(rng.uniform(0.42, 0.56)), float(rng.uniform(0.5, 0.65)))
    if negatives:
        add_hard_negatives(b, negatives_rng, lay)
    if "partial" not in without:
        add_partial_views(b, partial_rng, lay)
    if "hidden" not in without:
        add_hidden_pedestrians(b, hidden_rng)
    if "groups" not in without:
        add_groups(b, groups_rng, lay)
    if "lone_people" not in without:
        add_lone_pedestrians(b, lone_rng, lay)
    return b.build(np.array(lines), patches, *rho)
