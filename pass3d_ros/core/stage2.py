"""Stage 2's front door: the classifier interface, the registry of classifiers, which weights one uses, and
loading it. The node and every tool go through here, so "network without weights = the shipped weights"
is decided once.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

import numpy as np

from pass3d_ros.core.segmentation import DEFAULT_MAX_PROPOSALS, Segmenter, SegmentResult
from pass3d_ros.core.size_rules import SizeRuleClassifier
from pass3d_ros.weights import default_weights

CLASSIFIERS: tuple[str, ...] = ("network", "size_rules")
DEFAULT_CLASSIFIER = "network"


class ClassifierError(ValueError):
    """A classifier cannot be chosen or loaded as asked (kind, weights); the message says why."""


class Classifier(Protocol):
    """What the evaluation and the ROS node need from a stage-2 classifier."""

    max_proposals: int

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult: ...

    def warm_up(self) -> None: ...


def resolve_weights(kind: str | None, weights: str | os.PathLike | None) -> tuple[str, str | None]:
    """(kind, weights path or None): the network by default, with the shipped weights unless `weights` is given."""
    kind = kind or DEFAULT_CLASSIFIER
    if kind not in CLASSIFIERS:
        raise ClassifierError(f"unknown classifier {kind!r}: choose {' or '.join(CLASSIFIERS)}")
    if kind == "size_rules":
        if weights:
            raise ClassifierError(
                "--weights applies to the network classifier, not size_rules (node parameter: weights)"
            )
        return kind, None
    if weights:
        if not Path(weights).is_file():
            raise ClassifierError(f"{weights}: no such checkpoint file")
        return kind, str(weights)
    try:
        return kind, str(default_weights())
    except FileNotFoundError as exc:
        raise ClassifierError(
            f"{exc}; pass --weights W or --classifier size_rules (node parameters: weights, classifier)"
        ) from None


def load_classifier(
    kind: str,
    weights: str | os.PathLike | dict | None = None,
    device: str = "cpu",
    max_proposals: int = DEFAULT_MAX_PROPOSALS,
) -> Classifier:
    """'network' (needs weights: a checkpoint path or dict) or 'size_rules' (geometry only)."""
    if kind == "network":
        if weights is None:
            raise ClassifierError("the network classifier needs weights (a stage-2 checkpoint)")
        return Segmenter(weights, device=device, max_proposals=max_proposals)
    if kind == "size_rules":
        return SizeRuleClassifier(max_proposals=max_proposals)
    raise ClassifierError(f"unknown classifier {kind!r}: choose {' or '.join(CLASSIFIERS)}")
