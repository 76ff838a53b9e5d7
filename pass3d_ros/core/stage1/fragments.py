"""Low fragments joined to the proposal beside them: box refinement after the gates (`Stage1Config.join_fragments`).

Scan-line-run clustering links runs of neighbouring rings whose points lie within th_merge of each other. A car seen
from behind or ahead 15-30 m away breaks where its boot or bonnet ends and its rear or front window starts a laser
step further on: the windows and roof become one cluster, kept, and the boot or bonnet below them another, dropped as
too low to be a road user alone (its top under min_top). Stage 2 then reads only the top of the car, and the rest of
it is background in that scan (docs/experiments/tracks.md, where the ground-truth flicker left comes from).

A dropped cluster joins a kept proposal when it is such a fragment: at least th_num_floor points, its top
MIN_FRAGMENT_TOP_M to min_top above the ground, its bottom under max_bottom, MIN_FRAGMENT_SPAN_M long or more (a boot
or a bonnet; a person's legs are not), its nearest point within JOIN_GAP_M of the proposal's footprint rectangle, in
front of the proposal as the sensor sees it (nearer, and mostly within its bearings: `_in_front`; a hedge beside a
cyclist or a motorbike parked behind one is not), the proposal MIN_PROPOSAL_LENGTH_M long or more (not a person's),
and the two together still within max_length x max_width. Of several such proposals the nearest takes it; the
proposal's box is fitted again to the union (docs/experiments/sensors.md, rules J and J2).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pass3d_ros.core.stage1 import refinement as _refinement
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.ground import LocalGround
from pass3d_ros.data.frame import Box3D

JOIN_GAP_M = 1.0  # a fragment's nearest point lies at most this far outside the proposal's footprint rectangle
MIN_FRAGMENT_TOP_M = 0.3  # a fragment's top at least this high above the ground (kerbs and road marks stay out)
MIN_FRAGMENT_SPAN_M = 0.8  # a fragment's longer x-y extent at least this (a boot or a bonnet; a person's legs are not)
AZIMUTH_SHARE = 0.5  # ... at least this share of its points within the proposal's bearings, and nearer than it
MIN_PROPOSAL_LENGTH_M = 1.2  # a proposal's longer footprint side at least this to take a fragment (not a person's)


def join_fragments(points: np.ndarray, label: np.ndarray, kept: np.ndarray, boxes: list[Box3D],
                   planes: np.ndarray | LocalGround, segment_edges: np.ndarray,
                   config: Stage1Config) -> tuple[np.ndarray, list[Box3D]]:
    """`label` with each low fragment (module docstring) given the id of the kept cluster it joins, and `boxes` with
    those proposals' boxes fitted again. `kept`: the kept cluster ids (proposal k is cluster kept[k], box boxes[k]);
    `planes`: the segment planes or the local ground, as the gates read heights."""
    if not len(kept) or not len(label):
        return label, boxes
    n_total = int(label.max()) + 1
    local = planes if isinstance(planes, LocalGround) else None
    rows = local.planes if local is not None else planes
    count, sums, lo, hi, bottom, top = _refinement._cluster_stats(points, label, n_total, rows, segment_edges)
    dropped = np.ones(n_total, dtype=bool)
    dropped[kept] = False
    span = np.maximum(hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1])
    fragments = np.flatnonzero(dropped & (count >= config.th_num_floor) & (span >= MIN_FRAGMENT_SPAN_M))
    if local is not None and len(fragments):
        offset = local.offsets(sums[fragments] / count[fragments, None])
        bottom, top = bottom[fragments] - offset, top[fragments] - offset
    else:
        bottom, top = bottom[fragments], top[fragments]
    fragments = fragments[(top >= MIN_FRAGMENT_TOP_M) & (top < config.min_top) & (bottom <= config.max_bottom)]
    rects = np.array([[*box.center[:2], *box.size[:2], box.yaw] for box in boxes], dtype=np.float64).reshape(-1, 5)
    takers = np.flatnonzero(rects[:, 2:4].max(axis=1) >= MIN_PROPOSAL_LENGTH_M)
    if not len(fragments) or not len(takers):
        return label, boxes
    owner = _owners(points, label, kept, fragments, lo, hi, rects, takers, config)
    if not (owner >= 0).any():
        return label, boxes
    to_proposal = np.full(n_total, -1, dtype=np.int64)
    to_proposal[fragments] = owner
    moved = label >= 0
    moved[moved] = to_proposal[label[moved]] >= 0
    label = label.copy()
    label[moved] = kept[to_proposal[label[moved]]]
    grown = np.unique(owner[owner >= 0])
    return label, _refit(points, label, kept, grown, boxes)


def _owners(points: np.ndarray, label: np.ndarray, kept: np.ndarray, fragments: np.ndarray, lo: np.ndarray,
            hi: np.ndarray, rects: np.ndarray, takers: np.ndarray, config: Stage1Config) -> np.ndarray:
    """Per fragment, the proposal (row of `rects`, one of `takers`) it joins, -1 for none: the nearest within
    JOIN_GAP_M that it lies in front of (`_in_front`) and whose footprint with it stays within max_length x
    max_width."""
    reach = 0.5 * np.hypot(rects[takers, 2], rects[takers, 3]) + JOIN_GAP_M
    near = [takers[(lo[c, 0] <= rects[takers, 0] + reach) & (hi[c, 0] >= rects[takers, 0] - reach)
                   & (lo[c, 1] <= rects[takers, 1] + reach) & (hi[c, 1] >= rects[takers, 1] - reach)]
            for c in fragments.tolist()]
    owner = np.full(len(fragments), -1, dtype=np.int64)
    if not any(len(n) for n in near):
        return owner
    xy_of = _points_of(points, label, np.concatenate([fragments, kept[np.concatenate(near)]]))
    hosts: dict[int, tuple[float, float, float, float]] = {}  # each host's view, read once
    for f, c in enumerate(fragments.tolist()):
        if not len(near[f]):
            continue
        xy = xy_of(c)
        best = JOIN_GAP_M
        for k in near[f].tolist():
            if k not in hosts:
                hosts[k] = _seen_from_sensor(xy_of(int(kept[k])))
            if not _in_front(xy, hosts[k]):
                continue
            cx, cy, length, width, yaw = rects[k]
            rel = xy - (cx, cy)
            u = rel @ np.array([np.cos(yaw), np.sin(yaw)])
            v = rel @ np.array([-np.sin(yaw), np.cos(yaw)])
            gap = float(np.hypot(np.maximum(np.abs(u) - length / 2, 0.0), np.maximum(np.abs(v) - width / 2, 0.0)).min())
            long_side = max(u.max(), length / 2) - min(u.min(), -length / 2)
            short_side = max(v.max(), width / 2) - min(v.min(), -width / 2)
            if long_side < short_side:
                long_side, short_side = short_side, long_side
            if gap <= best and long_side <= config.max_length and short_side <= config.max_width:
                owner[f], best = k, gap
    return owner


def _points_of(points: np.ndarray, label: np.ndarray, clusters: np.ndarray) -> Callable[[int], np.ndarray]:
    """x, y (float64) of each of `clusters`' points, by cluster id: the scan read once for those clusters alone (a sort
    of a whole 120k-point scan's labels took a millisecond)."""
    wanted = np.zeros(int(label.max()) + 2, dtype=bool)
    wanted[np.asarray(clusters) + 1] = True
    index = np.flatnonzero(wanted[label + 1])
    index = index[np.argsort(label[index], kind="stable")]
    ids = label[index]
    xy = points[index, :2].astype(np.float64)
    return lambda c: xy[np.searchsorted(ids, c, "left"):np.searchsorted(ids, c, "right")]


def _seen_from_sensor(host: np.ndarray) -> tuple[float, float, float, float]:
    """A host proposal (x, y of its points) as the sensor sees it: its median bearing, its bearings' span about that
    (lowest, highest) and its median range."""
    bearing = np.arctan2(host[:, 1], host[:, 0])
    centre = float(np.median(bearing))
    spread = np.angle(np.exp(1j * (bearing - centre)))
    return centre, float(spread.min()), float(spread.max()), float(np.median(np.hypot(host[:, 0], host[:, 1])))


def _in_front(fragment: np.ndarray, host: tuple[float, float, float, float]) -> bool:
    """Whether the fragment (x, y of its points) lies in front of the host (`_seen_from_sensor`): nearer (median
    range) and within the host's bearings for AZIMUTH_SHARE of its points (bearings taken about the host's median
    one), as the lower part of one object seen from one side is."""
    centre, lowest, highest, host_range = host
    mine = np.angle(np.exp(1j * (np.arctan2(fragment[:, 1], fragment[:, 0]) - centre)))
    within = np.count_nonzero((mine >= lowest) & (mine <= highest))
    nearer = np.median(np.hypot(fragment[:, 0], fragment[:, 1])) < host_range
    return bool(nearer and within >= AZIMUTH_SHARE * len(fragment))


def _refit(points: np.ndarray, label: np.ndarray, kept: np.ndarray, grown: np.ndarray,
           boxes: list[Box3D]) -> list[Box3D]:
    """`boxes` with those of proposals `grown` fitted again to their clusters' points (footprint rectangle, z range)."""
    ids = kept[grown]
    rects = _refinement._cluster_rects(points, label, ids)
    slot = np.full(int(label.max()) + 1, -1, dtype=np.int64)
    slot[ids] = np.arange(len(ids))
    members = np.flatnonzero(label >= 0)
    members = members[slot[label[members]] >= 0]
    z_lo, z_hi = np.full(len(ids), np.inf), np.full(len(ids), -np.inf)
    np.minimum.at(z_lo, slot[label[members]], points[members, 2])
    np.maximum.at(z_hi, slot[label[members]], points[members, 2])
    out = list(boxes)
    for k, box in zip(grown.tolist(), _refinement.boxes_of(rects, z_lo, z_hi), strict=True):
        out[k] = box
    return out
