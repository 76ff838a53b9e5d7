"""People close together and people alone far away: two world changes of `synthetic.scene.generate_scene`, because
stage 2 misread both on real scans.

On real scans pedestrians in a group are called background more often than lone ones (alone in a proposal 56 % are
called pedestrian, with two or more others 43 %), and lone pedestrians 0.7-1.6 m long are called cyclist 23 % of the
time. The two changes:
- "groups" (`add_groups`, `add_rider_company`): 2-4 pedestrians standing or walking a hand's breadth apart, in a row
  or a ring, so that stage 1 proposes them as one cluster (its scan-line runs join across gaps under Th_ring = 0.5 m);
  and pedestrians standing 0.2-0.8 m from a rider, beside the scene's cyclists or with a rider waiting at the kerb;
- "lone_people" (`add_lone_pedestrians`): lone pedestrians at ranges where a sensor sees them with few rings, some
  holding a suitcase, a box or bags (`objects.people.LOADS`), so that a long lone person is not a cyclist cue.
Each person keeps its own label, instance and box: neighbours' boxes stand TOUCH_CLEARANCE_M or more apart, the
closest that keeps every labelled box clean (see `synthetic.builder`); stage 1's proposal holds them together.
Each change draws from a stream of its own and is placed after everything else, so leaving one out keeps the rest
of the scene object for object (without "groups" the lone pedestrians may stand elsewhere).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic.builder import FOREGROUND_GAP_M, TOUCH_CLEARANCE_M, SceneBuilder, SceneObject
from pass3d_ros.synthetic.objects.people import LOADS, cyclist_parts, pedestrian
from pass3d_ros.synthetic.street import RoadLayout

_GROUPS_P = (0.63, 0.3, 0.07)  # groups per scene: 0, 1, 2 (a third of the scenes hold one; some find no room)
_GROUP_SIZE_P = ((2, 0.3), (3, 0.4), (4, 0.3))  # real failures sit in proposals with two or more others
_GROUP_GAP_M = (TOUCH_CLEARANCE_M, 0.3)  # between neighbours' boxes (bodies at least as far apart)
_GROUP_LOAD_SHARE = 0.1
_GROUP_ROOM_M = 0.55  # a group's room keeps this from everything else (stage 1 joins runs under Th_ring = 0.5 m)
_RIDER_GAP_M = (0.2, 0.8)  # a pedestrian's box from a rider's
_BESIDE_RIDER_SHARE = 0.25  # of the scene's cyclists, those with a pedestrian standing beside them
_WAITING_RIDER_P = 0.2  # scenes with a rider waiting at the kerb among one or two pedestrians
# Lone pedestrians a sensor sees with few rings. The scene does not know the sensor (one scene serves them all), so
# the range mixes two bands: 30-58 m, where the HDL-64E and VLP-32C put 4-10 rings on a 1.7 m person (farther, stage 1
# drops most of them: fewer points than th_num, 12 at 50 m), and 9-25 m, where the HDL-32E puts 2-6 and the VLP-16 1-5.
_LONE_COUNT_P = (0.35, 0.4, 0.25)  # per scene: 0, 1, 2
_LONE_BANDS_M = ((30.0, 58.0), (9.0, 25.0))
_LONE_LOAD_SHARE = 0.4
_LOAD_P = (0.4, 0.25, 0.35)  # suitcase, box, bags


def _lateral(heading: float, d: float) -> tuple[float, float]:
    """Road-coordinate offset `d` metres to the left of a heading."""
    return -math.sin(heading) * d, math.cos(heading) * d


@dataclass
class _Placed:
    """A placed person or rider in road coordinates, with its extent in its own frame."""

    u: float
    v: float
    yaw: float  # heading relative to the road
    lo: np.ndarray
    hi: np.ndarray


def _support(lo: np.ndarray, hi: np.ndarray, ang: float) -> float:
    """How far an object's footprint (lo, hi in its own frame) reaches from its origin along direction `ang`."""
    c, s = math.cos(ang), math.sin(ang)
    return max(lo[0] * c, hi[0] * c) + max(lo[1] * s, hi[1] * s)


def _next_to(anchor: _Placed, lo: np.ndarray, hi: np.ndarray, yaw: float, ang: float, gap: float,
             along: float = 0.0) -> tuple[float, float]:
    """Road (u, v) of an object (extent lo, hi; heading yaw) whose footprint stands `gap` beyond `anchor`'s along
    direction `ang` (road frame), shifted `along` metres across that direction."""
    d = _support(anchor.lo, anchor.hi, ang - anchor.yaw) + _support(lo, hi, ang + math.pi - yaw) + gap
    return (anchor.u + d * math.cos(ang) - along * math.sin(ang),
            anchor.v + d * math.sin(ang) + along * math.cos(ang))


def _placed(b: SceneBuilder, obj: SceneObject) -> _Placed:
    """A scene object as a `_Placed` in road coordinates."""
    u, v = b.road_uv(obj.x, obj.y)
    return _Placed(u, v, obj.yaw - b.road_yaw(), obj.local_min, obj.local_max)


def _load(rng: np.random.Generator, share: float) -> str:
    """What a pedestrian holds: "" (nothing beyond `_carried`'s draws) or one of LOADS, `share` of the time."""
    return str(rng.choice(LOADS, p=_LOAD_P)) if rng.random() < share else ""


def _group_spot(rng: np.random.Generator, lay: RoadLayout) -> tuple[float, float, float, bool]:
    """(u, v, heading, standing) of a group: on the sidewalk, waiting at the kerb or a crossing, at a building front,
    or on the terrain beyond the sidewalk; 4-35 m away, more often ahead than behind."""
    side = float(rng.choice([-1.0, 1.0]))
    dist = rng.uniform(4.0, 35.0)
    u = dist if rng.random() < 0.7 else -dist
    standing = rng.random() < 0.3  # most groups walk (KITTI's pedestrian boxes hold a stride: 0.84 m long)
    heading = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.2)  # along the street
    where = rng.random()
    if where < 0.5:  # sidewalk
        v = side * (lay.half_width + rng.uniform(0.3, max(lay.sidewalk - 0.5, 0.4)))
    elif where < 0.72:  # waiting at the kerb to cross, facing the road (at the cross street when there is one)
        v = side * (lay.half_width + rng.uniform(0.3, 0.7))
        if lay.cross and rng.random() < 0.6:
            u = lay.cross_u + float(rng.choice([-1.0, 1.0])) * (lay.cross_half_width + rng.uniform(0.5, 2.5))
        heading, standing = -side * math.pi / 2 + rng.normal(0.0, 0.2), True
    elif where < 0.86:  # building front
        v = side * max(lay.frontage - rng.uniform(0.6, 1.5), lay.half_width + 0.4)
    else:  # terrain beyond the sidewalk
        v = side * (lay.half_width + lay.sidewalk + rng.uniform(0.5, 4.0))
    return float(u), float(v), float(heading), standing


def _group_room(size: int, ring: bool) -> tuple[float, float]:
    """Half extents (along the heading, across it) of the room a group of `size` needs: a row side by side, or a
    ring of people facing each other."""
    if ring:
        return 0.55 + 0.25 * (size - 1), 0.55 + 0.25 * (size - 1)
    return 0.55, 0.5 * (0.7 * size + 0.25 * (size - 1))


def _place_group(b: SceneBuilder, rng: np.random.Generator, u: float, v: float, heading: float, standing: bool,
                 size: int) -> int:
    """Place up to `size` pedestrians as one group at (u, v); how many were placed (0: no room there).

    The group's room keeps _GROUP_ROOM_M from everything placed, so that stage 1 proposes the group and not the
    group with a pole or a wall. Walkers go in a row (side by side, now and then a step behind), standing people in
    a row or a ring, each facing about the way of the one it joins; every newcomer stands 0.15-0.3 m beyond a
    member already placed.
    """
    ring = standing and rng.random() < 0.5
    room = _group_room(size, ring)
    if not b.area_free(u, v, heading, room, margin=_GROUP_ROOM_M - FOREGROUND_GAP_M):
        return 0
    if not ring:  # the row starts at its left end and grows to the right
        du, dv = _lateral(heading, room[1] - 0.35)
        u, v = u + du, v + dv
    pose = "stand" if standing else "walk"
    members: list[_Placed] = []
    for _member in range(size):
        parts, lo, hi = pedestrian(rng, pose, load=_load(rng, _GROUP_LOAD_SHARE))
        for attempt in range(10):
            if not members:
                du, dv = (0.0, 0.0) if attempt == 0 else rng.normal(0.0, 0.3, 2)
                pu, pv, yaw = u + du, v + dv, heading + rng.normal(0.0, 0.15)
            else:
                if ring:
                    anchor = members[int(rng.integers(len(members)))]
                    ang = rng.uniform(-math.pi, math.pi)
                    yaw = ang + math.pi + rng.normal(0.0, 0.5)  # turned toward the one it joins
                else:
                    anchor = members[-1]
                    ang = heading - (0.5 * math.pi if rng.random() < 0.85 else 0.8 * math.pi)  # beside, or behind
                    ang += rng.normal(0.0, 0.15)
                    yaw = heading + rng.normal(0.0, 0.15)
                gap = rng.uniform(*_GROUP_GAP_M)
                pu, pv = _next_to(anchor, lo, hi, yaw, ang, gap, rng.uniform(-0.15, 0.15))
            if b.place(parts, pu, pv, yaw, PEDESTRIAN, "Pedestrian", extent=(lo, hi), model="group_member",
                       clearance=_GROUP_GAP_M[0] if members else None):
                members.append(_Placed(pu, pv, yaw, lo, hi))
                break
        if not members:
            return 0
    return len(members)


def add_groups(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Groups of 2-4 pedestrians a hand's breadth apart ("groups"), in about a third of the scenes; then pedestrians
    beside riders (`add_rider_company`)."""
    sizes = np.array([n for n, _ in _GROUP_SIZE_P])
    weights = np.array([w for _, w in _GROUP_SIZE_P])
    for _ in range(int(rng.choice(len(_GROUPS_P), p=_GROUPS_P))):
        size = int(rng.choice(sizes, p=weights / weights.sum()))
        for _spot in range(8):  # a spot with room for the whole group
            u, v, heading, standing = _group_spot(rng, lay)
            if _place_group(b, rng, u, v, heading, standing, size):
                break
    add_rider_company(b, rng, lay)


def _beside_rider(b: SceneBuilder, rng: np.random.Generator, rider: _Placed, count: int) -> int:
    """Up to `count` pedestrians standing (or stepping) 0.2-0.8 m from a rider, mostly at its side; how many."""
    placed = 0
    for _ in range(count):
        parts, lo, hi = pedestrian(rng, "stand" if rng.random() < 0.7 else "walk")
        for _attempt in range(8):
            if rng.random() < 0.8:  # at the bike's side, anywhere from its rear wheel to its bar
                ang = rider.yaw + float(rng.choice([-0.5, 0.5])) * math.pi + rng.normal(0.0, 0.15)
                along = rng.uniform(-0.6, 0.6)
            else:  # in front of it or behind it
                ang = rider.yaw + float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.15)
                along = rng.uniform(-0.2, 0.2)
            yaw = rider.yaw + rng.normal(0.0, 0.3) if rng.random() < 0.7 else rng.uniform(-math.pi, math.pi)
            gap = rng.uniform(*_RIDER_GAP_M)
            u, v = _next_to(rider, lo, hi, yaw, ang, gap, along)
            if b.place(parts, u, v, yaw, PEDESTRIAN, "Pedestrian", extent=(lo, hi), model="beside_rider",
                       clearance=min(gap - 0.05, FOREGROUND_GAP_M)):
                placed += 1
                break
    return placed


def add_rider_company(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Pedestrians standing 0.2-0.8 m from a rider: beside a quarter of the scene's cyclists, and in a fifth of the
    scenes a rider waiting at the kerb (to cross, or at a light) with one or two pedestrians beside it."""
    for rider in [o for o in b.objects if o.label == CYCLIST]:
        if rng.random() < _BESIDE_RIDER_SHARE:
            _beside_rider(b, rng, _placed(b, rider), 1)
    if rng.random() >= _WAITING_RIDER_P:
        return
    parts = cyclist_parts(rng)
    company = int(rng.choice([1, 2], p=[0.6, 0.4]))
    for _attempt in range(8):
        side = float(rng.choice([-1.0, 1.0]))
        dist = rng.uniform(5.0, 30.0)
        u = dist if rng.random() < 0.7 else -dist
        if lay.cross and rng.random() < 0.5:
            u = lay.cross_u + float(rng.choice([-1.0, 1.0])) * (lay.cross_half_width + rng.uniform(0.5, 2.0))
        if rng.random() < 0.5:  # on the road at the kerb, or on the sidewalk's edge
            v = side * (lay.half_width - rng.uniform(0.5, 0.9))
        else:
            v = side * (lay.half_width + rng.uniform(0.5, 1.0))
        yaw = (-side * math.pi / 2 if rng.random() < 0.5 else float(rng.choice([0.0, math.pi])))
        yaw += rng.normal(0.0, 0.15)
        if b.place(parts, u, v, yaw, CYCLIST, "Cyclist", model="waiting_cyclist"):
            _beside_rider(b, rng, _placed(b, b.objects[-1]), company)
            return


def add_lone_pedestrians(b: SceneBuilder, rng: np.random.Generator, lay: RoadLayout) -> None:
    """Lone pedestrians ("lone_people") at ranges a sensor sees with few rings (see _LONE_BANDS_M), 0-2 a scene, on
    the sidewalk, at the road's edge or beyond; 40 % hold a suitcase, a box or bags."""
    v_ego = lay.v_ego
    for _ in range(int(rng.choice(len(_LONE_COUNT_P), p=_LONE_COUNT_P))):
        near, far = _LONE_BANDS_M[int(rng.integers(len(_LONE_BANDS_M)))]
        parts, lo, hi = pedestrian(rng, "walk" if rng.random() < 0.75 else "stand", load=_load(rng, _LONE_LOAD_SHARE))
        for _attempt in range(10):
            side = float(rng.choice([-1.0, 1.0]))
            where = rng.random()
            if where < 0.45:  # sidewalk
                v = side * (lay.half_width + rng.uniform(0.3, max(lay.sidewalk - 0.3, 0.4)))
            elif where < 0.8:  # road edge, crossing
                v = side * rng.uniform(0.5, lay.half_width - 0.3)
            else:  # building front or terrain
                v = side * (lay.half_width + lay.sidewalk + rng.uniform(0.3, 3.0))
            dist = rng.uniform(near, far)
            if dist <= abs(v - v_ego) + 1.0:
                continue
            u = math.sqrt(dist * dist - (v - v_ego) ** 2) * (1.0 if rng.random() < 0.7 else -1.0)
            if rng.random() < 0.75:
                heading = float(rng.choice([0.0, math.pi])) + rng.normal(0.0, 0.3)
            else:
                heading = rng.uniform(-math.pi, math.pi)
            if b.place(parts, u, v, heading, PEDESTRIAN, "Pedestrian", extent=(lo, hi), model="lone_pedestrian"):
                break
