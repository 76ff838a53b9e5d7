"""`pass3d_evaluate`: score the pipeline on labelled datasets (`--data FORMAT:PATH`, repeatable).

Modes (one per run):
  (default)       the full pipeline offline, no ROS: per frame stage 1 (`propose`) then stage 2 (the
                  classifier's `segment` on the proposals' members), scored point-wise against the frame's
                  labels: per-class precision / recall / IoU and ground-truth point counts, mean IoU over
                  car / pedestrian / cyclist, median ms per frame per stage (stage 1 = propose(); stage 2 =
                  proposal members + segment(); total = their sum per frame). The stage-1 numbers come
                  along, and how many background-only proposals in the front 90 degrees stage 2 called
                  an object (street clutter mistaken for road users). Car is scored twice: strictly
                  (van / truck points are background) and with the points of vans / trucks / buses left
                  out where the reader marks them; labelled objects found are counted by range bin too
                  (horizontal distance from the sensor to their points' centroid). A frame without
                  point labels is an error naming its spec. Points with a non-finite coordinate never reach the core:
                  they are predicted background and still scored (a labelled one counts as a miss).
  --stage1-only   stage 1 cluster proposals: foreground recall (share of ground-truth car / pedestrian /
                  cyclist points inside a kept proposal; a labelled point the input checks leave out counts as
                  a miss), proposals per frame, milliseconds per frame and per step, ground precision / recall
                  where the dataset has a ground truth.
  --view-agreement
                  labels unused (unlabelled scans welcome): stage 1, then the network on every proposal in each
                  of the 8 canonical views; per class (by the views' majority), the share of proposals all 8
                  views agree on, with a frame bootstrap interval. Synthetic scans read 97-99 % for cars; a
                  lower share says the network is not at home on that data (pass3d_ros.evaluation.agreement).
  --tracking      objects over time, labels optional: the full pipeline with the stream's tracker on, the same run's
                  scan-by-scan labels beside the labels with the tracks' class vote applied: per class IoU of both
                  and their paired difference, flicker (class changes per object per 10 s), id switches and
                  fragmentations per 100 object-tracks where instance ids persist (synthetic drives, SemanticKITTI;
                  --per-frame-instances where they name boxes within one frame), and the tracks' own label-free
                  flicker (pass3d_ros.evaluation.tracking). --scan-rate HZ where the stamps do not tell the rate
                  (the nuScenes parking lot's key frames: 2).
  --live          the live path: the data through cluster_proposal_node and segmentation_node running in
                  this process (pass3d_ros.evaluation.live.run_live, private DDS domain), outputs matched to
                  inputs by header stamp and scored against the bag's `label_gt` field, the segmentation node's
                  `tracking` off (scan by scan, as offline; --tracking scores the vote). One `bag:PATH[#/topic]`
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

--sample-draws N (full and view-agreement modes, network classifier): stage 2 picks 256 points of each proposal of
more points by a hash of their content and the draw (or, with --sampling draw, from a generator seeded by the
proposal's point count and the draw; a smaller proposal is read whole, its repeats drawn); N > 1
reruns the evaluation with draws 0..N-1 of that sample and adds, per class (and for the mean IoU), the IoU or view
agreement of each draw, their mean and the draw-to-draw range (draw 0's report is the default one). With
--paired-with, two runs that both drew N > 1 samples are compared on each frame's confusion pooled over its draws.
--average-draws K: stage 2 reads each proposal from K seeded draws and averages their class probabilities, an answer
that depends less on the draw for K times stage 2's work (an experiment, not the default; measured:
docs/experiments/trials-issue-37-sampling.md); with --sample-draws N, N disjoint sets of K.
--average-below P: only proposals whose points' mean winning probability in the first draw is below P, where stage 2
is unsure, so the others cost one draw.

`--json PATH` writes the summary, nested; docs/evaluate_json.md describes its keys. Full and view-agreement
runs map each spec's intensities onto the training scale (--no-intensity-match: as read).

--param KEY=VALUE: KEY as the cluster node names it (stage1.sensor) or bare (sensor); VALUE read by the parameter's
type: a number, true / false, a name without quotes (sensor=pandar64), three numbers (enlarge=0.1,0.1,0.4 or
[0.1,0.1,0.4]); Python literals ('pandar64', (0.1, 0.1, 0.4)) still work. Frames of one --data are a stream: a scan
in no firing order and without a ring field searches its laser lines once and the following frames reuse them (as
the cluster node does), so stage-1 times from the second frame on are a live stream's.
--params-file YAML: score with the nodes' settings (a pass3d_adapt folder's pass3d_params.yaml): its stage1.* under
any --param, its weights unless --weights is given.
Exit status: 0 done; 1 a live run lost frames it should not have (lockstep drops, mismatched outputs);
2 bad arguments, unusable data or weights.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage1.config import parse_params
from pass3d_ros.core.stage2 import CLASSIFIERS, open_classifier
from pass3d_ros.core.stage2.canonical import SAMPLINGS
from pass3d_ros.core.stage2.config import tracker_from_params
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS, Segmenter
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.threads import DEFAULT_THREADS, limit_threads
from pass3d_ros.data.outputs import write_text_atomic
from pass3d_ros.data.params_file import NodeSettings, read_params_file
from pass3d_ros.data.spec import Dataset, DatasetError, refuse_repeated_recordings, resolve_datasets
from pass3d_ros.evaluation.agreement import evaluate_agreement, evaluate_agreement_draws
from pass3d_ros.evaluation.live import LiveOptions
from pass3d_ros.evaluation.live_data import evaluate_live
from pass3d_ros.evaluation.offline import evaluate_draws, evaluate_full, evaluate_stage1, iter_frames
from pass3d_ros.evaluation.paired import format_paired, paired, read_baseline
from pass3d_ros.evaluation.report import PRINTERS
from pass3d_ros.evaluation.tracking import evaluate_tracking
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import (
    add_data,
    add_param,
    add_threads,
    add_weights,
    check_bag_writable,
    check_writable,
    number,
    run_tool,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pass3d_evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_data(parser, "dataset spec, repeatable (kitti_object:DIR, semantickitti:DIR/sequences/00, bag:B, ...)",
             metavar="FORMAT:PATH")
    modes = parser.add_mutually_exclusive_group()
    modes.add_argument("--stage1-only", action="store_true", help="evaluate stage 1 cluster proposals only")
    modes.add_argument("--view-agreement", action="store_true",
                       help="label-free: how often the network's class of a proposal agrees across the 8 views")
    modes.add_argument("--live", action="store_true", help="evaluate the live ROS path (both nodes, in process)")
    modes.add_argument("--tracking", action="store_true",
                       help="objects over time: IoU with and without the tracks' class vote, flicker, id switches "
                            "(labels optional)")
    parser.add_argument("--classifier", choices=CLASSIFIERS, help="stage-2 classifier (default network)")
    add_weights(parser)
    parser.add_argument("--device", default="cpu", help="torch device for the network: cpu (default) or cuda")
    add_threads(parser, f"torch CPU threads (default {DEFAULT_THREADS})")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the summary as JSON here")
    parser.add_argument("--limit", type=int, metavar="N", help="at most N frames from each spec (not with --live)")
    add_param(parser, "override a Stage1Config parameter, repeatable (e.g. th_dist=0.25, stage1.sensor=pandar64, "
                      "enlarge=0.1,0.1,0.4)")
    parser.add_argument("--params-file", type=Path, metavar="YAML",
                        help="the nodes' parameter file (pass3d_adapt's pass3d_params.yaml, or a copy of "
                             "launch_configs/pass3d_params.yaml): its stage1.* and segmentation_node's weights, "
                             "under --param and --weights")
    parser.add_argument("--max-proposals", type=int, default=DEFAULT_MAX_PROPOSALS, metavar="N",
                        help=f"stage 2's budget: at most N proposals per frame, the nearest first; the others are "
                             f"cut, counted and reported (default {DEFAULT_MAX_PROPOSALS}, the node's max_proposals; "
                             "not with --live)")
    parser.add_argument("--intensity-match", action=argparse.BooleanOptionalAction, default=INTENSITY_MATCH,
                        help="map each --data's intensities onto the network's training scale, as the segmentation "
                        "node does (default on; the map is fitted on a spec's first frames, then held)")
    parser.add_argument("--people-in-groups", action=argparse.BooleanOptionalAction, default=PEOPLE_IN_GROUPS,
                        help="read a proposal holding a group of people again person by person, as the "
                        f"segmentation node's people_in_groups does (default {'on' if PEOPLE_IN_GROUPS else 'off'}; "
                        "full and tracking modes)")
    parser.add_argument("--sample-draws", type=number(int, 1), default=1, metavar="N",
                        help="full and view-agreement modes, network classifier in process: run the evaluation "
                             "once per draw 0..N-1 of each proposal's N-point sample and report each "
                             "class's IoU (or view agreement) per draw, their mean and draw-to-draw range (JSON: "
                             "\"draws\"); draw 0 is the default sample (default 1)")
    parser.add_argument("--average-draws", type=number(int, 1, 64), default=1, metavar="K",
                        help="stage 2 reads each proposal from K seeded draws and averages their probabilities "
                             "(an experiment: an answer less tied to the draw, for K times the work; with "
                             "--sample-draws: disjoint sets of K)")
    parser.add_argument("--average-below", type=number(float, 0.0, 1.0), metavar="P",
                        help="with --average-draws: read again only proposals whose points' mean winning probability "
                             "in the first draw is below P (where stage 2 is unsure; the others cost one draw)")
    parser.add_argument("--sampling", choices=SAMPLINGS,
                        help="full and view-agreement modes, network classifier in process: how stage 2 picks "
                             "each proposal's points: "
                             "the count-seeded draw, the draw-free coverage sample, or a draw picked by the points' "
                             "content (default: the weights' own, as the nodes use it: content, coverage for "
                             "order-free weights, where --sample-draws uses draw)")
    parser.add_argument("--paired-with", type=Path, metavar="JSON",
                        help="full mode: another full run's --json on the same frames; print each class's IoU "
                             "difference (this run minus that one) with its paired frame-bootstrap interval "
                             "(JSON: \"paired\")")
    parser.add_argument("--scan-rate", type=number(float, 0.0, low_open=True), metavar="HZ",
                        help="--tracking: the scans' rate when their stamps do not tell it (default: the stamps' "
                             "median step)")
    parser.add_argument("--track", action="append", default=[], metavar="KEY=VALUE",
                        help="--tracking: a tracker setting as the segmentation node names it, repeatable "
                             "(track_fill_shapes=true, track_gate_car=2.5; docs/parameters.md); the JSON's "
                             "\"tracker\" holds every setting the run used")
    parser.add_argument("--per-frame-instances", action="store_true",
                        help="--tracking: the data's instance ids name boxes within one frame only, not objects over "
                             "time (nuscenes_parking): no ground-truth flicker, id switches or fragmentations")
    parser.add_argument("--per-frame", action="store_true", help="print one row per frame too")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    live = parser.add_argument_group("live mode")
    live.add_argument("--lockstep", action="store_true", help="publish the next frame only after the last output")
    live.add_argument("--rate", type=number(float, 0.0), default=1.0, metavar="R",
                      help="free-running: R x the recorded pace (default 1; 0 = as fast as possible)")
    live.add_argument("--record-out", type=Path, metavar="BAG", help="record /pass3d/labeled into this MCAP bag")
    live.add_argument("--force", action="store_true", help="replace an existing --record-out bag")
    live.add_argument("--timeout", type=number(float, 0.0, low_open=True), default=30.0, metavar="S",
                      help="seconds to wait for an output (lockstep: per frame; else after the last input)")
    return parser


def _check_args(args: argparse.Namespace) -> str:
    """The mode of this run, after checking option combinations."""
    if args.limit is not None and args.limit < 1:
        raise UserError("--limit must be >= 1")
    if args.threads < 1:
        raise UserError(f"--threads must be >= 1, got {args.threads}")
    if args.max_proposals < 1:
        raise UserError(f"--max-proposals must be >= 1, got {args.max_proposals}")
    mode = "live" if args.live else "stage1" if args.stage1_only else "view_agreement" if args.view_agreement \
        else "tracking" if args.tracking else "full"
    if mode != "tracking" and (args.scan_rate is not None or args.per_frame_instances or args.track):
        raise UserError("--scan-rate, --per-frame-instances and --track apply with --tracking only")
    tracker_from_params(args.track)  # a wrong --track fails now, not after the classifier loads
    live_only = [name for name, given in (("--lockstep", args.lockstep), ("--record-out", args.record_out),
                                          ("--rate", args.rate != 1.0), ("--timeout", args.timeout != 30.0),
                                          ("--force", args.force)) if given]
    if mode != "live" and live_only:
        raise UserError(f"{', '.join(live_only)} only apply with --live")
    if mode == "live" and args.max_proposals != DEFAULT_MAX_PROPOSALS:
        raise UserError("--max-proposals does not apply with --live (the node's parameter max_proposals)")
    if mode in ("live", "view_agreement", "stage1") and args.people_in_groups != PEOPLE_IN_GROUPS:
        raise UserError("--people-in-groups: full and tracking modes only (live: the node's people_in_groups)")
    if mode == "live" and args.intensity_match != INTENSITY_MATCH:
        raise UserError("--no-intensity-match does not apply with --live (the node's parameter intensity_match)")
    if mode == "live" and args.limit is not None:
        raise UserError("--limit does not apply with --live (choose the frames in the spec or bag)")
    if mode == "stage1" and (args.classifier or args.weights):
        raise UserError("--classifier and --weights do not apply with --stage1-only")
    if mode != "full" and args.paired_with:
        raise UserError("--paired-with applies to the full evaluation only")
    if mode not in ("full", "view_agreement") and args.sample_draws != 1:
        option = {"stage1": "--stage1-only", "live": "--live", "tracking": "--tracking"}[mode]
        raise UserError(f"--sample-draws applies to the full and view-agreement evaluations, not with {option}")
    if args.sampling is not None and (mode not in ("full", "view_agreement") or args.classifier == "size_rules"):
        raise UserError("--sampling applies to the full and view-agreement evaluations with the network classifier")
    if args.sampling == "coverage" and args.sample_draws != 1:
        raise UserError("--sample-draws draws the seeded sample again and again: the coverage sample has no draw")
    if args.average_draws != 1 and (mode != "full" or args.classifier == "size_rules" or args.sampling == "coverage"):
        raise UserError("--average-draws applies to the full evaluation with the network classifier's seeded draw")
    if args.average_below is not None and args.average_draws == 1:
        raise UserError("--average-below needs --average-draws K > 1")
    if args.sample_draws != 1 and args.classifier == "size_rules":
        raise UserError("--sample-draws needs the network classifier (size_rules draws no sample)")
    if mode == "view_agreement" and args.classifier == "size_rules":
        raise UserError("--view-agreement needs the network classifier (size_rules has no views)")
    return mode


def run(args: argparse.Namespace) -> tuple[str, dict, int]:
    """Evaluate as `args` ask: (mode, summary ending with the stage-1 config it ran with, exit status)."""
    datasets = resolve_datasets(args.data)
    refuse_repeated_recordings(datasets, "its frames would be scored twice")
    mode = _check_args(args)
    node = read_params_file(args.params_file) if args.params_file else NodeSettings()
    if node.weights and args.weights is None and mode != "stage1" and args.classifier in (None, "network"):
        args.weights = node.weights
    try:
        parse_params(node.stage1)
    except UserError as exc:
        raise UserError(f"--params-file {args.params_file}: {exc}") from None
    config = parse_params(node.stage1 + args.param)
    summary, status = _evaluate_mode(args, mode, datasets, config)
    return mode, {**summary, "config": config.to_dict()}, status


def _evaluate_mode(args: argparse.Namespace, mode: str, datasets: list[Dataset], config: Stage1Config
                   ) -> tuple[dict, int]:
    """The summary of `mode` on `datasets` with stage-1 `config`, and the exit status."""
    if mode == "stage1":
        frames = iter_frames(datasets, args.limit, not args.no_progress)
        return evaluate_stage1(frames, config, args.max_proposals), 0
    limit_threads(args.threads)
    classifier = open_classifier(args.weights, args.classifier, device=args.device,
                                 max_proposals=args.max_proposals)  # --live: checked before the run
    kind, weights = classifier.kind, classifier.weights
    settings = {"classifier": {"kind": kind, "weights": weights, "device": args.device, "threads": args.threads},
                "people_in_groups": args.people_in_groups}
    if mode == "tracking":
        frames = iter_frames(datasets, args.limit, not args.no_progress)
        return {**evaluate_tracking(frames, config, classifier, args.intensity_match, args.scan_rate,
                                    args.per_frame_instances, tracker_from_params(args.track),
                                    args.people_in_groups), **settings}, 0
    if mode in ("full", "view_agreement"):
        coverage = isinstance(classifier, Segmenter) and classifier.sampling == "coverage"
        sampling = args.sampling or ("draw" if args.sample_draws > 1 and coverage else None)  # coverage: no draws
        if sampling is not None:
            if not isinstance(classifier, Segmenter):
                raise UserError("--sampling needs the network classifier in this process")
            classifier.sampling = sampling
        if mode == "full":
            if isinstance(classifier, Segmenter):
                classifier.average_draws = args.average_draws
                classifier.average_below = args.average_below
                settings["classifier"]["sampling"] = classifier.sampling
                settings["classifier"]["average_draws"] = args.average_draws
                settings["classifier"]["average_below"] = args.average_below
            once = functools.partial(evaluate_full, people_in_groups=args.people_in_groups)
            drawn = functools.partial(evaluate_draws, people_in_groups=args.people_in_groups)
        else:
            if not isinstance(classifier, Segmenter):
                raise UserError("--view-agreement needs the network classifier in this process")
            settings["classifier"]["sampling"] = classifier.sampling
            once, drawn = evaluate_agreement, evaluate_agreement_draws
        if args.sample_draws > 1:  # each draw reads the frames again
            again = functools.partial(iter_frames, datasets, args.limit, not args.no_progress)
            return {**drawn(again, config, classifier, args.sample_draws, args.intensity_match), **settings}, 0
        frames = iter_frames(datasets, args.limit, not args.no_progress)
        return {**once(frames, config, classifier, args.intensity_match), **settings}, 0
    options = LiveOptions(lockstep=args.lockstep, rate=args.rate, record_out=args.record_out, timeout_s=args.timeout,
                          keep_labels=False, force=args.force, log_level="warn", progress=not args.no_progress)
    summary, result = evaluate_live(datasets, config, kind, weights, args.device, options)
    status = 0
    lost = (result.dropped if args.lockstep else 0) + result.mismatched
    if lost:
        print(f"pass3d_evaluate: warning: {lost} of {result.frames_in} frames did not come back complete",
              file=sys.stderr)
        status = 1
    return {**summary, **settings}, status


def main(argv: list[str] | None = None) -> int:
    """Console entry point: 0 done, 1 frames lost on a live run, 2 user error, 130 / 143 interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("pass3d_evaluate", lambda: _evaluate(args))


def _evaluate(args: argparse.Namespace) -> int:
    if args.json:
        check_writable(args.json, folder=False, what="--json file")
    if args.record_out:
        check_bag_writable(args.record_out, what="--record-out bag")
    baseline = read_baseline(args.paired_with) if args.paired_with else None
    try:
        mode, summary, status = run(args)
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith("pass3d_ros."):
            raise
        raise DatasetError(f"the reader for this format is not available ({exc.name})") from None
    frames_seen = summary["live"]["frames_in"] if mode == "live" else summary["frames"]
    if frames_seen == 0:
        raise DatasetError(f"no frames in {', '.join(args.data)}")
    summary = {"mode": mode, "frames": summary["frames"], "data": list(args.data), **summary}
    if baseline is not None:
        summary["paired"] = paired(summary, baseline, str(args.paired_with))
    print("\n".join([PRINTERS[mode](summary, per_frame=args.per_frame), *format_paired(summary.get("paired"))]))
    if args.json:
        write_text_atomic(args.json, json.dumps(summary, indent=2) + "\n")
        print(f"wrote {args.json}")
    return status


if __name__ == "__main__":
    sys.exit(main())
