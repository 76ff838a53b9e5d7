"""Evaluation accumulators: stage 1 proposal metrics, per-class precision / recall / IoU, and the full
pipeline's per-stage times; plus the one table printer of per-class metrics every tool shares.

All accumulate over frames and summarise into plain dicts (JSON-ready; a metric without data is None).
"""

from __future__ import annotations

from collections import defaultdict
from typing import TYPE_CHECKING

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_NAMES, FOREGROUND, IGNORE, NUM_CLASSES

if TYPE_CHECKING:
    from pass3d_ros.core.stage1 import Stage1Result


def _ratio(num: float, den: float) -> float | None:
    return float(num) / float(den) if den > 0 else None


class ConfusionAccumulator:
    """Point-wise confusion matrix over the project's classes; rows ground truth, columns prediction."""

    def __init__(self, num_classes: int = NUM_CLASSES, names: tuple[str, ...] = CLASS_NAMES) -> None:
        if len(names) != num_classes:
            raise ValueError(f"{len(names)} class names for {num_classes} classes")
        self.num_classes = num_classes
        self.names = names
        self.matrix = np.zeros((num_classes, num_classes), dtype=np.int64)

    def update(self, truth: np.ndarray, prediction: np.ndarray) -> None:
        """Add one frame's labels (same length, ids in 0..num_classes-1; truth IGNORE points are left out)."""
        truth = np.asarray(truth, dtype=np.int64)
        prediction = np.asarray(prediction, dtype=np.int64)
        if truth.shape != prediction.shape:
            raise ValueError(f"truth {truth.shape} and prediction {prediction.shape} differ in shape")
        known = truth != IGNORE
        truth, prediction = truth[known], prediction[known]
        k = self.num_classes
        for name, arr in (("truth", truth), ("prediction", prediction)):
            if arr.size and (arr.min() < 0 or arr.max() >= k):
                raise ValueError(f"{name} has class ids outside 0..{k - 1}")
        self.matrix += np.bincount(truth * k + prediction, minlength=k * k).reshape(k, k)

    def precision(self) -> list[float | None]:
        """Per class: true positives / predicted positives."""
        return [_ratio(self.matrix[c, c], self.matrix[:, c].sum()) for c in range(self.num_classes)]

    def recall(self) -> list[float | None]:
        """Per class: true positives / ground-truth positives."""
        return [_ratio(self.matrix[c, c], self.matrix[c, :].sum()) for c in range(self.num_classes)]

    def iou(self) -> list[float | None]:
        """Per class: true positives / (truth or prediction)."""
        m = self.matrix
        return [_ratio(m[c, c], m[c, :].sum() + m[:, c].sum() - m[c, c]) for c in range(self.num_classes)]

    def summary(self, classes: tuple[int, ...] = FOREGROUND) -> dict:
        """{"per_class": {name: {precision, recall, iou, points}}, "mean_iou": over `classes` with data}."""
        precision, recall, iou = self.precision(), self.recall(), self.iou()
        per_class = {
            self.names[c]: {
                "precision": precision[c], "recall": recall[c], "iou": iou[c], "points": int(self.matrix[c].sum())
            }
            for c in range(self.num_classes)
        }
        ious = [iou[c] for c in classes if iou[c] is not None and self.matrix[c].sum() > 0]
        return {"per_class": per_class, "mean_iou": float(np.mean(ious)) if ious else None}


class Stage1Metrics:
    """Stage 1 over frames: foreground recall (share of ground-truth car / pedestrian / cyclist points inside
    a kept proposal, pooled over points), proposals per frame, time per frame and step, ground P / R (over the
    frames whose ground truth marks some ground: a truth without any ground point is no ground truth)."""

    def __init__(self) -> None:
        self.frames = 0
        self.fg_points = np.zeros(NUM_CLASSES, dtype=np.int64)
        self.fg_covered = np.zeros(NUM_CLASSES, dtype=np.int64)
        self.ground_tp = self.ground_fp = self.ground_fn = 0
        self.ground_frames = 0
        self.proposals: list[int] = []
        self.step_ms: dict[str, list[float]] = defaultdict(list)
        self.per_frame: list[dict] = []

    def update(
        self,
        name: str,
        n_proposals: int,
        cluster_id: np.ndarray,
        cluster_id2: np.ndarray,
        ground: np.ndarray,
        timings_ms: dict[str, float],
        labels: np.ndarray | None = None,
        ground_truth: np.ndarray | None = None,
    ) -> dict:
        """Add one frame; returns that frame's own numbers."""
        covered = (np.asarray(cluster_id) >= 0) | (np.asarray(cluster_id2) >= 0)
        row: dict = {"frame": name, "points": len(covered), "proposals": int(n_proposals)}
        row["ms"] = float(timings_ms.get("total", np.nan))
        if labels is not None:
            labels = np.asarray(labels, dtype=np.int64)
            total = np.bincount(labels, minlength=NUM_CLASSES)[:NUM_CLASSES]
            hit = np.bincount(labels[covered], minlength=NUM_CLASSES)[:NUM_CLASSES]
            self.fg_points += total
            self.fg_covered += hit
            fg = list(FOREGROUND)
            row["fg_points"] = int(total[fg].sum())
            row["foreground_recall"] = _ratio(hit[fg].sum(), total[fg].sum())
        truth = None if ground_truth is None else np.asarray(ground_truth, dtype=bool)
        if truth is not None and truth.any():  # a frame without any ground point has no ground truth to score
            pred = np.asarray(ground, dtype=bool)
            tp = int(np.count_nonzero(truth & pred))
            fp = int(np.count_nonzero(pred & ~truth))
            fn = int(np.count_nonzero(truth & ~pred))
            self.ground_tp += tp
            self.ground_fp += fp
            self.ground_fn += fn
            self.ground_frames += 1
            row["ground_precision"] = _ratio(tp, tp + fp)
            row["ground_recall"] = _ratio(tp, tp + fn)
        self.frames += 1
        self.proposals.append(int(n_proposals))
        for step, ms in timings_ms.items():
            self.step_ms[step].append(float(ms))
        self.per_frame.append(row)
        return row

    def update_result(self, name: str, result: Stage1Result, labels: np.ndarray | None = None,
                      ground_truth: np.ndarray | None = None) -> dict:
        """`update` from a pass3d_ros.core.stage1.Stage1Result."""
        return self.update(name, result.n_proposals, result.cluster_id, result.cluster_id2, result.ground,
                           result.timings_ms, labels, ground_truth)

    def summary(self) -> dict:
        """Nested dict: {"frames", "stage1": {"foreground_recall", "proposals_per_frame": {median, mean},
        "ms_per_frame": {median, mean}, "ms_per_step": {step: median}, "ground": {precision, recall},
        "class_recall": {name: recall}, "foreground_points", "ground_frames"}}."""
        fg = list(FOREGROUND)
        props = np.asarray(self.proposals, dtype=np.float64)
        total_ms = np.asarray(self.step_ms.get("total", []), dtype=np.float64)
        tp, fp, fn = self.ground_tp, self.ground_fp, self.ground_fn
        has_ground = self.ground_frames > 0
        stage1 = {
            "foreground_recall": _ratio(self.fg_covered[fg].sum(), self.fg_points[fg].sum()),
            "foreground_points": int(self.fg_points[fg].sum()),
            "class_recall": {
                CLASS_NAMES[c]: _ratio(self.fg_covered[c], self.fg_points[c]) for c in range(NUM_CLASSES)
                if c != BACKGROUND
            },
            "proposals_per_frame": {
                "median": float(np.median(props)) if len(props) else None,
                "mean": float(props.mean()) if len(props) else None,
            },
            "ms_per_frame": {
                "median": float(np.median(total_ms)) if len(total_ms) else None,
                "mean": float(total_ms.mean()) if len(total_ms) else None,
            },
            "ms_per_step": {step: float(np.median(v)) for step, v in self.step_ms.items()},
            "ground": {
                "precision": _ratio(tp, tp + fp) if has_ground else None,
                "recall": _ratio(tp, tp + fn) if has_ground else None,
            },
            "ground_frames": self.ground_frames,
        }
        return {"frames": self.frames, "stage1": stage1}


def median_or_none(values: list[float]) -> float | None:
    """Median of `values`, None when there are none (JSON null rather than NaN)."""
    return float(np.median(np.asarray(values, dtype=np.float64))) if values else None


class SegmentationMetrics:
    """The full pipeline over frames: point-wise confusion against ground truth and milliseconds per stage.

    Stage times are per frame; `total` is each frame's own total (stage 1 + stage 2 offline, the end-to-end
    latency live), so its median is not the sum of the stage medians.
    """

    STAGES: tuple[str, ...] = ("stage1", "stage2", "total")

    def __init__(self) -> None:
        self.confusion = ConfusionAccumulator()
        self.stage_ms: dict[str, list[float]] = {stage: [] for stage in self.STAGES}
        self.frames = 0
        self.per_frame: list[dict] = []

    def update(
        self,
        name: str,
        truth: np.ndarray,
        predicted: np.ndarray,
        stage1_ms: float | None = None,
        stage2_ms: float | None = None,
        total_ms: float | None = None,
    ) -> dict:
        """Add one frame (total defaults to stage1 + stage2); returns its row: points, ms, per-class IoU."""
        frame = ConfusionAccumulator(self.confusion.num_classes, self.confusion.names)
        frame.update(truth, predicted)
        self.confusion.matrix += frame.matrix
        if total_ms is None and stage1_ms is not None and stage2_ms is not None:
            total_ms = stage1_ms + stage2_ms
        row: dict = {"frame": name, "points": len(truth)}
        for stage, ms in zip(self.STAGES, (stage1_ms, stage2_ms, total_ms), strict=True):
            row[f"{stage}_ms"] = None if ms is None else float(ms)
            if ms is not None:
                self.stage_ms[stage].append(float(ms))
        summary = frame.summary()
        row["iou"] = {self.confusion.names[c]: summary["per_class"][self.confusion.names[c]]["iou"] for c in FOREGROUND}
        row["mean_iou"] = summary["mean_iou"]
        self.frames += 1
        self.per_frame.append(row)
        return row

    def summary(self) -> dict:
        """{"frames", "classes": {name: {precision, recall, iou, points}}, "mean_iou" (car, pedestrian,
        cyclist with ground-truth points), "ms_per_frame": {stage1, stage2, total} (medians)}."""
        metrics = self.confusion.summary(FOREGROUND)
        return {
            "frames": self.frames,
            "classes": metrics["per_class"],
            "mean_iou": metrics["mean_iou"],
            "ms_per_frame": {stage: median_or_none(values) for stage, values in self.stage_ms.items()},
        }


def _pct(value: float | None) -> str:
    return "   n/a" if value is None else f"{100 * value:6.1f}"


def format_metrics(per_class: dict, mean_iou: float | None) -> list[str]:
    """Table lines: per-class precision / recall / IoU in %, point counts, and the foreground mean IoU."""
    lines = [f"{'class':<12}{'prec %':>8}{'recall %':>10}{'IoU %':>8}{'points':>10}"]
    for name in CLASS_NAMES:
        row = per_class[name]
        lines.append(f"{name:<12}{_pct(row['precision']):>8}{_pct(row['recall']):>10}{_pct(row['iou']):>8}"
                     f"{row['points']:>10}")
    lines.append(f"mean IoU (car, pedestrian, cyclist): {_pct(mean_iou).strip()} %")
    return lines
