"""`pass3d_view`: show a labeled bag or a dataset in class colours with its boxes, in the rerun viewer.

    pass3d_view --data bag:demo_out/labeled_bag --spawn             # the pipeline's output (predictions)
    pass3d_view --data semantickitti:.../sequences/00 --out seq00.rrd   # ground truth, saved for `rerun seq00.rrd`

A pass3d output bag shows its predictions (`label`), any other source its ground truth (`label_gt`, dataset labels).
Needs rerun-sdk (`pip install rerun-sdk`; installed with the test dependencies of this repository).
Exit status: 0 done, 2 bad input or rerun-sdk missing, 130 / 143 interrupted (no partial .rrd is left).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from pass3d_ros.data.bag import (
    TYPESTORE,
    LabelSource,
    is_output_cloud,
    iter_raw,
    parse_bag_spec,
    read_bag,
    select_topic,
)
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError, open_dataset, parse_spec
from pass3d_ros.msgs.pointcloud2 import decode
from pass3d_ros.tools.cli import check_writable, run_tool


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_view`."""
    parser = argparse.ArgumentParser(prog="pass3d_view", description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--data", action="append", required=True, metavar="SPEC", help="bag:PATH or FORMAT:PATH")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--out", type=Path, metavar="RRD", help="write a .rrd recording (open it with `rerun RRD`)")
    where.add_argument("--spawn", action="store_true", help="start the rerun viewer and stream to it")
    parser.add_argument("--limit", type=int, metavar="N", help="at most N frames from each spec")
    return parser


def _frames(specs: list[str], limit: int | None) -> Iterator[Frame]:
    for text in specs:
        spec = parse_spec(text)
        frames = read_bag(spec.path, labels=_bag_labels(spec.path)) if spec.format == "bag" else open_dataset(text)
        for index, frame in enumerate(frames):
            if limit is not None and index >= limit:
                break
            yield frame


def _bag_labels(path: str) -> LabelSource:
    """'predicted' for a pass3d output bag (its `label` field is the prediction), else 'truth'."""
    bag, topic = parse_bag_spec(path)
    for conn, _, raw in iter_raw(bag, select_topic(bag, topic)):
        names = decode(TYPESTORE.deserialize_cdr(raw, conn.msgtype)).dtype.names or ()
        return "predicted" if is_output_cloud(names) else "truth"
    return "truth"


def _view(args: argparse.Namespace) -> int:
    try:
        import rerun as rr
    except ImportError:
        raise DatasetError("pass3d_view needs rerun-sdk: pip install rerun-sdk") from None
    from pass3d_ros.evaluation.view import log_frame

    if args.limit is not None and args.limit < 1:
        raise DatasetError("--limit must be >= 1")
    for spec in args.data:
        parse_spec(spec)
    recording = rr.RecordingStream("pass3d_view")
    partial = None
    if args.out is not None:
        check_writable(args.out, folder=False, what="the recording")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        partial = args.out.with_name(f".{args.out.name}.partial-{os.getpid()}")
        try:
            recording.save(partial)
        except RuntimeError as exc:  # rerun reports file errors as RuntimeError
            raise DatasetError(f"{args.out}: cannot write the recording ({exc})") from None
    else:
        recording.spawn()
    try:
        count = 0
        for count, frame in enumerate(_frames(args.data, args.limit), 1):
            log_frame(recording, frame, count - 1)
        if count == 0:
            raise DatasetError(f"no frames in {', '.join(args.data)}")
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
