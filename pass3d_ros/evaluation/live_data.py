"""Datasets through the live nodes: any labelled spec becomes a temporary labelled bag, plays through both
nodes (`run_live`) and is summarised with the same keys as the offline evaluation."""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

from pass3d_ros.core.metrics import median_or_none
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage1.config import STAGE1_PREFIX
from pass3d_ros.data.bag import BagFile, first_frame
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.evaluation.live import LiveOptions, LiveResult, run_live
from pass3d_ros.evaluation.report import score


def live_bag(datasets: Sequence[Dataset], workdir: Path, progress: bool) -> tuple[BagFile, str | None]:
    """(the bag for run_live, opened once: the caller closes it; the `bag:` path played, None when converted):
    one `bag:` spec as it is, anything else converted to a labelled bag in `workdir` (a frame without labels is
    an error naming its spec; a cropped `bag:` is converted too)."""
    if len(datasets) == 1 and datasets[0].format == "bag" and not datasets[0].crop:
        bag = BagFile(datasets[0].path)
        try:
            first = first_frame(bag)
            if first is None:
                raise DatasetError(f"{datasets[0]}: no PointCloud2 messages")
            if first.labels is None:
                raise DatasetError(f"{datasets[0]}: no point labels (label_gt field); live evaluation needs "
                                   f"labelled data")
        except BaseException:
            bag.close()
            raise
        return bag, datasets[0].path
    out = workdir / "input_bag"
    convert(datasets, out, with_labels=True, progress=progress, log=lambda _: None)
    return BagFile(out), None


def evaluate_live(specs: Sequence[str | Dataset], config: Stage1Config, kind: str, weights: str | None, device: str,
                  options: LiveOptions) -> tuple[dict, LiveResult]:
    """Play the data through both live nodes (see the module notes); returns (summary, LiveResult).
    `options.node_parameters` is replaced by what `config`, `kind`, `weights` and `device` ask, and `tracking` off: the
    nodes' labels are scored scan by scan, as the offline mode scores them (`--tracking` scores the vote offline)."""
    defaults = Stage1Config().to_dict()
    node_parameters = {
        "cluster_proposal_node": {f"{STAGE1_PREFIX}{key}": value for key, value in config.to_dict().items()
                                  if value != defaults[key]},
        "segmentation_node": {"classifier": kind, "weights": weights or "", "device": device, "tracking": False},
    }
    datasets = resolve_datasets(specs)
    with tempfile.TemporaryDirectory(prefix="pass3d_evaluate_") as workdir:
        bag, played = live_bag(datasets, Path(workdir), options.progress)
        with bag:
            result = run_live(bag, options, node_parameters=node_parameters)
    scores = score(result)
    if result.frames_out and not result.labeled_frames:
        names = ", ".join(map(str, datasets))
        raise DatasetError(f"{names}: outputs came back but none could be scored (no labels?)")
    stage1 = [f.stage1_ms for f in result.frames if f.stage1_ms is not None]
    stage2 = [f.stage2_ms for f in result.frames if f.stage2_ms is not None]
    summary = {
        "frames": scores["frames"],
        "classes": scores["per_class"],
        "mean_iou": scores["mean_iou"],
        "mean_iou_interval": scores.get("mean_iou_interval"),
        "ms_per_frame": {"stage1": median_or_none(stage1), "stage2": median_or_none(stage2),
                         "total": median_or_none(result.latency_ms)},
        "bag": played,
        "record_out": None if options.record_out is None else str(options.record_out),
        "live": scores["live"],
    }
    return summary, result
