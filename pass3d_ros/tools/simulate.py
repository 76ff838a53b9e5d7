"""`pass3d_simulate`: write synthetic KITTI-like LiDAR scans with exact labels, or compare them with real ones.

  pass3d_simulate --frames 100 --seed 0 --out data/synth            # SemanticKITTI sequence layout
  pass3d_simulate --frames 100 --sensor vlp16 --out data/synth_vlp16 [--driver-intensity]
  pass3d_simulate --frames 100 --out data/synth_obj --format kitti_object
  pass3d_simulate --report --frames 20 [--real kitti_object:DIR ...]

--sensor picks the LiDAR (default hdl64e, KITTI's; vlp16, vlp32c, hdl32e, os1-64, os1-128, pandar64): the same
scenes, its laser table, resolution, noise and its ROS 2 driver's point order. Intensity is written in [0, 1] unless
--driver-intensity asks for the driver's scale (0..255 Velodyne and Hesai, 0..65535 Ouster reflectivity).

--report prints the realism scorecard: statistics of the synthetic frames next to the real ones (by default the
kitti_dev frames and the unlabelled kitti_unlabeled scans), each with its tolerance and PASS / FAIL (n/a where the
real data is too thin to judge); see pass3d_ros.synthetic.realism for what is measured and why each tolerance.
Below it come the descriptive statistics side by side (points per ring, range histogram, intensity quantiles).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from tqdm import tqdm

from pass3d_ros.data.frame import Frame
from pass3d_ros.data.kitti_object import write_kitti_object_frame
from pass3d_ros.data.outputs import (
    OutputError,
    check_force,
    has_marker,
    merge_into,
    out_path,
    refuse_protected,
    write_marker,
    writing,
)
from pass3d_ros.data.partials import partial_path, remove_stale_partials
from pass3d_ros.data.semantickitti import write_semantickitti_frame
from pass3d_ros.data.spec import Dataset, resolve_datasets
from pass3d_ros.synthetic.sensor import SENSOR_NAMES
from pass3d_ros.tools.cli import check_writable, run_tool

WRITERS: dict[str, Callable[[Path, Frame], None]] = {
    "semantickitti": write_semantickitti_frame,
    "kitti_object": write_kitti_object_frame,
}


def build_parser() -> argparse.ArgumentParser:
    """The command line: generation options, or --report with the real datasets to compare with."""
    parser = argparse.ArgumentParser(prog="pass3d_simulate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=None, help="number of frames (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="sequence seed: same seed, same scans (default 0)")
    parser.add_argument("--start", type=int, default=0, help="index of the first frame (default 0)")
    parser.add_argument("--out", help="output folder (a sequence folder or an object split folder)")
    parser.add_argument("--format", choices=sorted(WRITERS), default="semantickitti",
                        help="layout written (default semantickitti: velodyne/ + labels/)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty --out folder this tool wrote (it holds a .pass3d_output marker)")
    parser.add_argument("--sensor", default="hdl64e", type=str.lower, choices=SENSOR_NAMES,
                        help="LiDAR model (default hdl64e: KITTI's)")
    parser.add_argument("--driver-intensity", action="store_true",
                        help="write intensity on the sensor driver's scale instead of [0, 1]")
    parser.add_argument("--report", action="store_true",
                        help="print the realism scorecard (synthetic vs real), write nothing")
    parser.add_argument("--real", action="append", metavar="SPEC", default=None,
                        help="real dataset spec to compare with (repeatable; default: kitti_dev and kitti_unlabeled)")
    return parser


def generate(args: argparse.Namespace) -> int:
    """Write the frames, built in a hidden sibling and moved in when all are written; refuse a non-empty folder
    unless --force, and then one this tool did not write (no marker) or the working folder."""
    from pass3d_ros.synthetic.dataset import generate_frame
    from pass3d_ros.synthetic.sensor import driver_intensity, sensor_model

    out = out_path(args.out)
    refuse_protected(out)
    check_writable(out, folder=True, what="--out folder")
    if out.is_dir() and any(out.iterdir()):
        if not args.force:
            raise OutputError(f"{out}: folder is not empty (use --force to write into it)")
        check_force(out, ours=has_marker, kind="a folder of pass3d_simulate")
    write = WRITERS[args.format]
    frames = 10 if args.frames is None else args.frames
    points = 0
    sensor = sensor_model(args.sensor)
    remove_stale_partials(out.resolve())
    build = partial_path(out.resolve())
    try:
        with writing(out):
            build.mkdir(parents=True)
            write_marker(build, "pass3d_simulate")
            for index in tqdm(range(args.start, args.start + frames), desc="simulate", unit="frame", disable=None):
                frame = generate_frame(args.seed, index, sensor)
                if args.driver_intensity:
                    frame.points[:, 3] = driver_intensity(sensor, frame.points[:, 3])
                write(build, frame)
                points += len(frame.points)
            merge_into(build, out)
    except BaseException:
        shutil.rmtree(build, ignore_errors=True)
        raise
    print(f"wrote {frames} {args.sensor} frames ({points / max(frames, 1):.0f} points each on average): "
          f"{args.format}:{out}")
    return 0


def _short_name(dataset: Dataset) -> str:
    return f"{dataset.format}:{Path(dataset.path).name}"


def report(args: argparse.Namespace) -> int:
    """Print the realism scorecard, then the descriptive statistics: synthetic vs real."""
    from pass3d_ros.synthetic.realism import (
        ScanStats,
        collect,
        default_real_specs,
        default_unlabeled_specs,
        format_report,
        format_scorecard,
        scorecard,
        synthetic_frames,
    )

    frames = 10 if args.frames is None else args.frames
    real = resolve_datasets(default_real_specs() + default_unlabeled_specs() if args.real is None else args.real)
    if not real:
        print("no real dataset given or found (--real SPEC, or ../shared/data/kitti_dev)", file=sys.stderr)
    synth_stats = ScanStats(f"synthetic(seed {args.seed})")

    def synth() -> Iterator:
        for frame, material in tqdm(synthetic_frames(frames, args.seed, args.start), total=frames,
                                    desc="synthetic", unit="frame", disable=None):
            synth_stats.add(frame)
            yield frame, material

    names = ", ".join(map(str, real)) or "nothing"
    print(f"realism scorecard: {frames} synthetic frame(s) of seed {args.seed} vs {names}")
    print(format_scorecard(scorecard(synth(), real)))
    print()
    print(format_report([synth_stats] + [collect(dataset.frames(), _short_name(dataset)) for dataset in real]))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of `pass3d_simulate`; returns the exit status (2 for unusable input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.frames is not None and args.frames < 0:
        parser.error("--frames must not be negative")
    if args.start < 0 or args.seed < 0:
        parser.error("--start and --seed must not be negative")
    if not args.report and args.out is None:
        parser.error("--out DIR is required (or --report)")
    if args.report and (args.sensor != "hdl64e" or args.driver_intensity):
        parser.error("--report compares KITTI's hdl64e scans only: drop --sensor and --driver-intensity")
    if args.report and args.out is not None:
        parser.error("--report writes nothing: drop --out")
    return run_tool("pass3d_simulate", lambda: report(args) if args.report else generate(args))


if __name__ == "__main__":
    sys.exit(main())
