"""People models: pedestrians (walking or standing, adults and children) and cyclists on their bicycles."""

from __future__ import annotations

import math

import numpy as np

from pass3d_ros.synthetic.materials import M_CLOTH, M_METAL, M_SKIN, M_TIRE, cloth_rho
from pass3d_ros.synthetic.parts import Part, box, cylinder, disc, ellipsoid, rot_y


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
