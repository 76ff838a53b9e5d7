"""`pass3d_pseudo_label`: unlabelled scans -> a pseudo-labelled SemanticKITTI sequence for self-training.

    pass3d_pseudo_label --data SPEC [--data ...] --out DIR [--weights W] [--min-confidence C] [--param KEY=VALUE]
                        [--no-intensity-match] [--force] [--no-progress]

Per scan: stage 1, then the network on every proposal in all 8 canonical views. A proposal all 8 views give the same
class, with a median view-averaged confidence of at least C (default 0.9), keeps its points with the view-averaged
labels; the points of the other proposals are left out of the written scan; everything outside a proposal is
background (pass3d_ros.training.pseudo_labels). Writes DIR/velodyne/NNNNNN.bin and DIR/labels/NNNNNN.label (frames
numbered in order across every --data) and DIR/summary.json (what was kept per class). Train on it with
`pass3d_train --data semantickitti:DIR`. Input labels, if any, are never read: use it on unlabelled scans.

DIR is built in a hidden sibling and moved into place when complete (a full disk leaves nothing); an existing DIR
needs --force, which replaces only a folder this tool wrote (it holds a `.pass3d_output` marker) or an empty one,
never an input, a folder holding one or the working folder.
Exit status: 0 done, 2 user error, 130 / 143 interrupted.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Iterator
from dataclasses import replace

from pass3d_ros.core.stage1.config import parse_params
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.segmentation import Segmenter
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.threads import limit_threads
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import marked_folder_out, swap_into_place, write_marker, writing
from pass3d_ros.data.partials import partial_path, remove_stale_partials
from pass3d_ros.data.semantickitti import write_semantickitti_frame
from pass3d_ros.data.spec import DatasetError, resolve_datasets
from pass3d_ros.evaluation.offline import iter_frames
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import add_data, add_param, add_threads, add_weights, check_writable, number, run_tool
from pass3d_ros.training.pseudo_labels import DEFAULT_MIN_CONFIDENCE, PseudoLabelStats, pseudo_label_frames

PROG = "pass3d_pseudo_label"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_data(parser, "unlabelled scans, repeatable")
    parser.add_argument("--out", required=True, metavar="DIR", help="the pseudo-labelled sequence folder")
    add_weights(parser)
    parser.add_argument("--min-confidence", type=number(float, 0.0, 1.0), default=DEFAULT_MIN_CONFIDENCE, metavar="C",
                        help="median view-averaged confidence a kept proposal needs "
                        f"(default {DEFAULT_MIN_CONFIDENCE})")
    add_param(parser, "override a stage-1 parameter, repeatable (as in pass3d_evaluate)")
    parser.add_argument("--intensity-match", action=argparse.BooleanOptionalAction, default=INTENSITY_MATCH,
                        help="intensities onto the training scale, as the segmentation node does (default on)")
    add_threads(parser, "torch CPU threads")
    parser.add_argument("--force", action="store_true", help="replace an existing --out this tool wrote")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _numbered(frames: Iterator[Frame]) -> Iterator[Frame]:
    """Frames renamed 000000, 000001, ... in order (names of several --data could collide)."""
    for index, frame in enumerate(frames):
        yield replace(frame, name=f"{index:06d}")


def _run(args: argparse.Namespace) -> int:
    if args.threads < 1:
        raise UserError(f"--threads must be >= 1, got {args.threads}")
    datasets = resolve_datasets(args.data)
    out = marked_folder_out(args.out, datasets, args.force, "a pseudo-label folder")
    config = parse_params(args.param)
    check_writable(out, folder=True, what="--out folder")
    limit_threads(args.threads)
    segmenter = open_classifier(args.weights, "network")
    if not isinstance(segmenter, Segmenter):
        raise UserError("pseudo-labels need the network classifier")
    segmenter.warm_up()
    remove_stale_partials(out)
    build = partial_path(out)
    stats = PseudoLabelStats()
    try:
        with writing(out):
            build.mkdir(parents=True)
            write_marker(build, PROG)
            frames = iter_frames(datasets, None, not args.no_progress)
            for frame in _numbered(pseudo_label_frames(frames, config, segmenter, args.min_confidence,
                                                       args.intensity_match, stats)):
                write_semantickitti_frame(build, frame)
            if stats.frames == 0:
                raise DatasetError(f"no frames in {', '.join(args.data)}")
            summary = {"data": list(args.data), "weights": segmenter.weights, "min_confidence": args.min_confidence,
                       "intensity_match": args.intensity_match, **stats.summary()}
            (build / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
            swap_into_place(build, out)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise
    kept = ", ".join(f"{n} {name}" for name, n in summary["kept"].items())
    print(f"{stats.frames} scans -> {out}: kept {kept} proposals; left out {stats.left_out} "
          f"({stats.points_left_out} points)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Console entry point."""
    args = build_parser().parse_args(argv)
    return run_tool(PROG, lambda: _run(args))


if __name__ == "__main__":
    sys.exit(main())
