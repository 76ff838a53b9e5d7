"""Stage-2 validation: score a model over whole validation frames, point by point.

Each validation frame's proposals are segmented as in inference (one batch per frame, overlap rule, points
outside every proposal are background), and the per-class IoU is counted over every point of every
validation frame, so it includes stage 1's misses.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.core.stage2.pointnet2 import PointNet2Seg
from pass3d_ros.core.stage2.segmentation import (
    default_sampling,
    predict_probabilities,
    prepare_proposals,
    scatter_predictions,
)
from pass3d_ros.training.samples import SampleSet


def validate(model: PointNet2Seg, samples: SampleSet, device: str, progress: bool = False) -> dict:
    """Point-level scores over whole validation frames (see the module docstring): ConfusionAccumulator's
    summary (per-class precision, recall, IoU; mean IoU over car, pedestrian, cyclist) plus the matrix."""
    if samples.frame_labels is None:
        raise ValueError("validation samples need the frames' full labels")
    model.eval()
    starts = samples.frame_offsets()
    confusion = ConfusionAccumulator()
    order = np.argsort(samples.frame, kind="stable")
    bounds = np.searchsorted(samples.frame[order], np.arange(len(samples.frame_sizes) + 1))
    frames = range(len(samples.frame_sizes))
    for f in tqdm(frames, desc="validate", unit="frame", disable=None if progress else True, leave=False):
        ids = order[bounds[f] : bounds[f + 1]]
        size = int(samples.frame_sizes[f])
        labels = np.zeros(size, dtype=np.uint8)
        if len(ids):
            batch = prepare_proposals(samples.points, samples.members(ids), model.config,
                                      sampling=default_sampling(model.config))  # as inference samples
            probs = predict_probabilities(model, batch, device)
            pred = probs.argmax(1)
            labels, _ = scatter_predictions(
                size, samples.point_index[batch.query_index], pred.astype(np.uint8), probs[np.arange(len(pred)), pred]
            )
        confusion.update(samples.frame_labels[starts[f] : starts[f] + size], labels)
    return {**confusion.summary(), "confusion": confusion.matrix.tolist()}


def format_scores(scores: dict) -> str:
    """One log line of `validate`'s scores: per-class IoU and the foreground mean, in percent."""

    def pct(value: float | None) -> str:
        return "n/a" if value is None else f"{100 * value:.1f}"

    parts = [f"{name} {pct(row['iou'])}" for name, row in scores["per_class"].items()]
    return f"IoU % {', '.join(parts)}; mean(fg) {pct(scores['mean_iou'])}"
