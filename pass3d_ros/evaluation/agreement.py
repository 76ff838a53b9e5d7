"""View agreement: how often stage 2 gives a proposal the same class in all 8 canonical views.

The network saw every object in all 8 views in training, so on data like its training data a proposal reads the
same in each (synthetic scans: 97-99 % of car proposals); real scans it is not at home on split their votes
(20-22 % of real car proposals changed class). The measure needs no labels, so it scores adaptation on unlabelled
real scans. A proposal counts under the class most of its views give it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from pass3d_ros.classes import CAR, CLASS_NAMES, CYCLIST, PEDESTRIAN
from pass3d_ros.core.metrics import bootstrap_ratio
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config, warm_up
from pass3d_ros.core.stage2.segmentation import Segmenter, nearest_first
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.offline import INTENSITY_MATCH, each_draw, proposed_frame, spread

AGREEMENT_CLASSES = (CAR, PEDESTRIAN, CYCLIST)


def view_votes(views: np.ndarray) -> np.ndarray:
    """Per proposal, how many of its views give each class (P, classes)."""
    views = np.asarray(views, dtype=np.int64)
    return np.stack([(views == c).sum(axis=1) for c in range(len(CLASS_NAMES))], axis=1) if len(views) else \
        np.zeros((0, len(CLASS_NAMES)), dtype=np.int64)


def majority(views: np.ndarray) -> np.ndarray:
    """The class most of each proposal's views give (P,) (ties: the lower class): the class a proposal counts under."""
    return view_votes(views).argmax(axis=1)


class ViewAgreement:
    """Per frame and class: proposals the views' majority gives that class, and how many of them all 8 views do."""

    def __init__(self) -> None:
        self.counts: list[np.ndarray] = []  # per frame (classes, 2): proposals, unanimous

    def update(self, views: np.ndarray) -> np.ndarray:
        """Fold one frame's (P, 8) view classes in; returns its (classes, 2) counts."""
        views = np.asarray(views, dtype=np.int64)
        row = np.zeros((len(AGREEMENT_CLASSES), 2), dtype=np.int64)
        if len(views):
            votes = view_votes(views)
            chosen_class = votes.argmax(axis=1)
            unanimous = votes.max(axis=1) == views.shape[1]
            for i, cls in enumerate(AGREEMENT_CLASSES):
                chosen = chosen_class == cls
                row[i] = chosen.sum(), (chosen & unanimous).sum()
        self.counts.append(row)
        return row

    def summary(self) -> dict:
        """Per class: proposals, unanimous share and its frame bootstrap interval."""
        stack = np.asarray(self.counts, dtype=np.int64).reshape(-1, len(AGREEMENT_CLASSES), 2)
        out = {}
        for i, cls in enumerate(AGREEMENT_CLASSES):
            total, unanimous = int(stack[:, i, 0].sum()), int(stack[:, i, 1].sum())
            out[CLASS_NAMES[cls]] = {
                "proposals": total, "agreement": unanimous / total if total else None,
                "interval": bootstrap_ratio(stack[:, i, 1], stack[:, i, 0]),
            }
        return out


def evaluate_agreement(frames: Iterator[tuple[str, Frame]], config: Stage1Config, classifier: Segmenter,
                       intensity_match: bool = INTENSITY_MATCH) -> dict:
    """Stage 1, then the network in all 8 views on every frame (labels unused): the view agreement per class."""
    if not isinstance(classifier, Segmenter):
        raise TypeError("view agreement needs the network classifier")
    warm_up()
    classifier.warm_up()
    agreement = ViewAgreement()
    pipeline = ScanPipeline(config, intensity_match=intensity_match)
    per_frame = []
    for spec, frame in frames:
        proposed = proposed_frame(pipeline, spec, frame)
        members = [proposed.members[i] for i in nearest_first(proposed.scan.points, proposed.members,
                                                               classifier.max_proposals)]
        row = agreement.update(classifier.view_classes(proposed.points, members))
        per_frame.append({"frame": f"{spec}#{frame.name}", "proposals": len(members),
                          **{CLASS_NAMES[c]: row[i].tolist() for i, c in enumerate(AGREEMENT_CLASSES)}})
    return {"frames": len(per_frame), "agreement": agreement.summary(), "intensity": pipeline.stream.maps,
            "per_frame": per_frame}


def evaluate_agreement_draws(frames: Callable[[], Iterator[tuple[str, Frame]]], config: Stage1Config,
                             classifier: Segmenter, draws: int, intensity_match: bool = INTENSITY_MATCH) -> dict:
    """`evaluate_agreement` once per N-point sample draw 0..draws-1 (`frames()` yields the frames afresh each time):
    draw 0's summary plus "draws": {"count", "measure": "agreement", "classes": {class: spread of the unanimous
    share, with "proposals" per draw}}; one draw's agreement moves with the draw as its IoU does."""
    summaries = each_draw(classifier, draws, lambda: evaluate_agreement(frames(), config, classifier, intensity_match))
    first = summaries[0]
    first["draws"] = {"count": draws, "measure": "agreement", "classes": {
        name: {**spread([s["agreement"][name]["agreement"] for s in summaries], key="agreement"),
               "proposals": [s["agreement"][name]["proposals"] for s in summaries]}
        for name in first["agreement"]}}
    return first
