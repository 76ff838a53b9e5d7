"""`make demo`: a short synthetic drive through both live ROS nodes, evaluated, with pictures.

    python -m pass3d_ros.tools.demo [--frames 20] [--seed 8] [--sensor hdl64e] [--out demo_out]
                                    [--classifier auto|network|size_rules] [--weights W] [--force]
    make demo SENSOR=vlp16

Steps: generate a synthetic drive of the chosen LiDAR (default KITTI's HDL-64E; one street, scans 0.1 s apart, so
the node's tracker, on by default, follows its objects) with exact labels and write it as a rosbag2 (MCAP) bag; play
it in lockstep through cluster_proposal_node and segmentation_node running in this process (private DDS domain),
recording /pass3d/labeled into a second bag; score it (per-class precision / recall / IoU, mean IoU, latency, time per
stage); draw bird's-eye pictures of some recorded output frames (`bev/NAME.png`: ground truth | prediction, legend,
range rings, object boxes). The classifier is the PASS3D network with the shipped weights when they exist; otherwise
the geometric size-rules baseline, and the output says so.

Everything lands in --out (default ./demo_out, git-ignored). A folder the demo made before (it holds a
`.pass3d_demo` marker) is reused; any other non-empty folder needs --force, which adds the demo's entries beside
what is there but never replaces an entry of the same name, nor uses the working folder.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from pass3d_ros.core.metrics import Stage1Metrics
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.data.bag import read_bag
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.outputs import out_path, refuse_protected, write_text_atomic
from pass3d_ros.drawing.bev import frame_picture, output_cluster_ids, write_png
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.synthetic.sensor import SENSOR_NAMES
from pass3d_ros.tools.cli import add_weights, number, run_tool
from pass3d_ros.weights import DEFAULT_WEIGHTS

MARKER = ".pass3d_demo"
OUTPUTS = ("input_bag", "labeled_bag", "bev", "metrics.json")
BEV_FRAMES = 4


def choose_classifier(kind: str, weights: str | None) -> tuple[str, str, str]:
    """(classifier, weights or "", note for the user): auto = network with the shipped weights, else size_rules.
    The classifier is opened here once, so bad weights stop the demo before it starts the nodes."""
    if kind == "auto" and not weights and not DEFAULT_WEIGHTS.is_file():
        return "size_rules", "", (
            f"NOTE: shipped weights {DEFAULT_WEIGHTS} are absent, so this demo uses the size_rules classifier "
            "(a geometric baseline, NOT the PASS3D network). Train weights with pass3d_train to demo the network."
        )
    classifier = open_classifier(weights, "network" if kind == "auto" else kind)
    if classifier.weights is None:
        return "size_rules", "", "classifier: size_rules (geometric baseline, chosen with --classifier)"
    which = "weights" if weights else "shipped weights"
    return "network", classifier.weights, f"classifier: PASS3D network, {which} {classifier.weights}"


def prepare_out(out: Path, force: bool) -> None:
    """Create `out`, or clear the demo's own outputs from an earlier run; refuse the working folder (or one above
    it), and a foreign non-empty folder (with --force: one holding an entry the demo would replace)."""
    refuse_protected(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).exists():
        if not force:
            raise UserError(f"{out} is not empty and was not made by the demo; choose another --out or pass --force")
        clash = [name for name in OUTPUTS if (out / name).exists() or (out / name).is_symlink()]
        if clash:
            raise UserError(f"{out} was not made by the demo and holds {', '.join(clash)}, which the demo would "
                            "replace; --force never does that: choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    for name in OUTPUTS:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    (out / MARKER).write_text("made by python -m pass3d_ros.tools.demo\n")


def stage1_offline(bag: Path) -> dict:
    """Stage 1 on the input bag without ROS: foreground recall, proposals and ms per step (core timings)."""
    metrics = Stage1Metrics()
    pipeline = ScanPipeline(intensity_match=False)  # the bag is one stream, as the cluster node sees it
    for frame in read_bag(bag):
        proposed = pipeline.propose(frame.points, frame.ring)
        metrics.update_result(frame.name, proposed.result, proposed.kept_values(frame.labels))
    return metrics.summary()["stage1"]


def draw_frames(input_bag: Path, labeled_bag: Path, out: Path, count: int = BEV_FRAMES) -> tuple[list[Path], int]:
    """Bird's-eye pictures of `count` evenly spaced recorded output frames, each beside its ground truth:
    (the PNGs written, the number of panels in them)."""
    truth = {frame.stamp_ns: frame for frame in read_bag(input_bag)}
    outputs = list(zip(read_bag(labeled_bag, labels="predicted"), output_cluster_ids(labeled_bag), strict=True))
    chosen = sorted({int(k) for k in np.linspace(0, len(outputs) - 1, min(count, len(outputs)))}) if outputs else []
    folder = out / "bev"
    folder.mkdir(exist_ok=True)
    written, views = [], 0
    for position in chosen:
        frame, cluster_id = outputs[position]
        reference = truth.get(frame.stamp_ns)
        known = reference is not None and reference.labels is not None
        name = reference.name if reference is not None else frame.name
        path = folder / f"{name}.png"
        write_png(path, frame_picture(name, frame.points, frame.labels, cluster_id,
                                      truth=reference.labels if known else None,
                                      truth_points=reference.points if known else None))
        written.append(path)
        views += 2 if known else 1
    return written, views


def run(args: argparse.Namespace) -> int:
    """The demo itself; returns the exit status."""
    from pass3d_ros.evaluation.live import run_live
    from pass3d_ros.evaluation.report import format_report, score

    started = time.perf_counter()
    if args.frames < 1:
        raise UserError(f"--frames must be >= 1, got {args.frames}")
    kind, weights, note = choose_classifier(args.classifier, args.weights)
    out = out_path(args.out)
    prepare_out(out, args.force)
    print(note, flush=True)

    step = time.perf_counter()
    input_bag = out / "input_bag"
    spec = f"synthetic:drive={args.frames},seed={args.seed},sensor={args.sensor}"  # one street: the tracker follows it
    convert([spec], input_bag, with_labels=True, log=lambda _: None)
    print(f"[1/4] {args.frames} synthetic scans ({spec}) -> {input_bag} in {time.perf_counter() - step:.1f} s",
          flush=True)

    step = time.perf_counter()
    labeled_bag = out / "labeled_bag"
    result = run_live(
        input_bag,
        lockstep=True,
        node_parameters={"segmentation_node": {"classifier": kind, "weights": weights}},
        record_out=labeled_bag,
        timeout_s=120.0,
        log_level="warn",
        progress=True,
    )
    scores = score(result)
    print(f"[2/4] live run through cluster_proposal_node + segmentation_node ({kind}), lockstep, "
          f"recorded /pass3d/labeled -> {labeled_bag} in {time.perf_counter() - step:.1f} s", flush=True)

    step = time.perf_counter()
    stage1 = stage1_offline(input_bag)
    scores["classifier"] = {"kind": kind, "weights": weights or None}
    scores["stage1_offline"] = stage1
    write_text_atomic(out / "metrics.json", json.dumps(scores, indent=2) + "\n")
    print(f"[3/4] evaluated in {time.perf_counter() - step:.1f} s", flush=True)

    step = time.perf_counter()
    _, views = draw_frames(input_bag, labeled_bag, out)
    print(f"[4/4] {views} bird's-eye views in {time.perf_counter() - step:.1f} s", flush=True)

    steps = ", ".join(f"{name} {ms:.1f}" for name, ms in stage1["ms_per_step"].items())
    recall = stage1["foreground_recall"]
    print()
    print(format_report(scores))
    print(f"stage 1 core (offline, same frames): ms per step (median): {steps}; "
          f"{stage1['proposals_per_frame']['median']:.0f} proposals per frame; foreground recall "
          + ("n/a" if recall is None else f"{100 * recall:.1f} %"))
    print()
    print(note)
    print(f"input bag:        {input_bag}")
    print(f"labeled bag:      {labeled_bag}   (rviz2: play it and show /pass3d/labeled, colour by rgb)")
    print(f"metrics:          {out / 'metrics.json'}")
    print(f"bird's-eye views: {out / 'bev'}   (predicted and truth; car green, pedestrian blue, cyclist pink)")
    print(f"demo finished in {time.perf_counter() - started:.1f} s")
    lost = result.dropped + result.mismatched
    if lost:
        print(f"warning: {lost} of {result.frames_in} frames did not come back complete", file=sys.stderr)
        return 1
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line of the demo."""
    parser = argparse.ArgumentParser(prog="python -m pass3d_ros.tools.demo", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20, help="scans of the synthetic drive (default 20: 2 s)")
    parser.add_argument("--seed", type=number(int, 0), default=8,
                        help="synthetic street seed (default 8: the first from 7 whose drive holds all three classes)")
    parser.add_argument("--sensor", choices=SENSOR_NAMES, default="hdl64e",
                        help="simulated LiDAR (default hdl64e, KITTI's); its driver's point order and fields")
    parser.add_argument("--out", default="demo_out", help="output folder (default ./demo_out)")
    parser.add_argument("--classifier", choices=("auto", "network", "size_rules"), default="auto",
                        help="auto (default): the network with the shipped weights, else size_rules")
    add_weights(parser, "stage-2 checkpoint for the network (default: the shipped weights)", metavar=None)
    parser.add_argument("--force", action="store_true", help="use a non-empty --out the demo did not make")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point: 0 done, 1 frames lost on the way, 2 user error, 130 / 143 interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("demo", lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
