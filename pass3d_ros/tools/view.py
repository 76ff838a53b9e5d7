"""`pass3d_view`: show a labeled bag or a dataset in class colours with its boxes, in the rerun viewer.

    pass3d_view --data bag:demo_out/labeled_bag --spawn             # the pipeline's output (predictions)
    pass3d_view --data semantickitti:.../sequences/00 --out seq00.rrd   # ground truth, saved for `rerun seq00.rrd`

A pass3d output bag shows its predictions (`label`), any other source its ground truth (`label_gt`, dataset labels).
Needs rerun-sdk (`pip install rerun-sdk`; installed with the test dependencies of this repository).
An existing --out recording is replaced only with --force, and only when it is a rerun recording (never an input).
The recording is built in a hidden sibling
(`.NAME.partial-PID`) and renamed into place when complete; one left by a killed run is removed by the next.
Exit status: 0 done, 2 bad input, rerun-sdk or its viewer missing, 130 / 143 interrupted (no partial .rrd is left).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from pass3d_ros.data.bag import TYPESTORE, BagFile, LabelSource, is_output_cloud, read_bag
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import OutputError, check_force, dataset_paths, out_path, refuse_protected, writing
from pass3d_ros.data.partials import partial_path, remove_stale_partials
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.msgs.pointcloud2 import decode
from pass3d_ros.tools.cli import add_data, check_writable, run_tool

RRD_MAGIC = b"RRF"  # the first bytes of every rerun recording file


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_view`."""
    parser = argparse.ArgumentParser(prog="pass3d_view", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    add_data(parser, "bag:PATH or FORMAT:PATH")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", metavar="RRD", help="write a .rrd recording (open it with `rerun RRD`)")
    where.add_argument("--spawn", action="store_true", help="start the rerun viewer and stream to it")
    parser.add_argument("--limit", type=int, metavar="N", help="at most N frames from each spec")
    parser.add_argument("--force", action="store_true", help="replace an existing --out recording")
    return parser


def is_recording(path: Path) -> bool:
    """Whether `path` is a rerun recording (a file starting with rerun's `RRF` magic): what --force may replace."""
    try:
        with path.open("rb") as stream:
            return path.is_file() and stream.read(3) == RRD_MAGIC
    except OSError:
        return False


def _frames(datasets: list[Dataset], limit: int | None) -> Iterator[Frame]:
    for dataset in datasets:
        frames = (map(dataset.apply_crop, read_bag(dataset.path, labels=_bag_labels(dataset.path)))
                  if dataset.format == "bag" else dataset.frames())
        for index, frame in enumerate(frames):
            if limit is not None and index >= limit:
                break
            yield frame


def _bag_labels(path: str) -> LabelSource:
    """'predicted' for a pass3d output bag (its `label` field is the prediction), else 'truth'."""
    with BagFile(path) as bag:
        for conn, _, raw in bag.messages():
            names = decode(TYPESTORE.deserialize_cdr(raw, conn.msgtype)).dtype.names or ()
            return "predicted" if is_output_cloud(names) else "truth"
    return "truth"


def _view(args: argparse.Namespace) -> int:
    try:
        import rerun as rr
    except ImportError:
        raise UserError("pass3d_view needs rerun-sdk: pip install rerun-sdk") from None
    from pass3d_ros.drawing.view import log_frame

    if args.limit is not None and args.limit < 1:
        raise UserError("--limit must be >= 1")
    datasets = resolve_datasets(args.data)
    recording = rr.RecordingStream("pass3d_view")
    partial = None
    if args.out is not None:
        args.out = out_path(args.out)
        refuse_protected(args.out, dataset_paths(datasets))
        check_writable(args.out, folder=False, what="the recording")
        if args.out.exists() or args.out.is_symlink():
            if not args.force:
                raise UserError(f"{args.out} exists; pass --force to replace it")
            check_force(args.out, ours=is_recording, kind="a rerun recording", inputs=dataset_paths(datasets))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(args.out)
        partial = partial_path(args.out)
        try:
            recording.save(partial)
        except RuntimeError as exc:  # rerun reports file errors as RuntimeError
            raise OutputError(f"{args.out}: cannot write the recording ({exc})") from None
    else:
        if args.force:
            raise UserError("--force applies to --out only")
        try:
            recording.spawn()
        except RuntimeError as exc:  # rerun: "Failed to find Rerun Viewer executable in PATH."
            raise UserError(f"cannot start the rerun viewer ({str(exc).splitlines()[0]}); install it "
                            "(pip install rerun-sdk puts `rerun` on PATH) or write a recording with --out") from None
    try:
        count = 0
        for count, frame in enumerate(_frames(datasets, args.limit), 1):
            log_frame(recording, frame, count - 1)
        if count == 0:
            raise DatasetError(f"no frames in {', '.join(args.data)}")
        with writing(args.out or "the recording"):
            recording.flush()
            recording.disconnect()
            if partial is not None:
                os.replace(partial, args.out)
    finally:
        if partial is not None and partial.exists():
            partial.unlink()
    print(f"{count} frame(s) " + (f"written to {args.out} (open with: rerun {args.out})" if args.out else "streamed"))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Console entry point: 0 done, 2 user error, 130 / 143 interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("pass3d_view", lambda: _view(args))


if __name__ == "__main__":
    sys.exit(main())
