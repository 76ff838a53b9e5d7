"""Datasets through the live nodes: any labelled spec becomes a temporary labelled bag, plays through both
nodes (`run_live`) and is summarised with the same keys as the offline evaluation."""

from __future__ import annotations

import tempfile
from pathlib import Path

from pass3d_ros.core.metrics import median_or_none
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.data.bag import read_bag
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.spec import DatasetError, parse_spec
from pass3d_ros.evaluation.live import LiveOptions, LiveResult, run_live
from pass3d_ros.evaluation.report import score


def live_bag(specs: list[str], workdir: Path, progress: bool) -> tuple[str, bool]:
    """(bag spec for run_live, converted?): one `bag:` spec as it is, anything else converted to a labelled
    bag in `workdir` (a frame without labels is an error naming its spec)."""
    if len(specs) == 1 and parse_spec(specs[0]).format == "bag":
        path = parse_spec(specs[0]).path
        first = next(iter(read_bag(path)), None)
        if first is None:
            raise DatasetError(f"{specs[0]}: no PointCloud2 messages")
        if first.labels is None:
            raise DatasetError(f"{specs[0]}: no point labels (label_gt field); live evaluation needs labelled data")
        return path, False
    out = workdir / "input_bag"
    convert(specs, out, with_labels=True, progress=progress, log=lambda _: None)
    return str(out), True


def evaluate_live(specs: list[str], config: Stage1Config, kind: str, weights: str | None, device: str,
                  options: LiveOptions) -> tuple[dict, LiveResult]:
    """Play the data through both live nodes (see the module notes); returns (summary, LiveResult).
    `options.node_parameters` is replaced by what `config`, `kind`, `weights` and `device` ask."""
    defaults = Stage1Config().to_dict()
    node_parameters = {
        "cluster_proposal_node": {f"stage1.{key}": value for key, value in config.to_dict().items()
                                  if value != defaults[key]},
        "segmentation_node": {"classifier": kind, "weights": weights or "", "device": device},
    }
    with tempfile.TemporaryDirectory(prefix="pass3d_evaluate_") as workdir:
        bag, converted = live_bag(specs, Path(workdir), options.progress)
        result = run_live(bag, options, node_parameters=node_parameters)
    scores = score(result)
    if result.frames_out and not result.labeled_frames:
        raise DatasetError(f"{', '.join(specs)}: outputs came back but none could be scored (no labels?)")
    stage1 = [f.stage1_ms for f in result.frames if f.stage1_ms is not None]
    stage2 = [f.stage2_ms for f in result.frames if f.stage2_ms is not None]
    summary = {
        "frames": scores["frames"],
        "classes": scores["per_class"],
        "mean_iou": scores["mean_iou"],
        "mean_iou_interval": scores.get("mean_iou_interval"),
        "ms_per_frame": {"stage1": median_or_none(stage1), "stage2": median_or_none(stage2),
                         "total": median_or_none(result.latency_ms)},
        "bag": None if converted else bag,
        "record_out": None if options.record_out is None else str(options.record_out),
        "live": scores["live"],
    }
    return summary, result
