"""Stage 1 on one scan, `propose`: rings, ground plane fitting, scan-line-run clustering and proposal refinement
in order, and the proposals' member points (`proposal_members`).

Points are N x 4 float32 (x, y, z, intensity) in the sensor frame, in any order: rings come from the firing
order, a ring field, or the scan's laser lines (see `_propose_finite`). Every parameter lives in `Stage1Config`
(pass3d_ros.core.stage1.config, re-exported here), with the paper's values where the paper gives one.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from pass3d_ros.core.stage1 import fragments as _fragments
from pass3d_ros.core.stage1 import ground as _ground
from pass3d_ros.core.stage1 import refinement as _refinement
from pass3d_ros.core.stage1 import ring as _ring
from pass3d_ros.core.stage1 import ring_field as _ring_field
from pass3d_ros.core.stage1 import scanline as _scanline
from pass3d_ros.core.stage1 import sensor_params as _sensor
from pass3d_ros.core.stage1 import split as _split
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.sensor_params import SensorScale
from pass3d_ros.data.frame import Box3D

STEPS: tuple[str, ...] = ("ring", "ground", "clustering", "refinement", "total")
MAX_RING = int(np.iinfo(np.uint16).max)  # rings are read as uint16: a larger index would wrap onto another laser


@dataclass
class Stage1Result:
    """Per-point stage 1 output and the proposals' boxes (index = proposal id)."""

    ring: np.ndarray  # (N,) uint16
    ground: np.ndarray  # (N,) bool
    cluster_id: np.ndarray  # (N,) int32, proposal 0..K-1, or -1 = in no proposal (primary proposal)
    cluster_id2: np.ndarray  # (N,) int32, a second proposal for points inside two enlarged boxes, else -1
    boxes: list[Box3D]  # K kept proposals, un-enlarged; Box3D.label = 0
    timings_ms: dict[str, float]  # ring, ground, clustering, refinement, total
    ring_source: str = "field"  # how rings were obtained: see pass3d_ros.core.stage1.ring.RING_SOURCES
    ground_planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (n_seg, 4): a x+b y+c z+d=0
    n_clusters: int = 0  # clusters before the gates (and before the split)
    n_split: int = 0  # clusters cut into parts (Stage1Config.split_merged, split_rerun, split_protruding), gated again
    sensor: SensorScale | None = None  # the scan's resolution and the effective th_num / th_prop it ran with
    lines: _ring.LaserLines | None = None  # laser lines the rings were read from (NO_LINES: a search found none):
    # pass to the next scan's propose()
    ring_order: _ring_field.RingFieldOrder | None = None  # how a ring field was read (None: no field): pass it on too
    level: np.ndarray | None = None  # (3, 3) the rotation from the sensor's frame to the level frame stage 1 ran in
    # (None: the sensor's own); boxes and ground_planes are in that frame, per-point fields in the input's order
    gives_way: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (K,) rerun_dropped's parts:
    # they hold no point another proposal holds (refinement.enlarged_membership)

    @property
    def n_proposals(self) -> int:
        """K, the number of kept proposals."""
        return len(self.boxes)

    def people_only(self) -> np.ndarray | None:
        """Per point, whether it lies in a proposal that gives way (`gives_way`: a part of `rerun_dropped`, kept to
        find people, which stage 2 may call pedestrian or background only); None when no proposal gives way. Such a
        point is in no proposal of another kind (refinement.enlarged_membership), so its primary id says it."""
        if not self.gives_way.any():
            return None
        return (self.cluster_id >= 0) & self.gives_way[np.maximum(self.cluster_id, 0)]


def propose(points: np.ndarray, ring: np.ndarray | None = None, config: Stage1Config | None = None,
            lines: _ring.LaserLines | None = None,
            ring_order: _ring_field.RingFieldOrder | None = None, level: np.ndarray | None = None,
            spacing: float | None = None, scale: SensorScale | None = None) -> Stage1Result:
    """Run stage 1 on one scan: cluster proposals with per-point primary/secondary proposal ids.

    Points with a non-finite coordinate (a driver's no-return) take no part: ring 0, not ground, no proposal.
    `config`: the stage-1 parameters; None gives `Stage1Config()` (defaulted here only: the steps below require one).
    `lines`: the previous scan's `Stage1Result.lines` on a stream of one sensor; a scan in no firing order then skips
    the laser-line search when they still fit it, or (`NO_LINES`, from a search that found none) altogether
    (pass3d_ros.core.stage1.ring.recover_rings).
    `ring`: a driver's ring field in any numbering (bottom-up, top-down, the driver's own): it is read in the order of
    its rings' measured elevations, `ring_order` (the previous scan's `Stage1Result.ring_order`) while that covers
    its values; a field that does not fit the points is ignored (pass3d_ros.core.stage1.ring_field). `Stage1Result.ring`
    is then stage 1's ring, 0 = the highest laser.
    `level`: the rotation (3 x 3) from the sensor's frame to a level one (z up: pass3d_ros.core.stage1.mounting); rings
    are read in the sensor's frame, ground, clustering and refinement in the level one.
    `spacing`: the laser spacing a stream read from an earlier scan whose rings were elevation bins (its
    `Stage1Result.sensor.spacing_deg`), used instead of reading this scan's (pass3d_ros.core.stage1.sensor_params).
    `scale`: an earlier scan's `Stage1Result.sensor` on a stream of one sensor: its angular resolution and laser
    elevations are used instead of reading this scan's when its rings are of the same kind and number (the sensor's,
    not the scene's: 0.6 ms a KITTI scan).
    """
    cfg = config or Stage1Config()
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must be N x 4 (x, y, z, intensity), got shape {pts.shape}")
    if ring is not None:
        ring = np.asarray(ring)
        if len(ring) != len(pts):
            raise ValueError(f"ring field has {len(ring)} entries for {len(pts)} points")
        if not np.issubdtype(ring.dtype, np.integer):
            raise ValueError(f"ring field must hold laser indices (integers), got {ring.dtype}")
        if ring.dtype.itemsize > 2 and len(ring) and int(ring.max()) > MAX_RING:  # uint16 rings: no pass
            raise ValueError(f"ring field holds {int(ring.max())}: laser indices go up to {MAX_RING}")
    if np.isfinite(pts.sum()) or np.isfinite(pts[:, :3]).all():
        return _propose_finite(pts, ring, cfg, lines, ring_order, level, spacing, scale)
    valid = np.isfinite(pts[:, :3]).all(axis=1)
    part = _propose_finite(np.ascontiguousarray(pts[valid]), None if ring is None else ring[valid], cfg, lines,
                           ring_order, level, spacing, scale)
    n = len(pts)
    full = {"ring": np.zeros(n, np.uint16), "ground": np.zeros(n, bool), "cluster_id": np.full(n, -1, np.int32),
            "cluster_id2": np.full(n, -1, np.int32)}
    for key, values in full.items():
        values[valid] = getattr(part, key)
        setattr(part, key, values)
    return part


def _in_scan_order(rings: _ring.Rings) -> bool:
    """Whether the points are already in a scan order that clustering can read as they are: rings read from the
    firing order, or a ring field that never steps back (ring after ring)."""
    if rings.source in _ring.FIRING_ORDER_SOURCES:
        return True
    return rings.source == "field" and bool(np.all(rings.ring[1:] >= rings.ring[:-1]))


def level_points(points: np.ndarray, level: np.ndarray | None) -> np.ndarray:
    """The points' coordinates rotated into the level frame (float32, intensity kept); the same array without one."""
    if level is None:
        return points
    out = points.copy()
    out[:, :3] = points[:, :3] @ np.asarray(level, dtype=np.float32).T
    return out


def _propose_finite(pts: np.ndarray, ring: np.ndarray | None, cfg: Stage1Config,
                    lines: _ring.LaserLines | None, ring_order: _ring_field.RingFieldOrder | None,
                    level: np.ndarray | None = None, spacing: float | None = None,
                    scale: SensorScale | None = None) -> Stage1Result:
    """Stage 1 on float32 points whose coordinates are all finite.

    Ground plane fitting reads the points as they come (its sample does not depend on their order): its planes on
    the ground thread beside ring recovery, then its final test on both threads (the whole fit on both threads after
    assigning half of the points to held laser lines, when there are some).
    Points in any other order than a scan order are put in the canonical order (ring, then azimuth:
    pass3d_ros.core.stage1.scanline.canonical_order) for clustering and refinement, so the proposals do not depend
    on the order the points came in; the results are mapped back to the input order. The frame runs with the
    effective config for its sensor (pass3d_ros.core.stage1.sensor_params.effective_config), reported in the result.
    """
    t0 = time.perf_counter()
    if ring is not None:
        ring, ring_order = _ring_field.field_rings(pts, np.asarray(ring), ring_order)
    flat = level_points(pts, level)
    # Under held laser lines the ground thread first assigns half of the points to them; the ground is then fitted
    # on both threads (a stream whose points come in no firing order).
    pool = _ground_pool() if cfg.ground_thread else None
    split = pool is not None and ring is None and lines is not None and not lines.empty
    beside = pool.submit(_ground.fit_planes, flat, cfg) if pool is not None and not split else None
    ground_cfg = cfg  # the ground reads no field that effective_config changes
    rings = _ring.rings_for(pts, ring, cfg, lines, pool if split else None, tilted=level is not None)
    order, work, work_ring = None, pts, rings.ring
    if not _in_scan_order(rings):
        order, work, work_ring = _scanline.in_canonical_order(pts, rings.ring)
    binned = rings.source == "elevation_bins"
    held = scale is not None and scale.n_rings == rings.n_rings and (scale.spacing_deg is not None) == binned
    cfg, sensor = _sensor.effective_config(cfg, work, work_ring, rings.n_rings, binned, spacing=spacing,
                                           resolution=scale.resolution if held else None,
                                           elevations=scale.elevations_deg if held else None)
    if level is not None:  # the sensor's resolution is read in its own frame, the rest runs level
        work = flat if order is None else np.take(flat, order, axis=0)
    t1 = time.perf_counter()
    if beside is not None:  # the planes fitted beside the rings; both threads test the points against them
        fit = _ground.ground_of_planes(beside.result(), ground_cfg, pool)
    else:
        fit = _ground.fit_ground(flat, ground_cfg, in_scan_order=not split, pool=pool if split else None)
    if cfg.local_ground_as_ground:
        fit = fit._replace(ground=_ground.with_local_ground(flat, fit, cfg.th_dist))
    work_ground = fit.ground if order is None else np.take(fit.ground, order)
    t2 = time.perf_counter()
    label, n_clusters = _scanline.cluster_scanlines(work, work_ring, ~work_ground, cfg, pool)
    t3 = time.perf_counter()
    n_split, gives_way = 0, None
    # With a local ground the gates read heights above it (it passes through the split as the planes argument).
    surface = fit.local if fit.local is not None else fit.planes
    gate = _sensor.range_gate(sensor, fit.planes, fit.segment_edges, level)
    if cfg.split_merged or cfg.split_rerun or cfg.split_protruding:
        boxes, kept, label, n_split, gives_way = _split.select_with_split(work, label, n_clusters, surface,
                                                                          fit.segment_edges, cfg, work_ring, gate,
                                                                          pool)
    else:
        boxes, kept = _refinement.select_proposals(work, label, n_clusters, surface, fit.segment_edges, cfg, gate)
    if cfg.join_fragments:
        label, boxes = _fragments.join_fragments(work, label, kept, boxes, surface, fit.segment_edges, cfg)
    floors = None if fit.local is None else _refinement.ground_floors(boxes, fit.local, cfg.th_dist)
    cluster_id, cluster_id2 = _refinement.enlarged_membership(work, label, kept, boxes, cfg.enlarge, floors=floors,
                                                              gives_way=gives_way)
    if order is not None:
        cluster_id, cluster_id2 = _in_input_order(order, cluster_id, cluster_id2)
    t4 = time.perf_counter()
    timings = {"ring": t1 - t0, "ground": t2 - t1, "clustering": t3 - t2, "refinement": t4 - t3, "total": t4 - t0}
    return Stage1Result(
        ring=rings.ring, ground=fit.ground, cluster_id=cluster_id, cluster_id2=cluster_id2, boxes=boxes,
        timings_ms={k: 1e3 * v for k, v in timings.items()}, ring_source=rings.source, ground_planes=fit.planes,
        n_clusters=n_clusters, n_split=n_split, sensor=sensor, lines=rings.lines, ring_order=ring_order,
        level=None if level is None else np.asarray(level, dtype=np.float64),
        gives_way=np.zeros(len(boxes), dtype=bool) if gives_way is None else gives_way,
    )


_GROUND_POOL: ThreadPoolExecutor | None = None
_GROUND_POOL_LOCK = threading.Lock()


def _ground_pool() -> ThreadPoolExecutor:
    """The ground thread (`Stage1Config.ground_thread`): ground plane fitting reads the points in any order and
    releases the GIL, so it runs beside ring recovery and the canonical ordering. It reads no field that
    `effective_config` changes, so it starts before that config is known."""
    global _GROUND_POOL
    with _GROUND_POOL_LOCK:
        if _GROUND_POOL is None:
            _GROUND_POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pass3d-ground")
    return _GROUND_POOL


def _forget_ground_pool() -> None:
    """In a forked child: the parent's ground thread is not there (work given to its pool would wait for ever, and
    its lock may have been held at the fork), so the child starts a pool of its own on its first scan."""
    global _GROUND_POOL, _GROUND_POOL_LOCK
    _GROUND_POOL = None
    _GROUND_POOL_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):  # POSIX only: nothing forks elsewhere
    os.register_at_fork(after_in_child=_forget_ground_pool)


@nb.njit(cache=True, nogil=True)
def _in_input_order(order: np.ndarray, first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two per-point fields listed in `order` put back in input order (one scatter pass for both: a quarter of the
    time of inverting the permutation and taking each field)."""
    out_first = np.empty_like(first)
    out_second = np.empty_like(second)
    for j in range(order.shape[0]):
        out_first[order[j]] = first[j]
        out_second[order[j]] = second[j]
    return out_first, out_second


def proposal_members(
    cluster_id: np.ndarray, cluster_id2: np.ndarray, n_proposals: int | None = None
) -> list[np.ndarray]:
    """Point indices of every proposal (ascending; a point may be in two), from the two per-point id fields.

    `n_proposals` fixes the list length (proposals without points get an empty array); by default it is one
    more than the largest id.
    """
    cluster_id = np.asarray(cluster_id, dtype=np.int64)
    cluster_id2 = np.asarray(cluster_id2, dtype=np.int64)
    if cluster_id.shape != cluster_id2.shape:
        raise ValueError(f"cluster_id {cluster_id.shape} and cluster_id2 {cluster_id2.shape} differ in shape")
    top = max(int(cluster_id.max(initial=-1)), int(cluster_id2.max(initial=-1)))
    k = top + 1
    if n_proposals is not None:
        if n_proposals < k:
            raise ValueError(f"n_proposals={n_proposals} but ids go up to {k - 1}")
        k = n_proposals
    index, bounds = _refinement.grouped_points(cluster_id.reshape(-1), cluster_id2.reshape(-1), k)
    return [index[bounds[j]:bounds[j + 1]] for j in range(k)]


def synthetic_scan(n_rings: int = 64, points_per_ring: int = 720) -> np.ndarray:
    """A firing-order scan (HDL-64E elevations) of flat ground 1.73 m below the sensor, a 1.5 m tall flat-faced
    object 8 m ahead, and a backdrop at 60 m: for warm-up, benchmarks without data, and smoke tests."""
    elev = np.deg2rad(np.linspace(2.0, -24.8, n_rings))
    az = np.linspace(0.0, 2.0 * np.pi, points_per_ring, endpoint=False) + 1e-4
    e, a = np.meshgrid(elev, az, indexing="ij")
    tan_e = np.tan(e)
    dist = np.full(e.shape, 60.0)
    below = tan_e < -1.73 / 60.0
    dist[below] = -1.73 / tan_e[below]
    face = 8.0 / np.cos(a - 0.3)
    on_face = (np.abs(a - 0.3) < 0.15) & (tan_e * face >= -1.73) & (tan_e * face <= -0.23)
    dist[on_face] = face[on_face]
    pts = np.stack([dist * np.cos(a), dist * np.sin(a), dist * tan_e, np.full_like(dist, 0.5)], axis=-1)
    return pts.reshape(-1, 4).astype(np.float32)


def warm_up() -> None:
    """Compile every numba kernel of stage 1 (on disk cache after the first time) with a tiny scan."""
    _ring.warm_up()
    _ground.warm_up()
    _scanline.warm_up()
    _refinement.warm_up()
    _split.warm_up()
    scan = synthetic_scan(n_rings=16, points_per_ring=90)
    result = propose(scan, config=Stage1Config(n_rings=16))
    proposal_members(result.cluster_id, result.cluster_id2)
    shuffled = np.random.default_rng(0).permutation(len(scan))  # in no scan order: the canonical order and back
    propose(scan[shuffled], result.ring[shuffled], Stage1Config(n_rings=16))
    _sensor.laser_spacing(scan)  # rings from elevation bins (no ring field, no laser lines found)
