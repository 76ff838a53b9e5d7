"""Pseudo-labels for unlabelled real scans: the network's own answer where all 8 canonical views agree and it is sure.

Self-training adapts stage 2 to a sensor's real scans, which come without labels. Per scan: stage 1, then the
network on every proposal in all 8 views (`Segmenter.view_probabilities`). A proposal becomes a training sample when
all 8 views give it the same class and the median view-averaged confidence of its points is at least
`min_confidence`; its points take the view-averaged class. The points of the other proposals are left out of the
written scan (their labels are unknown: a proposal with a guessed label would teach the guess), and points outside
every proposal are background, as stage 1 left them. The result is a labelled SemanticKITTI sequence that
`pass3d_train --data semantickitti:DIR` reads like any other.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from pass3d_ros.classes import CLASS_NAMES, NUM_CLASSES
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage2.segmentation import Segmenter, proposal_majority, scatter_predictions
from pass3d_ros.data.frame import Frame
from pass3d_ros.training.real_scans import proposed_scans

DEFAULT_MIN_CONFIDENCE = 0.9  # median view-averaged confidence of a kept proposal's points


@dataclass
class PseudoLabelStats:
    """What a run kept: proposals per class (by the views' agreed class), and the proposals and points left out."""

    frames: int = 0
    kept: np.ndarray = field(default_factory=lambda: np.zeros(NUM_CLASSES, dtype=np.int64))
    left_out: int = 0
    points_left_out: int = 0

    def summary(self) -> dict:
        return {"frames": self.frames, "kept": {CLASS_NAMES[c]: int(n) for c, n in enumerate(self.kept)},
                "proposals_left_out": self.left_out, "points_left_out": self.points_left_out}


def pseudo_label_scan(points: np.ndarray, members: list[np.ndarray], segmenter: Segmenter,
                      min_confidence: float = DEFAULT_MIN_CONFIDENCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(labels (N,) uint8, keep (N,) bool, the agreed class of each kept proposal) of one scan; `members` are the
    non-empty proposals' point indices."""
    views = segmenter.view_probabilities(points, members)
    keep = np.ones(len(points), dtype=bool)
    if views.proposals == 0:
        return np.zeros(len(points), dtype=np.uint8), keep, np.zeros(0, dtype=np.int16)
    classes = np.stack([proposal_majority(views.query_batch, p.argmax(axis=1), views.proposals, NUM_CLASSES)
                        for p in views.probs])
    mean = views.probs.mean(axis=0)
    label, confidence = mean.argmax(axis=1).astype(np.uint8), mean.max(axis=1)
    sure = np.array([np.median(confidence[views.query_batch == p]) >= min_confidence
                     for p in range(views.proposals)])
    good = (classes == classes[0]).all(axis=0) & sure
    chosen = good[views.query_batch]
    labels, _ = scatter_predictions(len(points), views.query_index[chosen], label[chosen], confidence[chosen])
    unknown = np.zeros(len(points), dtype=bool)
    unknown[views.query_index[~chosen]] = True
    unknown[views.query_index[chosen]] = False
    keep &= ~unknown
    return labels, keep, classes[0][good]


def pseudo_label_frames(frames: Iterator[tuple[str, Frame]], config: Stage1Config, segmenter: Segmenter,
                        min_confidence: float = DEFAULT_MIN_CONFIDENCE, intensity_match: bool = True,
                        stats: PseudoLabelStats | None = None) -> Iterator[Frame]:
    """Each frame with pseudo-labels and only its kept points, intensities on the training scale (`intensity_match`,
    as stage 2 saw them); labels of the input are ignored; laser lines and the intensity map are held per spec."""
    stats = stats if stats is not None else PseudoLabelStats()
    for scan in proposed_scans(frames, config, intensity_match):
        labels, keep, kept = pseudo_label_scan(scan.points, scan.members, segmenter, min_confidence)
        stats.frames += 1
        stats.kept += np.bincount(kept, minlength=NUM_CLASSES)
        stats.left_out += len(scan.members) - len(kept)
        stats.points_left_out += int((~keep).sum())
        yield Frame(name=scan.frame.name, points=scan.points[keep], stamp_ns=scan.frame.stamp_ns,
                    ring=None if scan.ring is None else scan.ring[keep], labels=labels[keep])
