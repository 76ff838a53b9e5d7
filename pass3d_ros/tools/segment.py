"""`pass3d_segment`: label every point of every frame offline (stage 1 + stage 2), no ROS needed.

    pass3d_segment --data SPEC [--data ...] --out DIR [--weights W] [--classifier network|size_rules]
                   [--param KEY=VALUE ...] [--max-proposals N] [--threads N] [--nproc N] [--no-png] [--force]
                   [--no-progress]
    torchrun --nproc_per_node N [--nnodes M ...] -m pass3d_ros.tools.segment --data SPEC ... --out DIR

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
(pass3d_ros.core.stream.lines).

The output is built in a hidden sibling folder (`.DIR.partial-PID`) and moved into DIR only when every frame and
the summary are written, so a failed or interrupted run leaves DIR as it was (one left by a killed run is removed by
the next). DIR gets a `.pass3d_output` marker; --force writes into a non-empty DIR only when it holds one (an output
of this tool), and then the run's own entries (labels/, objects/, bev/, NN/, summary.json) replace those of the same
name; other files stay. Never into the working folder, an input or a folder holding one. A full disk is one line; DIR is
left as it was.

Several processes: `--nproc N` labels with N processes on this machine, started and stopped together by the launcher
pass3d_train --nproc uses (pass3d_ros.training.launcher), each with --threads threads (so N x --threads should not
exceed the cores). `torchrun --nproc_per_node N -m pass3d_ros.tools.segment ...` (without --nproc) does the same, on
several machines too through torchrun's rendezvous, with --out on a file system every machine sees. The frames of all
--data, in order, are cut into N contiguous blocks of equal size, one per process, rather than dealt out in turn: a
block is consecutive scans, so each process's frames stay a stream, and a stream learns from its first scans and keeps
adjusting what a scan's labels depend on: its laser lines and ring-field order, the full scale of its intensities and
the map of its intensities onto stage 2's training scale (pass3d_ros.core.stream). Dealt out in turn, every process
would see every stream with gaps. A process whose block starts inside a --data first replays that --data's earlier
frames through its stream (reading, input checks and stage 1; no stage 2, nothing written), so labels/ and objects/
are byte for byte those of --nproc 1. The replay costs the process with the last block up to (N-1)/N of its --data's
reading and stage 1: little for recorded scans, a lot for synthetic ones, whose reading is generating them.
--no-stream-warm-up skips it; then the first frames of each such block can get other laser lines, intensity scale or
intensity map (and so other labels) than one process gives them. Process 0 makes the hidden sibling and its folders,
each process writes its own frames' files there, and process 0 writes summary.json (metrics from the confusion matrix
summed over the processes, stage medians over every frame, "seconds", and "ranks": each process's first frame, frames,
seconds and warm-up) and moves the folder into place. A failure in any process stops them all; with --nproc the run
ends with that process's one line and exit status, DIR as it was (under torchrun, torchrun's report and status).
Starting N processes costs seconds of imports each, so --nproc pays off on long runs (docs/performance.md).

Label ids: car 10, pedestrian 30 (person), cyclist 31 (bicyclist), background 0 (unlabeled): PASS3D
only tells the three object classes from everything else, so background is left unnamed rather than
guessed as road or building. The `semantickitti:` reader maps these back to the project's classes.

Default classifier: `network` with the shipped weights (pass3d_ros/weights/pass3d_lite.pt), or --weights.
The work itself is `pass3d_ros.evaluation.segmenting`; this module parses the arguments and reports.
Exit status: 0 done, 2 user error (bad spec, weights, --param, --nproc, non-empty --out without --force, a full disk),
130 / 143 interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

from pass3d_ros.training import worker

PROG = "pass3d_segment"

# Before the seconds of imports below: a launched worker ties itself to its launcher, and Ctrl-C meanwhile is the one
# line and status 130 it is later, not a traceback (worker.starting).
with worker.starting(PROG):
    import pass3d_ros.tools.cli as cli
    from pass3d_ros.core.metrics import format_metrics
    from pass3d_ros.core.stage1.config import parse_params
    from pass3d_ros.core.stage2 import CLASSIFIERS, open_classifier
    from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS
    from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
    from pass3d_ros.core.threads import limit_threads
    from pass3d_ros.data.outputs import dataset_paths, out_path
    from pass3d_ros.data.partials import partial_prefix, process_gone, remove_stale
    from pass3d_ros.data.spec import resolve_datasets
    from pass3d_ros.evaluation.segmenting import SUMMARY, Ranks, build_folder, check_out_dir, segment, summary
    from pass3d_ros.msgs.errors import UserError
    from pass3d_ros.training import distributed, launcher


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_segment`."""
    parser = cli.RankParser(prog=PROG, description=__doc__.splitlines()[0])
    cli.add_data(parser, "dataset FORMAT:PATH (repeatable), e.g. semantickitti:.../sequences/08, bag:run.mcap")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder (labels/, objects/, bev/, summary.json)")
    parser.add_argument("--classifier", choices=CLASSIFIERS, help="stage-2 classifier (default network)")
    cli.add_weights(parser)
    parser.add_argument("--device", default="cpu", help="torch device for the network (default cpu)")
    cli.add_param(parser)
    parser.add_argument("--max-proposals", type=int, default=DEFAULT_MAX_PROPOSALS, metavar="N",
                        help=f"stage 2's budget: at most N proposals per frame, the nearest first; the others are cut "
                             f"(their points background), counted and reported (default {DEFAULT_MAX_PROPOSALS})")
    cli.add_threads(parser)
    parser.add_argument("--nproc", type=cli.number(int, 1), default=1, metavar="N",
                        help="label with N processes on this machine, each its contiguous block of the frames "
                             "(default 1; under torchrun leave it out)")
    parser.add_argument("--stream-warm-up", action=argparse.BooleanOptionalAction, default=True,
                        help="with several processes, a process whose block starts inside a --data first replays "
                             "that --data's earlier frames through its stream (reading and stage 1 only), so the "
                             "labels are those of one process (default on)")
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
    """Console entry point: exit 0 on success, 2 on a user error, 130 / 143 when interrupted. With several processes
    only rank 0 reports (see --nproc)."""
    args, argv = cli.parse_ranked(build_parser(), argv)
    if args.nproc > 1 and worker.world_size() == 1:
        return cli.run_tool(PROG, lambda: _launch(args, argv), interrupted=f"interrupted; {args.out} left as it was")
    return cli.reported(lambda: cli.run_tool(PROG, lambda: _run(args, log),
                                             interrupted=f"interrupted; {args.out} left as it was"))


def _check(args: argparse.Namespace) -> Path:
    """What can be refused before any work: the inputs, --out, --param, --threads, --max-proposals; --out's path."""
    out = out_path(args.out)
    datasets = resolve_datasets(args.data)
    check_out_dir(out, args.force, dataset_paths(datasets))
    cli.check_writable(out, folder=True, what="--out folder")
    cli.check_writable(build_folder(out).parent, folder=True, what="the folder --out is built in")
    parse_params(args.param)
    if args.threads < 1:
        raise UserError(f"--threads must be >= 1, got {args.threads}")
    if args.max_proposals < 1:
        raise UserError(f"--max-proposals must be >= 1, got {args.max_proposals}")
    return out


def _launch(args: argparse.Namespace, argv: list[str]) -> int:
    """--nproc N: refuse what can be refused once, run N workers of this command line (pass3d_ros.training.launcher),
    and after a failure remove the build folder a killed rank 0 could not (DIR itself was never touched)."""
    out = _check(args)
    status = launcher.launch("pass3d_ros.tools.segment", argv, args.nproc, PROG)
    if status != 0:
        prefix = partial_prefix(out.resolve())
        remove_stale(out.resolve(), lambda p: p.name[len(prefix):].isdigit()
                     and process_gone(int(p.name[len(prefix):])), lambda _text: None)
    return status


def _run(args: argparse.Namespace, log: Callable[[str], None]) -> int:
    out = _check(args)
    config = parse_params(args.param)
    ctx = distributed.setup(args.device)
    try:
        ranks = Ranks(ctx.rank, ctx.world, partial(distributed.all_gather, ctx), partial(distributed.broadcast, ctx))
        limit_threads(args.threads)
        classifier = open_classifier(args.weights, args.classifier, device=ctx.device,
                                     max_proposals=args.max_proposals)
        kind, weights = classifier.kind, classifier.weights
        started = time.perf_counter()
        stats = segment(args.data, out, classifier=classifier, config=config, png=not args.no_png, force=True,
                        progress=not args.no_progress, intensity_match=args.intensity_match, ranks=ranks,
                        warm=args.stream_warm_up)
    except Exception as exc:
        if not (ctx.enabled and distributed.is_peer_loss(exc)):
            raise
        if worker.LAUNCHER_ENV in os.environ:  # the launcher shows the report of the rank that failed
            return launcher.EXIT_PEER_LOST
        print(f"{PROG}: another process of this run stopped; {args.out} left as it was", file=sys.stderr)
        return 1
    finally:
        distributed.shutdown(ctx)
    if not ctx.main:
        return 0
    report = summary(stats, args.data, kind, weights)
    took = time.perf_counter() - started
    stage1, stage2 = report["ms_per_frame"]["stage1"], report["ms_per_frame"]["stage2"]
    log(f"segmented {stats.frames} frames ({stats.points} points) in {took:.1f} s with {kind}"
        + (f" ({weights})" if weights else "") + f"; median ms per frame: stage 1 {stage1:.1f}, stage 2 {stage2:.1f}"
        + (f"; {ctx.world} processes: {', '.join(str(r['frames']) for r in stats.ranks)} frames"
           if ctx.enabled else ""))
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
