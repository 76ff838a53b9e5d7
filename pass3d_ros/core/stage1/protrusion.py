"""Split instead of drop, second kind: a road user standing against a taller structure is cut out of it.

A person against a lamp mast or a building front, a car parked against a wall: scan-line-run clustering joins them
to the structure (their runs touch), and the joined cluster is too tall or too long for any road user, so it is
dropped whole. There is no gap to cut at (pass3d_ros.core.stage1.split); what tells the road user apart is that it
protrudes: its points lie below the tallest road user's height (`max_top`) where the structure, seen above that
height, does not reach. So per cluster: the x-y cells (`CELL_M`) holding the cluster's points above `max_top`,
grown by `PROTRUSION_M`, are the structure's footprint; the points below `max_top` outside it are grouped into
parts (cells within `JOIN_M` of each other join). A part becomes a cluster of its own, gated again like every
other, only where the structure around it (within `STRUCTURE_WINDOW_M`) is thin: the area of its cells above
`max_top`, divided by their length along their main direction, is at most `STRUCTURE_MAX_WIDTH_M` (a mast; a wall
or a building's corner as the street sees it, a line of cells). Under a tree's crown or beside a bulky mass,
bushes and clutter would otherwise each become a proposal. A bare pole or a plain wall protrudes nowhere and stays
dropped; a low structure with nothing above `max_top` is never examined.

Off by default (Stage1Config.split_protruding): on the six real KITTI dev frames it added 142 proposals (24 a frame,
none holding a road user: lower facade pieces, bushes, clutter before walls) and about 20 ms of stage 1 a frame,
for no recall there; on synthetic scans and the other real sensors it raised pedestrian recall
(docs/experiments/stage1-issue-27.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.refinement import grouped_by_slot

CELL_M = 0.1  # x-y cell of the footprints
PROTRUSION_M = 0.2  # a point this far (x-y) from every point above max_top protrudes
JOIN_M = 0.3  # protruding cells this close belong to one part
STRUCTURE_MAX_WIDTH_M = 1.0  # a part counts only beside a thin structure: a mast, a wall as the street sees it
STRUCTURE_WINDOW_M = 2.0  # how far around a part the structure's width is read
MAX_CELLS = 4_000_000  # a cluster whose x-y box holds more cells is not examined (a 200 m x 200 m structure)


@nb.njit(cache=True, nogil=True)
def _find(parent: np.ndarray, a: int) -> int:
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@nb.njit(cache=True, nogil=True)
def _protrusion_kernel(pts: np.ndarray, label: np.ndarray, height: np.ndarray, slot: np.ndarray, n_slots: int,
                       max_top: float, cell: float, reach: int, join: int, min_points: int, n_clusters: int,
                       max_cells: int, max_width: float, window: int) -> tuple:
    """New labels (each protruding part of an examined cluster gets a new id from n_clusters on), the new cluster
    count, and how many clusters gave parts. Cluster c is examined when slot[c] >= 0."""
    members, count = grouped_by_slot(label, slot, n_slots)  # the examined clusters' points
    out = label.copy()
    next_id = n_clusters
    n_cut = 0
    for t in range(n_slots):
        s, e = count[t], count[t + 1]
        if e - s < min_points:
            continue
        x0, y0, x1, y1 = np.inf, np.inf, -np.inf, -np.inf
        n_upper = 0
        for q in range(s, e):
            i = members[q]
            x0 = min(x0, pts[i, 0])
            y0 = min(y0, pts[i, 1])
            x1 = max(x1, pts[i, 0])
            y1 = max(y1, pts[i, 1])
            n_upper += height[i] > max_top
        if n_upper == 0:
            continue
        nx = int((x1 - x0) / cell) + 1
        ny = int((y1 - y0) / cell) + 1
        if nx * ny > max_cells:
            continue
        covered = np.zeros((nx, ny), dtype=np.bool_)
        upper = np.zeros((nx, ny), dtype=np.bool_)
        for q in range(s, e):
            i = members[q]
            if height[i] > max_top:
                cx = int((pts[i, 0] - x0) / cell)
                cy = int((pts[i, 1] - y0) / cell)
                upper[cx, cy] = True
                for ax in range(max(cx - reach, 0), min(cx + reach + 1, nx)):
                    for ay in range(max(cy - reach, 0), min(cy + reach + 1, ny)):
                        covered[ax, ay] = True
        # protruding points' cells, joined by union-find over cells within `join` of each other
        cell_id = np.full((nx, ny), -1, dtype=np.int64)
        cells_x = np.empty(e - s, dtype=np.int64)
        cells_y = np.empty(e - s, dtype=np.int64)
        n_cells = 0
        point_cell = np.full(e - s, -1, dtype=np.int64)
        for q in range(s, e):
            i = members[q]
            if height[i] > max_top:
                continue
            cx = int((pts[i, 0] - x0) / cell)
            cy = int((pts[i, 1] - y0) / cell)
            if covered[cx, cy]:
                continue
            if cell_id[cx, cy] < 0:
                cell_id[cx, cy] = n_cells
                cells_x[n_cells] = cx
                cells_y[n_cells] = cy
                n_cells += 1
            point_cell[q - s] = cell_id[cx, cy]
        if n_cells == 0:
            continue
        parent = np.arange(n_cells)
        for k in range(n_cells):
            cx, cy = cells_x[k], cells_y[k]
            for ax in range(max(cx - join, 0), min(cx + join + 1, nx)):
                for ay in range(max(cy - join, 0), min(cy + join + 1, ny)):
                    other = cell_id[ax, ay]
                    if other > k:
                        ra, rb = _find(parent, k), _find(parent, other)
                        if ra != rb:
                            parent[rb] = ra
        size = np.zeros(n_cells, dtype=np.int64)
        for q in range(e - s):
            if point_cell[q] >= 0:
                size[_find(parent, point_cell[q])] += 1
        # each part's bounding cells, for the structure's local width around it
        bx0 = np.full(n_cells, nx, dtype=np.int64)
        by0 = np.full(n_cells, ny, dtype=np.int64)
        bx1 = np.full(n_cells, -1, dtype=np.int64)
        by1 = np.full(n_cells, -1, dtype=np.int64)
        for k in range(n_cells):
            r = _find(parent, k)
            bx0[r] = min(bx0[r], cells_x[k])
            by0[r] = min(by0[r], cells_y[k])
            bx1[r] = max(bx1[r], cells_x[k])
            by1[r] = max(by1[r], cells_y[k])
        new_of = np.full(n_cells, -1, dtype=np.int64)
        made = 0
        for k in range(n_cells):
            if parent[k] != k or size[k] < min_points:
                continue
            # the structure within `window` cells of the part: thin (a mast, a wall, a wall's corner arm) or not
            m, sx, sy, sxx, syy, sxy = 0, 0.0, 0.0, 0.0, 0.0, 0.0
            for ax in range(max(bx0[k] - window, 0), min(bx1[k] + window + 1, nx)):
                for ay in range(max(by0[k] - window, 0), min(by1[k] + window + 1, ny)):
                    if upper[ax, ay]:
                        px = float(ax - bx0[k])
                        py = float(ay - by0[k])
                        m += 1
                        sx += px
                        sy += py
                        sxx += px * px
                        syy += py * py
                        sxy += px * py
            if m == 0:
                continue
            cxx = sxx / m - (sx / m) ** 2
            cyy = syy / m - (sy / m) ** 2
            cxy = sxy / m - (sx / m) * (sy / m)
            major = 0.5 * (cxx + cyy) + np.sqrt(max(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
            length = max(cell * np.sqrt(12.0 * major), cell)
            if m * cell * cell / length > max_width:
                continue  # under a crown or beside a bulky mass: bushes and clutter, not a road user against a wall
            new_of[k] = next_id + made
            made += 1
        if made == 0:
            continue
        for q in range(e - s):
            if point_cell[q] >= 0:
                root = new_of[_find(parent, point_cell[q])]
                if root >= 0:
                    out[members[s + q]] = root
        next_id += made
        n_cut += 1
    return out, next_id, n_cut


def protruding_parts(points: np.ndarray, label: np.ndarray, height: np.ndarray, n_clusters: int,
                     clusters: np.ndarray, max_top: float, min_points: int) -> tuple[np.ndarray, int, int]:
    """(labels, cluster count, clusters that gave parts): the parts of `clusters` protruding below `max_top` from
    what stands above it (module docstring) get new ids from `n_clusters` on; `height` is each point's height above
    the ground. Labels are `label` itself when no part was found."""
    if len(clusters) == 0:
        return label, n_clusters, 0
    slot = np.full(n_clusters, -1, dtype=np.int64)
    slot[clusters] = np.arange(len(clusters))
    out, n_total, n_cut = _protrusion_kernel(
        np.ascontiguousarray(points, dtype=np.float32), np.ascontiguousarray(label, dtype=np.int32),
        np.ascontiguousarray(height, dtype=np.float64), slot, len(clusters), float(max_top), CELL_M,
        round(PROTRUSION_M / CELL_M), round(JOIN_M / CELL_M), int(min_points), n_clusters, MAX_CELLS,
        STRUCTURE_MAX_WIDTH_M, round(STRUCTURE_WINDOW_M / CELL_M))
    return (out, int(n_total), int(n_cut)) if n_cut else (label, n_clusters, 0)


def warm_up() -> None:
    """Compile the kernel on a mast with a person beside it."""
    rng = np.random.default_rng(0)
    mast = rng.uniform([7.9, -0.1, 0.0], [8.1, 0.1, 6.0], (60, 3))
    person = rng.uniform([7.75, 0.35, 0.0], [8.25, 0.85, 1.7], (40, 3))
    xyz = np.concatenate([mast, person])
    pts = np.c_[xyz, np.zeros(len(xyz))].astype(np.float32)
    protruding_parts(pts, np.zeros(len(pts), dtype=np.int32), xyz[:, 2], 1, np.array([0]), 2.3, 5)
