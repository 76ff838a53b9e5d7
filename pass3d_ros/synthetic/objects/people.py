"""People models: pedestrians (adults and children, walking or standing, carrying things), seated people,
cyclists on different bicycles, and riderless bicycles and strollers.

Class rules, as KITTI's annotators draw them (and SqueezeSeg's point labels follow):
- a person riding a bicycle is a Cyclist: rider and bicycle share one box (`cyclist_parts`);
- a person walking beside or pushing a bicycle is a Pedestrian, and the bicycle is background (`bicycle_parts`,
  placed as its own object): KITTI keeps Cyclist for riders, and a riderless bicycle - parked or pushed - is
  never a Cyclist. One rule for both cases keeps "has a rider on it" the cue the network must learn;
- a seated person (bench, chair, curb) is KITTI's Person_sitting, background (`seated_person_parts`);
- what a pedestrian carries or holds (bag, backpack, umbrella, a box, a suitcase pulled by its handle) is part of
  the pedestrian; a stroller they push is not.
Target sizes (metres, L x W x H) are KITTI's training-label means as Frustum-PointNets tabulates them
(Qi et al., CVPR 2018): Pedestrian 0.84 x 0.66 x 1.76 (arm swing and stride included), Person_sitting
0.80 x 0.60 x 1.27, Cyclist 1.76 x 0.60 x 1.74.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pass3d_ros.synthetic.materials import M_CLOTH, M_METAL, M_OTHER, M_SKIN, M_TIRE, cloth_rho
from pass3d_ros.synthetic.parts import Part, box, cylinder, disc, ellipsoid, part_extent, rot_y

LOADS = ("suitcase", "box", "bags")  # what `pedestrian(..., load=...)` holds in its hands
ADULT_HEIGHT_M = (1.77, 0.09)  # mean, std of adults: with ~8% children the mix is near KITTI's 1.76 m box height


def _person_height(rng: np.random.Generator) -> float:
    """Standing height: about 8% children (1.0-1.45 m), adults around 1.76 m."""
    if rng.random() < 0.08:
        return float(rng.uniform(1.0, 1.45))
    return float(np.clip(rng.normal(*ADULT_HEIGHT_M), 1.5, 2.02))


def pedestrian_parts(rng: np.random.Generator, pose: str = "auto", reach: float = 0.0, load: str = "") -> list[Part]:
    """Pedestrian (KITTI 'Pedestrian'): legs with feet, pelvis, torso, swinging arms, head; maybe carrying things.

    `pose` is "walk", "stand" or "auto" (mostly walking). `reach` > 0 holds the left hand out that far to the
    left (y > 0), as when pushing a bicycle walking beside it. `load` (one of LOADS, or "" for none) is something
    held in the hands on top of what `_carried` draws: a wheeled suitcase pulled behind, a box carried in front,
    a heavy bag in each hand. Body proportions put the top of the head at the drawn height (hip 0.5 H, shoulder
    0.82 H).
    """
    return pedestrian(rng, pose, reach, load)[0]


def pedestrian(rng: np.random.Generator, pose: str = "auto", reach: float = 0.0,
               load: str = "") -> tuple[list[Part], np.ndarray, np.ndarray]:
    """(parts, amodal_min, amodal_max) of a pedestrian (see `pedestrian_parts`).

    The amodal extent is what KITTI's annotators box: the body over its whole gait cycle, so a walker's box holds
    the full stride and arm swing along the walking direction (x) whatever the phase the scan caught (KITTI's
    mean Pedestrian box is 0.84 m long). It is the union of the drawn pose's extent and the poses at both ends of
    the gait; a standing person's is the drawn pose's.
    """
    height = _person_height(rng)
    s = height / 1.76
    walking = pose == "walk" or (pose == "auto" and rng.random() < 0.75)
    if walking:
        amplitude = rng.uniform(0.3, 0.5)
        stride = amplitude * math.cos(rng.uniform(0, math.pi))
    else:
        stride = rng.uniform(-0.06, 0.06)
        amplitude = abs(stride)
    leg_len = 0.49 * height
    # Knees and ankles take up half of the hip drop a rigid leg would give at this stride.
    hip_z = leg_len * (0.5 + 0.5 * math.cos(stride)) + 0.035 * s
    shoulder_z = hip_z + 0.32 * height
    girth = rng.uniform(0.85, 1.15)
    rho_legs, rho_top = cloth_rho(rng), cloth_rho(rng)
    parts = _legs(stride, hip_z, s, girth, rho_legs)
    parts.append(ellipsoid([0.0, 0.0, hip_z], [0.1 * s * girth, 0.17 * s * girth, 0.1 * s], M_CLOTH, rho_legs))
    lean = rng.uniform(-0.04, 0.1)
    torso_half = 0.5 * (shoulder_z - hip_z) + 0.04 * s
    torso_c = np.array([math.sin(lean) * torso_half, 0.0, 0.5 * (hip_z + shoulder_z) + 0.02])
    parts.append(ellipsoid(torso_c, [0.12 * s * girth, 0.18 * s * girth, torso_half], M_CLOTH, rho_top, rot_y(-lean)))
    arm_len = 0.43 * height
    swing_gain = rng.uniform(1.0, 1.6) if walking else 0.0
    hands = []
    for side in (1.0, -1.0):
        shoulder = np.array([math.sin(lean) * 0.3 * height, side * (0.17 * girth + 0.04) * s, shoulder_z - 0.03])
        if side > 0 and reach > 0.0:
            hand = shoulder + np.array([rng.uniform(0.15, 0.3), reach, -0.35 * height])
            hands.append((shoulder, shoulder + (hand - shoulder) * min(1.0, arm_len / float(np.linalg.norm(
                hand - shoulder))), None))
        else:
            hands.append((shoulder, None, rng.uniform(0.02, 0.12)))
    held: list[Part] = []
    if load:  # drawn only when asked, so a pedestrian without a load takes the same draws as before
        hands, held = _held_load(rng, load, hands, arm_len, height, s, girth)
    parts += _arms(hands, swing_gain * stride, arm_len, s, rho_top)
    head_c = np.array([math.sin(lean) * 0.35 * height, 0.0, shoulder_z + 0.115 * height])
    parts.append(ellipsoid(head_c, [0.1 * s, 0.08 * s, 0.065 * height], M_SKIN, float(rng.uniform(0.1, 0.5))))
    parts += _carried(rng, s, girth, torso_c, shoulder_z, head_c, height) + held
    gait = list(parts)
    for end in (amplitude, -amplitude):
        gait += _legs(end, hip_z, s, girth, rho_legs) + _arms(hands, swing_gain * end, arm_len, s, rho_top)
    lo = np.min([p.center - part_extent(p) for p in gait], axis=0)
    hi = np.max([p.center + part_extent(p) for p in gait], axis=0)
    return parts, lo, hi


def _legs(stride: float, hip_z: float, s: float, girth: float, rho: float) -> list[Part]:
    """Both legs with feet at a stride angle (rad, + : left leg forward)."""
    parts = []
    for side, angle in ((1.0, stride), (-1.0, -stride)):
        hip = np.array([0.0, side * 0.09 * s, hip_z])
        foot = hip + (hip_z - 0.035 * s) / math.cos(angle) * np.array([math.sin(angle), 0.0, -math.cos(angle)])
        parts.append(cylinder(hip, foot, 0.065 * s * girth, M_CLOTH, rho))
        parts.append(box(foot + np.array([0.06 * s, 0.0, 0.0]), [0.13 * s, 0.05 * s, 0.035 * s], M_CLOTH, 0.1,
                         rounding=(1.2, 1.3, 1.5)))
    return parts


def _arms(hands: list, swing: float, arm_len: float, s: float, rho: float) -> list[Part]:
    """Both arms: (shoulder, fixed hand or None, sideways spread) per side (left first), swinging by `swing`."""
    parts = []
    for (shoulder, hand, spread), side, angle in zip(hands, (1.0, -1.0), (-swing, swing), strict=True):
        if hand is None:
            hand = shoulder + arm_len * np.array([math.sin(angle), side * math.sin(spread), -math.cos(angle)])
        parts.append(cylinder(shoulder, hand, 0.045 * s, M_CLOTH, rho))
    return parts


def _carried(rng: np.random.Generator, s: float, girth: float, torso_c: np.ndarray, shoulder_z: float,
             head_c: np.ndarray, height: float) -> list[Part]:
    """Things a pedestrian carries: backpack, shoulder or hand bag, umbrella (each drawn independently)."""
    parts = []
    if rng.random() < 0.25:  # backpack
        parts.append(box(torso_c + np.array([-0.12 * s * girth - 0.08, 0.0, 0.05]), [0.09, 0.15 * s, 0.2 * s],
                         M_CLOTH, cloth_rho(rng), rounding=(1.3, 1.3, 1.3)))
    if rng.random() < 0.3:  # shoulder bag or shopping bag at the hip, to one side
        side = float(rng.choice([-1.0, 1.0]))
        z = rng.uniform(0.45, 0.65) * height
        parts.append(box([rng.uniform(-0.08, 0.08), side * (0.22 * s * girth + 0.06), z],
                         [rng.uniform(0.12, 0.2), 0.05, rng.uniform(0.1, 0.18)], M_OTHER, cloth_rho(rng),
                         rounding=(1.2, 1.3, 1.3)))
    if rng.random() < 0.05:  # open umbrella held above the head
        radius = rng.uniform(0.42, 0.55)
        top = head_c + np.array([0.05, 0.1, rng.uniform(0.25, 0.35)])
        parts.append(ellipsoid(top, [radius, radius, 0.12], M_CLOTH, cloth_rho(rng)))
        parts.append(cylinder(top, np.array([0.15, 0.15, shoulder_z - 0.1]), 0.012, M_METAL, 0.3))
    return parts


def _held_load(rng: np.random.Generator, load: str, hands: list, arm_len: float, height: float, s: float,
               girth: float) -> tuple[list, list[Part]]:
    """(hands, parts) of a pedestrian holding `load` (see LOADS): the arms that hold it stop swinging.

    A pulled suitcase trails behind the walker (the pedestrian 1.0-1.45 m long, 1.2 m on average: as long as a short
    cyclist), a carried box sticks out in front, bags hang from both hands (0.8-0.9 m wide). Like `_carried`'s
    bags, what the person holds is part of the pedestrian (KITTI boxes the person with what they carry).
    """
    if load not in LOADS:
        raise ValueError(f"unknown load {load!r}, known: {', '.join(LOADS)}")
    (left, _, left_spread), (right, _, _) = hands
    rho = float(rng.uniform(0.05, 0.5))
    if load == "suitcase":  # right hand back and down on the handle of a tilted wheeled case
        back = rng.uniform(0.35, 0.6)
        hand = right + arm_len * np.array([-math.sin(back), -0.05, -math.cos(back)])
        hd, hw, hh = rng.uniform(0.1, 0.14), rng.uniform(0.17, 0.22), rng.uniform(0.26, 0.36)
        tilt = rng.uniform(0.35, 0.6)
        axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])  # the case's long axis, top toward the hand
        handle = 0.05  # at least; a child's case is smaller, so that it stands on the ground below the hand
        hh = min(hh, (hand[2] - handle * math.cos(tilt) - hd * math.sin(tilt)) / (2.0 * math.cos(tilt)))
        top_z = 2.0 * hh * math.cos(tilt) + hd * math.sin(tilt)  # its bottom edge on the ground
        handle = max((hand[2] - top_z) / math.cos(tilt), handle)
        top = hand - handle * axis
        parts = [box(top - hh * axis, [hd, hw, hh], M_OTHER, rho, rot_y(-tilt), rounding=(1.2, 1.3, 1.3)),
                 cylinder(hand, top, 0.012, M_METAL, 0.3)]
        return [(left, None, left_spread), (right, hand, None)], parts
    if load == "box":  # a box in front of the chest, held at its sides
        hx, hy, hz = rng.uniform(0.12, 0.22), rng.uniform(0.15, 0.25), rng.uniform(0.1, 0.2)
        center = np.array([0.12 * s * girth + 0.08 + hx, 0.0, rng.uniform(0.52, 0.6) * height])
        fixed = []
        for shoulder, side in ((left, 1.0), (right, -1.0)):
            hand = center + np.array([-0.3 * hx, side * (hy + 0.03), -0.3 * hz])
            reach_to = hand - shoulder
            fixed.append((shoulder, shoulder + reach_to * min(1.0, arm_len / float(np.linalg.norm(reach_to))), None))
        return fixed, [box(center, [hx, hy, hz], M_OTHER, rho, rounding=(1.2, 1.3, 1.3))]
    fixed, parts = [], []  # "bags": a heavy shopping bag in each hand, arms held a little out
    for shoulder, side in ((left, 1.0), (right, -1.0)):
        spread = rng.uniform(0.12, 0.22)
        hand = shoulder + arm_len * np.array([rng.uniform(-0.05, 0.1), side * math.sin(spread), -math.cos(spread)])
        hx, hy, hz = rng.uniform(0.13, 0.2), rng.uniform(0.04, 0.07), rng.uniform(0.13, 0.2)
        fixed.append((shoulder, hand, None))
        parts.append(box(hand + np.array([0.0, side * 0.02, -hz - 0.02]), [hx, hy, hz], M_OTHER,
                         float(rng.uniform(0.05, 0.5)), rounding=(1.2, 1.3, 1.3)))
    return fixed, parts


def seated_person_parts(rng: np.random.Generator, seat: str = "bench") -> list[Part]:
    """Seated person (background, KITTI 'Person_sitting') on a bench, a chair or the curb; the seat included.

    Facing +x: thighs forward from the seat, shins down to the ground, upright torso, arms on the thighs.
    """
    s = _person_height(rng) / 1.76
    seat_h = {"bench": rng.uniform(0.42, 0.48), "chair": rng.uniform(0.44, 0.5), "curb": rng.uniform(0.12, 0.2)}[seat]
    rho_legs, rho_top = cloth_rho(rng), cloth_rho(rng)
    girth = rng.uniform(0.9, 1.25)
    hip_z = seat_h + 0.1 * s
    thigh = 0.43 * s
    knee_x = thigh if seat != "curb" else 0.36 * s
    knee_z = hip_z + (0.0 if seat != "curb" else 0.22 * s)
    parts = []
    for side in (1.0, -1.0):
        hip = np.array([0.0, side * 0.1 * s, hip_z])
        knee = np.array([knee_x, side * 0.11 * s, knee_z])
        foot = np.array([knee_x + rng.uniform(0.0, 0.15), side * 0.12 * s, 0.04])
        parts.append(cylinder(hip, knee, 0.075 * s * girth, M_CLOTH, rho_legs))
        parts.append(cylinder(knee, foot, 0.055 * s, M_CLOTH, rho_legs))
        shoulder = np.array([-0.02, side * 0.21 * s * girth, hip_z + 0.52 * s])
        parts.append(cylinder(shoulder, np.array([0.5 * knee_x, side * 0.17 * s, hip_z + 0.1]), 0.045 * s, M_CLOTH,
                              rho_top))
    lean = rng.uniform(-0.15, 0.25)
    parts.append(ellipsoid([0.0 + 0.25 * math.sin(lean), 0.0, hip_z + 0.3 * s],
                           [0.13 * s * girth, 0.2 * s * girth, 0.3 * s], M_CLOTH, rho_top, rot_y(-lean)))
    parts.append(ellipsoid([0.55 * s * math.sin(lean), 0.0, hip_z + 0.72 * s], [0.1 * s, 0.08 * s, 0.115 * s],
                           M_SKIN, float(rng.uniform(0.1, 0.5))))
    rho_seat = float(rng.uniform(0.1, 0.5))
    if seat == "bench":
        width = rng.uniform(1.4, 2.0)
        y0 = rng.uniform(-0.4, 0.4)
        parts.append(box([-0.05, y0, seat_h - 0.03], [0.22, width / 2, 0.03], M_OTHER, rho_seat))
        parts.append(box([-0.28, y0, seat_h + 0.25], [0.03, width / 2, 0.2], M_OTHER, rho_seat))
        for end in (1.0, -1.0):
            parts.append(box([-0.05, y0 + end * (width / 2 - 0.1), (seat_h - 0.06) / 2],
                             [0.2, 0.03, (seat_h - 0.06) / 2], M_METAL, 0.25))
    elif seat == "chair":
        parts.append(box([-0.02, 0.0, seat_h - 0.02], [0.22, 0.22, 0.02], M_OTHER, rho_seat))
        parts.append(box([-0.24, 0.0, seat_h + 0.22], [0.02, 0.21, 0.2], M_OTHER, rho_seat))
        for dx in (0.18, -0.2):
            for dy in (0.18, -0.18):
                parts.append(cylinder([dx, dy, 0.0], [dx, dy, seat_h - 0.04], 0.015, M_METAL, 0.3))
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


class _Bike(NamedTuple):
    """Where a rider meets the bicycle, in the bicycle's frame."""

    bb: np.ndarray  # bottom bracket (pedal axle)
    saddle: np.ndarray
    bar: np.ndarray  # handlebar centre
    bar_half: float
    style: int  # 0 city, 1 road, 2 mountain


def _bicycle(rng: np.random.Generator, s: float) -> tuple[list[Part], _Bike]:
    """Bicycle frame and wheels (city, road or mountain bike) and the points a rider holds: saddle, bar, bb."""
    style = int(rng.choice(3, p=[0.5, 0.25, 0.25]))  # city, road, mountain
    wheel_r = (rng.uniform(0.33, 0.36), rng.uniform(0.33, 0.35), rng.uniform(0.3, 0.37))[style]
    base = (rng.uniform(1.05, 1.15), rng.uniform(0.97, 1.03), rng.uniform(1.05, 1.2))[style]
    rho_bike, rho_tire = float(rng.uniform(0.1, 0.55)), float(rng.uniform(0.02, 0.1))
    tire_w = (0.025, 0.015, 0.035)[style]
    rear, front = np.array([-base / 2, 0.0, wheel_r]), np.array([base / 2, 0.0, wheel_r])
    bb = np.array([-base / 2 + 0.43, 0.0, 0.3])
    saddle = bb + np.array([-0.2, 0.0, 0.55 * s + 0.05])
    head_tube = np.array([base / 2 - 0.12, 0.0, 0.55 * s + 0.28])
    bar_up = (rng.uniform(0.15, 0.28), rng.uniform(-0.05, 0.05), rng.uniform(0.05, 0.15))[style]
    bar = head_tube + np.array([-0.08 if style == 0 else 0.0, 0.0, bar_up])
    bar_half = (0.28, 0.21, 0.33)[style]
    top_tube_end = saddle if style != 0 else bb + 0.6 * (saddle - bb)  # city bikes: step-through frame
    parts = [
        disc(rear, [0, 1, 0], wheel_r, tire_w, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        disc(front, [0, 1, 0], wheel_r, tire_w, M_TIRE, rho_tire, inner=wheel_r - 0.04),
        cylinder(bb, saddle, 0.02, M_METAL, rho_bike),
        cylinder(bb, head_tube, 0.025, M_METAL, rho_bike),
        cylinder(top_tube_end, head_tube, 0.02, M_METAL, rho_bike),
        cylinder(bb, rear, 0.015, M_METAL, rho_bike),
        cylinder(saddle, rear, 0.015, M_METAL, rho_bike),
        cylinder(_shift(head_tube, 0.0, 0.0, 0.05), front, 0.02, M_METAL, rho_bike),
        cylinder(_shift(bar, 0.0, -bar_half, 0.0), _shift(bar, 0.0, bar_half, 0.0), 0.015, M_METAL, rho_bike),
    ]
    if style == 0 and rng.random() < 0.4:  # basket or rear rack with a bag
        at = _shift(front, 0.12, 0.0, 0.45) if rng.random() < 0.5 else _shift(rear, 0.0, 0.0, 0.38)
        parts.append(box(at, [0.17, 0.16, 0.12], M_OTHER, float(rng.uniform(0.1, 0.5))))
    return parts, _Bike(bb, saddle, bar, bar_half, style)


def bicycle_parts(rng: np.random.Generator) -> list[Part]:
    """A riderless bicycle (background: parked, or pushed by a pedestrian walking beside it)."""
    return _bicycle(rng, rng.uniform(0.92, 1.08))[0]


def cyclist_parts(rng: np.random.Generator) -> list[Part]:
    """Cyclist (KITTI 'Cyclist'): a rider on a city, road or mountain bike, posture from upright to racing.

    City bikes carry upright riders (torso 0.15-0.5 rad from vertical), road bikes low ones (0.8-1.1 rad);
    pedals at a random phase, some riders with a backpack.
    """
    s = rng.uniform(0.75, 0.85) if rng.random() < 0.07 else rng.uniform(0.92, 1.1)  # a few children
    parts, at = _bicycle(rng, s)
    bb, saddle, bar, style = at.bb, at.saddle, at.bar, at.style
    lean = (rng.uniform(0.15, 0.5), rng.uniform(0.8, 1.1), rng.uniform(0.45, 0.8))[style]  # torso from vertical
    hip = saddle + np.array([-0.02, 0.0, 0.08])
    torso_len = 0.55 * s
    shoulder = hip + torso_len * np.array([math.sin(lean), 0.0, math.cos(lean)])
    rho_top, rho_legs = cloth_rho(rng), cloth_rho(rng)
    girth = rng.uniform(0.9, 1.2)
    parts.append(ellipsoid(0.5 * (hip + shoulder), [0.11 * s * girth, 0.19 * s * girth, torso_len / 2 + 0.04],
                           M_CLOTH, rho_top, rot_y(-lean)))
    head = shoulder + 0.22 * s * np.array([math.sin(0.5 * lean), 0.0, math.cos(0.5 * lean)])
    parts.append(ellipsoid(head, [0.11 * s, 0.09 * s, 0.12 * s], M_SKIN, float(rng.uniform(0.05, 0.6))))
    grip = at.bar_half - 0.06
    for side in (1.0, -1.0):
        parts.append(cylinder(_shift(shoulder, 0.0, side * 0.19 * s, 0.0), _shift(bar, 0.0, side * grip, 0.02),
                              0.04 * s, M_CLOTH, rho_top))
    phase = rng.uniform(0, 2 * math.pi)
    for side, ph in ((1.0, phase), (-1.0, phase + math.pi)):
        pedal = bb + 0.17 * np.array([math.cos(ph), 0.0, math.sin(ph)])
        hip_side = _shift(hip, 0.0, side * 0.1 * s, 0.0)
        foot = _shift(pedal, 0.0, side * 0.13, 0.0)
        knee = _knee(hip_side, foot, 0.45 * s, 0.47 * s)
        parts.append(cylinder(hip_side, knee, 0.07 * s, M_CLOTH, rho_legs))
        parts.append(cylinder(knee, foot, 0.05 * s, M_CLOTH, rho_legs))
    if rng.random() < 0.25:
        back = 0.5 * (hip + shoulder) + np.array([-0.17 * math.cos(lean), 0.0, 0.17 * math.sin(lean)])
        parts.append(box(back, [0.08, 0.15 * s, 0.19 * s], M_CLOTH, cloth_rho(rng), rot_y(-lean),
                         rounding=(1.3, 1.3, 1.3)))
    return parts


def stroller_parts(rng: np.random.Generator) -> list[Part]:
    """A pushed stroller / pram (background: KITTI boxes the person, not what they push); handle toward -x."""
    rho = float(rng.uniform(0.05, 0.5))
    length, width = rng.uniform(0.75, 0.95), rng.uniform(0.5, 0.6)
    parts = [box([0.0, 0.0, 0.65], [length / 2 - 0.05, width / 2, 0.22], M_CLOTH, rho, rounding=(1.2, 1.3, 1.4)),
             cylinder([-length / 2 + 0.05, 0.0, 0.5], [-length / 2 - 0.05, 0.0, 1.0], 0.015, M_METAL, 0.3),
             cylinder([-length / 2 - 0.05, -width / 2, 1.0], [-length / 2 - 0.05, width / 2, 1.0], 0.015, M_METAL,
                      0.3)]
    for x in (length / 2 - 0.12, -length / 2 + 0.12):
        for y in (width / 2 - 0.03, -width / 2 + 0.03):
            parts.append(disc([x, y, 0.12], [0, 1, 0], 0.12, 0.02, M_TIRE, 0.05))
    return parts
