"""`pass3d_evaluate`: score the pipeline on labelled datasets (`--data FORMAT:PATH`, repeatable).

Modes (one per run):
  --stage1-only   stage 1 cluster proposals: foreground recall (share of ground-truth car / pedestrian /
                  cyclist points inside a kept proposal), proposals per frame, milliseconds per frame and
                  per step, ground precision / recall where the dataset has a ground truth.
  (default)       the full pipeline (stage 2 per-class precision / recall / IoU): not yet available.
New modes register in MODES: a function (args, frames) -> summary dict, and a printer for its table.

`--json PATH` writes the summary, nested:
  {"mode": "stage1", "frames": N, "data": [specs],
   "stage1": {"foreground_recall": r | null, "foreground_points": n,
              "class_recall": {"car": r | null, "pedestrian": ..., "cyclist": ...},
              "proposals_per_frame": {"median": m, "mean": m},
              "ms_per_frame": {"median": m, "mean": m},
              "ms_per_step": {"ring": m, "ground": m, "clustering": m, "refinement": m, "total": m},
              "ground": {"precision": p | null, "recall": r | null}, "ground_frames": n},
   "config": {every Stage1Config parameter}, "per_frame": [{"frame", "points", "proposals", "ms", ...}]}
Ground keys are null when no frame has a ground truth; recall keys are null without foreground points.
Exit status: 0 done, 2 bad arguments, unusable data, or a mode that is not available yet.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tqdm import tqdm

from pass3d_ros.core.metrics import Stage1Metrics
from pass3d_ros.core.stage1 import STEPS, Stage1Config, propose, warm_up
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError, count_frames, open_dataset, parse_spec


class EvaluationUnavailableError(RuntimeError):
    """The requested evaluation mode exists in the interface but not yet in the code."""


def parse_params(items: list[str]) -> Stage1Config:
    """Stage1Config from `KEY=VALUE` overrides (values as Python literals: 0.2, 3, (0.1, 0.1, 0.4))."""
    values: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--param {item!r}: expected KEY=VALUE")
        try:
            values[key.strip()] = ast.literal_eval(text.strip())
        except (ValueError, SyntaxError) as exc:
            raise ValueError(f"--param {item!r}: {text!r} is not a number or tuple") from exc
    return Stage1Config.from_mapping(values)


def iter_frames(specs: list[str], limit: int | None, progress: bool) -> Iterator[tuple[str, Frame]]:
    """(spec, frame) over all specs, at most `limit` frames from each, with a progress bar on stderr."""
    for spec in specs:
        total = count_frames(spec)
        if limit is not None:
            total = limit if total is None else min(total, limit)
        bar = tqdm(total=total, desc=spec, unit="frame", disable=not progress, file=sys.stderr, leave=False)
        try:
            for index, frame in enumerate(open_dataset(spec)):
                if limit is not None and index >= limit:
                    break
                yield spec, frame
                bar.update(1)
        finally:
            bar.close()


def evaluate_stage1(frames: Iterator[tuple[str, Frame]], config: Stage1Config) -> dict:
    """Run stage 1 on every frame and accumulate its metrics; returns the summary with per-frame rows."""
    warm_up()
    metrics = Stage1Metrics()
    for spec, frame in frames:
        result = propose(frame.points, frame.ring, config)
        row = metrics.update_result(f"{spec}#{frame.name}", result, frame.labels, frame.ground)
        row["ring_source"] = result.ring_source
    summary = metrics.summary()
    summary["per_frame"] = metrics.per_frame
    return summary


def evaluate_full(frames: Iterator[tuple[str, Frame]], config: Stage1Config) -> dict:
    """Full pipeline evaluation (stage 2 per-class IoU): its place, until stage 2 evaluation lands here."""
    raise EvaluationUnavailableError(
        "full-pipeline evaluation (stage 2 per-class precision / recall / IoU) is not yet available; "
        "run with --stage1-only"
    )


def _fmt(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def format_stage1(summary: dict, per_frame: bool = False) -> str:
    """Human-readable table of a stage 1 summary."""
    s = summary["stage1"]
    lines = [f"stage 1 over {summary['frames']} frame(s)"]
    rows = [
        ("foreground recall", _fmt(s["foreground_recall"]) + f"  ({s['foreground_points']} points)"),
        *[(f"  {name} recall", _fmt(value)) for name, value in s["class_recall"].items()],
        ("proposals / frame", f"median {_fmt(s['proposals_per_frame']['median'], 1)}, "
                              f"mean {_fmt(s['proposals_per_frame']['mean'], 1)}"),
        ("ms / frame", f"median {_fmt(s['ms_per_frame']['median'], 2)}, mean {_fmt(s['ms_per_frame']['mean'], 2)}"),
        *[(f"  {step} ms (median)", _fmt(s["ms_per_step"].get(step), 2)) for step in STEPS if step != "total"],
        ("ground precision", _fmt(s["ground"]["precision"]) + f"  ({s['ground_frames']} frame(s) with ground truth)"),
        ("ground recall", _fmt(s["ground"]["recall"])),
    ]
    width = max(len(name) for name, _ in rows)
    lines += [f"  {name:<{width}}  {value}" for name, value in rows]
    if per_frame:
        lines.append("")
        lines.append(f"  {'frame':<48} {'points':>7} {'props':>5} {'ms':>6} {'fg rec':>6} {'gnd P':>6} {'gnd R':>6}")
        for row in summary["per_frame"]:
            lines.append(
                f"  {row['frame'][-48:]:<48} {row['points']:>7} {row['proposals']:>5} {row['ms']:>6.2f} "
                f"{_fmt(row.get('foreground_recall')):>6} {_fmt(row.get('ground_precision')):>6} "
                f"{_fmt(row.get('ground_recall')):>6}"
            )
    return "\n".join(lines)


# mode -> (evaluation, table printer)
MODES: dict[str, tuple[Callable[[Iterator[tuple[str, Frame]], Stage1Config], dict], Callable[..., str]]] = {
    "stage1": (evaluate_stage1, format_stage1),
    "full": (evaluate_full, format_stage1),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pass3d_evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", action="append", required=True, metavar="FORMAT:PATH",
                        help="dataset spec, repeatable (kitti_object:DIR, semantickitti:DIR/sequences/00, ...)")
    parser.add_argument("--stage1-only", action="store_true", help="evaluate stage 1 cluster proposals only")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the summary as JSON here")
    parser.add_argument("--limit", type=int, metavar="N", help="at most N frames from each spec")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="override a Stage1Config parameter, repeatable (e.g. th_dist=0.25)")
    parser.add_argument("--per-frame", action="store_true", help="print one row per frame too")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    mode = "stage1" if args.stage1_only else "full"
    try:
        for spec in args.data:
            parse_spec(spec)
        if args.limit is not None and args.limit < 1:
            raise ValueError("--limit must be >= 1")
        config = parse_params(args.param)
        evaluate, printer = MODES[mode]
        summary = evaluate(iter_frames(args.data, args.limit, not args.no_progress), config)
    except EvaluationUnavailableError as exc:
        print(f"pass3d_evaluate: {exc}", file=sys.stderr)
        return 2
    except (DatasetError, ValueError, FileNotFoundError, NotADirectoryError) as exc:
        print(f"pass3d_evaluate: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith("pass3d_ros."):
            raise
        print(f"pass3d_evaluate: error: the reader for this format is not available ({exc.name})", file=sys.stderr)
        return 2
    if summary["frames"] == 0:
        print(f"pass3d_evaluate: error: no frames in {', '.join(args.data)}", file=sys.stderr)
        return 2
    summary = {"mode": mode, "frames": summary["frames"], "data": list(args.data), **summary,
               "config": config.to_dict()}
    print(printer(summary, per_frame=args.per_frame))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
