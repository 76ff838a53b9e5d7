"""Offline evaluation over labelled datasets, no ROS: stage 1 alone or the full pipeline, scored point-wise.

Points with a non-finite coordinate never reach the core: they are predicted background and still scored
(a labelled one counts as a miss). A frame without point labels is an error naming its spec.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import BACKGROUND, IGNORE
from pass3d_ros.core.metrics import ObjectRecall, SegmentationMetrics, Stage1Metrics
from pass3d_ros.core.pipeline import ProposedScan, ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config, warm_up
from pass3d_ros.core.stage2 import Classifier
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS, Segmenter, proposals_cut
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.msgs.errors import UserError


def iter_frames(specs: Sequence[str | Dataset], limit: int | None, progress: bool) -> Iterator[tuple[str, Frame]]:
    """(spec, frame) over all specs, at most `limit` frames from each, with a progress bar on stderr."""
    for dataset in resolve_datasets(specs):
        spec = str(dataset)
        total = dataset.count()
        if limit is not None:
            total = limit if total is None else min(total, limit)
        bar = tqdm(total=total, desc=spec, unit="frame", disable=None if progress else True, file=sys.stderr,
                   leave=False)
        try:
            for index, frame in enumerate(dataset.frames()):
                if limit is not None and index >= limit:
                    break
                yield spec, frame
                bar.update(1)
        finally:
            bar.close()


@dataclass
class BudgetCuts:
    """Proposals a stage-2 budget (`max_proposals`, nearest first) leaves unclassified over a run, and in how many
    frames: counted as the segmentation node counts them (pass3d_ros.core.stage2.segmentation.proposals_cut)."""

    max_proposals: int = DEFAULT_MAX_PROPOSALS
    proposals: int = 0
    frames: int = 0

    def add(self, count: int) -> int:
        """Count the cut of one frame with `count` non-empty proposals; returns it."""
        cut = proposals_cut(count, self.max_proposals)
        self.proposals += cut
        self.frames += cut > 0
        return cut

    def summary(self) -> dict:
        return {"max_proposals": self.max_proposals, "proposals_cut": self.proposals, "frames_cut": self.frames}


def proposed_frame(pipeline: ScanPipeline, spec: str, frame: Frame, printed: set[str] | None = None) -> ProposedScan:
    """`frame` through its spec's stream (`pipeline.follow(spec)`): the input checks, as the cluster node checks a live
    scan, and stage 1; prints on stderr what the checks repaired, once a topic per stream; with `printed` ("SPEC|TOPIC"
    keys already printed, updated) a tool that reads the same scans in several streams prints each topic of a spec
    once."""
    pipeline.follow(spec)
    scan = pipeline.prepare(frame.points, frame.ring)
    proposed = pipeline.stage1(scan)
    for note in pipeline.stream.first_notes(scan.notes + pipeline.stream.mounting_notes(pipeline.config)):
        key = f"{spec}|{note.topic}"
        if printed is None or key not in printed:
            print(f"{spec}: {note.text}", file=sys.stderr)
        if printed is not None:
            printed.add(key)
    return proposed


def score_stage1(metrics: Stage1Metrics, name: str, proposed: ProposedScan, frame: Frame) -> dict:
    """Add one frame's stage 1 to `metrics` over the input's points: a point the input checks left out is in no
    proposal and not ground, so a labelled one counts as a miss, as the full evaluation scores it; returns its row."""
    result, size = proposed.result, len(frame.points)
    cluster_id, cluster_id2 = (proposed.in_input(ids, size, -1) for ids in (result.cluster_id, result.cluster_id2))
    ground = proposed.in_input(result.ground, size, False)
    return metrics.update(name, result.n_proposals, cluster_id, cluster_id2, ground, result.timings_ms, frame.labels,
                          frame.ground)


def evaluate_stage1(frames: Iterator[tuple[str, Frame]], config: Stage1Config,
                    max_proposals: int = DEFAULT_MAX_PROPOSALS) -> dict:
    """Run stage 1 on every frame and accumulate its metrics; returns the summary with per-frame rows. Laser lines
    and the mounting are held across the frames of one spec (pass3d_ros.core.stream), as the cluster node holds them.
    "budget": the proposals a stage-2 budget of `max_proposals` would cut."""
    warm_up()
    metrics = Stage1Metrics()
    pipeline = ScanPipeline(config, intensity_match=False)
    budget = BudgetCuts(max_proposals)
    for spec, frame in frames:
        proposed = proposed_frame(pipeline, spec, frame)
        result = proposed.result
        row = score_stage1(metrics, f"{spec}#{frame.name}", proposed, frame)
        row["ring_source"] = result.ring_source
        row["proposals_cut"] = budget.add(result.n_proposals)  # a kept proposal has points
    summary = metrics.summary()
    summary["budget"] = budget.summary()
    summary["mounting"] = pipeline.stream.mountings
    summary["per_frame"] = metrics.per_frame
    return summary


FRONT_VIEW_DEG = 45.0  # KITTI's camera view, as the project applies it: |azimuth| <= 45 degrees ahead


def background_proposals(points: np.ndarray, truth: np.ndarray, members: list[np.ndarray],
                         proposal_class: np.ndarray) -> tuple[int, int]:
    """(background-only front-view proposals, how many of them stage 2 called an object): proposals whose
    labelled points are all background and whose median point lies in the front view; the clutter a real
    street offers stage 2 (posts, trunks, wall fragments), where false positives show first."""
    total = called = 0
    for k, m in enumerate(members):
        labels = truth[m]
        known = labels[labels != IGNORE]
        if len(known) == 0 or np.any(known != BACKGROUND):
            continue
        x, y = np.median(points[m, 0]), np.median(points[m, 1])
        if x <= 0.0 or abs(np.degrees(np.arctan2(y, x))) > FRONT_VIEW_DEG:
            continue
        total += 1
        called += int(proposal_class[k] > BACKGROUND)
    return total, called


def evaluate_full(frames: Iterator[tuple[str, Frame]], config: Stage1Config, classifier: Classifier,
                  intensity_match: bool = INTENSITY_MATCH, people_in_groups: bool = PEOPLE_IN_GROUPS) -> dict:
    """Stage 1 then stage 2 on every frame, scored against its labels: per-class metrics (car also with the points
    of vans / trucks / buses left out, where the reader marks them), labelled objects found (overall and by range),
    stage times, and the stage-1 summary. Each spec's intensities go to stage 2 on the training scale
    (`intensity_match`); `people_in_groups`: Stage2Config.people_in_groups."""
    warm_up()
    classifier.warm_up()
    segmentation = SegmentationMetrics()
    objects = ObjectRecall()
    stage1 = Stage1Metrics()
    background = np.zeros(2, dtype=np.int64)
    budget = BudgetCuts(classifier.max_proposals)
    pipeline = ScanPipeline(config, classifier, intensity_match=intensity_match, people_in_groups=people_in_groups)
    for spec, frame in frames:
        if frame.labels is None:
            raise DatasetError(f"{spec}: frame {frame.name} has no point labels; full evaluation needs labelled data")
        proposed = proposed_frame(pipeline, spec, frame)
        result, members = proposed.result, proposed.members
        truth = proposed.kept_values(frame.labels)
        cut = budget.add(len(proposed.nonempty_members()))
        labelled = pipeline.segment(proposed)
        background += background_proposals(proposed.scan.points, truth, members, labelled.segmented.proposal_class)
        predicted = labelled.labels_in_input(len(frame.points))
        name = f"{spec}#{frame.name}"
        row = segmentation.update(name, frame.labels, predicted, proposed.stage1_ms, labelled.stage2_ms,
                                  vehicle_other=frame.vehicle_other)
        objects.update(frame.labels, predicted, frame.instance, frame.points)
        row["proposals"] = result.n_proposals
        row["proposals_cut"] = cut
        score_stage1(stage1, name, proposed, frame)
    summary = segmentation.summary()
    summary["stage1"] = stage1.summary()["stage1"]
    summary["objects"] = objects.summary()
    summary["background_proposals"] = {"front_view": int(background[0]), "called_object": int(background[1])}
    summary["budget"] = budget.summary()
    summary["intensity"] = pipeline.stream.maps
    summary["mounting"] = pipeline.stream.mountings
    summary["per_frame"] = segmentation.per_frame
    return summary


def spread(values: list[float | None], key: str = "iou") -> dict:
    """{key: the values as given, "mean", "min", "max"} over those that are not None (all None: null)."""
    known = [v for v in values if v is not None]
    if not known:
        return {key: list(values), "mean": None, "min": None, "max": None}
    return {key: list(values), "mean": float(np.mean(known)), "min": float(min(known)), "max": float(max(known))}


def each_draw(classifier: Segmenter, draws: int, run: Callable[[], dict]) -> list[dict]:
    """`run()`'s summary with the classifier reading its N-point sample draw 0, 1, ... draws-1 in turn; the
    classifier is left on draw 0."""
    summaries = []
    try:
        for draw in range(draws):
            classifier.draw = draw
            summaries.append(run())
    finally:
        classifier.draw = 0
    return summaries


def evaluate_draws(frames: Callable[[], Iterator[tuple[str, Frame]]], config: Stage1Config, classifier: Classifier,
                   draws: int, intensity_match: bool = INTENSITY_MATCH, people_in_groups: bool = PEOPLE_IN_GROUPS
                   ) -> dict:
    """`evaluate_full` once per N-point sample draw 0..draws-1 (`each_draw`; `frames()` yields the frames afresh
    each time): draw 0's summary, plus "draws": {"count", "classes": {class: spread}, "mean_iou":
    spread} with each draw's IoU, and per frame "confusion_draws", its confusion summed over the draws (what a
    paired comparison pools). Needs the in-process network classifier (UserError otherwise)."""
    if draws < 1:
        raise UserError(f"--sample-draws must be >= 1, got {draws}")
    if not isinstance(classifier, Segmenter):
        raise UserError(f"--sample-draws needs the in-process network classifier, not {classifier.kind}")
    summaries = each_draw(classifier, draws, lambda: evaluate_full(frames(), config, classifier, intensity_match,
                                                                   people_in_groups))
    first = summaries[0]
    for rows in zip(*(s["per_frame"] for s in summaries), strict=True):
        rows[0]["confusion_draws"] = np.sum([row["confusion"] for row in rows], axis=0).tolist()
    first["draws"] = {
        "count": draws,
        "classes": {name: spread([s["classes"][name]["iou"] for s in summaries]) for name in first["classes"]},
        "mean_iou": spread([s["mean_iou"] for s in summaries]),
    }
    return first
