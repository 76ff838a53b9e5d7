"""The "negatives" world change: car-sized background the real scans hold, fewer thin posts, so that stage 2 trained
on synthetic scenes meets the background real scans show (docs/experiments/partial-views-and-hard-negatives.md).

`add_hard_negatives` stands jersey barriers, long planters, low hedges and car-sized bushes along the street;
`thinned_out` tells the street clutter which posts, short poles and trunks to leave out. Both draw from the change's
own stream, so a scene generated without "negatives" keeps the rest of its street.
"""

from __future__ import annotations

import math

import numpy as np

from pass3d_ros.synthetic.builder import SceneBuilder
from pass3d_ros.synthetic.objects import street_furniture as sf
from pass3d_ros.synthetic.objects import vegetation as vg
from pass3d_ros.synthetic.parts import Part
from pass3d_ros.synthetic.street import PartsFn, RoadLayout, in_cross

# Street clutter kinds that make thin tall proposals (pole / trunk-like: footprint <= 0.5 m, >= 1.2 m tall). The
# synthetic world held 8.4 % of its stage-1 proposals thin and tall against 2.5 % on the 13 real unlabelled HDL-64E
# scans (3.1 a frame against 0.6 a scan; 20 frames of seed 7 against the 13 scans, measured:
# docs/experiments/partial-views-and-hard-negatives.md); with the "negatives" change this share of them is drawn but not
# placed (the scene's stream is kept).
_THIN_CLUTTER = ("post", "short_pole", "trunk")
_THIN_DROP = 0.5


def thinned_out(name: str, rng: np.random.Generator | None) -> bool:
    """Whether a drawn clutter item `name` is left out: a _THIN_DROP share of the thin kinds, decided by `rng` (the
    change's stream; None: the change is off and nothing is left out)."""
    return name in _THIN_CLUTTER and rng is not None and rng.random() < _THIN_DROP


# Hard negatives: car-sized background the real scans hold and the synthetic world lacked, so stage 2 never learnt to
# call it background. Low wide stage-1 proposals (2.5-6 m long, 0.5-1.1 m tall: barriers, planters, low hedges) are
# 17.5 % of the proposals of the 13 real unlabelled HDL-64E scans (4.3 a scan), 10.2 % of the synthetic ones (3.7 a
# frame; 20 frames of seed 7); real stage 2 calls 6.5 % of such separate objects car. Each entry: (model, parts
# function, weight, where: "walk" back half of the sidewalk, "kerb" the kerb line, "front" the property line, "yard"
# beyond it).
_NEGATIVES: tuple[tuple[str, PartsFn, float, str], ...] = (
    ("long_planter", sf.long_planter_parts, 1.0, "walk"),
    ("jersey_barrier", lambda r: sf.jersey_barrier_parts(r, float(r.uniform(4.0, 10.0))), 0.6, "kerb"),
    ("low_hedge", vg.low_hedge_parts, 1.0, "front"),
    ("car_bush", vg.car_bush_parts, 0.8, "front"),
    ("car_bush", vg.car_bush_parts, 0.8, "yard"),
)
_NEGATIVE_SPACING_M = 16.0  # mean street length (per side) per hard negative: about 17 a scene over 2 x 140 m
_NEGATIVE_MIN_RANGE_M = 8.0  # nearer, a planter beside the ego car hides a third of the ground around it
_NEGATIVE_VEHICLE_GAP_M = 1.2  # kept from foreground objects: a barrier against a parked car would chain them


def add_hard_negatives(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Jersey barrier runs on the kerb line, long planters on the sidewalk, low hedges and car-sized bushes at the
    property line and in yards, about one per _NEGATIVE_SPACING_M of street on each side, 1.2 m clear of every car,
    person and cyclist (so stage 1 proposes them on their own, as real barriers and planters are)."""
    weights = np.array([w for _, _, w, _ in _NEGATIVES])
    for side in (1.0, -1.0):
        u = -60.0 + rng.exponential(_NEGATIVE_SPACING_M)
        while u < 80.0:
            name, fn, _, where = _NEGATIVES[int(rng.choice(len(_NEGATIVES), p=weights / weights.sum()))]
            parts = fn(rng)
            walk_out = lay.half_width + lay.sidewalk
            for _attempt in range(3):  # the property line and yards are crowded: a few places nearby
                if where == "kerb":
                    v = lay.half_width + rng.uniform(0.35, 0.6)
                elif where == "walk":
                    v = walk_out - rng.uniform(0.8, max(0.9, lay.sidewalk / 2))
                elif where == "front":  # just inside the property line, or on it where nothing stands
                    v = max(walk_out + 0.6, lay.frontage - rng.uniform(0.6, 1.5)) if rng.random() < 0.7 else \
                        lay.frontage + rng.uniform(-0.3, 0.6)
                else:
                    v = walk_out + rng.uniform(0.8, max(lay.frontage - walk_out, 0.8) + 3.0)
                uu = u + rng.uniform(-3.0, 3.0) * _attempt
                if math.hypot(*b.world_xy(uu, side * v)) < _NEGATIVE_MIN_RANGE_M:
                    continue
                if not in_cross(lay, uu, 3.0) and _place_negative(
                        b, parts, uu, side * v, float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.05), name):
                    break
            u += rng.exponential(_NEGATIVE_SPACING_M)


def _place_negative(b: SceneBuilder, parts: list[Part], u: float, v: float, yaw: float, name: str,
                    gap: float = _NEGATIVE_VEHICLE_GAP_M) -> bool:
    """Place a background object `gap` clear of foreground objects (it stays an ordinary background object)."""
    if not b.place(parts, u, v, yaw, model=name, clearance=gap, veg=name in ("car_bush", "low_hedge")):
        return False
    b.objects[-1].clearance = None  # kept farther, not closer, than the usual gap: not a lapsed clearance
    return True
