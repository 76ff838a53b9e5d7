"""Stage-1 foreground recall and mean IoU of every simulated sensor on every mount (tilted, high, low, inverted).

`pass3d_benchmark sensors [--frames N] [--seed S] [--sensors A,B] [--mounts M,N] [--stage1-only] [--json PATH]`.
One table: a row per simulated sensor (pass3d_ros.synthetic.sensor.SENSOR_NAMES), a column per mount (MOUNTS, each a
`synthetic:` spec's height=, roll= or pitch=), each cell "stage-1 foreground recall / mean IoU" of stage 1 and the
shipped stage 2 (pass3d_ros.evaluation.offline.evaluate_full) on frames 0..N-1 of a seed never trained on (97, 98 or
99). A sensor whose driver publishes a ring field is scored again on the same frames with the field dropped
(frame.ring = None: rings recovered from the points), and the difference is printed below it. The recall and IoU do
not depend on the machine; the stage-1 milliseconds per scan (median) that follow do.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import add_weights, check_writable

# Mount name -> the spec's mount items: level at the model's 1.73 m, pitched down 5 and 10 degrees, rolled 10
# degrees, high on a bus or mast, low on a small robot, upside down.
MOUNTS: dict[str, str] = {
    "level": "",
    "pitch5": "pitch=5",
    "pitch10": "pitch=10",
    "roll10": "roll=10",
    "high3.5m": "height=3.5",
    "low0.6m": "height=0.6",
    "inverted": "roll=180",
}
UNSEEN_SEEDS: tuple[int, ...] = (97, 98, 99)  # synthetic seeds no shipped weights were trained on
CELL_WIDTH = 13


def _names(text: str | None, known: tuple[str, ...], what: str) -> list[str]:
    if not text:
        return list(known)
    names = [name.strip().lower() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in known]
    if unknown or not names:
        raise UserError(f"unknown --{what} {', '.join(unknown) or repr(text)}; known: {', '.join(known)}")
    return names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark sensors`."""
    parser.add_argument("--frames", type=int, default=3, metavar="N", help="frames per sensor and mount (default 3)")
    parser.add_argument("--seed", type=int, default=UNSEEN_SEEDS[0],
                        help=f"synthetic seed, one never trained on: {', '.join(map(str, UNSEEN_SEEDS))} (default 97)")
    parser.add_argument("--sensors", metavar="A,B", help="simulated sensors, comma-separated (default: all)")
    parser.add_argument("--mounts", metavar="M,N", help=f"mounts, comma-separated: {', '.join(MOUNTS)} (default: all)")
    parser.add_argument("--stage1-only", action="store_true", help="stage 1 alone: no mean IoU (faster)")
    add_weights(parser, "stage-2 checkpoint (default: the shipped weights)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON here")


def _score(spec: str, frames: list, config, classifier) -> dict:
    """Recall, mean IoU (None with stage 1 alone), stage-1 ms per scan and proposals per frame over `frames`."""
    from pass3d_ros.evaluation.offline import evaluate_full, evaluate_stage1

    pairs = ((spec, frame) for frame in frames)
    summary = evaluate_stage1(pairs, config) if classifier is None else evaluate_full(pairs, config, classifier)
    stage1 = summary["stage1"]
    return {"foreground_recall": stage1["foreground_recall"],
            "mean_iou": None if classifier is None else summary["mean_iou"],
            "stage1_ms": stage1["ms_per_frame"]["median"],
            "proposals": stage1["proposals_per_frame"]["mean"]}


def _cell(score: dict | None) -> str:
    if score is None:
        return "-"
    iou = "" if score["mean_iou"] is None else f"/{score['mean_iou']:.2f}"
    return f"{score['foreground_recall']:.2f}{iou}"


def _delta(without: dict | None, with_ring: dict | None) -> str:
    if without is None or with_ring is None:
        return "-"
    text = f"{without['foreground_recall'] - with_ring['foreground_recall']:+.2f}"
    if with_ring["mean_iou"] is not None:
        text += f"/{without['mean_iou'] - with_ring['mean_iou']:+.2f}"
    return text


def _print_table(title: str, mounts: list[str], rows: list[tuple[str, list[str]]]) -> None:
    label = max([len(name) for name, _ in rows] + [14])
    print(title)
    print(f"  {'sensor':<{label}}" + "".join(f"{m:>{CELL_WIDTH}}" for m in mounts))
    for name, cells in rows:
        print(f"  {name:<{label}}" + "".join(f"{c:>{CELL_WIDTH}}" for c in cells))


def run(args: argparse.Namespace) -> int:
    """Generate each sensor's frames on each mount, score them with and (ring field) without rings, print, save."""
    import pass3d_ros.synthetic  # noqa: F401  (registers the synthetic: format)
    from pass3d_ros.core.stage1 import Stage1Config
    from pass3d_ros.core.stage2 import open_classifier
    from pass3d_ros.data.outputs import write_text_atomic
    from pass3d_ros.data.spec import open_dataset
    from pass3d_ros.synthetic.sensor import SENSOR_NAMES, sensor_model

    if args.frames < 1:
        raise UserError("--frames must be at least 1")
    if args.seed < 0:
        raise UserError("--seed must not be negative")
    if args.json:
        check_writable(args.json, folder=False, what="--json file")
    sensors = _names(args.sensors, SENSOR_NAMES, "sensors")
    mounts = _names(args.mounts, tuple(MOUNTS), "mounts")
    if args.seed not in UNSEEN_SEEDS:
        print(f"sensors: note: seed {args.seed} is not one of the unseen seeds {UNSEEN_SEEDS}", file=sys.stderr)
    classifier = None if args.stage1_only else open_classifier(args.weights)
    config = Stage1Config()
    cells: list[dict] = []
    scores: dict[tuple[str, str, bool], dict] = {}
    for sensor in sensors:
        has_ring_field = sensor_model(sensor).driver != "kitti"  # a KITTI .bin carries no ring field
        for mount in mounts:
            spec = ",".join(filter(None, (f"synthetic:sensor={sensor},frames={args.frames},seed={args.seed}",
                                          MOUNTS[mount])))
            frames = list(open_dataset(spec))
            variants = [(True, frames)]
            if has_ring_field:
                variants.append((False, [replace(frame, ring=None) for frame in frames]))
            for ring_field, chosen in variants:
                label = spec if ring_field else f"{spec} (ring field dropped)"
                score = _score(label, chosen, config, classifier)
                scores[(sensor, mount, ring_field)] = score
                cells.append({"sensor": sensor, "mount": mount, "spec": spec, "ring_field": ring_field, **score})
            print(f"sensors: {sensor} {mount} done", file=sys.stderr)
    what = "stage-1 foreground recall" + ("" if classifier is None else " / mean IoU (stage 1 + stage 2)")
    rows: list[tuple[str, list[str]]] = []
    ms_rows: list[tuple[str, list[str]]] = []
    for sensor in sensors:
        rows.append((sensor, [_cell(scores.get((sensor, m, True))) for m in mounts]))
        ms_rows.append((sensor, [f"{scores[(sensor, m, True)]['stage1_ms']:.1f}" for m in mounts]))
        if (sensor, mounts[0], False) in scores:
            rows.append(("  no ring field", [_cell(scores.get((sensor, m, False))) for m in mounts]))
            rows.append(("  difference", [_delta(scores.get((sensor, m, False)), scores.get((sensor, m, True)))
                                          for m in mounts]))
            ms_rows.append(("  no ring field", [f"{scores[(sensor, m, False)]['stage1_ms']:.1f}" for m in mounts]))
    print(f"sensors: {what}, synthetic seed {args.seed}, frames 0..{args.frames - 1} per cell; mounts: "
          + ", ".join(f"{m} ({MOUNTS[m] or 'height 1.73 m'})" for m in mounts))
    _print_table(f"{what} (machine-independent):", mounts, rows)
    _print_table("stage-1 ms per scan (median; this machine):", mounts, ms_rows)
    if args.json:
        report = {"seed": args.seed, "frames": args.frames, "mounts": {m: MOUNTS[m] for m in mounts},
                  "stage2": classifier is not None, "cells": cells}
        write_text_atomic(args.json, json.dumps(report, indent=2) + "\n")
    return 0
