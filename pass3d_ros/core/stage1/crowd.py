"""People apart in a crowd: one part per person standing in a group that clustering kept together.

People walking side by side, a queue, a group chatting are tenths of a metre apart, closer than scan-line-run
clustering's reach even at `split_rerun`'s half thresholds; their part is too big for one person and stage 2 calls a
group of three or more mostly background (a lone person's points pedestrian 70 % of the time on the parking lot, a
group's 2-14 %; docs/experiments/sensors.md, rule C1). Each person's head and shoulders are the highest points
around them, so the points are taken from the highest down: one that stands SEED_MIN_H or more above the ground,
PERSON_SPACING or more (in x-y) from every head already found, and alone (no point from HEAD_WIDTH out to
PERSON_SPACING around it less than HEAD_DROP lower: the top of a wall, a hedge or a vehicle runs on at one height; a
neighbour's head 0.45-0.6 m away does not hide it, rule C4) is another person's head. A group with two heads or more
is parted: every point goes to the nearest head in x-y, if within PERSON_RADIUS; the rest (a bag, a pole between
them) to none.
"""

from __future__ import annotations

import numba as nb
import numpy as np

SEED_MIN_H = 1.0  # m above ground: a head or shoulders (a child of 1.1 m has its head there), not a bag or a bonnet
PERSON_SPACING = 0.45  # m between two heads: adult shoulders are 0.4-0.5 m broad, so side by side they are this apart
HEAD_WIDTH = 0.3  # m: points nearer a head than this may be as high (the head and the shoulders under it) ...
HEAD_DROP = 0.15  # ... points from there out to PERSON_SPACING must be this much lower than the head's top
PERSON_RADIUS = 0.6  # m from the head in x-y: a walking person's feet and arms reach about this far


@nb.njit(cache=True, nogil=True)
def _people_kernel(x: np.ndarray, y: np.ndarray, h: np.ndarray, start: np.ndarray, seed_min_h: float,
                   spacing: float, radius: float, inner: float, head_drop: float) -> tuple:
    """Per point (listed group by group, each group from its highest point down, groups at `start`), the person it
    belongs to (0 .. P-1 over all groups, -1 for none), and P."""
    n = x.shape[0]
    person = np.full(n, -1, dtype=np.int64)
    seed_x = np.empty(n, dtype=np.float64)
    seed_y = np.empty(n, dtype=np.float64)
    spacing2 = spacing * spacing
    radius2 = radius * radius
    inner2 = inner * inner
    n_people = 0
    for g in range(start.shape[0] - 1):
        lo = start[g]
        hi = start[g + 1]
        first = n_people
        top = lo  # points lo .. top - 1 are higher than the candidate's height less head_drop
        for i in range(lo, hi):
            if h[i] < seed_min_h:
                break  # highest first: every later point is lower
            apart = True
            for s in range(first, n_people):
                dx = x[i] - seed_x[s]
                dy = y[i] - seed_y[s]
                if dx * dx + dy * dy < spacing2:
                    apart = False
                    break
            if not apart:
                continue
            while top < hi and h[top] >= h[i] - head_drop:
                top += 1
            for j in range(lo, top):  # a head stands alone: nothing as high beside it (a wall's, a hedge's top do)
                dx = x[j] - x[i]
                dy = y[j] - y[i]
                d2 = dx * dx + dy * dy
                if inner2 <= d2 < spacing2:
                    apart = False
                    break
            if apart:
                seed_x[n_people] = x[i]
                seed_y[n_people] = y[i]
                n_people += 1
        if n_people - first < 2:  # one head or none: no crowd to part
            n_people = first
            continue
        for i in range(lo, hi):
            best = radius2
            for s in range(first, n_people):
                dx = x[i] - seed_x[s]
                dy = y[i] - seed_y[s]
                d2 = dx * dx + dy * dy
                if d2 < best:
                    best = d2
                    person[i] = s
    return person, n_people


@nb.njit(cache=True, nogil=True)
def _with_height(label: np.ndarray, chosen: np.ndarray, height: np.ndarray) -> np.ndarray:
    """The indices of the points of the clusters flagged in `chosen` that have a height (not NaN), in order: one
    pass over the scan, where numpy's masks took five."""
    out = np.empty(label.shape[0], np.int64)
    found = 0
    for i in range(label.shape[0]):
        c = label[i]
        if c >= 0 and chosen[c] and height[i] == height[i]:
            out[found] = i
            found += 1
    return out[:found]


def people_apart(points: np.ndarray, label: np.ndarray, n_total: int, groups: np.ndarray, height: np.ndarray
                 ) -> tuple[np.ndarray, int, int]:
    """(labels, cluster count, people found): the points of the clusters `groups` given to the people found in them
    (module docstring), each person a new cluster id from `n_total` on; a point of no person, or of a group where at
    most one head was found, keeps its label. `height`: each point's height above the ground (NaN where not read)."""
    chosen = np.zeros(n_total, dtype=bool)
    chosen[groups] = True
    inside = _with_height(label, chosen, height)
    if len(inside) == 0:
        return label, n_total, 0
    order = inside[np.lexsort((-height[inside], label[inside]))]
    group_of = label[order]
    start = np.flatnonzero(np.r_[True, group_of[1:] != group_of[:-1], True])
    person, n_people = _people_kernel(points[order, 0].astype(np.float64), points[order, 1].astype(np.float64),
                                      height[order], start, SEED_MIN_H, PERSON_SPACING, PERSON_RADIUS, HEAD_WIDTH,
                                      HEAD_DROP)
    if n_people == 0:
        return label, n_total, 0
    out = label.copy()
    found = person >= 0
    out[order[found]] = n_total + person[found]
    return out, n_total + n_people, n_people
