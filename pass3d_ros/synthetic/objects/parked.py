"""Riderless two-wheelers and trailers: background under SqueezeSeg's rule, yet shaped like cyclists and cars.

KITTI labels a parked bicycle or motorbike Misc or DontCare, and a trailer Misc, so their points are background;
stage 1 proposes them like cyclists and cars, which is why stage 2 must see them in training.
"""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.materials import M_METAL, M_OTHER, M_PAINT, M_TIRE, paint_rho
from pass3d_ros.synthetic.objects.vehicles import WHEEL_ROT
from pass3d_ros.synthetic.parts import Part, box, cylinder, disc


def parked_bicycle_parts(rng: np.random.Generator) -> list[Part]:
    """Bicycle standing alone along x (on its stand or against something), leaning a little, no rider."""
    wheel_r, base = rng.uniform(0.3, 0.36), rng.uniform(1.0, 1.12)
    rho_bike, rho_tire = float(rng.uniform(0.1, 0.55)), float(rng.uniform(0.02, 0.1))
    lean = rng.uniform(-0.12, 0.12)
    rear, front = np.array([-base / 2, 0.0, wheel_r]), np.array([base / 2, 0.0, wheel_r])
    bb = np.array([-base / 2 + 0.43, 0.0, 0.3])
    saddle = bb + np.array([-0.2, 0.0, rng.uniform(0.55, 0.7)])
    head = np.array([base / 2 - 0.12, 0.0, rng.uniform(0.8, 0.95)])
    bar = head + np.array([-0.05, 0.0, rng.uniform(0.08, 0.2)])

    def tilt(p: np.ndarray) -> np.ndarray:
        return np.array([p[0], p[1] + lean * p[2], p[2]])

    parts = [
        disc(tilt(rear), [0, 1, 0], wheel_r, 0.025, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        disc(tilt(front), [0, 1, 0], wheel_r, 0.025, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        cylinder(tilt(bb), tilt(saddle), 0.02, M_METAL, rho_bike),
        cylinder(tilt(bb), tilt(head), 0.025, M_METAL, rho_bike),
        cylinder(tilt(saddle), tilt(head), 0.02, M_METAL, rho_bike),
        cylinder(tilt(bb), tilt(rear), 0.015, M_METAL, rho_bike),
        cylinder(tilt(head), tilt(front), 0.02, M_METAL, rho_bike),
        cylinder(tilt(bar + np.array([0, -0.27, 0])), tilt(bar + np.array([0, 0.27, 0])), 0.015, M_METAL, rho_bike),
        box(tilt(saddle + np.array([0, 0, 0.03])), [0.13, 0.07, 0.03], M_OTHER, 0.1),
    ]
    if rng.random() < 0.3:  # basket or bag
        rho_bag = float(rng.uniform(0.1, 0.5))
        parts.append(box(tilt(bar + np.array([0.2, 0, -0.1])), [0.15, 0.18, 0.12], M_OTHER, rho_bag))
    return parts


def parked_motorbike_parts(rng: np.random.Generator) -> list[Part]:
    """Motorbike or scooter on its stand along x, no rider: 1.8-2.2 m long, 1.0-1.4 m high."""
    length, wheel_r = rng.uniform(1.8, 2.2), rng.uniform(0.25, 0.33)
    rho = paint_rho(rng)
    top = rng.uniform(1.0, 1.4)
    axle = length / 2 - wheel_r
    parts = [
        disc([axle, 0.0, wheel_r], [0, 1, 0], wheel_r, 0.06, M_TIRE, 0.05),
        disc([-axle, 0.0, wheel_r], [0, 1, 0], wheel_r, 0.07, M_TIRE, 0.05),
        box([0.0, 0.0, wheel_r + 0.2], [length / 2 - wheel_r, 0.2, 0.25], M_PAINT, rho, rounding=(1.2, 1.5, 1.6)),
        box([-0.2, 0.0, wheel_r + 0.5], [0.4, 0.15, 0.06], M_OTHER, 0.05),
        cylinder([axle - 0.1, 0.0, wheel_r], [axle - 0.25, 0.0, top - 0.05], 0.035, M_METAL, 0.3),
        cylinder([axle - 0.25, -0.35, top - 0.05], [axle - 0.25, 0.35, top - 0.05], 0.02, M_METAL, 0.3),
    ]
    if rng.random() < 0.4:  # top box
        parts.append(box([-length / 2 + 0.25, 0.0, wheel_r + 0.75], [0.2, 0.2, 0.17], M_PAINT, rho))
    return parts


def trailer_parts(rng: np.random.Generator) -> list[Part]:
    """Car or box trailer 2.5-5 m long with drawbar, one axle, open flatbed or box (KITTI 'Misc')."""
    length, width = rng.uniform(2.0, 4.0), rng.uniform(1.3, 2.0)
    wheel_r = rng.uniform(0.25, 0.33)
    floor = wheel_r + rng.uniform(0.1, 0.3)
    rho = float(rng.uniform(0.1, 0.5))
    boxed = rng.random() < 0.5
    height = rng.uniform(1.4, 2.2) if boxed else floor + rng.uniform(0.3, 0.5)
    parts = [
        box([0.0, 0.0, 0.5 * (floor + height)], [length / 2, width / 2, 0.5 * (height - floor)],
            M_PAINT if boxed else M_METAL, rho),
        cylinder([length / 2, 0.0, floor], [length / 2 + 1.0, 0.0, floor - 0.05], 0.04, M_METAL, 0.2),
    ]
    parts += [Part(rc.CYLINDER, np.array([0.0, side * (width / 2 - 0.12), wheel_r]), WHEEL_ROT,
                   np.array([wheel_r, wheel_r, 0.09, 0.0, 0.0, 0.0]), M_TIRE, 0.05) for side in (1.0, -1.0)]
    return parts
