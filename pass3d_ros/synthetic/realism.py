"""Realism report: the same scan statistics for synthetic and real frames, printed side by side.

Statistics per dataset: points per frame, points per ring, range histogram, share of ground points (where the
source knows ground), points per labelled object by class and distance, and intensity distribution.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pass3d_ros.classes import CAR, CLASS_NAMES, CYCLIST, PEDESTRIAN
from pass3d_ros.core.ring import rings_for
from pass3d_ros.data.frame import Frame

RANGE_BINS_M = (0.0, 5.0, 10.0, 20.0, 40.0, 80.0, np.inf)
OBJECT_BINS_M = (0.0, 10.0, 20.0, 40.0, np.inf)
INTENSITY_QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
REPO_ROOT = Path(__file__).resolve().parents[2]


@dataclass
class ScanStats:
    """Accumulated statistics of one dataset."""

    name: str
    points: list[int] = field(default_factory=list)
    ring_min: list[int] = field(default_factory=list)
    ring_median: list[float] = field(default_factory=list)
    ring_max: list[int] = field(default_factory=list)
    range_counts: np.ndarray = field(default_factory=lambda: np.zeros(len(RANGE_BINS_M) - 1, dtype=np.int64))
    ground_points: int = 0
    ground_known_points: int = 0
    # class -> distance bin -> point counts of the objects seen there
    objects: dict[int, list[list[int]]] = field(
        default_factory=lambda: {c: [[] for _ in OBJECT_BINS_M[:-1]] for c in (CAR, PEDESTRIAN, CYCLIST)})
    intensity: list[np.ndarray] = field(default_factory=list)
    car_intensity: list[np.ndarray] = field(default_factory=list)

    def add(self, frame: Frame) -> None:
        """Fold one frame into the statistics."""
        pts = frame.points
        self.points.append(len(pts))
        if len(pts) == 0:
            return
        ring = rings_for(pts, frame.ring).ring
        per_ring = np.bincount(ring.astype(np.int64), minlength=64)
        self.ring_min.append(int(per_ring.min()))
        self.ring_median.append(float(np.median(per_ring)))
        self.ring_max.append(int(per_ring.max()))
        dist = np.linalg.norm(pts[:, :3], axis=1)
        self.range_counts += np.histogram(dist, bins=np.array(RANGE_BINS_M))[0]
        if frame.ground is not None:
            self.ground_points += int(np.count_nonzero(frame.ground))
            self.ground_known_points += len(pts)
        self.intensity.append(pts[:, 3].copy())
        if frame.labels is not None:
            self.car_intensity.append(pts[frame.labels == CAR, 3].copy())
            self._add_objects(frame)

    def _add_objects(self, frame: Frame) -> None:
        if frame.instance is None:
            return
        fg = (frame.instance >= 0) & (frame.labels > 0)
        if not fg.any():
            return
        inst, lab = frame.instance[fg], frame.labels[fg]
        xy = frame.points[fg, :2]
        keys = inst.astype(np.int64) * 4 + lab
        uniq, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        centre = np.stack([np.bincount(inverse, xy[:, k]) / counts for k in range(2)], axis=1)
        dist = np.hypot(centre[:, 0], centre[:, 1])
        bins = np.digitize(dist, OBJECT_BINS_M[1:-1])
        for key, n, b in zip(uniq, counts, bins, strict=True):
            self.objects[int(key % 4)][int(b)].append(int(n))


def collect(frames: Iterable[Frame], name: str) -> ScanStats:
    """Statistics of every frame of an iterable."""
    stats = ScanStats(name)
    for frame in frames:
        stats.add(frame)
    return stats


def _fmt_range(values: list, fmt: str = "{:.0f}") -> str:
    if not values:
        return "-"
    return fmt.format(np.median(values))


def rows(stats: ScanStats) -> list[tuple[str, str]]:
    """(metric, value) rows of one dataset, in report order."""
    out = [("frames", str(len(stats.points))),
           ("points/frame median", _fmt_range(stats.points)),
           ("points/frame min-max", f"{min(stats.points)}-{max(stats.points)}" if stats.points else "-"),
           ("points/ring min", _fmt_range(stats.ring_min)),
           ("points/ring median", _fmt_range(stats.ring_median)),
           ("points/ring max", _fmt_range(stats.ring_max))]
    total = max(int(stats.range_counts.sum()), 1)
    for lo, hi, count in zip(RANGE_BINS_M[:-1], RANGE_BINS_M[1:], stats.range_counts, strict=True):
        label = f"range {lo:.0f}-{hi:.0f} m" if np.isfinite(hi) else f"range {lo:.0f}+ m"
        out.append((label, f"{100.0 * count / total:.1f}%"))
    ground = f"{100.0 * stats.ground_points / stats.ground_known_points:.1f}%" if stats.ground_known_points else "n/a"
    out.append(("ground share", ground))
    for cls, per_bin in stats.objects.items():
        for lo, hi, counts in zip(OBJECT_BINS_M[:-1], OBJECT_BINS_M[1:], per_bin, strict=True):
            span = f"{lo:.0f}-{hi:.0f}" if np.isfinite(hi) else f"{lo:.0f}+"
            value = f"{np.median(counts):.0f} (n={len(counts)})" if counts else "-"
            out.append((f"{CLASS_NAMES[cls]} pts/obj {span} m", value))
    values = np.concatenate(stats.intensity) if stats.intensity else np.zeros(0)
    if len(values):
        out.append(("intensity mean", f"{values.mean():.3f}"))
        quantiles = np.quantile(values, INTENSITY_QUANTILES)
        out.append(("intensity q05/25/50/75/95", "/".join(f"{q:.2f}" for q in quantiles)))
        out.append(("intensity == 0", f"{100.0 * np.mean(values == 0):.1f}%"))
    cars = np.concatenate(stats.car_intensity) if stats.car_intensity else np.zeros(0)
    out.append(("car intensity mean", f"{cars.mean():.3f}" if len(cars) else "-"))
    return out


def format_report(all_stats: list[ScanStats]) -> str:
    """A text table: one row per metric, one column per dataset."""
    columns = [dict(rows(s)) for s in all_stats]
    metrics = [name for name, _ in rows(all_stats[0])] if all_stats else []
    width0 = max([len(m) for m in metrics] + [6])
    widths = [max(len(s.name), *(len(c.get(m, "-")) for m in metrics)) for s, c in zip(all_stats, columns, strict=True)]
    lines = ["  ".join([" " * width0] + [s.name.rjust(w) for s, w in zip(all_stats, widths, strict=True)])]
    for m in metrics:
        cells = [c.get(m, "-").rjust(w) for c, w in zip(columns, widths, strict=True)]
        lines.append("  ".join([m.ljust(width0), *cells]))
    return "\n".join(lines)


def default_real_specs() -> list[str]:
    """The real KITTI development frames ($PASS3D_KITTI_DEV or ../shared/data/kitti_dev), when present."""
    candidates = [os.environ.get("PASS3D_KITTI_DEV"), str(REPO_ROOT.parent / "shared" / "data" / "kitti_dev")]
    for candidate in candidates:
        if candidate and Path(candidate).is_dir():
            root = Path(candidate)
            specs = []
            if (root / "object" / "training" / "velodyne").is_dir():
                specs.append(f"kitti_object:{root / 'object' / 'training'}")
            if (root / "semantickitti" / "sequences" / "00" / "velodyne").is_dir():
                specs.append(f"semantickitti:{root / 'semantickitti' / 'sequences' / '00'}")
            return specs
    return []
