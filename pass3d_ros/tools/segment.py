"""`pass3d_segment`: label every point of every frame offline (stage 1 + stage 2), no ROS needed.

    pass3d_segment --data SPEC [--data ...] --out DIR [--weights W] [--classifier network|size_rules]
                   [--param KEY=VALUE ...] [--max-proposals N] [--threads N] [--no-png] [--force] [--no-progress]

Writes, per frame, `labels/NAME.label` in SemanticKITTI's format (one little-endian uint32 per point, in the scan's
point order, instance bits 0), `objects/NAME.json`, the objects as /pass3d/detections carries them ({"frame": NAME,
"objects": [{"id", "class_id", "score", "center", "size", "yaw"}, ...]}: one oriented box per labelled proposal,
fitted to its points of that class; docs/outputs.md) and, unless --no-png, `bev/NAME.png`, a bird's-eye picture:
the prediction coloured by class with its object boxes, beside the ground truth when the data has labels. NAME is the
reader's frame name. With several --data, each gets its own folder `OUT/NN/` (NN = position of the --data, from 00)
so equal frame names cannot collide. `OUT/summary.json` records the inputs, the classifier, times per stage and, when
the data has ground-truth labels, per-class precision, recall and IoU, how many proposals stage 2's budget
(max_proposals, nearest first) cut ("budget"), and the intensity map each --data got ("intensity": stage 2 sees
intensities on its training scale, as the segmentation node does; --no-intensity-match feeds them as read). `--param
KEY=VALUE` (repeatable) overrides a stage-1 parameter, as in pass3d_evaluate (stage1.sensor=pandar64 or
sensor=pandar64). The frames of one --data are a stream: laser lines found on one scan are reused by the next
(pass3d_ros.core.stage1.held_lines).

The output is built in a hidden sibling folder (`.DIR.partial-PID`) and moved into DIR only when every frame and
the summary are written, so a failed or interrupted run leaves DIR as it was (one left by a killed run is removed by
the next). DIR gets a `.pass3d_output` marker; --force writes into a non-empty DIR only when it holds one (an output
of this tool), and then the run's own entries (labels/, objects/, bev/, NN/, summary.json) replace those of the same
name; other files stay. Never into the working folder, an input or a folder holding one. A full disk is one line; DIR is
left as it was.

Label ids: car 10, pedestrian 30 (person), cyclist 31 (bicyclist), background 0 (unlabeled): PASS3D
only tells the three object classes from everything else, so background is left unnamed rather than
guessed as road or building. The `semantickitti:` reader maps these back to the project's classes.

Default classifier: `network` with the shipped weights (pass3d_ros/weights/pass3d_lite.pt), or --weights.
The work itself is `pass3d_ros.evaluation.segmenting`; this module parses the arguments and reports.
Exit status: 0 done, 2 user error (bad spec, weights, --param, non-empty --out without --force, a full disk), 130 /
143 interrupted.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

from pass3d_ros.core.metrics import format_metrics
from pass3d_ros.core.stage2 import CLASSIFIERS, open_classifier
from pass3d_ros.core.stage2.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS
from pass3d_ros.core.threads import DEFAULT_THREADS, limit_threads
from pass3d_ros.data.errors import UserError
from pass3d_ros.data.outputs import dataset_paths, out_path
from pass3d_ros.data.spec import resolve_datasets
from pass3d_ros.evaluation.offline import parse_params
from pass3d_ros.evaluation.segmenting import SUMMARY, build_folder, check_out_dir, segment, summary
from pass3d_ros.tools.cli import check_writable, run_tool


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_segment`."""
    parser = argparse.ArgumentParser(prog="pass3d_segment", description=__doc__.splitlines()[0])
    parser.add_argument("--data", action="append", required=True, metavar="SPEC",
                        help="dataset FORMAT:PATH (repeatable), e.g. semantickitti:.../sequences/08, bag:run.mcap")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder (labels/, objects/, bev/, summary.json)")
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
                        help="write into a non-empty --out this tool wrote (this run's labels/, objects/, bev/, "
                             "summary.json replace the old)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None, log: Callable[[str], None] = print) -> int:
    """Console entry point: exit 0 on success, 2 on a user error, 130 / 143 when interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("pass3d_segment", lambda: _run(args, log),
                    interrupted=f"interrupted; {args.out} left as it was")


def _run(args: argparse.Namespace, log: Callable[[str], None]) -> int:
    out = out_path(args.out)
    datasets = resolve_datasets(args.data)
    check_out_dir(out, args.force, dataset_paths(datasets))
    check_writable(out, folder=True, what="--out folder")
    check_writable(build_folder(out).parent, folder=True, what="the folder --out is built in")
    config = parse_params(args.param)
    if args.threads < 1:
        raise UserError(f"--threads must be >= 1, got {args.threads}")
    if args.max_proposals < 1:
        raise UserError(f"--max-proposals must be >= 1, got {args.max_proposals}")
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
    log(f"labels: {', '.join(f + '/labels' for f in stats.folders)}; objects: "
        f"{', '.join(f + '/objects' for f in stats.folders)}"
        + ("" if args.no_png else f"; bird's-eye views: {', '.join(f + '/bev' for f in stats.folders)}")
        + f"; summary: {out / SUMMARY}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
