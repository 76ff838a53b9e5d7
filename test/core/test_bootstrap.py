"""Frame bootstrap intervals of the segmentation metrics: contain the estimate, shrink with more frames,
degenerate with one frame, reproducible, and present in the JSON-ready summary and the printed table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.metrics import BOOTSTRAP_LEVEL, SegmentationMetrics, bootstrap_iou, format_metrics

INTERVAL_KEYS = {"low", "high", "level", "resamples", "skipped", "method", "frames", "degenerate"}


def _frame(rng: np.random.Generator, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Labels of one frame and a prediction that is right with a frame-specific accuracy."""
    truth = rng.choice([BACKGROUND, CAR, PEDESTRIAN, CYCLIST], size=n, p=[0.7, 0.15, 0.1, 0.05])
    wrong = rng.random(n) > rng.uniform(0.5, 0.95)
    predicted = np.where(wrong, rng.integers(0, 4, n), truth)
    return truth, predicted


def _metrics(frames: list[tuple[np.ndarray, np.ndarray]]) -> SegmentationMetrics:
    metrics = SegmentationMetrics()
    for i, (truth, predicted) in enumerate(frames):
        metrics.update(f"f{i}", truth, predicted, 1.0, 1.0)
    return metrics


def _width(interval: dict) -> float:
    return interval["high"] - interval["low"]


def test_interval_contains_point_estimate_and_keys_present() -> None:
    rng = np.random.default_rng(1)
    summary = _metrics([_frame(rng) for _ in range(12)]).summary()
    json.dumps(summary)  # JSON-ready
    for name, row in summary["classes"].items():
        interval = row["interval"]
        assert set(interval) == INTERVAL_KEYS, name
        assert interval["level"] == BOOTSTRAP_LEVEL and interval["method"] == "frame bootstrap"
        assert interval["resamples"] == 1000 and interval["frames"] == 12 and not interval["degenerate"]
        assert interval["low"] <= row["iou"] <= interval["high"], name
        assert interval["low"] < interval["high"], name
    mean = summary["mean_iou_interval"]
    assert set(mean) == INTERVAL_KEYS and mean["low"] <= summary["mean_iou"] <= mean["high"]


def test_interval_shrinks_with_more_frames_of_the_same_kind() -> None:
    rng = np.random.default_rng(2)
    base = [_frame(rng) for _ in range(6)]
    small = _metrics(base).summary()
    large = _metrics(base * 8).summary()  # the same six frames, eight times over: same estimate, more frames
    assert large["mean_iou"] == pytest.approx(small["mean_iou"])
    assert _width(large["mean_iou_interval"]) < 0.6 * _width(small["mean_iou_interval"])
    for name in ("car", "pedestrian", "cyclist"):
        assert _width(large["classes"][name]["interval"]) < _width(small["classes"][name]["interval"]), name


def test_one_frame_is_degenerate_and_the_table_says_so() -> None:
    summary = _metrics([_frame(np.random.default_rng(3))]).summary()
    for row in summary["classes"].values():
        interval = row["interval"]
        assert interval["degenerate"] and interval["frames"] == 1
        assert interval["low"] == pytest.approx(row["iou"]) and interval["high"] == pytest.approx(row["iou"])
    lines = format_metrics(summary["classes"], summary["mean_iou"], summary["mean_iou_interval"])
    assert any("degenerate" in line for line in lines)
    car = next(line for line in lines if line.startswith("car"))
    iou = 100 * summary["classes"]["car"]["iou"]
    assert f"{iou:.1f} [{iou:.1f}, {iou:.1f}]" in " ".join(car.split())


def test_reproducible_with_the_seed() -> None:
    rng = np.random.default_rng(4)
    frames = [_frame(rng) for _ in range(10)]
    first, second = _metrics(frames).summary(), _metrics(frames).summary()
    assert first["mean_iou_interval"] == second["mean_iou_interval"]
    assert first["classes"]["car"]["interval"] == second["classes"]["car"]["interval"]
    matrices = np.asarray(_metrics(frames).confusion.frames)
    other = bootstrap_iou(matrices, seed=99)["mean_iou"]
    assert (other["low"], other["high"]) != (first["mean_iou_interval"]["low"], first["mean_iou_interval"]["high"])


def test_class_absent_from_a_resample_is_skipped() -> None:
    """Cyclists in one frame of ten: resamples that miss it (and predict none) have no cyclist IoU."""
    frames = [np.diag([50, 10, 0, 0]) for _ in range(9)] + [np.diag([50, 10, 0, 5])]
    boot = bootstrap_iou(np.asarray(frames), resamples=500)
    cyclist = boot["per_class"][CYCLIST]
    assert 0 < cyclist["skipped"] < 500 and cyclist["low"] == cyclist["high"] == 1.0
    pedestrian = boot["per_class"][PEDESTRIAN]
    assert pedestrian["skipped"] == 500 and pedestrian["low"] is None and pedestrian["high"] is None
    assert boot["mean_iou"]["skipped"] == 0
