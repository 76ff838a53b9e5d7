"""Stage 2's front door: the classifier interface, the registry of classifiers, and `open_classifier`, the one way
the node and every tool get a classifier, so "network without weights = the shipped weights" and the check that
the checkpoint exists are written once.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from pass3d_ros.core.stage2.config import CLASSIFIERS, DEFAULT_CLASSIFIER
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS, Segmenter, SegmentResult, no_checkpoint_file
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.weights import DEFAULT_WEIGHTS

# CLASSIFIERS and DEFAULT_CLASSIFIER, defined in config.py, are re-exported here, where the node and the tools have
# always found them
__all__ = ["CLASSIFIERS", "DEFAULT_CLASSIFIER", "Classifier", "ClassifierError", "check_device", "open_classifier"]


class ClassifierError(UserError):
    """A classifier cannot be chosen or loaded as asked (kind, weights); the message says why."""


class Classifier(Protocol):
    """What the evaluation and the ROS node need from a stage-2 classifier."""

    kind: str  # one of CLASSIFIERS
    weights: str | None  # the checkpoint file it was loaded from (None: size rules, or a checkpoint dict)
    max_proposals: int

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult: ...

    def warm_up(self) -> None: ...


def open_classifier(
    weights: str | os.PathLike | dict | None,
    classifier: str | None = DEFAULT_CLASSIFIER,
    device: str = "cpu",
    max_proposals: int = DEFAULT_MAX_PROPOSALS,
) -> Classifier:
    """The loaded classifier: 'network' (the default) from `weights`, a checkpoint file or dict (None or '': the
    shipped weights), or 'size_rules' (geometry only, no weights). ClassifierError names a missing file or a device
    torch cannot use here."""
    kind = classifier or DEFAULT_CLASSIFIER
    if kind not in CLASSIFIERS:
        raise ClassifierError(f"unknown classifier {kind!r}: choose {' or '.join(CLASSIFIERS)}")
    if kind == "size_rules":
        if weights:
            raise ClassifierError(
                "--weights applies to the network classifier, not size_rules (node parameter: weights)"
            )
        return SizeRuleClassifier(max_proposals=max_proposals)
    check_device(device)
    if isinstance(weights, dict):
        return Segmenter(weights, device=device, max_proposals=max_proposals)
    path = Path(weights) if weights else DEFAULT_WEIGHTS
    if not path.is_file():
        raise ClassifierError(no_checkpoint_file(path) if weights else (
            f"shipped stage-2 weights missing: {path} (train them with pass3d_train); pass --weights W or "
            "--classifier size_rules (node parameters: weights, classifier)"))
    return Segmenter(path, device=device, max_proposals=max_proposals)


def check_device(device: str) -> None:
    """ClassifierError for a torch device name that is malformed or names hardware this machine lacks (the nodes'
    `device` parameter and the tools' --device, one check)."""
    try:
        chosen = torch.device(device)
    except RuntimeError:
        raise ClassifierError(f"device {device!r} is not a torch device (cpu, cuda or cuda:N)") from None
    if chosen.type == "cuda" and (chosen.index or 0) >= torch.cuda.device_count():
        seen = torch.cuda.device_count()
        build = "built without CUDA" if torch.version.cuda is None else f"sees {seen} CUDA device(s)"
        raise ClassifierError(f"device {device!r}: no such CUDA device here (torch {torch.__version__} {build}); "
                              "use cpu")
    if chosen.type not in ("cpu", "cuda"):
        try:  # mps, xpu, hip ...: a build without them fails here; meta holds no data to copy back
            torch.empty(1, device=chosen).cpu()
        except Exception:
            raise ClassifierError(f"device {device!r}: torch {torch.__version__} cannot run on it here; use cpu or "
                                  "cuda") from None
