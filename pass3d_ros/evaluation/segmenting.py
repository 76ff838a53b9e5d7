"""Offline segmenting of whole datasets: stage 1 + stage 2 on every frame, each frame's labels written in
SemanticKITTI's format, its objects as JSON (and a bird's-eye PNG), a summary.json with the stage times and, where the
data has ground truth, the metrics. The output folder is built in a hidden sibling and moved into place only when
complete. `pass3d_segment` is its command line.

Several processes (`Ranks`: pass3d_segment --nproc N, or torchrun) share one run. The frames of all --data, in order,
are cut into one contiguous block per rank (`blocks`), not dealt out frame by frame: a block is a run of consecutive
scans, so each rank's frames stay a stream (a ScanPipeline's stream learns the laser lines, the intensity scale and
the intensity map from a stream's first scans and keeps adjusting them), and a cut falls mid-stream at most
once per rank. A rank whose block starts inside a --data first warms its stream on that --data's earlier frames
(`warm`, on by default): input checks and stage 1 only, no stage 2 and nothing written, so its stream state, and hence
its labels and objects, are those of a single process, byte for byte. Without the warm-up (`warm=False`) the laser
lines, the intensity scale and the intensity map of such a rank are learned afresh from its block's first scans, and
its first frames can differ from a single process's. Rank 0 builds the hidden sibling and its folders, every rank
writes its own frames' files there, and rank 0, once every rank's counts reached it, writes the summary (confusion,
counts and times summed or pooled over the ranks, never averaged percentages) and moves the folder into place.
With several machines, --out must be on a file system every one of them sees."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.core.objects import LabelledObject, objects_json
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage2 import Classifier
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
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
from pass3d_ros.evaluation.offline import BudgetCuts, proposed_frame

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
    pipeline: ScanPipeline | None = None  # the scans' one door, holding each --data's stream state
    intensity: dict[str, str] = field(default_factory=dict)  # the intensity map each --data got (str of the map)
    ranks: list[dict] = field(default_factory=list)  # per rank: frames, first frame, seconds, warm-up frames, seconds
    seconds: float = 0.0  # from the start of the work to the summary


def _alone(value: Any) -> list[Any]:
    return [value]


def _same(value: Any) -> Any:
    return value


@dataclass(frozen=True)
class Ranks:
    """The processes a run is shared by, and the two collectives it needs: `gather` (every rank's value, in rank
    order, on every rank) and `broadcast` (rank 0's value on every rank). The default is a single process;
    pass3d_segment passes torch.distributed's."""

    rank: int = 0
    world: int = 1
    gather: Callable[[Any], list[Any]] = _alone
    broadcast: Callable[[Any], Any] = _same

    @property
    def main(self) -> bool:
        """Whether this rank builds the output folder and writes the summary."""
        return self.rank == 0


def blocks(total: int, world: int) -> list[tuple[int, int]]:
    """Each rank's [start, stop) of `total` frames in order: contiguous blocks whose sizes differ by one at most."""
    return [(total * rank // world, total * (rank + 1) // world) for rank in range(world)]


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
    ranks: Ranks | None = None,
    warm: bool = True,
) -> SegmentStats:
    """Stage 1 (`config`, default the paper's) + `classifier` on every frame of `specs`; writes labels, PNGs and
    summary.json under `out`, built in a hidden sibling and moved into place only when complete. Each --data's
    intensities reach stage 2 on the training scale (`intensity_match`), as the segmentation node does. With several
    `ranks`, each segments its block of the frames (warming its stream first when `warm`: see the module's
    docstring); rank 0 gets the whole run's stats, another rank its own share's."""
    if not specs:
        raise DatasetError("no --data given")
    ranks = ranks or Ranks()
    started = time.perf_counter()
    datasets = resolve_datasets(specs)
    out = out_path(out)
    check_out_dir(out, force, dataset_paths(datasets))
    build = build_folder(out)
    try:
        with writing(out):
            if ranks.main:
                remove_stale_partials(out.resolve())
                build.mkdir(parents=True)
                write_marker(build, "pass3d_segment")
                _make_folders(build, len(datasets), png)
            build = Path(ranks.broadcast(str(build)))  # every rank writes into rank 0's folder
            if not build.is_dir():
                raise OutputError(f"{build}: rank 0's build folder of {out} is not visible to rank {ranks.rank}; "
                                  "with several machines --out must be on a file system they all share")
            stats = _segment_all(datasets, out, build, classifier, config, png, progress and ranks.main,
                                 intensity_match, ranks, warm)
            shares = ranks.gather(_share(stats))
            if not ranks.main:
                return stats
            stats = _merged(shares, stats)
            if stats.frames == 0:
                raise DatasetError(f"{', '.join(map(str, datasets))}: no frames")
            stats.seconds = time.perf_counter() - started
            report = summary(stats, [str(spec) for spec in specs], classifier.kind, classifier.weights)
            (build / SUMMARY).write_text(json.dumps(report, indent=2) + "\n")
            _move_into_place(build, out)
    except BaseException:
        if ranks.main:
            shutil.rmtree(build, ignore_errors=True)
        raise
    return stats


def build_folder(out: Path) -> Path:
    """The hidden sibling of `out` this run builds in (`.NAME.partial-PID`)."""
    resolved = out.resolve()
    if not resolved.name:
        raise OutputError(f"--out {out}: name a folder below the file-system root")
    return partial_path(resolved)


def _make_folders(build: Path, count: int, png: bool) -> None:
    """The folders every rank writes into: labels/, objects/ (and bev/) per --data (in `NN/` with several)."""
    for position in range(count):
        folder = build / ("." if count == 1 else f"{position:02d}")
        (folder / "labels").mkdir(parents=True, exist_ok=True)
        (folder / "objects").mkdir(exist_ok=True)
        if png:
            (folder / "bev").mkdir(exist_ok=True)


def _count(dataset: Dataset) -> int:
    """The frame count of `dataset`: the reader's when it tells cheaply, else by going through them once."""
    count = dataset.count()
    return count if count is not None else sum(1 for _ in dataset.shard(lambda _k: False))


def _own_frames(dataset: Dataset, low: int, high: int, warm: bool) -> Iterator[tuple[bool, Frame]]:
    """(mine, frame) for the frames of `dataset` before `high`: positions from `low` are this rank's; the earlier
    ones come (mine False) only when `warm`, to replay the stream's learning."""
    if high <= low:
        return
    start = 0 if warm else low
    for k, frame in enumerate(dataset.shard(lambda k: start <= k < high)):
        if k >= high:
            return
        if frame is not None:
            yield k >= low, frame


def _segment_all(datasets: list[Dataset], out: Path, build: Path, classifier: Classifier,
                 config: Stage1Config | None, png: bool, progress: bool, intensity_match: bool,
                 ranks: Ranks | None = None, warm: bool = True) -> SegmentStats:
    """This rank's frames' labels (and PNGs) into `build` (its folders made); `stats.folders` names where they will
    be, under `out`, and `stats.ranks` holds this rank's one row."""
    ranks = ranks or Ranks()
    started = time.perf_counter()
    counts = [dataset.count() for dataset in datasets]
    if ranks.world > 1:
        counts = [c if c is not None else _count(d) for c, d in zip(counts, datasets, strict=True)]
    first, stop = blocks(sum(counts), ranks.world)[ranks.rank] if None not in counts else (0, None)
    total = None if stop is None else stop - first
    stats = SegmentStats(budget=BudgetCuts(classifier.max_proposals),
                         pipeline=ScanPipeline(config, classifier, intensity_match=intensity_match))
    warmed, warm_seconds, offset = 0, 0.0, 0
    with tqdm(total=total, unit="frame", desc="segment", disable=None if progress else True) as bar:
        for position, (dataset, count) in enumerate(zip(datasets, counts, strict=True)):
            sub = "." if len(datasets) == 1 else f"{position:02d}"
            folder = build / sub
            stats.folders.append(str(out if len(datasets) == 1 else out / sub))
            low = 0 if stop is None else max(first - offset, 0)
            high = (1 << 62) if stop is None else min(stop - offset, count)
            offset += count or 0
            seen: set[str] = set()
            tick = time.perf_counter()  # a warm-up frame costs its reading and its stream step
            for mine, frame in _own_frames(dataset, low, high, warm):
                name = _safe_name(frame.name)
                if name in seen:
                    raise DatasetError(f"{dataset}: frame name {frame.name!r} repeats; outputs would overwrite")
                seen.add(name)
                if not mine:
                    proposed_frame(stats.pipeline, str(dataset), frame)
                    warm_seconds += time.perf_counter() - tick
                    warmed += 1
                    tick = time.perf_counter()
                    continue
                labels, cluster_id, objects = _segment_frame(str(dataset), frame, stats)
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
                tick = time.perf_counter()
    if stats.frames == 0 and ranks.world == 1:
        raise DatasetError(f"{', '.join(map(str, datasets))}: no frames")
    stats.intensity = dict(stats.pipeline.stream.maps)
    stats.seconds = time.perf_counter() - started
    stats.ranks = [{"rank": ranks.rank, "first_frame": first, "frames": stats.frames,
                    "seconds": round(stats.seconds, 3), "warm_frames": warmed, "warm_seconds": round(warm_seconds, 3)}]
    return stats


def _share(stats: SegmentStats) -> dict:
    """What rank 0 needs of a rank's stats to write the summary (small and picklable)."""
    return {"frames": stats.frames, "points": stats.points, "labeled_frames": stats.labeled_frames,
            "stage1_ms": stats.stage1_ms, "stage2_ms": stats.stage2_ms, "matrix": stats.confusion.matrix,
            "frame_matrices": stats.confusion.frames, "budget": (stats.budget.proposals, stats.budget.frames),
            "intensity": stats.intensity, "ranks": stats.ranks}


def _merged(shares: list[dict], mine: SegmentStats) -> SegmentStats:
    """The whole run's stats from every rank's share (in rank order, hence frame order): counts and confusion
    matrices summed, per-frame times pooled, the first intensity map of each --data kept."""
    if len(shares) == 1:
        return mine
    stats = SegmentStats(folders=mine.folders, budget=BudgetCuts(mine.budget.max_proposals), pipeline=mine.pipeline)
    for share in shares:
        stats.frames += share["frames"]
        stats.points += share["points"]
        stats.labeled_frames += share["labeled_frames"]
        stats.stage1_ms += share["stage1_ms"]
        stats.stage2_ms += share["stage2_ms"]
        stats.confusion.matrix += share["matrix"]
        stats.confusion.frames += share["frame_matrices"]
        stats.budget.proposals += share["budget"][0]
        stats.budget.frames += share["budget"][1]
        for key, value in share["intensity"].items():
            stats.intensity.setdefault(key, value)
        stats.ranks += share["ranks"]
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


def _segment_frame(spec: str, frame: Frame, stats: SegmentStats) -> tuple[np.ndarray, np.ndarray,
                                                                          list[LabelledObject]]:
    """Labels, cluster ids (-1 none) and objects of one scan as the nodes publish them (core.objects.frame_objects),
    through its stream's input checks: points they leave out (non-finite, as KITTI raw may hold, or absurd) are
    background in no proposal and never reach the core."""
    proposed = proposed_frame(stats.pipeline, spec, frame)
    if proposed.empty:
        stats.stage1_ms.append(0.0)
        stats.stage2_ms.append(0.0)
        return np.zeros(len(frame.points), dtype=np.uint8), np.full(len(frame.points), -1, dtype=np.int32), []
    stats.budget.add(len(proposed.nonempty_members()))
    labelled = stats.pipeline.segment(proposed)
    stats.stage2_ms.append(labelled.stage2_ms)
    stats.stage1_ms.append(proposed.result.timings_ms["total"])
    labels, cluster_id = labelled.published_in_input(len(frame.points))
    return labels, cluster_id, labelled.published.objects


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
        "intensity": stats.intensity,
        "labeled_frames": stats.labeled_frames,
        "per_class": metrics["per_class"] if metrics else None,
        "mean_iou": metrics["mean_iou"] if metrics else None,
        "seconds": round(stats.seconds, 3),
        "ranks": stats.ranks,
    }
