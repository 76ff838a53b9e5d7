"""Two full evaluations of the same frames compared class by class, with paired frame-bootstrap intervals: what
`pass3d_evaluate --paired-with` prints. Each resample draws the same frames for both runs, so what the frames share
(hard frames, easy frames) cancels and a difference of a few points can be told from noise."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pass3d_ros.classes import CLASS_NAMES, FOREGROUND
from pass3d_ros.core.metrics import interval_text, paired_iou_difference
from pass3d_ros.msgs.errors import UserError


def read_baseline(path: Path) -> dict:
    """A full run's `--json` summary with per-frame confusion matrices; UserError naming the file otherwise."""
    try:
        summary = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"--paired-with {path}: cannot read it ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"--paired-with {path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    rows = summary.get("per_frame") if isinstance(summary, dict) else None  # any JSON value may be in the file
    if (not isinstance(rows, list) or not rows or summary.get("mode") != "full"
            or any(not isinstance(row, dict) or "confusion" not in row for row in rows)):
        raise UserError(f"--paired-with {path}: not a full evaluation's --json with per-frame confusion matrices "
                        "(written by this version of pass3d_evaluate)")
    return summary


def paired(summary: dict, baseline: dict, source: str) -> dict:
    """This run minus `baseline`, per foreground class: {"with": source, "pooled_draws": [ours, theirs] or null,
    "classes": {name: {"difference", interval}}}. When both runs drew several samples (`--sample-draws`), each
    frame's confusion is pooled over its run's draws, so the difference is of the draws' pooled IoU, not of one
    draw each. UserError when the two runs did not score the same frames in the same order, or a frame's labelled
    points per class differ (the same names, other data)."""
    ours, theirs = [row["frame"] for row in summary["per_frame"]], [row["frame"] for row in baseline["per_frame"]]
    if ours != theirs:
        raise UserError(f"--paired-with {source}: it scored other frames ({len(theirs)}, this run {len(ours)}; "
                        "the same --data and --limit make a pair)")
    for mine, other in zip(summary["per_frame"], baseline["per_frame"], strict=True):
        truth_mine, truth_other = (np.asarray(row["confusion"]).sum(axis=1).tolist() for row in (mine, other))
        if truth_mine != truth_other:  # the data changed under the same names (a new dataset copy, a new world)
            raise UserError(f"--paired-with {source}: frame {mine['frame']} holds other labelled points there "
                            f"(points per class {truth_other}, this run {truth_mine}): not the same frames")
    pooled = all("confusion_draws" in row for row in summary["per_frame"] + baseline["per_frame"])
    key = "confusion_draws" if pooled else "confusion"
    first = np.array([row[key] for row in baseline["per_frame"]])
    second = np.array([row[key] for row in summary["per_frame"]])
    differences = paired_iou_difference(first, second, FOREGROUND)
    draws = [summary["draws"]["count"], baseline["draws"]["count"]] if pooled else None
    return {"with": source, "pooled_draws": draws, "classes": {CLASS_NAMES[c]: differences[c] for c in FOREGROUND}}


def format_paired(result: dict | None) -> list[str]:
    """Lines: each class's IoU difference in points and its paired interval; none without a pair."""
    if not result:
        return []
    draws = result.get("pooled_draws")
    pooled = f", each frame pooled over {draws[0]} and {draws[1]} draws" if draws else ""
    lines = [f"IoU difference, this run minus {result['with']} (paired frame bootstrap{pooled}):"]
    for name, row in result["classes"].items():
        diff = row["difference"]
        text = "n/a" if diff is None else f"{100.0 * diff:+.1f}"
        lines.append(f"  {name:<12} {text:>6}  {interval_text(row)}")
    return lines
