"""Vehicle models: passenger cars (class Car) and vans and trucks (background, KITTI 'Van' and 'Truck')."""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.materials import M_CABIN, M_METAL, M_PAINT, M_SIGN, M_TIRE, paint_rho
from pass3d_ros.synthetic.parts import Part, box

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
