"""`pass3d_evaluate`: score the pipeline on labelled datasets (`--data FORMAT:PATH`, repeatable).

Modes (one per run):
  (default)       the full pipeline offline, no ROS: per frame stage 1 (`propose`) then stage 2 (the
                  classifier's `segment` on the proposals' members), scored point-wise against the frame's
                  labels: per-class precision / recall / IoU and ground-truth point counts, mean IoU over
                  car / pedestrian / cyclist, median ms per frame per stage (stage 1 = propose(); stage 2 =
                  proposal members + segment(); total = their sum per frame). The stage-1 numbers come
                  along. A frame without point labels is an error naming its spec. Points with a
                  non-finite coordinate never reach the core: they are predicted background and still
                  scored (a labelled one counts as a miss).
  --stage1-only   stage 1 cluster proposals: foreground recall (share of ground-truth car / pedestrian /
                  cyclist points inside a kept proposal), proposals per frame, milliseconds per frame and
                  per step, ground precision / recall where the dataset has a ground truth.
  --live          the live path: the data through cluster_proposal_node and segmentation_node running in
                  this process (pass3d_ros.ros.live_eval.run_live, private DDS domain), outputs matched to
                  inputs by header stamp and scored against the bag's `label` field. One `bag:PATH[#/topic]`
                  plays as it is; any other spec (synthetic:, kitti_object:, ..., or several specs) is first
                  converted into a temporary labelled bag, as `pass3d_kitti2bag --with-labels` would, and
                  deleted afterwards. Free-running at --rate x the recorded pace (frames a busy node cannot
                  take are dropped and counted) unless --lockstep (next frame only after the previous
                  output). Stage times: stage 1 = publish -> /pass3d/proposals, stage 2 = -> /pass3d/labeled,
                  total = end-to-end latency; each includes its DDS hop.

Stage 2: --classifier network (default) with --weights W, by default the shipped
pass3d_ros/weights/pass3d_lite.pt; or --classifier size_rules, the geometric baseline. --threads N sets
torch's CPU threads (default 1: on the 2-core development machine, shared with other work, one thread ran
the lite network faster than two).

`--json PATH` writes the summary, nested. Full and live runs share the segmentation keys:
  {"mode": "full" | "live", "frames": N, "data": [specs],
   "classifier": {"kind", "weights", "device", "threads"},
   "classes": {"background" | "car" | "pedestrian" | "cyclist": {"precision", "recall", "iou", "points"}},
   "mean_iou": m, "ms_per_frame": {"stage1": m, "stage2": m, "total": m}, "config": {Stage1Config}, ...}
  full adds "stage1" (as below) and "per_frame": [{"frame", "points", "proposals", "stage1_ms",
  "stage2_ms", "total_ms", "iou": {class: iou}, "mean_iou"}]; live adds "bag" (the bag played; null when
  it was a deleted temporary), "record_out", and "live": {"frames_in", "frames_out", "dropped",
  "latency_ms": {"median", "mean", "p95", "max"}, "stage_ms", "output_hz", "mismatched", "timeouts", ...}.
  stage1-only: {"mode": "stage1", "frames": N, "data": [specs],
   "stage1": {"foreground_recall": r | null, "foreground_points": n,
              "class_recall": {"car": r | null, "pedestrian": ..., "cyclist": ...},
              "proposals_per_frame": {"median": m, "mean": m},
              "ms_per_frame": {"median": m, "mean": m},
              "ms_per_step": {"ring": m, "ground": m, "clustering": m, "refinement": m, "total": m},
              "ground": {"precision": p | null, "recall": r | null}, "ground_frames": n},
   "config": {every Stage1Config parameter}, "per_frame": [{"frame", "points", "proposals", "ms", ...}]}
A metric without data is null (no ground truth of that kind, no foreground points).
Exit status: 0 done; 1 a live run lost frames it should not have (lockstep drops, mismatched outputs);
2 bad arguments, unusable data or weights.
"""

from __future__ import annotations

import argparse
import ast
import json
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.metrics import SegmentationMetrics, Stage1Metrics, format_metrics, median_or_none
from pass3d_ros.core.stage1 import STEPS, Stage1Config, proposal_members, propose, warm_up
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError, count_frames, open_dataset, parse_spec
from pass3d_ros.weights import default_weights

if TYPE_CHECKING:
    from pass3d_ros.core.segmentation import Classifier
    from pass3d_ros.ros.live_eval import LiveResult

CLASSIFIERS: tuple[str, ...] = ("network", "size_rules")
DEFAULT_THREADS = 1


class EvaluationError(ValueError):
    """The evaluation cannot run as asked (classifier, weights, options); the message says why."""


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


def resolve_classifier(kind: str | None, weights: str | Path | None) -> tuple[str, str | None]:
    """(kind, weights path or None): network by default, with the shipped weights unless `weights` is given."""
    kind = kind or "network"
    if kind not in CLASSIFIERS:
        raise EvaluationError(f"unknown classifier {kind!r}: choose {' or '.join(CLASSIFIERS)}")
    if kind == "size_rules":
        if weights:
            raise EvaluationError("--weights applies to the network classifier, not size_rules")
        return kind, None
    if weights:
        if not Path(weights).is_file():
            raise EvaluationError(f"{weights}: no such checkpoint file")
        return kind, str(weights)
    try:
        return kind, str(default_weights())
    except FileNotFoundError as exc:
        raise EvaluationError(f"{exc}; pass --weights W or --classifier size_rules") from None


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


def evaluate_full(frames: Iterator[tuple[str, Frame]], config: Stage1Config, classifier: Classifier) -> dict:
    """Stage 1 then stage 2 on every frame, scored against its labels: per-class metrics, stage times,
    and the stage-1 summary."""
    warm_up()
    classifier.warm_up()
    segmentation = SegmentationMetrics()
    stage1 = Stage1Metrics()
    for spec, frame in frames:
        if frame.labels is None:
            raise DatasetError(f"{spec}: frame {frame.name} has no point labels; full evaluation needs labelled data")
        finite = np.isfinite(frame.points[:, :3]).all(axis=1)
        keep = None if finite.all() else finite
        points = frame.points if keep is None else np.ascontiguousarray(frame.points[keep])
        ring = frame.ring if keep is None or frame.ring is None else frame.ring[keep]
        truth = frame.labels if keep is None else frame.labels[keep]
        ground = frame.ground if keep is None or frame.ground is None else frame.ground[keep]
        started = time.perf_counter()
        result = propose(points, ring, config)
        split = time.perf_counter()
        members = proposal_members(result.cluster_id, result.cluster_id2, result.n_proposals)
        labels = classifier.segment(points, members).labels
        done = time.perf_counter()
        predicted = labels
        if keep is not None:
            predicted = np.full(len(frame.points), BACKGROUND, dtype=np.uint8)
            predicted[keep] = labels
        name = f"{spec}#{frame.name}"
        row = segmentation.update(name, frame.labels, predicted, 1e3 * (split - started), 1e3 * (done - split))
        row["proposals"] = result.n_proposals
        stage1.update_result(name, result, truth, ground)
    summary = segmentation.summary()
    summary["stage1"] = stage1.summary()["stage1"]
    summary["per_frame"] = segmentation.per_frame
    return summary


def live_bag(specs: list[str], workdir: Path, progress: bool) -> tuple[str, bool]:
    """(bag spec for run_live, converted?): one `bag:` spec as it is, anything else converted to a labelled
    bag in `workdir` (a frame without labels is an error naming its spec)."""
    if len(specs) == 1 and parse_spec(specs[0]).format == "bag":
        path = parse_spec(specs[0]).path
        from pass3d_ros.data.bag import read_bag

        first = next(iter(read_bag(path)), None)
        if first is None:
            raise DatasetError(f"{specs[0]}: no PointCloud2 messages")
        if first.labels is None:
            raise DatasetError(f"{specs[0]}: no point labels (label field); live evaluation needs labelled data")
        return path, False
    from pass3d_ros.tools.kitti2bag import convert

    out = workdir / "input_bag"
    convert(specs, out, with_labels=True, progress=progress, log=lambda _: None)
    return str(out), True


def evaluate_live(specs: list[str], config: Stage1Config, kind: str, weights: str | None,
                  args: argparse.Namespace) -> tuple[dict, LiveResult]:
    """Play the data through both live nodes (see the module notes); returns (summary, LiveResult)."""
    from pass3d_ros.ros.live_eval import run_live, score

    defaults = Stage1Config().to_dict()
    node_parameters = {
        "cluster_proposal_node": {f"stage1.{key}": value for key, value in config.to_dict().items()
                                  if value != defaults[key]},
        "segmentation_node": {"classifier": kind, "weights": weights or "", "device": args.device},
    }
    with tempfile.TemporaryDirectory(prefix="pass3d_evaluate_") as workdir:
        bag, converted = live_bag(specs, Path(workdir), not args.no_progress)
        result = run_live(
            bag, lockstep=args.lockstep, rate=args.rate, node_parameters=node_parameters,
            record_out=args.record_out, timeout_s=args.timeout, keep_labels=False, force=args.force,
            log_level="warn", progress=not args.no_progress,
        )
    scores = score(result)
    if result.frames_out and not result.labeled_frames:
        raise DatasetError(f"{', '.join(specs)}: outputs came back but none could be scored (no labels?)")
    stage1 = [f.stage1_ms for f in result.frames if f.stage1_ms is not None]
    stage2 = [f.stage2_ms for f in result.frames if f.stage2_ms is not None]
    summary = {
        "frames": scores["frames"],
        "classes": scores["per_class"],
        "mean_iou": scores["mean_iou"],
        "ms_per_frame": {"stage1": median_or_none(stage1), "stage2": median_or_none(stage2),
                         "total": median_or_none(result.latency_ms)},
        "bag": None if converted else bag,
        "record_out": None if args.record_out is None else str(args.record_out),
        "live": scores["live"],
    }
    return summary, result


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


def _classifier_line(summary: dict) -> str:
    c = summary["classifier"]
    what = "size_rules (geometric baseline)" if c["kind"] == "size_rules" else f"network, weights {c['weights']}"
    return f"classifier: {what}; device {c['device']}, torch threads {c['threads']}"


def _stage_ms_line(ms: dict) -> str:
    return (f"ms / frame (median): stage 1 {_fmt(ms['stage1'], 1)}, stage 2 {_fmt(ms['stage2'], 1)}, "
            f"total {_fmt(ms['total'], 1)}")


def format_full(summary: dict, per_frame: bool = False) -> str:
    """Human-readable table of a full-pipeline summary: per-class metrics, stage times, stage-1 recap."""
    s1 = summary["stage1"]
    lines = [f"full pipeline over {summary['frames']} frame(s)", _classifier_line(summary)]
    lines += format_metrics(summary["classes"], summary["mean_iou"])
    lines.append(_stage_ms_line(summary["ms_per_frame"]))
    lines.append(f"stage 1: foreground recall {_fmt(s1['foreground_recall'])}, proposals / frame median "
                 f"{_fmt(s1['proposals_per_frame']['median'], 1)}")
    if per_frame:
        lines.append("")
        lines.append(f"  {'frame':<48} {'points':>7} {'props':>5} {'s1 ms':>7} {'s2 ms':>7} {'mIoU':>6}")
        for row in summary["per_frame"]:
            lines.append(f"  {row['frame'][-48:]:<48} {row['points']:>7} {row['proposals']:>5} "
                         f"{row['stage1_ms']:>7.1f} {row['stage2_ms']:>7.1f} {_fmt(row['mean_iou']):>6}")
    return "\n".join(lines)


def format_live(summary: dict, per_frame: bool = False) -> str:
    """Human-readable report of a live summary (per-class metrics, counters, latency, stage times)."""
    from pass3d_ros.ros.live_eval import format_report

    report = format_report({"per_class": summary["classes"], "mean_iou": summary["mean_iou"], "live": summary["live"]})
    lines = [f"live pipeline over {summary['frames']} scored frame(s)", _classifier_line(summary), report,
             _stage_ms_line(summary["ms_per_frame"])]
    if summary["record_out"]:
        lines.append(f"recorded /pass3d/labeled -> {summary['record_out']}")
    return "\n".join(lines)


PRINTERS: dict[str, Callable[..., str]] = {"stage1": format_stage1, "full": format_full, "live": format_live}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pass3d_evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data", action="append", required=True, metavar="FORMAT:PATH",
                        help="dataset spec, repeatable (kitti_object:DIR, semantickitti:DIR/sequences/00, bag:B, ...)")
    modes = parser.add_mutually_exclusive_group()
    modes.add_argument("--stage1-only", action="store_true", help="evaluate stage 1 cluster proposals only")
    modes.add_argument("--live", action="store_true", help="evaluate the live ROS path (both nodes, in process)")
    parser.add_argument("--classifier", choices=CLASSIFIERS, help="stage-2 classifier (default network)")
    parser.add_argument("--weights", metavar="W", help="stage-2 checkpoint (default: the shipped weights)")
    parser.add_argument("--device", default="cpu", help="torch device for the network: cpu (default) or cuda")
    parser.add_argument("--threads", type=int, default=DEFAULT_THREADS, metavar="N",
                        help=f"torch CPU threads (default {DEFAULT_THREADS})")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the summary as JSON here")
    parser.add_argument("--limit", type=int, metavar="N", help="at most N frames from each spec (not with --live)")
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                        help="override a Stage1Config parameter, repeatable (e.g. th_dist=0.25)")
    parser.add_argument("--per-frame", action="store_true", help="print one row per frame too")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    live = parser.add_argument_group("live mode")
    live.add_argument("--lockstep", action="store_true", help="publish the next frame only after the last output")
    live.add_argument("--rate", type=float, default=1.0, metavar="R",
                      help="free-running: R x the recorded pace (default 1; 0 = as fast as possible)")
    live.add_argument("--record-out", type=Path, metavar="BAG", help="record /pass3d/labeled into this MCAP bag")
    live.add_argument("--force", action="store_true", help="replace an existing --record-out bag")
    live.add_argument("--timeout", type=float, default=30.0, metavar="S",
                      help="seconds to wait for an output (lockstep: per frame; else after the last input)")
    return parser


def _check_args(args: argparse.Namespace) -> str:
    """The mode of this run, after checking option combinations."""
    for spec in args.data:
        parse_spec(spec)
    if args.limit is not None and args.limit < 1:
        raise EvaluationError("--limit must be >= 1")
    if args.threads < 1:
        raise EvaluationError(f"--threads must be >= 1, got {args.threads}")
    mode = "live" if args.live else "stage1" if args.stage1_only else "full"
    live_only = [name for name, given in (("--lockstep", args.lockstep), ("--record-out", args.record_out),
                                          ("--rate", args.rate != 1.0), ("--timeout", args.timeout != 30.0),
                                          ("--force", args.force)) if given]
    if mode != "live" and live_only:
        raise EvaluationError(f"{', '.join(live_only)} only apply with --live")
    if mode == "live" and args.limit is not None:
        raise EvaluationError("--limit does not apply with --live (choose the frames in the spec or bag)")
    if mode == "stage1" and (args.classifier or args.weights):
        raise EvaluationError("--classifier and --weights do not apply with --stage1-only")
    return mode


def run(args: argparse.Namespace) -> tuple[str, dict, int]:
    """Evaluate as `args` ask: (mode, summary, exit status)."""
    mode = _check_args(args)
    config = parse_params(args.param)
    frames = iter_frames(args.data, args.limit, not args.no_progress)
    if mode == "stage1":
        return mode, evaluate_stage1(frames, config), 0
    kind, weights = resolve_classifier(args.classifier, args.weights)
    import torch

    torch.set_num_threads(args.threads)
    settings = {"classifier": {"kind": kind, "weights": weights, "device": args.device, "threads": args.threads}}
    if mode == "full":
        from pass3d_ros.core.segmentation import load_classifier

        classifier = load_classifier(kind, weights, device=args.device)
        return mode, {**evaluate_full(frames, config, classifier), **settings}, 0
    summary, result = evaluate_live(args.data, config, kind, weights, args)
    status = 0
    lost = (result.dropped if args.lockstep else 0) + result.mismatched
    if lost:
        print(f"pass3d_evaluate: warning: {lost} of {result.frames_in} frames did not come back complete",
              file=sys.stderr)
        status = 1
    return mode, {**summary, **settings}, status


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        mode, summary, status = run(args)
    except (DatasetError, ValueError, OSError) as exc:
        print(f"pass3d_evaluate: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith("pass3d_ros."):
            raise
        print(f"pass3d_evaluate: error: the reader for this format is not available ({exc.name})", file=sys.stderr)
        return 2
    frames_seen = summary["live"]["frames_in"] if mode == "live" else summary["frames"]
    if frames_seen == 0:
        print(f"pass3d_evaluate: error: no frames in {', '.join(args.data)}", file=sys.stderr)
        return 2
    summary = {"mode": mode, "frames": summary["frames"], "data": list(args.data), **summary,
               "config": parse_params(args.param).to_dict()}
    print(PRINTERS[mode](summary, per_frame=args.per_frame))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"wrote {args.json}")
    return status


if __name__ == "__main__":
    sys.exit(main())
