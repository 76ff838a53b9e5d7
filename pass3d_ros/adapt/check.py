"""The label-free check of adaptation: what stage 2 says about held-out scans of the user's sensor, with no label.

Per scan: stage 1 once, then stage 2 in all 8 canonical views for each of `draws` point samples. Reported: the view
agreement per class (the share of proposals all 8 views give the class their majority gives; pass3d_ros.evaluation.
agreement) as a mean and range over the draws, proposals per scan, and the share of proposals each class takes per
range bin (by the views' majority, draw 0), and with 2 or more draws the draw agreement: the share of proposals whose
views' majority is the same class in every draw (all proposals, and those some draw calls an object). A network at
home on a sensor agrees with itself across views and draws, and an adaptation that starts calling every far blob a
car shows in the shares before any label would.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_NAMES
from pass3d_ros.core.metrics import OBJECT_RANGE_EDGES_M, range_bin_names
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config, warm_up
from pass3d_ros.core.stage2.segmentation import Segmenter, nearest_first
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.agreement import ViewAgreement, majority
from pass3d_ros.evaluation.offline import INTENSITY_MATCH, proposed_frame, spread


def check_scans(frames: Iterable[tuple[str, Frame]], config: Stage1Config, classifier: Segmenter, draws: int = 1,
                intensity_match: bool = INTENSITY_MATCH, printed: set[str] | None = None) -> dict:
    """The label-free check (module docstring) over (spec, frame) pairs; labels, if any, are not read. `printed`:
    input-check lines already printed (evaluation.offline.proposed_frame)."""
    if draws < 1:
        raise ValueError(f"draws must be >= 1, got {draws}")
    warm_up()
    classifier.warm_up()
    pipeline = ScanPipeline(config, intensity_match=intensity_match)
    agreements = [ViewAgreement() for _ in range(draws)]
    bins = len(OBJECT_RANGE_EDGES_M) + 1
    shares = np.zeros((bins, len(CLASS_NAMES)), dtype=np.int64)
    proposals = []
    same = np.zeros((2, 2), dtype=np.int64)  # (all proposals, those some draw calls an object) x (count, same class)
    try:
        for spec, frame in frames:
            proposed = proposed_frame(pipeline, spec, frame, printed)
            members = [proposed.members[i] for i in nearest_first(proposed.scan.points, proposed.members,
                                                                   classifier.max_proposals)]
            members = [m for m in members if len(m)]
            points = proposed.points
            proposals.append(len(members))
            chosen = []
            for draw, agreement in enumerate(agreements):
                classifier.draw = draw
                views = classifier.view_classes(points, members)
                agreement.update(views)
                chosen.append(majority(views))
                if draw == 0 and len(members):
                    ranges = np.array([np.hypot(*points[m, :2].mean(axis=0)) for m in members])
                    where = np.searchsorted(OBJECT_RANGE_EDGES_M, ranges, side="right")
                    np.add.at(shares, (where, chosen[0]), 1)
            _count_same(same, np.stack(chosen))
    finally:
        classifier.draw = 0
    summaries = [a.summary() for a in agreements]
    totals = shares.sum(axis=1, keepdims=True)
    return {
        "scans": len(proposals),
        "draws": draws,
        "proposals_per_scan": {"median": float(np.median(proposals)) if proposals else None,
                               "mean": float(np.mean(proposals)) if proposals else None},
        "agreement": {name: {**spread([s[name]["agreement"] for s in summaries], key="agreement"),
                             "proposals": [s[name]["proposals"] for s in summaries],
                             "interval": summaries[0][name]["interval"]}
                      for name in summaries[0]},
        "draw_agreement": _draw_agreement(same) if draws > 1 else None,
        "class_shares": {bin_name: {"proposals": int(totals[b, 0]),
                                    **{CLASS_NAMES[c]: float(shares[b, c] / totals[b, 0]) if totals[b, 0] else None
                                       for c in range(len(CLASS_NAMES))}}
                         for b, bin_name in enumerate(range_bin_names())},
        "intensity": pipeline.stream.maps,
        "mounting": pipeline.stream.mountings,
    }


def _count_same(same: np.ndarray, chosen: np.ndarray) -> None:
    """Fold one scan's (draws, P) majority classes into `same`: proposals, and those every draw gives one class."""
    if chosen.shape[1] == 0:
        return
    agree = (chosen == chosen[0]).all(axis=0)
    objects = (chosen != BACKGROUND).any(axis=0)
    same[0] += len(agree), int(agree.sum())
    same[1] += int(objects.sum()), int((agree & objects).sum())


def _draw_agreement(same: np.ndarray) -> dict:
    """The shares of proposals (all; those some draw calls an object) every draw gives the same class."""
    return {key: {"proposals": int(same[k, 0]), "share": float(same[k, 1] / same[k, 0]) if same[k, 0] else None}
            for k, key in enumerate(("all", "objects"))}
