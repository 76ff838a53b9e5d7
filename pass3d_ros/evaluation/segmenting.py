"""Offline segmenting of whole datasets: stage 1 + stage 2 on every frame, each frame's labels written in
SemanticKITTI's format, its objects as JSON (and a bird's-eye PNG), a summary.json with the stage times and, where the
data has ground truth, the metrics. The output folder is built in a hidden sibling and moved into place only when
complete. `pass3d_segment` is its command line."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.core.objects import LabelledObject, labelled_objects, objects_json
from pass3d_ros.core.stage1 import Stage1Config, proposal_members
from pass3d_ros.core.stage2 import Classifier
from pass3d_ros.core.stage2.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stream import ScanStream
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import (
    OutputError,
    check_force,
    dataset_paths,
    has_marker,
    out_path,
    refuse_protected,
    write_marker,
    write_text_atomic,
    writing,
)
from pass3d_ros.data.partials import partial_path, remove_stale_partials
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.drawing.bev import frame_picture, write_png
from pass3d_ros.evaluation.offline import BudgetCuts, prepared

SEMANTIC_KITTI_IDS: np.ndarray = np.array([0, 10, 30, 31], dtype=np.uint32)  # by class id: bg, car, ped, cyc
SUMMARY = "summary.json"


@dataclass
class SegmentStats:
    """What a run wrote and how long the stages took."""

    frames: int = 0
    points: int = 0
    folders: list[str] = field(default_factory=list)
    stage1_ms: list[float] = field(default_factory=list)
    stage2_ms: list[float] = field(default_factory=list)
    confusion: ConfusionAccumulator = field(default_factory=ConfusionAccumulator)
    labeled_frames: int = 0
    budget: BudgetCuts = field(default_factory=BudgetCuts)  # proposals stage 2's max_proposals cut
    stream: ScanStream = field(default_factory=ScanStream)  # each --data's stream state (pass3d_ros.core.stream)


def to_semantic_kitti(labels: np.ndarray) -> np.ndarray:
    """Project class ids (0..3) -> SemanticKITTI label words (uint32)."""
    labels = np.asarray(labels)
    if labels.size and (labels.min() < 0 or labels.max() >= NUM_CLASSES):
        raise ValueError(f"labels must lie in 0..{NUM_CLASSES - 1}")
    return SEMANTIC_KITTI_IDS[labels.astype(np.intp)]


def check_out_dir(out: Path, force: bool, inputs: Sequence[str | Path] = ()) -> None:
    """Refuse the working folder, an input or a folder holding one, a file, or a non-empty folder unless `force` and
    it is an output of this tool (its marker); files of the same name are then replaced."""
    refuse_protected(out, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise OutputError(f"{out} is not empty; pass --force to write into it")
        check_force(out, ours=has_marker, kind="an output folder of pass3d_segment", inputs=inputs)


def _safe_name(name: str) -> str:
    return name.replace("/", "_").replace("\\", "_") or "frame"


def segment(
    specs: Sequence[str | Dataset],
    out: str | Path,
    *,
    classifier: Classifier,
    config: Stage1Config | None = None,
    png: bool = True,
    force: bool = False,
    progress: bool = True,
    intensity_match: bool = INTENSITY_MATCH,
) -> SegmentStats:
    """Stage 1 (`config`, default the paper's) + `classifier` on every frame of `specs`; writes labels, PNGs and
    summary.json under `out`, built in a hidden sibling and moved into place only when complete. Each --data's
    intensities reach stage 2 on the training scale (`intensity_match`), as the segmentation node does."""
    if not specs:
        raise DatasetError("no --data given")
    datasets = resolve_datasets(specs)
    out = out_path(out)
    check_out_dir(out, force, dataset_paths(datasets))
    build = build_folder(out)
    remove_stale_partials(out.resolve())
    try:
        with writing(out):
            build.mkdir(parents=True)
            write_marker(build, "pass3d_segment")
            stats = _segment_all(datasets, out, build, classifier, config, png, progress, intensity_match)
            report = summary(stats, [str(spec) for spec in specs], classifier.kind, classifier.weights)
            (build / SUMMARY).write_text(json.dumps(report, indent=2) + "\n")
            _move_into_place(build, out)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise
    return stats


def build_folder(out: Path) -> Path:
    """The hidden sibling of `out` this run builds in (`.NAME.partial-PID`)."""
    resolved = out.resolve()
    if not resolved.name:
        raise OutputError(f"--out {out}: name a folder below the file-system root")
    return partial_path(resolved)


def _segment_all(datasets: list[Dataset], out: Path, build: Path, classifier: Classifier,
                 config: Stage1Config | None, png: bool, progress: bool, intensity_match: bool) -> SegmentStats:
    """Every frame's labels (and PNG) into `build`; `stats.folders` names where they will be, under `out`."""
    counts = [dataset.count() for dataset in datasets]
    total = None if None in counts else sum(c for c in counts if c is not None)
    stats = SegmentStats(budget=BudgetCuts(classifier.max_proposals),
                         stream=ScanStream(intensity_match=intensity_match and classifier.kind != "size_rules"))
    with tqdm(total=total, unit="frame", desc="segment", disable=None if progress else True) as bar:
        for position, dataset in enumerate(datasets):
            sub = "." if len(datasets) == 1 else f"{position:02d}"
            folder = build / sub
            (folder / "labels").mkdir(parents=True, exist_ok=True)
            (folder / "objects").mkdir(exist_ok=True)
            if png:
                (folder / "bev").mkdir(exist_ok=True)
            stats.folders.append(str(out if len(datasets) == 1 else out / sub))
            seen: set[str] = set()
            for frame in dataset.frames():
                name = _safe_name(frame.name)
                if name in seen:
                    raise DatasetError(f"{dataset}: frame name {frame.name!r} repeats; outputs would overwrite")
                seen.add(name)
                labels, cluster_id, objects = _segment_frame(str(dataset), frame, classifier, stats, config)
                to_semantic_kitti(labels).astype("<u4").tofile(folder / "labels" / f"{name}.label")
                write_text_atomic(folder / "objects" / f"{name}.json", objects_json(frame.name, objects))
                if png:
                    image = frame_picture(frame.name, frame.points, labels, cluster_id, frame.labels, frame.instance)
                    write_png(folder / "bev" / f"{name}.png", image)
                if frame.labels is not None:
                    stats.confusion.update(frame.labels, labels)
                    stats.labeled_frames += 1
                stats.frames += 1
                stats.points += len(frame.points)
                bar.update(1)
    if stats.frames == 0:
        raise DatasetError(f"{', '.join(map(str, datasets))}: no frames")
    return stats


def _move_into_place(build: Path, out: Path) -> None:
    """Move the finished `build` to `out`: a rename when `out` is missing or empty, else entry by entry, replacing
    those of the same name; an old summary.json goes first and the new one comes last, so only a complete
    output has one."""
    if out.is_dir() and not any(out.iterdir()):
        out.rmdir()
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        build.rename(out)
        return
    (out / SUMMARY).unlink(missing_ok=True)
    for entry in sorted(build.iterdir(), key=lambda p: p.name == SUMMARY):
        target = out / entry.name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        elif target.exists() or target.is_symlink():
            target.unlink()
        entry.rename(target)
    build.rmdir()


def _segment_frame(spec: str, frame: Frame, classifier: Classifier, stats: SegmentStats,
                   config: Stage1Config | None) -> tuple[np.ndarray, np.ndarray, list[LabelledObject]]:
    """Labels, proposal ids (-1 none) and objects of one scan, through its stream's input checks: points they leave
    out (non-finite, as KITTI raw may hold, or absurd) are background in no proposal and never reach the core."""
    scan = prepared(stats.stream, spec, frame, config or Stage1Config())
    labels = np.zeros(len(frame.points), dtype=np.uint8)
    cluster_id = np.full(len(frame.points), -1, dtype=np.int32)
    if len(scan.points) == 0:
        stats.stage1_ms.append(0.0)
        stats.stage2_ms.append(0.0)
        return labels, cluster_id, []
    result = stats.stream.propose(scan, config)
    started = time.perf_counter()
    members = proposal_members(result.cluster_id, result.cluster_id2, result.n_proposals)
    stats.budget.add(sum(1 for m in members if len(m) > 0))
    segmented = classifier.segment(stats.stream.on_training_scale(scan.points), members)
    predicted = segmented.labels
    stats.stage2_ms.append(1e3 * (time.perf_counter() - started))
    stats.stage1_ms.append(result.timings_ms["total"])
    objects = labelled_objects(scan.points, members, segmented.proposal_class, predicted, segmented.confidence)
    if scan.kept is None:
        return predicted.astype(np.uint8), result.cluster_id, objects
    labels[scan.kept] = predicted
    cluster_id[scan.kept] = result.cluster_id
    return labels, cluster_id, objects


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def summary(stats: SegmentStats, specs: Sequence[str], kind: str, weights: str | None) -> dict:
    """The JSON summary of a run: inputs, outputs, stage medians and, with ground truth, the metrics."""
    metrics = stats.confusion.summary() if stats.labeled_frames else None
    return {
        "data": list(specs),
        "folders": stats.folders,
        "label_ids": {"background": 0, "car": 10, "pedestrian": 30, "cyclist": 31},
        "classifier": kind,
        "weights": weights,
        "frames": stats.frames,
        "points": stats.points,
        "ms_per_frame": {"stage1": _median(stats.stage1_ms), "stage2": _median(stats.stage2_ms)},
        "budget": stats.budget.summary(),
        "intensity": stats.stream.maps,
        "labeled_frames": stats.labeled_frames,
        "per_class": metrics["per_class"] if metrics else None,
        "mean_iou": metrics["mean_iou"] if metrics else None,
    }
