"""Split instead of drop: a cluster too long or too wide for any road user is often several of them (cars parked
end to end 0.5-1 m apart chain into one cluster through scan-line-run clustering's 0.5 m / 1.0 m reach), so such a
cluster is cut at the gaps along its long axis and each part is gated again on its own.

Which clusters: those that pass every gate of `pass3d_ros.core.stage1.refinement.select_proposals` but the footprint one
(point count, range, height, bottom and top above the ground) yet are longer than `max_length` or wider than
`max_width`. Their points are projected on the long axis of the cluster's minimal-area rectangle and binned
(`split_gap` / 4 wide); a run of empty bins at least `split_gap` less one bin long is a gap, and the cluster is cut
there when the metre of axis on each side of it is at least half covered (points within about two bins of each
other). That last check keeps the cut to real gaps between dense surfaces: a surface seen far away or at a grazing
angle has holes from its point spacing alone, and a uniform wall has no gap at all, so neither is cut. Every part of
a cut cluster gets a new cluster id and goes through every gate again; a part that fails stays dropped, as the whole
cluster was. Clusters that pass the gates are never touched: the proposals without the split all stay, first.

Scan-line runs again (`split_rerun`): a road user with clutter tenths of a metre beside it (a car by a bush or a hedge
seen over its roof) joins it through one close pair of points; no empty stretch separates them along either axis, and
the cluster fails the footprint gate by its width alone. Such a cluster, not longer than `max_length` and not cut at
a gap, is clustered again on its own points by the same scan-line-run clustering (Zermas et al.) with th_ring and
th_prop times `rerun_scale` (half: 0.25 m within a ring, 0.5 m between rings), and each part is gated again.
Clusters that are too long are left to the gap cut: long walls, hedges and fences, cut into car-sized pieces, would
only add background proposals.

`select_with_split` also runs the last kind of split on what is still dropped: road users protruding from a taller
structure (pass3d_ros.core.stage1.protrusion, `split_protruding`).
"""

from __future__ import annotations

import copy
from concurrent.futures import Executor

import numba as nb
import numpy as np

from pass3d_ros.core.stage1 import canopy as _canopy
from pass3d_ros.core.stage1 import crowd as _crowd
from pass3d_ros.core.stage1 import protrusion as _protrusion
from pass3d_ros.core.stage1 import refinement as _refinement
from pass3d_ros.core.stage1 import scanline as _scanline
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.ground import LocalGround, plane_distance
from pass3d_ros.core.stage1.ground import fit_ground as _fit_ground
from pass3d_ros.core.stage1.sensor_params import RangeGate
from pass3d_ros.data.frame import Box3D

PART_MAX_LENGTH_M = 2.0  # `rerun_dropped` keeps a part of a cluster it chose only when this short (KITTI's mean
PART_MAX_WIDTH_M = 1.2  # cyclist 1.76 x 0.60 m, pedestrian 0.84 x 0.66 m) and this narrow: people, not pieces of walls
# ... and only when shaped like a person standing there (`_person_shaped`; rule R3, docs/experiments/sensors.md):
PART_MIN_RISE_M = 0.88  # its points span at least half KITTI's mean pedestrian height (1.76 m) from bottom to top
PART_MIN_DEPTH_M = 0.1  # its footprint's short side at least this: the near half of a body 0.2-0.3 m deep, not a
# pole, sign or panel seen edge on
SIDE_WINDOW = 1.0  # metres of axis on each side of a gap whose coverage is checked
SIDE_COVER = 0.5  # share of that window's bins that must hold a point
BINS_PER_GAP = 4  # bin width = split_gap / BINS_PER_GAP


@nb.njit(cache=True, nogil=True)
def _split_kernel(pts: np.ndarray, label: np.ndarray, slot: np.ndarray, axes: np.ndarray, u0: np.ndarray,
                  offset: np.ndarray, bin_w: float, min_run: int, window: int, min_cover: float,
                  n_clusters: int) -> tuple:
    """New labels (every part of a cut cluster gets a new id from n_clusters on), the new cluster count, and how
    many clusters were cut. Cluster c is examined when slot[c] = t >= 0: `axes[t]` is its long axis (unit x, y),
    `u0[t]` its lowest coordinate on it, and `offset[t]:offset[t + 1]` its bins."""
    n = pts.shape[0]
    k = axes.shape[0]
    occ = np.zeros(offset[k], dtype=np.int32)
    bins = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        c = label[i]
        if c < 0:
            continue
        t = slot[c]
        if t < 0:
            continue
        u = pts[i, 0] * axes[t, 0] + pts[i, 1] * axes[t, 1]
        b = int((u - u0[t]) / bin_w)
        b = min(max(b, 0), offset[t + 1] - offset[t] - 1) + offset[t]
        bins[i] = b
        occ[b] += 1
    part = np.empty(offset[k], dtype=np.int32)
    next_id = n_clusters
    n_cut = 0
    for t in range(k):
        s = offset[t]
        e = offset[t + 1]
        current = next_id
        b = s
        while b < e:
            if occ[b] > 0:
                part[b] = current
                b += 1
                continue
            r = b
            while r < e and occ[r] == 0:
                r += 1
            if r - b >= min_run and b > s and r < e:
                lo = max(s, b - window)
                left = 0
                for q in range(lo, b):
                    left += occ[q] > 0
                hi = min(e, r + window)
                right = 0
                for q in range(r, hi):
                    right += occ[q] > 0
                if left >= min_cover * (b - lo) and right >= min_cover * (hi - r):
                    current += 1
            for q in range(b, r):
                part[q] = current
            b = r
        if current > next_id:
            n_cut += 1
            next_id = current + 1
        else:
            for q in range(s, e):
                part[q] = -1  # not cut: the cluster keeps its id
    out = label.copy()
    if n_cut > 0:
        for i in range(n):
            if bins[i] >= 0 and part[bins[i]] >= 0:
                out[i] = part[bins[i]]
    return out, next_id, n_cut


def cut_at_gaps(points: np.ndarray, label: np.ndarray, n_clusters: int, clusters: np.ndarray,
                rects: np.ndarray, config: Stage1Config) -> tuple[np.ndarray, int, int]:
    """(labels, cluster count, clusters cut): `clusters` (with their minimal-area rectangles `rects`) cut at the gaps
    along their long axis; every part of a cut cluster gets a new id from `n_clusters` on. Labels are `label` itself
    when nothing was cut."""
    if len(clusters) == 0:
        return label, n_clusters, 0
    axes = np.stack([np.cos(rects[:, 4]), np.sin(rects[:, 4])], axis=1)
    bin_w = config.split_gap / BINS_PER_GAP
    centre_u = rects[:, 0] * axes[:, 0] + rects[:, 1] * axes[:, 1]
    u0 = centre_u - 0.5 * rects[:, 2] - bin_w  # one spare bin each side against rounding
    n_bins = np.ceil((rects[:, 2] + 2.0 * bin_w) / bin_w).astype(np.int64) + 1
    offset = np.zeros(len(clusters) + 1, dtype=np.int64)
    np.cumsum(n_bins, out=offset[1:])
    slot = np.full(n_clusters, -1, dtype=np.int64)
    slot[clusters] = np.arange(len(clusters))
    out, n_total, n_cut = _split_kernel(
        points, np.ascontiguousarray(label, dtype=np.int32), slot, np.ascontiguousarray(axes), u0, offset, bin_w,
        BINS_PER_GAP - 1, round(SIDE_WINDOW / bin_w), SIDE_COVER, n_clusters,
    )
    return (out, int(n_total), int(n_cut)) if n_cut else (label, n_clusters, 0)


def rerun_runs(points: np.ndarray, ring: np.ndarray, label: np.ndarray, n_clusters: int, clusters: np.ndarray,
               config: Stage1Config, pool: Executor | None = None) -> tuple[np.ndarray, int, int]:
    """(labels, cluster count, clusters cut): the points of `clusters` clustered again by scan-line runs
    (pass3d_ros.core.stage1.scanline) with th_ring and th_prop times `config.rerun_scale`, each cluster on its own
    (a part is a cluster id and a new run label together); every part of a cluster that falls apart gets a new id from
    `n_clusters` on. Labels are `label` itself when nothing was cut. `points` and `ring` in scan order, as clustering
    read them. `pool`: a free thread for clustering's search (scanline.cluster_scanlines)."""
    if len(clusters) == 0:
        return label, n_clusters, 0
    chosen = np.zeros(n_clusters, dtype=bool)
    chosen[clusters] = True
    members = _members_of(label, chosen)
    tight = copy.copy(config)  # two thresholds changed, both smaller: still in range, not validated again
    tight.th_ring = config.th_ring * config.rerun_scale
    tight.th_prop = config.th_prop * config.rerun_scale
    runs, n_runs = _scanline.cluster_scanlines(np.take(points, members, axis=0), ring[members],
                                               np.ones(len(members), dtype=bool), tight, pool)
    new_id, n_new, n_cut = _new_part_ids(label[members], runs, n_clusters, max(n_runs, 1))
    if n_cut == 0:
        return label, n_clusters, 0
    out = label.copy()
    _move_parts(out, members, new_id)
    return out, n_clusters + n_new, n_cut


@nb.njit(cache=True, nogil=True)
def _members_of(label: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """The indices of the points whose cluster (label >= 0) is flagged in `chosen`, in order: one pass, where
    numpy's mask took three over the scan."""
    out = np.empty(len(label), np.int64)
    found = 0
    for i in range(len(label)):
        if label[i] >= 0 and chosen[label[i]]:
            out[found] = i
            found += 1
    return out[:found]


@nb.njit(cache=True, nogil=True)
def _new_part_ids(label: np.ndarray, runs: np.ndarray, n_clusters: int, n_runs: int) -> tuple[np.ndarray, int, int]:
    """For `rerun_runs`: per point (a cluster id in `label` and a run of the second clustering in `runs`), the new id
    of its part (cluster id and run together) where its cluster fell apart into more than one part, else -1; the new
    ids count up from `n_clusters` in the order of the parts' keys (cluster id, then run). Also the count of new ids
    and of clusters that fell apart. A two-pass counting sort by run, then by cluster: the parts' order of a sort of
    their keys, without a comparison sort (np.argsort and np.unique took a tenth of a millisecond and more here)."""
    m = label.shape[0]
    ordered = _sorted_by(label, n_clusters, _sorted_by(runs, n_runs, np.arange(m)))
    part = np.empty(m, dtype=np.int64)  # per point: its part, numbered in key order
    parts_of = np.zeros(n_clusters, dtype=np.int64)
    owner = np.empty(m, dtype=np.int64)  # per part: its cluster
    n_parts = 0
    for t in range(m):
        i = ordered[t]
        if t == 0 or label[i] != label[ordered[t - 1]] or runs[i] != runs[ordered[t - 1]]:
            owner[n_parts] = label[i]
            parts_of[label[i]] += 1
            n_parts += 1
        part[i] = n_parts - 1
    new_of_part = np.full(n_parts, -1, dtype=np.int64)
    n_new = 0
    n_cut = 0
    for q in range(n_parts):
        if parts_of[owner[q]] > 1:
            new_of_part[q] = n_clusters + n_new
            n_new += 1
    for c in range(n_clusters):
        if parts_of[c] > 1:
            n_cut += 1
    new_id = np.empty(m, dtype=np.int64)
    for i in range(m):
        new_id[i] = new_of_part[part[i]]
    return new_id, n_new, n_cut


@nb.njit(cache=True, nogil=True)
def _sorted_by(key: np.ndarray, n_keys: int, items: np.ndarray) -> np.ndarray:
    """`items` (indices into `key`, whose values are 0 .. n_keys - 1) stably sorted by their key: a counting sort."""
    start = np.zeros(n_keys + 1, dtype=np.int64)
    for i in items:
        start[key[i] + 1] += 1
    for k in range(n_keys):
        start[k + 1] += start[k]
    out = np.empty(items.shape[0], dtype=np.int64)
    for i in items:
        out[start[key[i]]] = i
        start[key[i]] += 1
    return out


@nb.njit(cache=True, nogil=True)
def _move_parts(out: np.ndarray, members: np.ndarray, new_id: np.ndarray) -> None:
    """Give the points `members` their new part id where they have one (>= 0)."""
    for j in range(members.shape[0]):
        if new_id[j] >= 0:
            out[members[j]] = new_id[j]


def _gate_parts(points: np.ndarray, label: np.ndarray, first: int, count: int, surface: np.ndarray | LocalGround,
                segment_edges: np.ndarray, config: Stage1Config, small_only: np.ndarray | None = None,
                gate: RangeGate | None = None) -> tuple[list[Box3D], np.ndarray, np.ndarray]:
    """Boxes and ids of the clusters `first` .. `first + count - 1` of `label` that pass every gate on their own;
    those flagged in `small_only` (one bool per part) only with a person- or rider-sized footprint and the shape of
    a person standing there (`_person_shaped`). Third, the ids of the flagged parts that may be groups of people
    (`_people_in_groups`): they pass every gate but the footprint or this one, with points for two people."""
    part_points = np.flatnonzero(label >= first)
    sub = np.take(points, part_points, axis=0)  # take: a tenth of fancy indexing's time on rows
    sub_label = (label[part_points] - first).astype(np.int32)
    z_lo, z_hi, fitted, rects, keep, _, _, may_part = _refinement.gate_clusters(sub, sub_label, count, surface,
                                                                                segment_edges, config, gate=gate)
    groups = np.zeros(0, dtype=np.int64)
    if small_only is not None:
        sized = ((rects[:, 2] <= PART_MAX_LENGTH_M) & (rects[:, 3] <= PART_MAX_WIDTH_M)
                 & (rects[:, 3] >= PART_MIN_DEPTH_M))
        flagged = np.zeros(count, dtype=bool)
        flagged[fitted[keep & small_only[fitted]]] = True
        shaped = _person_shaped(sub, sub_label, flagged, surface, segment_edges)
        keep &= ~small_only[fitted] | (sized & shaped[fitted])
        groups = first + fitted[small_only[fitted] & ~keep & may_part[fitted]]
    parts = fitted[keep]
    return _refinement.boxes_of(rects[keep], z_lo[parts], z_hi[parts]), first + parts, groups


def _person_shaped(points: np.ndarray, label: np.ndarray, flagged: np.ndarray, surface: np.ndarray | LocalGround,
                   segment_edges: np.ndarray) -> np.ndarray:
    """Per cluster id (`flagged`: those to look at; the others are False), whether its points rise at least
    PART_MIN_RISE_M from their lowest to their highest, as the gates read heights (`heights_above_ground`). The gates
    let a cluster's bottom float 1.5 m up (an occluded car, a person behind one); a part of a crowd's cluster that
    shows less than half a person was clutter far more often than a person on the development scans (rule R3). Its
    top is bounded by the gates' max_top alone (rule R4: a tall person, or one whose ground reads low, reaches
    2.1-2.3 m)."""
    return _shaped(heights_above_ground(points, label, flagged, surface, segment_edges), label, flagged)


def _shaped(height: np.ndarray, label: np.ndarray, flagged: np.ndarray) -> np.ndarray:
    """`_person_shaped` from the points' heights above the ground (NaN for points of clusters not flagged)."""
    return flagged & (_rise(height, label, len(flagged)) >= PART_MIN_RISE_M)


@nb.njit(cache=True, nogil=True)
def _rise(height: np.ndarray, label: np.ndarray, n_clusters: int) -> np.ndarray:
    """Per cluster id, its highest point's height less its lowest's over the points with a height (not NaN);
    -inf for a cluster without one. One pass, where np.maximum.at and np.minimum.at took two and a mask."""
    top = np.full(n_clusters, -np.inf)
    bottom = np.full(n_clusters, np.inf)
    for i in range(height.shape[0]):
        h = height[i]
        if h == h:
            c = label[i]
            if h > top[c]:
                top[c] = h
            if h < bottom[c]:
                bottom[c] = h
    return top - bottom


def _people_in_groups(points: np.ndarray, label: np.ndarray, n_total: int, groups: np.ndarray,
                      surface: np.ndarray | LocalGround, segment_edges: np.ndarray, config: Stage1Config,
                      gate: RangeGate | None = None) -> tuple[np.ndarray, int, list[Box3D], np.ndarray]:
    """(labels, cluster count, boxes, kept ids) of the people found in the clusters `groups` (parts of
    `rerun_dropped` too big for one person, yet of a person's height: pass3d_ros.core.stage1.crowd), each person a new
    cluster id gated again as a part of `rerun_dropped` is."""
    flagged = np.zeros(n_total, dtype=bool)
    flagged[groups] = True
    height = heights_above_ground(points, label, flagged, surface, segment_edges)
    shaped = np.flatnonzero(_shaped(height, label, flagged))
    if len(shaped) == 0:
        return label, n_total, [], np.zeros(0, dtype=np.int64)
    out, n_after, n_people = _crowd.people_apart(points, label, n_total, shaped, height)
    if n_people == 0:
        return label, n_total, [], np.zeros(0, dtype=np.int64)
    boxes, ids, _ = _gate_parts(points, out, n_total, n_people, surface, segment_edges, config,
                                np.ones(n_people, dtype=bool), gate)
    return out, n_after, boxes, ids


def _under_canopies(points: np.ndarray, label: np.ndarray, first: int, n_total: int, small_only: np.ndarray,
                    surface: np.ndarray | LocalGround, segment_edges: np.ndarray, config: Stage1Config,
                    gate: RangeGate | None = None) -> np.ndarray:
    """`cut_canopies`: the labels with the canopies over `rerun_dropped`'s parts (ids `first` on, flagged in
    `small_only`) taken out of them (pass3d_ros.core.stage1.canopy). Only parts that a gate could keep once cut are
    looked at (points for the few-points gate, a person's rise) and only those reaching above max_top near enough
    (`canopy.looked_at`) are cut: a few of a frame's hundreds."""
    planes = surface.planes if isinstance(surface, LocalGround) else surface
    part_points = np.flatnonzero(label >= first)  # the parts' points alone: passes over the scan's took 0.3 ms
    sub, sub_label = np.take(points, part_points, axis=0), label[part_points]
    count, centre, bottom, top = _refinement.cluster_heights(sub, sub_label - first, n_total - first, planes,
                                                             segment_edges)
    read = np.flatnonzero(small_only & (top - bottom >= PART_MIN_RISE_M))
    read = read[count[read] >= _refinement.points_needed(np.hypot(centre[read, 0], centre[read, 1]), config, gate,
                                                         centre[read])]
    offset = np.zeros(len(read))
    if isinstance(surface, LocalGround) and len(read):
        offset = surface.offsets(centre[read])
    looked = _canopy.looked_at(centre[read], top[read] - offset, config.max_top)
    cut = _canopy.under_canopies(sub, sub_label, first + read[looked], offset[looked], planes, segment_edges,
                                 config.max_top)
    if cut is sub_label:
        return label
    out = label.copy()
    out[part_points] = cut
    return out


def heights_above_ground(points: np.ndarray, label: np.ndarray, chosen: np.ndarray, surface: np.ndarray | LocalGround,
                         segment_edges: np.ndarray) -> np.ndarray:
    """Height above the ground of the points of the clusters flagged in `chosen` (one bool per cluster id; NaN for
    every other point), as the gates read it: the point's segment plane, moved by the local ground's offset at its
    cluster's centre when `surface` is a LocalGround."""
    planes = surface.planes if isinstance(surface, LocalGround) else surface
    height, count, sums = _plane_heights(points, label, chosen, planes, float(segment_edges[0]),
                                         float(segment_edges[1] - segment_edges[0]))
    if isinstance(surface, LocalGround) and count.any():
        present = np.flatnonzero(count)
        offset = np.zeros(len(count))
        offset[present] = surface.offsets(sums[present] / count[present, None])
        _take_offsets(height, label, offset)
    return height


@nb.njit(cache=True, nogil=True)
def _plane_heights(points: np.ndarray, label: np.ndarray, chosen: np.ndarray, planes: np.ndarray, x0: float,
                   width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`heights_above_ground` over the segment planes in one pass over the scan (numpy's masks took five): the
    heights (NaN outside the chosen clusters) and, per cluster id, its chosen points' count and x-y sums (summed in
    point order, as np.bincount sums)."""
    n = points.shape[0]
    height = np.full(n, np.nan)
    count = np.zeros(chosen.shape[0], dtype=np.int64)
    sums = np.zeros((chosen.shape[0], 2))
    for i in range(n):
        c = label[i]
        if c < 0 or not chosen[c]:
            continue
        x = np.float64(points[i, 0])
        y = np.float64(points[i, 1])
        height[i] = plane_distance(planes, x0, width, x, y, np.float64(points[i, 2]))
        count[c] += 1
        sums[c, 0] += x
        sums[c, 1] += y
    return height, count, sums


@nb.njit(cache=True, nogil=True)
def _take_offsets(height: np.ndarray, label: np.ndarray, offset: np.ndarray) -> None:
    """Take each point's cluster's local-ground offset off its height, where it has one."""
    for i in range(height.shape[0]):
        if height[i] == height[i]:
            height[i] -= offset[label[i]]


def _protrusion_candidates(n_total: int, kept: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray,
                           config: Stage1Config) -> np.ndarray:
    """Per cluster id, whether the protrusion split looks at it: dropped, and tall enough to hold a point above
    max_top and one within max_bottom of the ground (parts of a gap cut, without heights here, are all looked at)."""
    chosen = np.ones(n_total, dtype=bool)
    chosen[kept] = False
    n = len(z_lo)
    chosen[:n] &= (z_hi - z_lo) >= config.max_top - max(config.max_bottom, 0.0)
    return chosen


def _dropped_to_rerun(points: np.ndarray, label: np.ndarray, n_clusters: int, n_total: int, kept: np.ndarray,
                      count: np.ndarray, may_part: np.ndarray, config: Stage1Config,
                      gate: RangeGate | None = None) -> np.ndarray:
    """Cluster ids `rerun_dropped` clusters again: not kept, with at most `rerun_max_points` points, and such that a
    part of them could pass the gates no split changes (`may_part` of the `n_clusters` clusters clustering made: at
    least twice the few-points gate's count, within max_range, near enough the ground and tall enough), or, for the
    parts of a gap cut (ids n_clusters .. n_total - 1), at least twice the few-points gate's count within max_range."""
    chosen = np.zeros(n_total, dtype=bool)
    chosen[:n_clusters] = may_part & (count <= config.rerun_max_points)
    if n_total > n_clusters:
        part_count, centre = _part_sums(points, label, n_clusters, n_total - n_clusters)
        rng = np.hypot(centre[:, 0], centre[:, 1]) / np.maximum(part_count, 1)
        need = _refinement.points_needed(rng, config, gate, centre)  # the summed centres: the same directions
        chosen[n_clusters:] = ((part_count >= 2 * need) & (part_count <= config.rerun_max_points)
                               & (rng <= config.max_range))
    chosen[kept] = False
    return np.flatnonzero(chosen)


@nb.njit(cache=True, nogil=True)
def _part_sums(points: np.ndarray, label: np.ndarray, first: int, n_parts: int) -> tuple[np.ndarray, np.ndarray]:
    """Per part (cluster ids `first` .. `first + n_parts - 1`): its point count and x-y sums, summed in point order
    as np.bincount sums; one pass over the scan, where the masks and bincounts took five."""
    count = np.zeros(n_parts, dtype=np.int64)
    sums = np.zeros((n_parts, 2))
    for i in range(label.shape[0]):
        c = label[i] - first
        if c >= 0:
            count[c] += 1
            sums[c, 0] += points[i, 0]
            sums[c, 1] += points[i, 1]
    return count, sums


def select_with_split(
    points: np.ndarray, label: np.ndarray, n_clusters: int, planes: np.ndarray | LocalGround,
    segment_edges: np.ndarray, config: Stage1Config, ring: np.ndarray | None = None,
    gate: RangeGate | None = None, pool: Executor | None = None,
) -> tuple[list[Box3D], np.ndarray, np.ndarray, int, np.ndarray]:
    """`select_proposals` with the splits: (boxes, kept cluster ids, labels with the parts' new ids, clusters split,
    which kept proposals give way). The boxes and ids of `select_proposals` come first, unchanged; kept parts follow,
    first those cut at gaps (`split_merged`, module docstring), then those of scan-line runs again (`split_rerun`;
    needs `ring`, the rings clustering read, else skipped), then those protruding from dropped taller structures
    (`split_protruding`, pass3d_ros.core.stage1.protrusion). `planes`: the segment planes or the local ground, as the
    gates take them. The parts of the clusters only `rerun_dropped` chose give way (one bool per kept id): they hold
    no point another proposal holds (refinement.enlarged_membership), so the option only adds labels. `gate`: the
    few-points gate's factor per range (refinement.points_needed), for every gate here. `pool`: a free thread for
    `rerun_runs`' clustering."""
    if n_clusters == 0:
        return [], np.zeros(0, dtype=np.int64), label, 0, np.zeros(0, dtype=bool)
    z_lo, z_hi, fitted, rects, keep, footprint, count, may_part = _refinement.gate_clusters(
        points, label, n_clusters, planes, segment_edges, config, fit_all=True, gate=gate)
    kept = fitted[keep]
    boxes = _refinement.boxes_of(rects[keep], z_lo[kept], z_hi[kept])
    out, n_total, n_split = label, n_clusters, 0
    gives_way = np.zeros(0, dtype=np.int64)  # kept ids of rerun_dropped's parts
    if config.split_merged:
        out, n_total, n_split = cut_at_gaps(points, label, n_clusters, fitted[~footprint], rects[~footprint], config)
        if n_split:
            part_boxes, part_ids, _ = _gate_parts(points, out, n_clusters, n_total - n_clusters, planes,
                                                  segment_edges, config, gate=gate)
            boxes += part_boxes
            kept = np.concatenate([kept, part_ids])
    if config.split_rerun and ring is not None:
        wide = fitted[~footprint & (rects[:, 2] <= config.max_length)]  # too wide, not too long
        chosen = wide
        if config.rerun_dropped:
            chosen = np.union1d(wide, _dropped_to_rerun(points, out, n_clusters, n_total, kept, count, may_part,
                                                        config, gate))
        if n_split:  # only the clusters the gap cut left whole
            chosen = chosen[np.bincount(out[out >= 0], minlength=n_total)[chosen] > 0]
        first, before = n_total, out
        out, n_total, n_rerun = rerun_runs(points, ring, out, n_total, chosen, config, pool)
        if n_rerun:
            small_only = None
            if config.rerun_dropped:  # parts of the clusters only rerun_dropped chose: people-sized ones only
                origin = np.full(n_total - first, -1, dtype=np.int64)
                moved = out >= first
                origin[out[moved] - first] = before[moved]
                small_only = ~np.isin(origin, wide)
            if small_only is not None and config.cut_canopies:
                out = _under_canopies(points, out, first, n_total, small_only, planes, segment_edges, config, gate)
            part_boxes, part_ids, groups = _gate_parts(points, out, first, n_total - first, planes, segment_edges,
                                                       config, small_only, gate)
            boxes += part_boxes
            kept = np.concatenate([kept, part_ids])
            n_split += n_rerun
            if small_only is not None:
                gives_way = part_ids[small_only[part_ids - first]]
                if config.split_groups and len(groups):  # a group too big for one person: one part per person
                    out, n_total, people_boxes, people_ids = _people_in_groups(points, out, n_total, groups, planes,
                                                                               segment_edges, config, gate)
                    boxes += people_boxes
                    kept = np.concatenate([kept, people_ids])
                    gives_way = np.concatenate([gives_way, people_ids])
    if config.split_protruding:
        chosen = _protrusion_candidates(n_total, kept, z_lo, z_hi, config)
        height = heights_above_ground(points, out, chosen, planes, segment_edges)
        cut, n_parts, n_made = _protrusion.protruding_parts(points, out, height, n_total, np.flatnonzero(chosen),
                                                            config.max_top, config.th_num_floor)
        if n_made:
            part_boxes, part_ids, _ = _gate_parts(points, cut, n_total, n_parts - n_total, planes, segment_edges,
                                                  config, gate=gate)
            boxes += part_boxes
            kept = np.concatenate([kept, part_ids])
            out, n_split = cut, n_split + n_made
    return boxes, kept, out, n_split, np.isin(kept, gives_way)


def warm_up() -> None:
    """Compile the split kernels on two short walls 1 m apart in one cluster, and the other kernels of this module
    and of the crowd split on the same points: the first scan a node labels then runs compiled code."""
    x = np.concatenate([np.linspace(5.0, 9.0, 80), np.linspace(10.0, 14.0, 80)])
    pts = np.zeros((160, 4), dtype=np.float32)
    pts[:, 0] = x
    pts[:, 1] = 3.0
    pts[:, 2] = np.tile([-1.6, -0.4], 80)
    label = np.zeros(160, dtype=np.int32)
    config = Stage1Config(th_num_floor=1, th_num_near=1.0)
    planes, edges = np.array([[0.0, 0.0, 1.0, 1.73]]), np.array([-80.0, 80.0])
    select_with_split(pts, label, 1, planes, edges, config)
    _protrusion.warm_up()
    _canopy.warm_up()
    # The kernels the wall above does not reach (parts, heights, crowds), with stage 1's dtypes: float32 points,
    # int32 labels, int64 ids.
    two = np.repeat(np.arange(2, dtype=np.int32), 80)
    chosen = np.ones(2, dtype=bool)
    local = _fit_ground(pts, config).local
    for surface in (planes, local):
        _shaped(heights_above_ground(pts, two, chosen, surface, edges), two, chosen)
    ring = np.tile(np.arange(2, dtype=np.uint16), 80)
    out, n_total, _ = rerun_runs(pts, ring, two, 2, np.arange(2, dtype=np.int64), config)
    _move_parts(two.copy(), np.arange(160, dtype=np.int64), np.full(160, -1, dtype=np.int64))
    _part_sums(pts, out, 2, max(n_total - 2, 1))
    height = np.where(np.arange(160) % 2 == 0, 1.6, 0.2)
    _crowd.people_apart(pts, two, 2, np.arange(2, dtype=np.int64), height)
