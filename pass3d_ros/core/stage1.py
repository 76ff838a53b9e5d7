"""PASS3D stage 1, accelerated cluster proposal: rings, ground plane fitting, scan-line-run clustering and
proposal refinement behind one call, `propose`.

Points are N x 4 float32 (x, y, z, intensity) in the sensor frame, in firing order when there is no ring
field. Every parameter lives in `Stage1Config`, with the paper's values where the paper gives one.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from pass3d_ros.core import ground as _ground
from pass3d_ros.core import refinement as _refinement
from pass3d_ros.core import ring as _ring
from pass3d_ros.core import scanline as _scanline
from pass3d_ros.data.frame import Box3D

STEPS: tuple[str, ...] = ("ring", "ground", "clustering", "refinement", "total")


def _param(default: Any, description: str, lo: float, hi: float) -> Any:
    """A config field whose metadata carries its description and allowed closed range (ROS parameters)."""
    return field(default=default, metadata={"description": description, "range": (lo, hi)})


@dataclass
class Stage1Config:
    """Stage 1 parameters (metres, counts). The paper's values: n_seg .. th_prop and the enlargement; the
    rest is what the paper leaves open, chosen on KITTI (see each field's description)."""

    # Ground plane fitting (Zermas et al.; PASS3D's values).
    n_seg: int = _param(3, "ground: segments along x", 1, 64)
    n_iter: int = _param(3, "ground: plane fits per segment", 1, 20)
    n_lpr: int = _param(20, "ground: lowest points whose mean height (the LPR) sets the seed height", 1, 1000)
    th_seeds: float = _param(0.4, "ground: seeds lie less than this above the LPR (m)", 0.01, 5.0)
    th_dist: float = _param(0.3, "ground: |distance to plane| below this is ground (m, two-sided)", 0.01, 2.0)
    # Scan-line-run clustering (Zermas et al.; PASS3D's values).
    th_ring: float = _param(0.5, "clustering: consecutive ring points closer than this form a run (m)", 0.01, 5.0)
    th_prop: float = _param(1.0, "clustering: a run takes the label of a previous-ring point this close (m)", 0.01, 5.0)
    n_prev_rings: int = _param(2, "clustering: rings searched back when the previous one has no match", 1, 8)
    # Proposal refinement: point count needed, about 30 near the sensor and falling as 1/range.
    th_num_near: float = _param(30.0, "refinement: points a cluster needs up to th_num_range", 1.0, 1e4)
    th_num_range: float = _param(
        20.0, "refinement: beyond this range (m) a cluster needs th_num_near * th_num_range / range points", 0.1, 200.0
    )
    th_num_floor: int = _param(5, "refinement: a cluster never needs fewer points than this", 1, 1000)
    # Size gates: what an (occluded) car, pedestrian or cyclist can look like.
    max_length: float = _param(7.0, "refinement: longest footprint side (m)", 0.1, 100.0)
    max_width: float = _param(3.5, "refinement: longest short footprint side (m)", 0.1, 100.0)
    max_height: float = _param(3.0, "refinement: largest z extent (m)", 0.1, 100.0)
    max_bottom: float = _param(
        1.5, "refinement: lowest point at most this above the ground plane (m; a person behind a car)", -5.0, 10.0
    )
    min_top: float = _param(0.9, "refinement: highest point at least this above the ground plane (m)", -5.0, 10.0)
    max_top: float = _param(2.3, "refinement: highest point at most this above the ground plane (m)", 0.0, 20.0)
    min_extent: float = _param(0.2, "refinement: the larger of length and height reaches this (m)", 0.0, 10.0)
    max_range: float = _param(70.0, "refinement: largest horizontal range of a cluster centre (m)", 1.0, 500.0)
    # Enlargement of kept boxes, added on each side (paper: 0.1, 0.1, 0.4 m).
    enlarge: tuple[float, float, float] = _param(
        (0.1, 0.1, 0.4), "refinement: kept boxes grow by this on each side in x, y, z (m)", 0.0, 5.0
    )
    # Sensor and robustness details the paper leaves open.
    n_rings: int = _param(64, "rings: lasers of the sensor (HDL-64E); ring recovery checks for this many", 1, 256)
    sensor_height: float = _param(1.73, "ground: sensor height above the road (m, KITTI)", 0.0, 10.0)
    below_ground_margin: float = _param(1.0, "ground: points lower than sensor_height + this never seed (m)", 0.0, 10.0)
    ground_x_extent: float = _param(80.0, "ground: segments split x in [-extent, extent] evenly (m)", 1.0, 500.0)
    ground_seed_band: float = _param(20.0, "ground: only points with |y| below this seed and fit planes (m)", 0.5, 1e3)
    ground_lpr_outlier_share: float = _param(
        0.05, "ground: 0.1 m height bins holding less than this share of the fullest cannot set the LPR", 0.0, 1.0
    )
    ground_max_step: float = _param(
        0.5, "ground: an outer plane stepping more than this at its inner edge takes its neighbour's (m)", 0.0, 10.0
    )
    ground_max_slope_deg: float = _param(25.0, "ground: a steeper plane is rejected (degrees)", 0.0, 90.0)

    def __post_init__(self) -> None:
        self.enlarge = tuple(float(v) for v in self.enlarge)
        self.validate()

    def validate(self) -> None:
        """Raise ValueError naming every parameter outside its allowed range."""
        problems = []
        if len(self.enlarge) != 3:
            problems.append(f"enlarge needs 3 values (x, y, z), got {len(self.enlarge)}")
        for f in fields(self):
            lo, hi = f.metadata["range"]
            values = getattr(self, f.name)
            for v in values if isinstance(values, tuple) else (values,):
                if not lo <= v <= hi:
                    problems.append(f"{f.name}={v} outside [{lo}, {hi}]")
        if self.n_seg > 127:
            problems.append("n_seg must be <= 127")
        if problems:
            raise ValueError("Stage1Config: " + "; ".join(problems))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> Stage1Config:
        """Config from a dict (YAML, ROS parameters); unknown keys are an error, not silently ignored."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"Stage1Config: unknown parameter(s) {', '.join(unknown)}")
        return cls(**dict(values))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of all parameters (for logs and JSON)."""
        return asdict(self)

    def gates(self) -> _refinement.Gates:
        """The refinement gates of this config."""
        return _refinement.Gates(
            num_near=self.th_num_near, num_ref_range=self.th_num_range, num_floor=self.th_num_floor,
            max_length=self.max_length, max_width=self.max_width, max_height=self.max_height,
            max_bottom=self.max_bottom, min_top=self.min_top, max_top=self.max_top, min_extent=self.min_extent,
            max_range=self.max_range,
        )


@dataclass
class Stage1Result:
    """Per-point stage 1 output and the proposals' boxes (index = proposal id)."""

    ring: np.ndarray  # (N,) uint16
    ground: np.ndarray  # (N,) bool
    cluster_id: np.ndarray  # (N,) int32, proposal 0..K-1, or -1 = in no proposal (primary proposal)
    cluster_id2: np.ndarray  # (N,) int32, a second proposal for points inside two enlarged boxes, else -1
    boxes: list[Box3D]  # K kept proposals, un-enlarged; Box3D.label = 0
    timings_ms: dict[str, float]  # ring, ground, clustering, refinement, total
    ring_source: str = "field"  # how rings were obtained: see pass3d_ros.core.ring.RING_SOURCES
    ground_planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (n_seg, 4): a x+b y+c z+d=0
    n_clusters: int = 0  # clusters before the gates

    @property
    def n_proposals(self) -> int:
        """K, the number of kept proposals."""
        return len(self.boxes)


def propose(points: np.ndarray, ring: np.ndarray | None = None, config: Stage1Config | None = None) -> Stage1Result:
    """Run stage 1 on one scan: cluster proposals with per-point primary/secondary proposal ids.

    Points with a non-finite coordinate (a driver's no-return) take no part: ring 0, not ground, no proposal.
    """
    cfg = config or Stage1Config()
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must be N x 4 (x, y, z, intensity), got shape {pts.shape}")
    if ring is not None and len(ring) != len(pts):
        raise ValueError(f"ring field has {len(ring)} entries for {len(pts)} points")
    if np.isfinite(pts.sum()) or np.isfinite(pts[:, :3]).all():
        return _propose_finite(pts, ring, cfg)
    valid = np.isfinite(pts[:, :3]).all(axis=1)
    part = _propose_finite(np.ascontiguousarray(pts[valid]), None if ring is None else ring[valid], cfg)
    n = len(pts)
    full = {"ring": np.zeros(n, np.uint16), "ground": np.zeros(n, bool), "cluster_id": np.full(n, -1, np.int32),
            "cluster_id2": np.full(n, -1, np.int32)}
    for key, values in full.items():
        values[valid] = getattr(part, key)
        setattr(part, key, values)
    return part


def _propose_finite(pts: np.ndarray, ring: np.ndarray | None, cfg: Stage1Config) -> Stage1Result:
    """Stage 1 on float32 points whose coordinates are all finite."""
    t0 = time.perf_counter()
    rings = _ring.rings_for(pts, ring, n_rings=cfg.n_rings)
    t1 = time.perf_counter()
    fit = _ground.fit_ground(
        pts, n_seg=cfg.n_seg, n_iter=cfg.n_iter, n_lpr=cfg.n_lpr, th_seeds=cfg.th_seeds, th_dist=cfg.th_dist,
        sensor_height=cfg.sensor_height, below_ground_margin=cfg.below_ground_margin,
        max_slope_deg=cfg.ground_max_slope_deg, x_extent=cfg.ground_x_extent, seed_band=cfg.ground_seed_band,
        lpr_outlier_share=cfg.ground_lpr_outlier_share, max_step=cfg.ground_max_step,
    )
    t2 = time.perf_counter()
    label, n_clusters = _scanline.cluster_scanlines(
        pts, rings.ring, ~fit.ground, th_ring=cfg.th_ring, th_prop=cfg.th_prop, n_prev_rings=cfg.n_prev_rings
    )
    t3 = time.perf_counter()
    boxes, kept = _refinement.select_proposals(pts, label, n_clusters, fit.planes, fit.segment_edges, cfg.gates())
    cluster_id, cluster_id2 = _refinement.enlarged_membership(pts, label, kept, boxes, cfg.enlarge)
    t4 = time.perf_counter()
    timings = {"ring": t1 - t0, "ground": t2 - t1, "clustering": t3 - t2, "refinement": t4 - t3, "total": t4 - t0}
    return Stage1Result(
        ring=rings.ring, ground=fit.ground, cluster_id=cluster_id, cluster_id2=cluster_id2, boxes=boxes,
        timings_ms={k: 1e3 * v for k, v in timings.items()}, ring_source=rings.source, ground_planes=fit.planes,
        n_clusters=n_clusters,
    )


def proposal_members(
    cluster_id: np.ndarray, cluster_id2: np.ndarray, n_proposals: int | None = None
) -> list[np.ndarray]:
    """Point indices of every proposal (ascending; a point may be in two), from the two per-point id fields.

    `n_proposals` fixes the list length (proposals without points get an empty array); by default it is one
    more than the largest id.
    """
    cluster_id = np.asarray(cluster_id)
    cluster_id2 = np.asarray(cluster_id2)
    if cluster_id.shape != cluster_id2.shape:
        raise ValueError(f"cluster_id {cluster_id.shape} and cluster_id2 {cluster_id2.shape} differ in shape")
    ids = np.concatenate([cluster_id, cluster_id2]).astype(np.int64)
    index = np.concatenate([np.arange(len(cluster_id)), np.arange(len(cluster_id2))])
    valid = ids >= 0
    ids, index = ids[valid], index[valid]
    k = int(ids.max()) + 1 if len(ids) else 0
    if n_proposals is not None:
        if n_proposals < k:
            raise ValueError(f"n_proposals={n_proposals} but ids go up to {k - 1}")
        k = n_proposals
    order = np.argsort(ids * (len(cluster_id) + 1) + index, kind="stable")
    ids, index = ids[order], index[order]
    bounds = np.searchsorted(ids, np.arange(k + 1))
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
    propose(synthetic_scan(n_rings=16, points_per_ring=90), config=Stage1Config(n_rings=16))
