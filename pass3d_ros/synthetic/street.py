"""The street a scene stands on: its cross-section (`RoadLayout`) and the road users drawn on it.

Shared by `synthetic.scene` and its add-ons (`synthetic.occlusion`, `synthetic.hard_negatives`), which place things
by road coordinates (u along the road, v across it) and draw vehicles with the same shares and labels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR
from pass3d_ros.synthetic.objects.vehicles import car_parts, truck_parts, van_parts
from pass3d_ros.synthetic.parts import Part

PartsFn = Callable[[np.random.Generator], list[Part]]


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


def road_layout(rng: np.random.Generator, style: str) -> RoadLayout:
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


def in_cross(lay: RoadLayout, u: float, margin: float) -> bool:
    """Whether road coordinate `u` lies within `margin` of the cross street (its road and sidewalks)."""
    return lay.cross and abs(u - lay.cross_u) < lay.cross_half_width + lay.sidewalk + margin


# Class of each KITTI vehicle kind: only Car is foreground (SqueezeSeg's rule; vans and trucks are background).
VEHICLE_LABEL = {"Car": CAR, "Van": BACKGROUND, "Truck": BACKGROUND}


def draw_vehicle(rng: np.random.Generator, p_van: float, p_truck: float) -> tuple[str, list[Part]]:
    """(KITTI kind, parts) of a car, van or truck drawn with the given shares."""
    r = rng.random()
    if r < p_van:
        return "Van", van_parts(rng)
    if r < p_van + p_truck:
        return "Truck", truck_parts(rng)
    return "Car", car_parts(rng)
