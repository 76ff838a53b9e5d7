"""Things the sensor sees only in part: pedestrians behind nearer objects, cars behind occluders.

Two world changes of `synthetic.scene.generate_scene`, each drawn from a stream of its own so that leaving it out
keeps the rest of the scene: "hidden" (`add_hidden_pedestrians`: people standing just beyond a parked car, a hedge or
a bin, so only their upper body shows) and "partial" (`add_partial_views`: occluders in the sensor's line of sight
that leave a piece, or the upper part, of a car).
"""

from __future__ import annotations

import math

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.synthetic.builder import TOUCH_CLEARANCE_M, SceneBuilder
from pass3d_ros.synthetic.objects import street_furniture as sf
from pass3d_ros.synthetic.objects import structures as st
from pass3d_ros.synthetic.objects import vegetation as vg
from pass3d_ros.synthetic.objects.people import pedestrian
from pass3d_ros.synthetic.objects.vegetation import tree_parts
from pass3d_ros.synthetic.parts import Part, part_extent
from pass3d_ros.synthetic.street import VEHICLE_LABEL, RoadLayout, draw_vehicle

# What a pedestrian stands behind, and how often each is picked.
_HIDING = {"Car": 0.6, "Van": 0.3, "Truck": 0.2, "hedge_fragment": 1.0, "wall_fragment": 1.0, "bin": 0.6,
           "mailbox": 0.4, "bench": 0.6, "utility_box": 0.8, "Pedestrian": 0.8, "car_bush": 0.6, "low_hedge": 0.6,
           "long_planter": 0.6, "jersey_barrier": 0.4}
_HIDDEN_COUNT_P = (0.2, 0.35, 0.3, 0.15)  # pedestrians placed behind something per scene: 0, 1, 2, 3


def add_hidden_pedestrians(b: SceneBuilder, rng: np.random.Generator) -> None:
    """Pedestrians (alone or a pair) standing or walking just beyond a parked car, van, truck, hedge or wall
    fragment, bin, mailbox, bench, utility box, another pedestrian, or (with "negatives") a planter, barrier, low
    hedge or car-sized bush as the sensor sees it, so only their upper body shows.

    Measured on the dev data (real VLP-32C boxes corrected, see docs/experiments/investigations.md): 15 of 22 real
    pedestrians of >= 10 points at 8-35 m show only the upper body (a crowded street), the one KITTI pedestrian its
    whole body, against 3 of 46 synthetic ones placed by `scene._add_people` alone. These placements bring the
    synthetic share to about a third.
    """
    hiders = [o for o in b.objects if o.model in _HIDING and 5.0 < math.hypot(o.x, o.y) < 35.0]
    if not hiders:
        return
    weights = np.array([_HIDING[o.model] for o in hiders])
    for _ in range(int(rng.choice(len(_HIDDEN_COUNT_P), p=_HIDDEN_COUNT_P))):
        hider = hiders[int(rng.choice(len(hiders), p=weights / weights.sum()))]
        dist = math.hypot(hider.x, hider.y)
        ray = math.atan2(hider.y, hider.x)
        across = ray - hider.yaw  # the ray in the hider's frame: how deep and how wide it looks along the ray
        half = 0.5 * (hider.local_max - hider.local_min)
        depth = abs(math.cos(across)) * half[0] + abs(math.sin(across)) * half[1]
        wide = abs(math.sin(across)) * half[0] + abs(math.cos(across)) * half[1]
        heading = float(rng.uniform(-math.pi, math.pi))
        pair = rng.random() < 0.3
        for member in range(2 if pair else 1):
            for _attempt in range(4):
                behind = dist + depth + rng.uniform(0.45, 1.6)
                side = rng.uniform(-0.6, 0.6) * wide + 0.8 * member  # a pair's second walks beside the first
                x = behind * math.cos(ray) - side * math.sin(ray)
                y = behind * math.sin(ray) + side * math.cos(ray)
                u, v = b.road_uv(x, y)
                parts, lo, hi = pedestrian(rng, "walk" if rng.random() < 0.6 else "stand")
                if b.place(parts, u, v, heading - b.road_yaw() + rng.normal(0.0, 0.15), PEDESTRIAN, "Pedestrian",
                           clearance=TOUCH_CLEARANCE_M if member else None, extent=(lo, hi)):
                    break


# Partial views, because real cars called background are occluded and cut ones (visible width 1.1 vs 1.55 m, proposal
# length 1.8 vs 3.4 m, lowest point 0.13 m higher): real partial cars (visible length < 2.5 m) fail 6 of 14, synthetic
# ones 0 of 58, and the real short fragments are cut at both ends by nearer things (one occluder does not make them:
# docs/experiments/trials-steps-2-3.md, cars behind cars). A share of the cars 6-28 m away get occluders in the sensor's
# line of sight: two that leave a 0.7-2.4 m piece, one that hides an end, or a low one (planter, low hedge, barrier,
# bush) that hides the lower part. Occluders stand where such things stand: vehicles in the lanes and parking lanes,
# street trees, utility boxes, bushes and hedges on the sidewalk and beyond.
_PARTIAL_SHARE = 0.4
_PARTIAL_RANGE_M = (6.0, 28.0)  # real short fragments: 9.5-21 m (docs/experiments/investigations.md)
_PARTIAL_SCENARIO_P = (("cut2", 0.45), ("cut1", 0.25), ("low", 0.30))
_PIECE_M = (0.7, 2.4)


def add_partial_views(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Occluders in front of some cars so that only a piece (or the upper part) of the car shows."""
    names, probs = zip(*_PARTIAL_SCENARIO_P, strict=True)
    for car in [o for o in b.objects if o.label == CAR]:
        corners = _footprint_corners(car.x, car.y, car.yaw, car.local_min, car.local_max)
        near = float(np.hypot(corners[:, 0], corners[:, 1]).min())
        if rng.random() >= _PARTIAL_SHARE or not _PARTIAL_RANGE_M[0] < near < _PARTIAL_RANGE_M[1]:
            continue
        ray = math.atan2(car.y, car.x)
        lo, hi = _azimuth_span(corners, ray)
        scenario = str(rng.choice(names, p=probs))
        length = float(car.local_max[0] - car.local_min[0])
        visible = rng.uniform(*_PIECE_M)
        piece = (hi - lo) * visible / length  # the piece left visible, as an angle (its share of the car's length)
        if scenario == "low":
            spans = [(lo - 0.01, hi + 0.01, None)]
        elif visible > 0.8 * length or hi - lo < 0.03:
            continue  # nothing to cut (a short car, or seen end-on or far)
        elif scenario == "cut1":
            spans = [(lo - 0.01, hi - piece, (hi - piece, hi))] if rng.random() < 0.5 else \
                [(lo + piece, hi + 0.01, (lo, lo + piece))]
        else:
            start = rng.uniform(lo, hi - piece)
            window = (start, start + piece)
            spans = [(lo - 0.01, start, window), (start + piece, hi + 0.01, window)]
        for a0, a1, window in spans:
            if a1 - a0 > 0.004:
                _place_occluder(b, rng, lay, near, a0, a1, window)


def _footprint_corners(x: float, y: float, yaw: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(4, 2) sensor-frame corners of a footprint lo..hi (object frame) at pose (x, y, yaw)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([(x + c * lx - s * ly, y + s * lx + c * ly) for lx in (lo[0], hi[0]) for ly in (lo[1], hi[1])])


def _azimuth_span(corners: np.ndarray, ray: float) -> tuple[float, float]:
    """Azimuth interval (about `ray`, unwrapped) that corners cover as the sensor sees them."""
    rel = np.angle(np.exp(1j * (np.arctan2(corners[:, 1], corners[:, 0]) - ray)))
    return ray + float(rel.min()), ray + float(rel.max())


def _parts_box(parts: list[Part]) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) object-frame corners of the box around all of `parts`."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for p in parts:
        ext = part_extent(p)
        lo, hi = np.minimum(lo, p.center - ext), np.maximum(hi, p.center + ext)
    return lo, hi


def _occluder_for(rng: np.random.Generator, lay: RoadLayout, av: float, width: float, phi: float,
                  low: bool) -> tuple[str, list[Part], int, str, list | None] | None:
    """(model, parts, label, kind, footprint) of an occluder standing |v| = av from the road's centre line, that
    should cover `width` metres across the ray (the ray meets the road at sin-angle `phi`); None: nothing there."""
    if av < lay.half_width - 0.3:  # on the road: another road user
        # Vans as often as in the parked rows: a van is background with dark paint cells, and 40 % vans here put the
        # scorecard's non-ground background zero-intensity share 2 points up (12.4 % against the real 6.9 %).
        kind, parts = draw_vehicle(rng, 0.1, 0.0)
        return kind, parts, VEHICLE_LABEL[kind], kind, None
    if av < lay.half_width + 0.15:
        return None  # the kerb face itself
    depth = 0.8
    length = float(np.clip((width - depth * math.sqrt(max(0.0, 1.0 - phi * phi))) / max(phi, 0.2), 0.6, 5.0))
    sidewalk = av < lay.half_width + lay.sidewalk
    pick = rng.random()
    if low:
        height = rng.uniform(0.7, 1.1)
        if sidewalk and pick < 0.3 and av < lay.half_width + 1.0:
            return "jersey_barrier", sf.jersey_barrier_parts(rng, max(length, 2.0)), BACKGROUND, "", None
        if pick < 0.65:
            return "low_hedge", vg.low_hedge_parts(rng, length, height), BACKGROUND, "", None
        return "car_bush", vg.car_bush_parts(rng, max(length, 1.2), height), BACKGROUND, "", None
    if width < 0.5 and sidewalk:
        parts, footprint = tree_parts(rng, min_base=2.6)
        return "tree", parts, BACKGROUND, "", footprint
    height = rng.uniform(1.6, 2.2)
    if sidewalk and width < 1.3 and pick < 0.5:
        return "utility_box", sf.utility_box_parts(rng), BACKGROUND, "", None
    if pick < 0.5:
        return "hedge_fragment", vg.low_hedge_parts(rng, length, height), BACKGROUND, "", None
    if not sidewalk and pick < 0.7:
        return "wall_fragment", st.wall_fragment_parts(rng), BACKGROUND, "", None
    return "car_bush", vg.car_bush_parts(rng, max(length, 1.2), height), BACKGROUND, "", None


def _place_occluder(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout, near: float, a0: float, a1: float,
                    window: tuple[float, float] | None) -> bool:
    """Something between the sensor and a car at range `near`, covering azimuths a0..a1 as the sensor sees them
    (tall enough to hide the car; low, hiding its lower part, when there is no `window` to keep), chosen by where
    it would stand and slid along the road so that it leaves the window (the car's piece) open."""
    ac = 0.5 * (a0 + a1)
    road_dir = b.road_yaw()
    if near - 2.0 <= 5.0:
        return False
    for _attempt in range(10):
        d = rng.uniform(max(5.0, 0.25 * near), near - 2.0)
        u, v = b.road_uv(d * math.cos(ac), d * math.sin(ac))
        if abs(v - lay.v_ego) < lay.lane_width * 0.75 and abs(u) < 8.0:
            continue
        phi = abs(math.sin(ac - road_dir))  # 1: the ray crosses the road, 0: it runs along it
        found = _occluder_for(rng, lay, abs(v), (a1 - a0) * d + 0.2, phi, window is None)
        if found is None:
            continue
        name, parts, label, kind, footprint = found
        if label != BACKGROUND and abs(v) > lay.lanes * lay.lane_width / 2:  # parking lane: parked in line
            v = math.copysign(lay.half_width - 1.1 + rng.uniform(-0.15, 0.2), v)
        if label != BACKGROUND and abs(v) <= lay.lanes * lay.lane_width / 2:
            yaw = (0.0 if v < 0 or lay.lanes == 1 else math.pi) + rng.normal(0.0, 0.03)
        else:
            yaw = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.05)
        lo, hi = _parts_box(parts)
        reach = float(hi[0] - lo[0])
        # Slide along the road: cover a0..a1, keep out of the window.
        best, best_score = None, -np.inf
        for du in np.linspace(-1.5 * reach, 1.5 * reach, 21):
            x, y = b.world_xy(u + du, v)
            span = _azimuth_span(_footprint_corners(x, y, road_dir + yaw, lo, hi), ac)
            cover = max(0.0, min(span[1], a1) - max(span[0], a0)) / (a1 - a0)
            spill = 0.0 if window is None else max(0.0, min(span[1], window[1]) - max(span[0], window[0])) / max(
                window[1] - window[0], 1e-6)
            score = cover - 1.5 * spill - 0.05 * abs(du) / max(reach, 1e-6)
            if score > best_score:
                best, best_score = du, score
        if best_score < 0.25:
            continue
        if b.place(parts, u + best, v, yaw, label, kind, footprint=footprint, model=name,
                   veg=name in ("car_bush", "low_hedge", "hedge_fragment", "tree")):
            return True
    return False
