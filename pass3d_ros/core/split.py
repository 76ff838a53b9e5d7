"""Split instead of drop: a cluster too long or too wide for any road user is often several of them (cars parked
end to end 0.5-1 m apart chain into one cluster through scan-line-run clustering's 0.5 m / 1.0 m reach), so such a
cluster is cut at the gaps along its long axis and each part is gated again on its own.

Which clusters: those that pass every gate of `pass3d_ros.core.refinement.select_proposals` but the footprint one
(point count, range, height, bottom and top above the ground) yet are longer than `max_length` or wider than
`max_width`. Their points are projected on the long axis of the cluster's minimal-area rectangle and binned
(`split_gap` / 4 wide); a run of empty bins at least `split_gap` less one bin long is a gap, and the cluster is cut
there when the metre of axis on each side of it is at least half covered (points within about two bins of each
other). That last check keeps the cut to real gaps between dense surfaces: a surface seen far away or at a grazing
angle has holes from its point spacing alone, and a uniform wall has no gap at all, so neither is cut. Every part of
a cut cluster gets a new cluster id and goes through every gate again; a part that fails stays dropped, as the whole
cluster was. Clusters that pass the gates are never touched: the proposals without the split all stay, first.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pass3d_ros.core import refinement as _refinement
from pass3d_ros.core.config import Stage1Config
from pass3d_ros.data.frame import Box3D

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


def select_with_split(
    points: np.ndarray, label: np.ndarray, n_clusters: int, planes: np.ndarray, segment_edges: np.ndarray,
    config: Stage1Config,
) -> tuple[list[Box3D], np.ndarray, np.ndarray, int]:
    """`select_proposals` with the split (module docstring): (boxes, kept cluster ids, labels with the parts' new
    ids, clusters cut). The boxes and ids of `select_proposals` come first, unchanged; kept parts follow."""
    if n_clusters == 0:
        return [], np.zeros(0, dtype=np.int64), label, 0
    z_lo, z_hi, fitted, rects, keep, footprint = _refinement.gate_clusters(
        points, label, n_clusters, planes, segment_edges, config, fit_all=True)
    kept = fitted[keep]
    boxes = _refinement.boxes_of(rects[keep], z_lo[kept], z_hi[kept])
    out, n_total, n_cut = cut_at_gaps(points, label, n_clusters, fitted[~footprint], rects[~footprint], config)
    if n_cut == 0:
        return boxes, kept, label, 0
    part_points = np.flatnonzero(out >= n_clusters)  # the points of the cut clusters, gated again on their own
    sub = np.ascontiguousarray(points[part_points])
    sub_label = (out[part_points] - n_clusters).astype(np.int32)
    z_lo, z_hi, fitted, rects, keep, _ = _refinement.gate_clusters(
        sub, sub_label, n_total - n_clusters, planes, segment_edges, config)
    parts = fitted[keep]
    boxes += _refinement.boxes_of(rects[keep], z_lo[parts], z_hi[parts])
    return boxes, np.concatenate([kept, n_clusters + parts]), out, n_cut


def warm_up() -> None:
    """Compile the split kernel on two short walls 1 m apart in one cluster."""
    x = np.concatenate([np.linspace(5.0, 9.0, 80), np.linspace(10.0, 14.0, 80)])
    pts = np.zeros((160, 4), dtype=np.float32)
    pts[:, 0] = x
    pts[:, 1] = 3.0
    pts[:, 2] = np.tile([-1.6, -0.4], 80)
    label = np.zeros(160, dtype=np.int32)
    config = Stage1Config(th_num_floor=1, th_num_near=1.0)
    select_with_split(pts, label, 1, np.array([[0.0, 0.0, 1.0, 1.73]]), np.array([-80.0, 80.0]), config)
