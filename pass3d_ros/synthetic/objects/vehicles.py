"""Vehicle models with KITTI's class boundaries: cars (class Car) and vans, trucks and buses (background).

KITTI's annotators do not cut Car from Van by height: tall SUVs and minivans (up to about 2.0 m) are labelled
Car, small delivery vans (from about 1.8-1.9 m) Van. The models overlap in the same way, so height alone never
separates the classes. Target means (metres, L x W x H) are the KITTI training-label means tabulated by
Frustum-PointNets (Qi et al., CVPR 2018, `kitti/kitti_util` type_mean_size): Car 3.88 x 1.63 x 1.53,
Van 5.07 x 1.90 x 2.21, Truck 10.14 x 2.59 x 3.25. KITTI labels a bus Truck or Misc, both background here, so
city buses are drawn among the trucks (`truck_parts`).
"""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.materials import M_CABIN, M_METAL, M_PAINT, M_SIGN, M_TIRE, paint_rho
from pass3d_ros.synthetic.parts import Part, box

WHEEL_ROT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # cylinder axis along object y

# Car body styles: name, probability, length / width / height ranges (m), ground clearance, wheel radius,
# cabin length as a share of the car, and the gap between the cabin's rear and the car's rear (m).
# Chosen so the mix averages about 3.9 x 1.65 x 1.52 m (KITTI Car 3.88 x 1.63 x 1.53, see the module docstring).
CAR_STYLES: tuple[tuple[str, float, tuple[float, float], tuple[float, float], tuple[float, float],
                        tuple[float, float], tuple[float, float], float, float], ...] = (
    ("city", 0.22, (2.9, 3.5), (1.5, 1.62), (1.42, 1.58), (0.13, 0.17), (0.27, 0.31), 0.60, 0.18),
    ("hatchback", 0.33, (3.45, 4.0), (1.56, 1.68), (1.4, 1.52), (0.13, 0.18), (0.29, 0.32), 0.58, 0.15),
    ("sedan", 0.2, (4.0, 4.55), (1.62, 1.76), (1.36, 1.5), (0.13, 0.18), (0.3, 0.34), 0.48, 0.75),
    ("suv", 0.12, (3.95, 4.65), (1.68, 1.84), (1.58, 1.98), (0.18, 0.26), (0.34, 0.38), 0.62, 0.12),
    ("minivan", 0.1, (3.95, 4.7), (1.66, 1.8), (1.58, 1.98), (0.14, 0.2), (0.3, 0.34), 0.74, 0.08),
    ("pickup", 0.03, (4.6, 5.3), (1.75, 1.9), (1.62, 1.85), (0.22, 0.28), (0.36, 0.4), 0.33, 1.5),
)
CAR_STYLE_P = np.array([s[1] for s in CAR_STYLES])


def _wheels(xs: list[float], half_track: float, radius: float, rho: float, width: float = 0.1) -> list[Part]:
    return [Part(rc.CYLINDER, np.array([x, side * half_track, radius]), WHEEL_ROT,
                 np.array([radius, radius, width, 0.0, 0.0, 0.0]), M_TIRE, rho)
            for x in xs for side in (1.0, -1.0)]


def _plates(length: float, z: float) -> list[Part]:
    return [box([end * (length / 2 + 0.005), 0.0, z], [0.012, 0.26, 0.06], M_SIGN, 0.95) for end in (1.0, -1.0)]


def car_parts(rng: np.random.Generator, style: str | None = None) -> list[Part]:
    """Passenger car (KITTI 'Car'): city car, hatchback, sedan, SUV, minivan or pickup-like car.

    A rounded body, a rounded cabin (glass sides, painted roof) placed by style, four wheels; a pickup gets an
    open bed (side walls and tailgate) behind a short cabin. Tall SUVs and minivans reach 1.98 m, as KITTI's
    Car boxes do.
    """
    k = int(rng.choice(len(CAR_STYLES), p=CAR_STYLE_P)) if style is None else \
        [s[0] for s in CAR_STYLES].index(style)
    name, _, l_rng, w_rng, h_rng, c_rng, r_rng, cabin_share, rear_gap = CAR_STYLES[k]
    length, width, height = rng.uniform(*l_rng), rng.uniform(*w_rng), rng.uniform(*h_rng)
    clearance, wheel_r = rng.uniform(*c_rng), rng.uniform(*r_rng)
    rho = paint_rho(rng)
    tall = name in ("suv", "minivan")
    body_top = clearance + (height - clearance) * rng.uniform(0.5, 0.58 if tall else 0.56)
    cabin_len = min(length * cabin_share * rng.uniform(0.94, 1.06), length - 0.5)
    gap = rear_gap * rng.uniform(0.8, 1.2) if name != "pickup" else length - cabin_len - rng.uniform(0.9, 1.2)
    cabin_x = -(length / 2 - cabin_len / 2 - gap)
    cabin_bottom = body_top - 0.06
    roof_round = rng.uniform(1.2, 1.3) if tall else rng.uniform(1.1, 1.2)  # tall bodies are boxier
    parts = [
        box([0.0, 0.0, 0.5 * (clearance + body_top)], [length / 2, width / 2, 0.5 * (body_top - clearance)],
            M_PAINT, rho, rounding=(1.08 if tall else 1.12, 1.6, 2.6)),
        # Centred on the belt line: the rounding ellipsoid then gives a domed roof and sloped pillars.
        box([cabin_x, 0.0, cabin_bottom], [cabin_len / 2, 0.46 * width, height - cabin_bottom],
            M_CABIN, rho, rounding=(roof_round, 1.3, rng.uniform(1.25, 1.4) if tall else rng.uniform(1.12, 1.22))),
    ]
    if name == "pickup":
        bed_front = cabin_x - cabin_len / 2 - 0.05
        bed_len = bed_front + length / 2
        wall_h = rng.uniform(0.35, 0.45)
        for side in (1.0, -1.0):
            parts.append(box([bed_front - bed_len / 2, side * (width / 2 - 0.03), body_top + wall_h / 2],
                             [bed_len / 2, 0.03, wall_h / 2], M_PAINT, rho))
        parts.append(box([-length / 2 + 0.04, 0.0, body_top + wall_h / 2], [0.03, width / 2 - 0.06, wall_h / 2],
                         M_PAINT, rho))
    if tall and rng.random() < 0.4:  # roof rails
        for side in (1.0, -1.0):
            parts.append(box([cabin_x, side * 0.36 * width, height + 0.01], [cabin_len * 0.4, 0.025, 0.025],
                             M_METAL, 0.3))
    axle = length / 2 - rng.uniform(0.62, 0.9) * (1.0 if length > 3.6 else 0.85)
    parts += _wheels([axle, -axle], width / 2 - 0.13, wheel_r, float(rng.uniform(0.02, 0.08)))
    parts += _plates(length, clearance + 0.35 * (body_top - clearance))
    return parts


def van_parts(rng: np.random.Generator) -> list[Part]:
    """Van (background, KITTI 'Van'): small delivery van, minibus or panel van.

    Small vans (Caddy, Kangoo class) are only 1.8-1.95 m tall, lower than the tallest cars; panel vans reach
    2.6 m. The mix averages about 5.1 x 1.9 x 2.15 m (KITTI Van 5.07 x 1.90 x 2.21).
    """
    kind = rng.random()
    if kind < 0.3:  # small delivery van: car-like nose, tall boxy rear
        length, width, height = rng.uniform(4.1, 4.7), rng.uniform(1.72, 1.86), rng.uniform(1.8, 1.98)
        nose, clearance, wheel_r = rng.uniform(0.8, 1.1), rng.uniform(0.15, 0.2), rng.uniform(0.3, 0.33)
    elif kind < 0.65:  # minibus (T5 class): short nose
        length, width, height = rng.uniform(4.8, 5.3), rng.uniform(1.86, 1.96), rng.uniform(1.9, 2.1)
        nose, clearance, wheel_r = rng.uniform(0.55, 0.8), rng.uniform(0.17, 0.22), rng.uniform(0.32, 0.35)
    else:  # panel van (Sprinter class)
        length, width, height = rng.uniform(5.2, 6.4), rng.uniform(1.93, 2.05), rng.uniform(2.25, 2.65)
        nose, clearance, wheel_r = rng.uniform(0.7, 1.0), rng.uniform(0.2, 0.26), rng.uniform(0.33, 0.37)
    rho = paint_rho(rng)
    parts = [
        box([-nose / 2, 0.0, 0.5 * (clearance + height)], [(length - nose) / 2, width / 2, 0.5 * (height - clearance)],
            M_PAINT, rho, rounding=(1.08, 1.25, 1.35)),
        box([length / 2 - nose / 2 - 0.05, 0.0, clearance + 0.45], [nose / 2 + 0.05, width / 2 - 0.03, 0.45],
            M_PAINT, rho, rounding=(1.2, 1.4, 1.6)),
    ]
    axle = length / 2 - rng.uniform(0.75, 0.95)
    parts += _wheels([axle, -axle + 0.1], width / 2 - 0.14, wheel_r, 0.05)
    parts += _plates(length, clearance + 0.25)
    return parts


def bus_parts(rng: np.random.Generator) -> list[Part]:
    """City bus (background, KITTI 'Truck' or 'Misc'): a 10.5-12.2 m two-axle low-floor solo bus.

    Sizes are typical published figures of the Mercedes-Benz Citaro (Daimler technical information: 11.95 m solo,
    10.5 m Citaro K midi; 2.55 m wide; 3.08-3.12 m high with the roof air conditioning; front / rear overhang
    2.7 / 3.4 m; 275/70 R 22.5 tyres, radius about 0.48 m; boarding height 0.32 m). A painted box body 2.9-3.1 m
    high, 0.3 m above the road, with a window band all round but the engine wall at the back (glass as on car
    cabins, 1.0-1.2 m to 2.5-2.7 m up) and a roof unit on top (3.05-3.35 m in all). Mean 11.35 x 2.53 x 3.2 m.
    """
    length, width = rng.uniform(10.5, 12.2), rng.uniform(2.5, 2.55)
    body_h, unit_h = rng.uniform(2.9, 3.1), rng.uniform(0.15, 0.25)
    window_lo, window_hi = rng.uniform(1.0, 1.2), rng.uniform(2.5, 2.7)
    front, rear, wheel_r = rng.uniform(2.5, 2.7), rng.uniform(3.2, 3.5), rng.uniform(0.47, 0.5)
    rho = paint_rho(rng)
    clearance, engine_wall, inset = 0.3, 0.25, 0.02  # glass sits `inset` behind the body's faces
    glass_back, glass_front = -length / 2 + engine_wall, length / 2 - inset
    glass_x, glass_half = 0.5 * (glass_back + glass_front), 0.5 * (glass_front - glass_back)
    band_z, band_h = 0.5 * (window_lo + window_hi), 0.5 * (window_hi - window_lo)
    parts = [
        box([0.0, 0.0, 0.5 * (clearance + window_lo)], [length / 2, width / 2, 0.5 * (window_lo - clearance)],
            M_PAINT, rho),
        box([glass_x, 0.0, band_z], [glass_half, width / 2 - inset, band_h], M_CABIN, rho),
        box([-length / 2 + engine_wall / 2, 0.0, band_z], [engine_wall / 2, width / 2, band_h], M_PAINT, rho),
        box([0.0, 0.0, 0.5 * (window_hi + body_h)], [length / 2, width / 2, 0.5 * (body_h - window_hi)], M_PAINT, rho),
        box([0.1 * length, 0.0, body_h + unit_h / 2], [1.5, 0.38 * width, unit_h / 2], M_PAINT, rho),
    ]
    parts += _wheels([length / 2 - front, -length / 2 + rear], width / 2 - 0.25, wheel_r, 0.04, width=0.25)
    return parts


def truck_parts(rng: np.random.Generator) -> list[Part]:
    """Truck (background, KITTI 'Truck'): tractor with semi-trailer (30 %), city bus (15 %, `bus_parts`) or box
    truck (55 %); two to four axles.

    The mix averages about 10.35 x 2.46 x 3.29 m (KITTI Truck 10.14 x 2.59 x 3.25; 9.9 x 2.45 x 3.3 before the buses).
    The first draw picks the kind; box trucks and semis then draw exactly as they did before buses were added.
    """
    r = rng.random()
    if 0.3 <= r < 0.45:
        return bus_parts(rng)
    semi = r < 0.3
    length = rng.uniform(12.0, 16.5) if semi else rng.uniform(6.0, 10.0)
    width, height = rng.uniform(2.35, 2.55), rng.uniform(2.9, 3.9 if semi else 3.6)
    cab_len, cab_h, clearance, wheel_r = rng.uniform(1.9, 2.4), rng.uniform(2.5, 3.1), 0.35, rng.uniform(0.48, 0.53)
    rho_cab, rho_box = paint_rho(rng), float(rng.uniform(0.2, 0.6))
    cargo_len = length - cab_len - (0.6 if semi else 0.15)
    parts = [
        box([length / 2 - cab_len / 2, 0.0, 0.5 * (clearance + cab_h)],
            [cab_len / 2, width / 2 - 0.03, 0.5 * (cab_h - clearance)], M_PAINT, rho_cab, rounding=(1.15, 1.3, 1.4)),
        box([-length / 2 + cargo_len / 2, 0.0, 0.5 * (1.0 + height)], [cargo_len / 2, width / 2, 0.5 * (height - 1.0)],
            M_PAINT, rho_box),
        box([-length / 2 + cargo_len / 2, 0.0, 0.75], [cargo_len / 2 - 0.3, width / 2 - 0.3, 0.2], M_METAL, 0.1),
    ]
    front = length / 2 - 1.1
    if semi:
        axles = [front, front - 3.4, -length / 2 + 1.2, -length / 2 + 2.5]
    else:
        axles = [front, -length / 2 + 1.3] + ([-length / 2 + 2.5] if length > 8.0 else [])
    parts += _wheels(axles, width / 2 - 0.25, wheel_r, 0.04, width=0.25)
    return parts
