"""`pass3d_segment`: label every point of every frame offline (stage 1 + stage 2), no ROS needed.

    pass3d_segment --data SPEC [--data ...] --out DIR [--weights W] [--classifier network|size_rules]
                   [--param KEY=VALUE ...] [--max-proposals N] [--threads N] [--no-png] [--force] [--no-progress]

Writes, per frame, `labels/NAME.label` in SemanticKITTI's format (one little-endian uint32 per point, in
the scan's point order, instance bits 0) and, unless --no-png, `bev/NAME.png`, a bird's-eye picture: the
prediction coloured by class with its object boxes, beside the ground truth when the data has labels. NAME is
the reader's frame name. With several --data, each gets its own folder `OUT/NN/` (NN = position of the --data,
from 00) so equal frame names cannot collide. `OUT/summary.json` records the
inputs, the classifier, times per stage and, when the data has ground-truth labels, per-class precision,
recall and IoU, how many proposals stage 2's budget (max_proposals, nearest first) cut ("budget"), and the
intensity map each --data got ("intensity": stage 2 sees intensities on its training scale, as the segmentation
node does; --no-intensity-match feeds them as read). `--param
KEY=VALUE` (repeatable) overrides a stage-1 parameter, as in pass3d_evaluate (stage1.sensor=pandar64 or
sensor=pandar64). The frames of one --data are a stream: laser lines found on one scan are reused by the next
(pass3d_ros.core.stage1.held_lines).

The output is built in a hidden sibling folder (`.DIR.partial-PID`) and moved into DIR only when every frame and
the summary are written, so a failed or interrupted run leaves DIR as it was (one left by a killed run is removed by
the next). DIR gets a `.pass3d_output` marker; --force writes into a non-empty DIR only when it holds one (an output
of this tool), and then the run's own entries (labels/, bev/, NN/, summary.json) replace those of the same name;
other files stay. Never into the working folder, an input or a folder holding one. A full disk is one line; DIR is
left as it was.

Label ids: car 10, pedestrian 30 (person), cyclist 31 (bicyclist), background 0 (unlabeled): PASS3D
only tells the three object classes from everything else, so background is left unnamed rather than
guessed as road or building. The `semantickitti:` reader maps these back to the project's classes.

Default classifier: `network` with the shipped weights (pass3d_ros/weights/pass3d_lite.pt), or --weights.
Exit status: 0 done, 2 user error (bad spec, weights, --param, non-empty --out without --force, a full disk), 130 /
143 interrupted.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.metrics import ConfusionAccumulator, format_metrics
from pass3d_ros.core.stage1 import Stage1Config, proposal_members
from pass3d_ros.core.stage1.held_lines import LineHolder
from pass3d_ros.core.stage2 import CLASSIFIERS, Classifier, open_classifier
from pass3d_ros.core.stage2.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS
from pass3d_ros.core.threads import DEFAULT_THREADS, limit_threads
from pass3d_ros.data.outputs import (
    check_force,
    dataset_paths,
    has_marker,
    out_path,
    refuse_protected,
    write_marker,
    writing,
)
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.evaluation.bev import frame_picture, write_png
from pass3d_ros.evaluation.offline import BudgetCuts, StreamIntensity, parse_params
from pass3d_ros.tools.cli import USER_ERRORS, check_writable, partial_path, remove_stale_partials, run_tool

SEMANTIC_KITTI_IDS: np.ndarray = np.array([0, 10, 30, 31], dtype=np.uint32)  # by class id: bg, car, ped, cyc
SUMMARY = "summary.json"


class SegmentError(ValueError):
    """The command cannot run as asked (output folder, classifier choice); the message says why."""


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
    lines: LineHolder = field(default_factory=LineHolder)  # laser lines held across the frames of one --data
    intensity: StreamIntensity | None = None  # each --data's intensity map onto the training scale


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
        raise SegmentError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise SegmentError(f"{out} is not empty; pass --force to write into it")
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
        raise SegmentError(f"--out {out}: name a folder below the file-system root")
    return partial_path(resolved)


def _segment_all(datasets: list[Dataset], out: Path, build: Path, classifier: Classifier,
                 config: Stage1Config | None, png: bool, progress: bool, intensity_match: bool) -> SegmentStats:
    """Every frame's labels (and PNG) into `build`; `stats.folders` names where they will be, under `out`."""
    counts = [dataset.count() for dataset in datasets]
    total = None if None in counts else sum(c for c in counts if c is not None)
    stats = SegmentStats(budget=BudgetCuts(classifier.max_proposals),
                         intensity=StreamIntensity(intensity_match, classifier))
    with tqdm(total=total, unit="frame", desc="segment", disable=None if progress else True) as bar:
        for position, dataset in enumerate(datasets):
            sub = "." if len(datasets) == 1 else f"{position:02d}"
            folder = build / sub
            (folder / "labels").mkdir(parents=True, exist_ok=True)
            if png:
                (folder / "bev").mkdir(exist_ok=True)
            stats.folders.append(str(out if len(datasets) == 1 else out / sub))
            seen: set[str] = set()
            stats.lines.follow(position)
            for frame in dataset.frames():
                name = _safe_name(frame.name)
                if name in seen:
                    raise DatasetError(f"{dataset}: frame name {frame.name!r} repeats; outputs would overwrite")
                seen.add(name)
                labels, cluster_id = _segment_frame(str(dataset), frame.points, frame.ring, classifier, stats, config)
                to_semantic_kitti(labels).astype("<u4").tofile(folder / "labels" / f"{name}.label")
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


def _segment_frame(
    spec: str, points: np.ndarray, ring: np.ndarray | None, classifier: Classifier, stats: SegmentStats,
    config: Stage1Config | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Labels and proposal ids (-1 none) of one scan; NaN points (as KITTI raw may hold) are background in no
    proposal and never reach the core."""
    finite = np.isfinite(points[:, :3]).all(axis=1)
    keep = None if finite.all() else finite
    pts = points if keep is None else points[keep]
    rng = ring if ring is None or keep is None else ring[keep]
    labels = np.zeros(len(points), dtype=np.uint8)
    cluster_id = np.full(len(points), -1, dtype=np.int32)
    if len(pts) == 0:
        stats.stage1_ms.append(0.0)
        stats.stage2_ms.append(0.0)
        return labels, cluster_id
    result = stats.lines.propose(pts, rng, config)
    started = time.perf_counter()
    members = proposal_members(result.cluster_id, result.cluster_id2, result.n_proposals)
    stats.budget.add(sum(1 for m in members if len(m) > 0))
    stage2_points = pts if stats.intensity is None else stats.intensity(spec, pts)
    predicted = classifier.segment(stage2_points, members).labels
    stats.stage2_ms.append(1e3 * (time.perf_counter() - started))
    stats.stage1_ms.append(result.timings_ms["total"])
    if keep is None:
        return predicted.astype(np.uint8), result.cluster_id
    labels[keep] = predicted
    cluster_id[keep] = result.cluster_id
    return labels, cluster_id


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
        "intensity": stats.intensity.maps if stats.intensity else {},
        "labeled_frames": stats.labeled_frames,
        "per_class": metrics["per_class"] if metrics else None,
        "mean_iou": metrics["mean_iou"] if metrics else None,
    }


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_segment`."""
    parser = argparse.ArgumentParser(prog="pass3d_segment", description=__doc__.splitlines()[0])
    parser.add_argument("--data", action="append", required=True, metavar="SPEC",
                        help="dataset FORMAT:PATH (repeatable), e.g. semantickitti:.../sequences/08, bag:run.mcap")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder (labels/, bev/, summary.json)")
    parser.add_argument("--classifier", choices=CLASSIFIERS, help="stage-2 classifier (default network)")
    parser.add_argument("--weights", metavar="W", help="stage-2 checkpoint (default: the shipped weights)")
    parser.add_argument("--device", default="cpu", help="torch device for the network (default cpu)")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="override a Stage1Config parameter, repeatable (e.g. th_dist=0.25, "
                             "stage1.sensor=pandar64)")
    parser.add_argument("--max-proposals", type=int, default=DEFAULT_MAX_PROPOSALS, metavar="N",
                        help=f"stage 2's budget: at most N proposals per frame, the nearest first; the others are cut "
                             f"(their points background), counted and reported (default {DEFAULT_MAX_PROPOSALS})")
    parser.add_argument("--threads", type=int, default=DEFAULT_THREADS, metavar="N",
                        help=f"CPU threads: torch, OpenMP, OpenBLAS (default {DEFAULT_THREADS})")
    parser.add_argument("--intensity-match", action=argparse.BooleanOptionalAction, default=INTENSITY_MATCH,
                        help="map each --data's intensities onto the network's training scale, as the segmentation "
                        "node does (default on)")
    parser.add_argument("--no-png", action="store_true", help="skip the bird's-eye-view PNGs")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty --out this tool wrote (this run's labels/, bev/, summary.json "
                             "replace the old)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None, log: Callable[[str], None] = print) -> int:
    """Console entry point: exit 0 on success, 2 on a user error, 130 / 143 when interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("pass3d_segment", lambda: _run(args, log), errors=(SegmentError, *USER_ERRORS),
                    interrupted=f"interrupted; {args.out} left as it was")


def _run(args: argparse.Namespace, log: Callable[[str], None]) -> int:
    out = out_path(args.out)
    datasets = resolve_datasets(args.data)
    check_out_dir(out, args.force, dataset_paths(datasets))
    check_writable(out, folder=True, what="--out folder")
    check_writable(build_folder(out).parent, folder=True, what="the folder --out is built in")
    config = parse_params(args.param)
    if args.threads < 1:
        raise SegmentError(f"--threads must be >= 1, got {args.threads}")
    if args.max_proposals < 1:
        raise SegmentError(f"--max-proposals must be >= 1, got {args.max_proposals}")
    limit_threads(args.threads)
    classifier = open_classifier(args.weights, args.classifier, device=args.device, max_proposals=args.max_proposals)
    kind, weights = classifier.kind, classifier.weights
    started = time.perf_counter()
    stats = segment(args.data, out, classifier=classifier, config=config, png=not args.no_png, force=True,
                    progress=not args.no_progress, intensity_match=args.intensity_match)
    report = summary(stats, args.data, kind, weights)
    took = time.perf_counter() - started
    stage1, stage2 = report["ms_per_frame"]["stage1"], report["ms_per_frame"]["stage2"]
    log(f"segmented {stats.frames} frames ({stats.points} points) in {took:.1f} s with {kind}"
        + (f" ({weights})" if weights else "") + f"; median ms per frame: stage 1 {stage1:.1f}, stage 2 {stage2:.1f}")
    budget = report["budget"]
    if budget["proposals_cut"]:
        log(f"proposals cut by the budget (max_proposals {budget['max_proposals']}, nearest first; their points "
            f"labelled background): {budget['proposals_cut']} in {budget['frames_cut']} frame(s)")
    if report["per_class"]:
        log("\n".join(format_metrics(report["per_class"], report["mean_iou"])))
    log(f"labels: {', '.join(f + '/labels' for f in stats.folders)}"
        + ("" if args.no_png else f"; bird's-eye views: {', '.join(f + '/bev' for f in stats.folders)}")
        + f"; summary: {out / SUMMARY}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
