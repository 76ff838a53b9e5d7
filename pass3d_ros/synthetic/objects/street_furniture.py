"""Street furniture models: lamps, signs, posts, bollards, traffic lights, bins, benches, shelters (background).

Most of them are 0.9-2.3 m tall and narrow, so stage 1 keeps them as proposals that stage 2 must call background
(a short pole looks like a pedestrian); the layout stands them on kerb lines and sidewalks.
"""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic.materials import M_CABIN, M_METAL, M_OTHER, M_PAINT, M_POLE, M_SIGN, M_VEGETATION, M_WALL
from pass3d_ros.synthetic.parts import Part, box, cylinder, disc, ellipsoid


def street_lamp_parts(rng: np.random.Generator, arm_side: float) -> list[Part]:
    """Street lamp: a tall pole whose arm and lamp head reach out along `arm_side` * y (toward the road)."""
    height, radius = rng.uniform(5.0, 9.0), rng.uniform(0.06, 0.12)
    rho = float(rng.uniform(0.1, 0.35))
    arm = rng.uniform(0.8, 2.0)
    return [
        cylinder([0, 0, -0.2], [0, 0, height], radius, M_POLE, rho),
        cylinder([0, 0, height - 0.1], [0, arm_side * arm, height + 0.15], 0.04, M_POLE, rho),
        box([0, arm_side * arm, height + 0.05], [0.3, 0.15, 0.08], M_POLE, rho),
    ]


def sign_parts(rng: np.random.Generator) -> list[Part]:
    """Traffic sign: a thin post with a round or square retro-reflective face toward +x."""
    height = rng.uniform(2.2, 3.2)
    rho_sign = float(rng.uniform(0.6, 0.95))
    parts = [cylinder([0, 0, -0.2], [0, 0, height], 0.035, M_POLE, 0.25)]
    if rng.random() < 0.5:
        parts.append(disc([0.05, 0, height - 0.1], [1, 0, 0], rng.uniform(0.3, 0.45), 0.01, M_SIGN, rho_sign))
    else:
        parts.append(box([0.05, 0, height - 0.2], [0.01, rng.uniform(0.3, 0.45), rng.uniform(0.3, 0.45)],
                         M_SIGN, rho_sign))
    return parts


def post_parts(rng: np.random.Generator) -> list[Part]:
    """Post: a round or square metal or wooden post 0.9-1.8 m tall (barrier, parking-meter or marker post)."""
    height, radius = rng.uniform(0.9, 1.8), rng.uniform(0.04, 0.1)
    rho = float(rng.uniform(0.1, 0.5))
    if rng.random() < 0.5:
        parts = [cylinder([0, 0, -0.2], [0, 0, height], radius, M_POLE, rho)]
    else:
        parts = [box([0, 0, height / 2 - 0.1], [radius, radius, height / 2 + 0.1], M_POLE, rho)]
    if rng.random() < 0.3:  # a meter head or reflector cap
        parts.append(box([0, 0, height + 0.12], [0.1, 0.12, 0.15], M_METAL, float(rng.uniform(0.2, 0.7))))
    return parts


def bollard_parts(rng: np.random.Generator) -> list[Part]:
    """Bollard: a stout post 0.7-1.2 m tall, often with a reflective band."""
    height, radius = rng.uniform(0.7, 1.2), rng.uniform(0.06, 0.15)
    rho = float(rng.uniform(0.15, 0.5))
    parts = [cylinder([0, 0, -0.2], [0, 0, height], radius, M_POLE, rho)]
    if rng.random() < 0.5:
        parts.append(cylinder([0, 0, height - 0.2], [0, 0, height - 0.1], radius + 0.005, M_SIGN, 0.9))
    return parts


def short_pole_parts(rng: np.random.Generator) -> list[Part]:
    """Short sign pole 1.6-2.3 m with a small plate (parking, bus stop, street name): pedestrian-sized."""
    height = rng.uniform(1.6, 2.3)
    parts = [cylinder([0, 0, -0.2], [0, 0, height], rng.uniform(0.03, 0.05), M_POLE, float(rng.uniform(0.15, 0.4)))]
    if rng.random() < 0.75:
        w, h = rng.uniform(0.15, 0.35), rng.uniform(0.15, 0.4)
        parts.append(box([0.04, 0, height - h], [0.01, w, h], M_SIGN, float(rng.uniform(0.5, 0.95))))
    return parts


def traffic_light_parts(rng: np.random.Generator, arm_side: float) -> list[Part]:
    """Traffic light: a pole with a signal head at 2.2-3.5 m, sometimes a push-button box and an arm."""
    height = rng.uniform(2.6, 4.2)
    rho = float(rng.uniform(0.1, 0.35))
    head_z = rng.uniform(2.2, height - 0.4)
    parts = [
        cylinder([0, 0, -0.2], [0, 0, height], rng.uniform(0.05, 0.09), M_POLE, rho),
        box([0.12, 0, head_z], [0.1, 0.15, 0.45], M_PAINT, 0.05),
        box([0.0, 0.09, 1.1], [0.06, 0.05, 0.1], M_METAL, float(rng.uniform(0.2, 0.6))),
    ]
    if rng.random() < 0.3:
        arm = rng.uniform(2.0, 5.0)
        parts.append(cylinder([0, 0, height - 0.2], [0, arm_side * arm, height - 0.2], 0.06, M_POLE, rho))
        parts.append(box([0.1, arm_side * arm, height - 0.6], [0.1, 0.15, 0.4], M_PAINT, 0.05))
    return parts


def bin_parts(rng: np.random.Generator) -> list[Part]:
    """Litter bin or wheelie bin: 0.8-1.3 m, round on a post or a rounded box."""
    rho = float(rng.uniform(0.05, 0.5))
    if rng.random() < 0.5:
        h, r = rng.uniform(0.8, 1.1), rng.uniform(0.2, 0.3)
        return [cylinder([0, 0, h - 0.55], [0, 0, h], r, M_PAINT, rho),
                cylinder([0, 0, -0.2], [0, 0, h - 0.55], 0.04, M_POLE, 0.2)]
    h, d, w = rng.uniform(0.95, 1.3), rng.uniform(0.55, 1.1), rng.uniform(0.55, 1.4)
    return [box([0, 0, h / 2], [d / 2, w / 2, h / 2], M_OTHER, rho, rounding=(1.3, 1.3, 1.5))]


def mailbox_parts(rng: np.random.Generator) -> list[Part]:
    """Post box (pillar or box on a stand) 1.1-1.6 m tall."""
    rho = float(rng.uniform(0.2, 0.6))
    h = rng.uniform(1.1, 1.6)
    if rng.random() < 0.5:
        return [cylinder([0, 0, -0.2], [0, 0, h], rng.uniform(0.2, 0.3), M_PAINT, rho)]
    return [box([0, 0, h - 0.3], [0.2, 0.3, 0.3], M_PAINT, rho),
            cylinder([0, 0, -0.2], [0, 0, h - 0.6], 0.05, M_POLE, 0.2)]


def hydrant_parts(rng: np.random.Generator) -> list[Part]:
    """Fire hydrant: a short column 0.6-1.0 m with side nozzles and a domed top."""
    h, r = rng.uniform(0.6, 1.0), rng.uniform(0.1, 0.15)
    rho = float(rng.uniform(0.3, 0.7))
    return [cylinder([0, 0, -0.2], [0, 0, h], r, M_PAINT, rho),
            cylinder([0, -r - 0.08, h * 0.65], [0, r + 0.08, h * 0.65], 0.05, M_PAINT, rho),
            ellipsoid([0, 0, h], [r, r, 0.08], M_PAINT, rho)]


def bench_parts(rng: np.random.Generator) -> list[Part]:
    """Bench 1.5-2.5 m long along x: seat, backrest at 0.8-1.0 m, legs."""
    length = rng.uniform(1.5, 2.5)
    rho = float(rng.uniform(0.15, 0.5))
    back = rng.uniform(0.8, 1.0)
    parts = [box([0, 0, 0.45], [length / 2, 0.22, 0.03], M_OTHER, rho),
             box([0, -0.22, 0.5 * (0.55 + back)], [length / 2, 0.03, 0.5 * (back - 0.55)], M_OTHER, rho)]
    for x in (-length / 2 + 0.15, length / 2 - 0.15):
        parts.append(box([x, -0.05, 0.2], [0.03, 0.2, 0.3], M_METAL, 0.2))
    return parts


def bus_shelter_parts(rng: np.random.Generator) -> list[Part]:
    """Bus shelter 3-6 m along x: glass back and side panels (partly returned), roof at 2.4-2.8 m, an ad column."""
    length, depth, height = rng.uniform(3.0, 6.0), rng.uniform(1.2, 1.8), rng.uniform(2.4, 2.8)
    rho = float(rng.uniform(0.2, 0.4))
    parts = [
        box([0, -depth / 2, height / 2], [length / 2, 0.02, height / 2 - 0.1], M_CABIN, 0.1),
        box([0, 0, height], [length / 2 + 0.1, depth / 2 + 0.1, 0.06], M_METAL, rho),
        box([length / 2, 0, height / 2], [0.02, depth / 2, height / 2 - 0.1], M_CABIN, 0.1),
        box([-length / 2, -depth / 4, height / 2], [0.15, depth / 4, height / 2], M_SIGN, float(rng.uniform(0.4, 0.8))),
    ]
    for x in (-length / 2, length / 2):
        for y in (-depth / 2, depth / 2):
            parts.append(cylinder([x, y, -0.1], [x, y, height], 0.04, M_POLE, rho))
    return parts


def bike_rack_parts(rng: np.random.Generator, length: float) -> list[Part]:
    """Bike rack `length` along x: inverted-U hoops 0.8 m high every 0.8-1.0 m, across the rack."""
    rho = float(rng.uniform(0.2, 0.5))
    parts = []
    for x in np.arange(-length / 2, length / 2 + 1e-6, rng.uniform(0.8, 1.0)):
        for y in (-0.3, 0.3):
            parts.append(cylinder([x, y, -0.1], [x, y, 0.8], 0.025, M_POLE, rho))
        parts.append(cylinder([x, -0.3, 0.8], [x, 0.3, 0.8], 0.025, M_POLE, rho))
    return parts


def utility_box_parts(rng: np.random.Generator) -> list[Part]:
    """Utility cabinet or ticket machine: a box 1.0-1.8 m tall on the sidewalk."""
    h, d, w = rng.uniform(1.0, 1.8), rng.uniform(0.3, 0.6), rng.uniform(0.5, 1.4)
    return [box([0, 0, h / 2 - 0.1], [d / 2, w / 2, h / 2 + 0.1], M_WALL, float(rng.uniform(0.2, 0.6)),
                rounding=(1.4, 1.4, 2.0))]


def planter_parts(rng: np.random.Generator) -> list[Part]:
    """Concrete planter or barrier block 0.5-1.0 m tall (a wide low obstacle)."""
    h, r = rng.uniform(0.5, 1.0), rng.uniform(0.4, 0.8)
    return [box([0, 0, h / 2 - 0.1], [r, r * rng.uniform(0.5, 1.0), h / 2 + 0.1], M_WALL, float(rng.uniform(0.3, 0.6)))]


def jersey_barrier_parts(rng: np.random.Generator, length: float) -> list[Part]:
    """Concrete (jersey) barrier run `length` along x: a 0.6 m wide foot and a narrower wall to 0.8-1.1 m, in
    segments 2-4 m long that touch (a low wide proposal: stage 2 sees it beside parked cars as car-long)."""
    height = rng.uniform(0.8, 1.1)
    rho = float(rng.uniform(0.3, 0.6))
    foot, top = rng.uniform(0.28, 0.35), rng.uniform(0.12, 0.16)
    parts = []
    x = -length / 2
    while x < length / 2 - 0.5:
        seg = min(rng.uniform(2.0, 4.0), length / 2 - x)
        cx = x + seg / 2
        parts.append(box([cx, 0, 0.1], [seg / 2 - 0.01, foot, 0.3], M_WALL, rho))
        parts.append(box([cx, 0, 0.4 + (height - 0.4) / 2], [seg / 2 - 0.01, top, (height - 0.4) / 2], M_WALL, rho))
        x += seg
    return parts


def long_planter_parts(rng: np.random.Generator) -> list[Part]:
    """Long concrete planter 2.5-5 m x 0.8-1.5 m, 0.5-0.8 m high, mostly planted with shrubs that reach 0.85-1.5 m:
    a barrier-like block about the footprint of a car, seen low."""
    length, width, h = rng.uniform(2.5, 5.0), rng.uniform(0.8, 1.5), rng.uniform(0.5, 0.8)
    parts = [box([0, 0, h / 2 - 0.1], [length / 2, width / 2, h / 2 + 0.1], M_WALL, float(rng.uniform(0.3, 0.6)))]
    if rng.random() < 0.85:
        top = rng.uniform(0.35, 0.7)
        parts.append(box([0, 0, h + top / 2], [length / 2 - 0.1, width / 2 - 0.1, top / 2 + 0.05], M_VEGETATION,
                         float(rng.uniform(0.35, 0.6)), rounding=(1.1, 1.4, 1.6)))
    return parts
