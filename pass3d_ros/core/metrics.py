"""Evaluation accumulators: stage 1 proposal metrics, per-class precision / recall / IoU, and the full
pipeline's per-stage times; plus the one table printer of per-class metrics every tool shares.

All accumulate over frames and summarise into plain dicts (JSON-ready; a metric without data is None).

Uncertainty: the confusion accumulator keeps each frame's own (small, k x k) matrix, so `bootstrap_iou` can
give a frame bootstrap interval for every class IoU and the mean IoU: frames are drawn with replacement
(`BOOTSTRAP_RESAMPLES` times, seed `BOOTSTRAP_SEED`, so the same frames give the same interval), the drawn
frames' matrices are summed, and the IoUs of those sums give the percentile interval at `BOOTSTRAP_LEVEL`.
A class whose IoU is undefined in a resample (no ground-truth and no predicted point of it in the drawn
frames), and a resample without any ground-truth point of the mean's classes, is left out of that
interval and counted as "skipped"; an interval with no usable resample has low = high = None. With one
frame every resample is that frame: the interval is degenerate (low = high = the point estimate) and says so.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CLASS_NAMES, FOREGROUND, IGNORE, NUM_CLASSES

if TYPE_CHECKING:
    from pass3d_ros.core.stage1 import Stage1Result


BOOTSTRAP_RESAMPLES = 1000
BOOTSTRAP_LEVEL = 0.9
BOOTSTRAP_SEED = 0
BOOTSTRAP_METHOD = "frame bootstrap"


def _ratio(num: float, den: float) -> float | None:
    return float(num) / float(den) if den > 0 else None


def _interval(values: np.ndarray, frames: int, resamples: int, level: float) -> dict:
    """Percentile interval of the finite `values` (one per resample), JSON-ready."""
    ok = values[np.isfinite(values)]
    tail = (1.0 - level) / 2.0
    low, high = (float(q) for q in np.quantile(ok, [tail, 1.0 - tail])) if len(ok) else (None, None)
    return {"low": low, "high": high, "level": level, "resamples": resamples, "skipped": resamples - len(ok),
            "method": BOOTSTRAP_METHOD, "frames": frames, "degenerate": frames < 2}


def _frame_weights(frames: int, resamples: int, seed: int) -> np.ndarray:
    """(resamples, frames): how often each resample draws each frame (frames drawn with replacement)."""
    return np.random.default_rng(seed).multinomial(frames, np.full(frames, 1.0 / frames), size=resamples)


def _resampled_sums(weights: np.ndarray, stack: np.ndarray) -> np.ndarray:
    """(R, k, k): the confusion matrices `stack` (F, k, k) summed with each row of `weights` (R, F)."""
    return np.einsum("rf,fij->rij", weights, stack, optimize=True).astype(np.float64)


def _pooled_iou(sums: np.ndarray) -> np.ndarray:
    """(R, k): each class's IoU of each summed confusion matrix (R, k, k); NaN where a class has no union."""
    tp = np.diagonal(sums, axis1=1, axis2=2)
    union = sums.sum(axis=2) + sums.sum(axis=1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / union, np.nan)


def bootstrap_iou(
    matrices: list[np.ndarray] | np.ndarray,
    classes: tuple[int, ...] = FOREGROUND,
    resamples: int = BOOTSTRAP_RESAMPLES,
    level: float = BOOTSTRAP_LEVEL,
    seed: int = BOOTSTRAP_SEED,
) -> dict:
    """Frame bootstrap of per-frame confusion matrices (F x k x k): {"per_class": [interval per class id],
    "mean_iou": interval of the mean over `classes` with ground-truth points}; see the module notes.
    Each interval: {"low", "high", "level", "resamples", "skipped", "method", "frames", "degenerate"}."""
    stack = np.asarray(matrices, dtype=np.int64)
    if stack.ndim != 3 or stack.shape[1] != stack.shape[2]:
        raise ValueError(f"expected F x k x k confusion matrices, got shape {stack.shape}")
    if not 0.0 < level < 1.0 or resamples < 1:
        raise ValueError(f"need 0 < level < 1 and resamples >= 1, got {level}, {resamples}")
    frames, k = stack.shape[0], stack.shape[1]
    if frames == 0:
        empty = np.full(resamples, np.nan)
        return {"per_class": [_interval(empty, 0, resamples, level) for _ in range(k)],
                "mean_iou": _interval(empty, 0, resamples, level)}
    sums = _resampled_sums(_frame_weights(frames, resamples, seed), stack)
    iou, truth = _pooled_iou(sums), sums.sum(axis=2)
    chosen = list(classes)
    present = truth[:, chosen] > 0
    with np.errstate(invalid="ignore"):
        mean = np.where(present.any(axis=1),
                        np.nansum(np.where(present, iou[:, chosen], 0.0), axis=1) / present.sum(axis=1), np.nan)
    return {"per_class": [_interval(iou[:, c], frames, resamples, level) for c in range(k)],
            "mean_iou": _interval(mean, frames, resamples, level)}


def paired_iou_difference(
    first: list[np.ndarray] | np.ndarray,
    second: list[np.ndarray] | np.ndarray,
    classes: tuple[int, ...] = FOREGROUND,
    resamples: int = BOOTSTRAP_RESAMPLES,
    level: float = BOOTSTRAP_LEVEL,
    seed: int = BOOTSTRAP_SEED,
) -> dict[int, dict]:
    """Per class of `classes`: the pooled IoU of `second` minus that of `first` (two runs' per-frame confusion
    matrices, F x k x k, the same frames in the same order) and its paired frame-bootstrap interval: each resample
    draws the same frames for both runs, so what the frames share cancels. {class id: {"difference", **interval}}."""
    a, b = np.asarray(first, dtype=np.int64), np.asarray(second, dtype=np.int64)
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"paired runs need the same F x k x k confusion matrices, got {a.shape} and {b.shape}")
    frames = a.shape[0]
    weights = np.vstack([np.ones(frames, dtype=np.int64), _frame_weights(frames, resamples, seed)])  # row 0: as run
    delta = _pooled_iou(_resampled_sums(weights, b)) - _pooled_iou(_resampled_sums(weights, a))
    return {c: {"difference": None if np.isnan(delta[0, c]) else float(delta[0, c]),
                **_interval(delta[1:, c], frames, resamples, level)} for c in classes}


def bootstrap_ratio(numerator: np.ndarray, denominator: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES,
                    level: float = BOOTSTRAP_LEVEL, seed: int = BOOTSTRAP_SEED) -> dict:
    """Frame bootstrap interval of sum(numerator) / sum(denominator) over frames (one count of each per frame),
    drawn as `bootstrap_iou` draws frames."""
    num, den = np.asarray(numerator, dtype=np.float64), np.asarray(denominator, dtype=np.float64)
    frames = len(num)
    if frames == 0:
        return _interval(np.full(resamples, np.nan), 0, resamples, level)
    weights = _frame_weights(frames, resamples, seed)
    top, bottom = weights @ num, weights @ den
    with np.errstate(invalid="ignore", divide="ignore"):
        return _interval(np.where(bottom > 0, top / bottom, np.nan), frames, resamples, level)


class ConfusionAccumulator:
    """Point-wise confusion matrix over the project's classes; rows ground truth, columns prediction."""

    def __init__(self, num_classes: int = NUM_CLASSES, names: tuple[str, ...] = CLASS_NAMES) -> None:
        if len(names) != num_classes:
            raise ValueError(f"{len(names)} class names for {num_classes} classes")
        self.num_classes = num_classes
        self.names = names
        self.matrix = np.zeros((num_classes, num_classes), dtype=np.int64)
        self.frames: list[np.ndarray] = []  # each update's own matrix, for the frame bootstrap

    def update(self, truth: np.ndarray, prediction: np.ndarray) -> None:
        """Add one frame's labels (same length, ids in 0..num_classes-1; truth IGNORE points are left out);
        its own matrix is kept in `frames`."""
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
        frame = np.bincount(truth * k + prediction, minlength=k * k).reshape(k, k)
        self.matrix += frame
        self.frames.append(frame)

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

    def intervals(self, classes: tuple[int, ...] = FOREGROUND, resamples: int = BOOTSTRAP_RESAMPLES,
                  level: float = BOOTSTRAP_LEVEL, seed: int = BOOTSTRAP_SEED) -> dict:
        """Frame bootstrap intervals over the updates so far: {"per_class": {name: interval}, "mean_iou": interval}."""
        frames = self.frames or np.zeros((0, self.num_classes, self.num_classes), dtype=np.int64)
        boot = bootstrap_iou(frames, classes, resamples, level, seed)
        return {"per_class": dict(zip(self.names, boot["per_class"], strict=True)), "mean_iou": boot["mean_iou"]}

    def summary_with_intervals(self, classes: tuple[int, ...] = FOREGROUND) -> dict:
        """`summary` with an "interval" in every class row and "mean_iou_interval" beside "mean_iou"."""
        summary = self.summary(classes)
        boot = self.intervals(classes)
        for name, row in summary["per_class"].items():
            row["interval"] = boot["per_class"][name]
        summary["mean_iou_interval"] = boot["mean_iou"]
        return summary


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


def ignore_vehicles(truth: np.ndarray, vehicle_other: np.ndarray | None) -> np.ndarray:
    """`truth` with its background points on a non-car vehicle (`vehicle_other`: van, truck, bus; Frame.vehicle_other)
    set to IGNORE, so they leave the score: a copy, or `truth` itself when the mask is None or marks nothing.
    Points labelled a class keep it (a car box overlapping a van box stays car)."""
    if vehicle_other is None:
        return truth
    mask = np.asarray(vehicle_other, dtype=bool)
    truth = np.asarray(truth)
    if mask.shape != truth.shape:
        raise ValueError(f"vehicle mask {mask.shape} and truth {truth.shape} differ in shape")
    drop = mask & (truth == BACKGROUND)
    if not drop.any():
        return truth
    relaxed = truth.copy()
    relaxed[drop] = IGNORE
    return relaxed


class SegmentationMetrics:
    """The full pipeline over frames: point-wise confusion against ground truth and milliseconds per stage.

    Stage times are per frame; `total` is each frame's own total (stage 1 + stage 2 offline, the end-to-end
    latency live), so its median is not the sum of the stage medians.
    """

    STAGES: tuple[str, ...] = ("stage1", "stage2", "total")

    def __init__(self) -> None:
        self.confusion = ConfusionAccumulator()
        self.vehicles_ignored = ConfusionAccumulator()  # truth with background points on non-car vehicles ignored
        self.ignored_points = 0
        self.vehicle_frames = 0  # frames whose source marks non-car vehicles
        self.frames_with_vehicles = 0  # frames with a point left out of the vehicles-ignored score
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
        vehicle_other: np.ndarray | None = None,
    ) -> dict:
        """Add one frame (total defaults to stage1 + stage2); returns its row: points, ms, per-class IoU.
        `vehicle_other` (the frame's Frame.vehicle_other) feeds the vehicles-ignored score, see `ignore_vehicles`."""
        frame = ConfusionAccumulator(self.confusion.num_classes, self.confusion.names)
        frame.update(truth, predicted)
        self.confusion.matrix += frame.matrix
        self.confusion.frames.append(frame.matrix)
        relaxed = ignore_vehicles(truth, vehicle_other)
        self.vehicles_ignored.update(relaxed, predicted)
        ignored = 0 if relaxed is truth else int(np.count_nonzero(relaxed != truth))  # truth itself: none left out
        self.ignored_points += ignored
        self.vehicle_frames += vehicle_other is not None
        self.frames_with_vehicles += ignored > 0
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
        row["confusion"] = frame.matrix.tolist()  # rows truth, columns prediction: what paired comparisons resample
        self.frames += 1
        self.per_frame.append(row)
        return row

    def summary(self) -> dict:
        """{"frames", "classes": {name: {precision, recall, iou, points, interval}}, "mean_iou" (car, pedestrian,
        cyclist with ground-truth points), "mean_iou_interval", "car_vehicles_ignored": {precision, recall, iou,
        points, interval, ignored_points, frames_with_vehicles, frames_known}, "ms_per_frame": {stage1, stage2,
        total} (medians)};
        intervals: frame bootstrap, see `bootstrap_iou` (the same resamples for both car scores)."""
        metrics = self.confusion.summary_with_intervals(FOREGROUND)
        relaxed = self.vehicles_ignored.summary_with_intervals(FOREGROUND)["per_class"][CLASS_NAMES[CAR]]
        return {
            "frames": self.frames,
            "classes": metrics["per_class"],
            "mean_iou": metrics["mean_iou"],
            "mean_iou_interval": metrics["mean_iou_interval"],
            "car_vehicles_ignored": {**relaxed, "ignored_points": self.ignored_points,
                                     "frames_with_vehicles": self.frames_with_vehicles,
                                     "frames_known": self.vehicle_frames},
            "ms_per_frame": {stage: median_or_none(values) for stage, values in self.stage_ms.items()},
        }


OBJECT_MIN_POINTS = 10  # smaller labelled objects are left out of the object count (1-5 point far returns)
OBJECT_FOUND_SHARE = 0.5  # an object is found when at least this share of its points carry its class
# Range bins of the objects found (metres, upper edges; the last bin is open): 0-15, 15-30, 30-50, 50+ m. An object's
# range is the horizontal distance from the sensor to the centroid of its points (every reader has points, few boxes).
OBJECT_RANGE_EDGES_M: tuple[float, ...] = (15.0, 30.0, 50.0)


def range_bin_names(edges: tuple[float, ...] = OBJECT_RANGE_EDGES_M) -> list[str]:
    """Names of the range bins `edges` make: "0-15", "15-30", ..., "50+"."""
    lows = (0.0, *edges)
    return [f"{low:g}-{high:g}" for low, high in zip(lows, edges, strict=False)] + [f"{lows[-1]:g}+"]


class ObjectRecall:
    """Labelled objects found, per foreground class and per range bin: an object (the points of one instance id and
    class, at least `OBJECT_MIN_POINTS`) is found when at least `OBJECT_FOUND_SHARE` of its points are labelled its
    class; its range bin is that of its points' centroid's horizontal distance from the sensor (`edges`, metres).
    Counts objects, not points, so one large car weighs as much as one small one; frames without instance
    ids are counted apart and add no object."""

    def __init__(self, min_points: int = OBJECT_MIN_POINTS, share: float = OBJECT_FOUND_SHARE,
                 edges: tuple[float, ...] = OBJECT_RANGE_EDGES_M) -> None:
        if list(edges) != sorted(edges) or any(e <= 0 for e in edges):
            raise ValueError(f"range edges must be positive and increasing, got {edges}")
        self.min_points, self.share, self.edges = min_points, share, tuple(float(e) for e in edges)
        self.objects: list[np.ndarray] = []  # per frame, objects per class id
        self.found: list[np.ndarray] = []
        self.objects_by_range: list[np.ndarray] = []  # per frame given points, objects per class id x range bin
        self.found_by_range: list[np.ndarray] = []
        self.frames_without_instances = 0

    def update(self, truth: np.ndarray, predicted: np.ndarray, instance: np.ndarray | None,
               xyz: np.ndarray | None = None) -> None:
        """Add one frame's labels, predictions and instance ids (-1: no instance); with its points (`xyz`, N x 3 or
        more columns) its objects are counted by range too."""
        if instance is None:
            self.frames_without_instances += 1
            return
        truth, predicted, instance = np.asarray(truth), np.asarray(predicted), np.asarray(instance)
        if not len(truth) == len(predicted) == len(instance):
            raise ValueError(f"{len(truth)} labels, {len(predicted)} predictions, {len(instance)} instance ids")
        if xyz is not None and len(xyz) != len(truth):
            raise ValueError(f"{len(xyz)} points for {len(truth)} labels")
        bins = len(self.edges) + 1
        objects, found = np.zeros(NUM_CLASSES, np.int64), np.zeros(NUM_CLASSES, np.int64)
        by_range, found_range = np.zeros((NUM_CLASSES, bins), np.int64), np.zeros((NUM_CLASSES, bins), np.int64)
        for c in FOREGROUND:
            member = (truth == c) & (instance >= 0)
            ids, slot, counts = np.unique(instance[member], return_inverse=True, return_counts=True)
            hits = np.bincount(np.searchsorted(ids, instance[member & (predicted == c)]), minlength=len(ids))
            large = counts >= self.min_points
            hit = large & (hits >= self.share * counts)
            objects[c], found[c] = int(large.sum()), int(hit.sum())
            if xyz is not None:
                where = np.asarray(xyz, dtype=np.float64)[member]
                centre_x = np.bincount(slot, weights=where[:, 0], minlength=len(ids)) / np.maximum(counts, 1)
                centre_y = np.bincount(slot, weights=where[:, 1], minlength=len(ids)) / np.maximum(counts, 1)
                band = np.searchsorted(self.edges, np.hypot(centre_x, centre_y), side="right")
                by_range[c] = np.bincount(band[large], minlength=bins)
                found_range[c] = np.bincount(band[hit], minlength=bins)
        self.objects.append(objects)
        self.found.append(found)
        if xyz is not None:
            self.objects_by_range.append(by_range)
            self.found_by_range.append(found_range)

    def _by_range(self) -> dict | None:
        """The "by_range" part of `summary`; None when no frame came with points."""
        if not self.objects_by_range:
            return None
        objects, found = np.stack(self.objects_by_range), np.stack(self.found_by_range)
        names = range_bin_names(self.edges)
        classes = {CLASS_NAMES[c]: {name: {"objects": int(objects[:, c, b].sum()), "found": int(found[:, c, b].sum()),
                                           "recall": _ratio(found[:, c, b].sum(), objects[:, c, b].sum()),
                                           "interval": bootstrap_ratio(found[:, c, b], objects[:, c, b])}
                                    for b, name in enumerate(names)} for c in FOREGROUND}
        return {"edges_m": list(self.edges), "bins": names, "frames": len(objects), "classes": classes}

    def summary(self) -> dict | None:
        """{"min_points", "share", "frames_without_instances", "classes": {name: {"objects", "found", "recall",
        "interval"}}, "by_range": {"edges_m", "bins", "frames", "classes": {name: {bin: {"objects", "found", "recall",
        "interval"}}}} (None without points)} (frame bootstrap intervals, as `bootstrap_ratio`); None when no frame
        had instance ids."""
        if not self.objects:
            return None
        objects, found = np.stack(self.objects), np.stack(self.found)
        classes = {CLASS_NAMES[c]: {"objects": int(objects[:, c].sum()), "found": int(found[:, c].sum()),
                                    "recall": _ratio(found[:, c].sum(), objects[:, c].sum()),
                                    "interval": bootstrap_ratio(found[:, c], objects[:, c])} for c in FOREGROUND}
        return {"min_points": self.min_points, "share": self.share,
                "frames_without_instances": self.frames_without_instances, "classes": classes,
                "by_range": self._by_range()}


def format_objects(objects: dict | None) -> list[str]:
    """The object-count line: per class, labelled objects found, with their interval; then the by-range table."""
    if not objects:
        return []
    parts = []
    for name, row in objects["classes"].items():
        share = ("" if row["recall"] is None
                 else f" ({percent_text(row['recall']).strip()} % {interval_text(row['interval'])})")
        parts.append(f"{name} {row['found']} of {row['objects']}{share}")
    head = (f"objects found (>= {round(100 * objects['share'])} % of their points, objects of >= "
            f"{objects['min_points']} points): " + "; ".join(parts))
    return [head, *format_objects_by_range(objects.get("by_range"))]


def format_objects_by_range(by_range: dict | None) -> list[str]:
    """Table lines: per class and range bin, objects found / objects and the share in %."""
    if not by_range:
        return []
    lines = ["objects found by range (m, horizontal, sensor to the centroid of the object's points): found / objects",
             f"  {'class':<12}" + "".join(f"{name + ' m':>16}" for name in by_range["bins"])]
    for name, row in by_range["classes"].items():
        cells = []
        for cell in row.values():
            share = "   -" if cell["recall"] is None else f"{round(100 * cell['recall']):3d}%"
            cells.append(f"{cell['found']:>5} /{cell['objects']:>4} {share}")
        lines.append(f"  {name:<12}" + "".join(f"{cell:>16}" for cell in cells))
    return lines


def percent_text(value: float | None) -> str:
    return "   n/a" if value is None else f"{100 * value:6.1f}"


def interval_text(interval: dict | None) -> str:
    if interval is None or interval["low"] is None:
        return "[n/a]"
    return f"[{100 * interval['low']:.1f}, {100 * interval['high']:.1f}]"


def mean_classes_text(per_class: dict) -> str:
    """The classes the mean IoU averages (foreground ones with ground-truth points), naming those it leaves out."""
    names = [CLASS_NAMES[c] for c in FOREGROUND]
    absent = [name for name in names if name in per_class and not per_class[name]["points"]]
    if not absent or len(absent) == len(names):
        return ", ".join(names)
    kept = [name for name in names if name not in absent]
    return f"{', '.join(kept)}; no ground-truth {' or '.join(absent)} points"


def format_metrics(per_class: dict, mean_iou: float | None, mean_interval: dict | None = None,
                   extra_rows: Sequence[tuple[str, str, dict]] = ()) -> list[str]:
    """Table lines: per-class precision / recall / IoU in %, point counts, and the foreground mean IoU; with the
    bootstrap interval after each IoU where the rows carry one ("interval") and a line saying how it was made.
    `extra_rows`: (class name, label, row) printed right after that class's row (e.g. car scored another way)."""
    boot = any("interval" in per_class[name] for name in CLASS_NAMES) or mean_interval is not None
    level = next((row["interval"] for row in per_class.values() if row.get("interval")), mean_interval)
    head = f"{round(100 * level['level'])}% interval" if boot and level else ""
    width = max([12] + [len(label) + 2 for _, label, _ in extra_rows])
    lines = [f"{'class':<{width}}{'prec %':>8}{'recall %':>10}{'IoU %':>8}" + (f"  {head:<16}" if boot else "")
             + f"{'points':>10}"]
    rows = [(name, per_class[name]) for name in CLASS_NAMES]
    for after, label, extra in extra_rows:
        at = next((k for k, (name, _) in enumerate(rows) if name == after), len(rows) - 1)
        rows.insert(at + 1, (label, extra))
    for name, row in rows:
        span = f"  {interval_text(row.get('interval')):<16}" if boot else ""
        lines.append(f"{name:<{width}}{percent_text(row['precision']):>8}{percent_text(row['recall']):>10}"
                     f"{percent_text(row['iou']):>8}{span}{row['points']:>10}")
    mean = f"mean IoU ({mean_classes_text(per_class)}): {percent_text(mean_iou).strip()} %"
    lines.append(mean + (f" {interval_text(mean_interval)}" if mean_interval is not None else ""))
    if boot and level:
        note = (f"intervals: {level['method']}, {level['resamples']} resamples of {level['frames']} frame(s), "
                f"percentile, seed {BOOTSTRAP_SEED}")
        if level["degenerate"]:
            note += "; degenerate: one frame has no frame-to-frame spread to resample"
        lines.append(note)
    return lines
