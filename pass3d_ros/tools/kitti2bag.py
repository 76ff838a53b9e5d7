"""`pass3d_kitti2bag`: dataset frames (any `--data FORMAT:PATH`) -> a rosbag2 of PointCloud2 messages.

The command line only; the conversion (stamps, fields, write-then-rename) is `pass3d_ros.data.bag_convert`.
"""

from __future__ import annotations

import argparse
import sys

from pass3d_ros.data.bag import STORAGES, VERSIONS, topic_name_problem
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.outputs import OutputError, out_path
from pass3d_ros.tools.cli import add_data, check_bag_writable, run_tool


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_kitti2bag`."""
    parser = argparse.ArgumentParser(prog="pass3d_kitti2bag", description=__doc__.splitlines()[0])
    add_data(parser, "dataset FORMAT:PATH (repeatable), e.g. semantickitti:.../sequences/00")
    parser.add_argument("--out", required=True, metavar="BAG", help="rosbag2 folder to create")
    parser.add_argument("--storage", choices=sorted(STORAGES), default="mcap", help="storage plugin (default mcap)")
    parser.add_argument("--rosbag-version", type=int, choices=VERSIONS, default=9,
                        help="rosbag2 metadata version: 9 (Jazzy, default) or 8 (Humble)")
    parser.add_argument("--topic", default="/velodyne_points", help="topic (default /velodyne_points)")
    parser.add_argument("--frame-id", default="velodyne", help="header frame_id (default velodyne)")
    parser.add_argument("--with-labels", action="store_true",
                        help="add a uint8 `label_gt` field (data must have labels)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing BAG (only a bag; never an input or the working folder)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Console entry point: exit 0 on success, 2 on a user error, 130 / 143 when interrupted."""
    args = build_parser().parse_args(argv)
    return run_tool("pass3d_kitti2bag", lambda: _convert(args), interrupted=f"interrupted, {args.out} not written")


def check_arguments(args: argparse.Namespace) -> None:
    """OutputError naming the argument for an empty --out or --frame-id, or a --topic ROS 2 would refuse."""
    out_path(args.out)
    problem = topic_name_problem(args.topic)
    if problem is not None:
        raise OutputError(f"--topic {args.topic!r} is not a valid ROS 2 topic name: {problem}")
    if not args.frame_id.strip():
        raise OutputError("--frame-id is empty; the clouds need a frame to be shown in (default velodyne)")


def _convert(args: argparse.Namespace) -> int:
    check_arguments(args)
    check_bag_writable(args.out)
    stats = convert(
        args.data,
        args.out,
        storage=args.storage,
        version=args.rosbag_version,
        topic=args.topic,
        frame_id=args.frame_id,
        with_labels=args.with_labels,
        force=args.force,
        progress=not args.no_progress,
        log=lambda text: print(text, file=sys.stderr),
    )
    span = (stats.last_stamp_ns - stats.first_stamp_ns) / 1e9
    print(
        f"wrote {stats.frames} frames ({stats.points} points, {span:.1f} s) to {args.out} "
        f"[{args.storage}, rosbag2 v{args.rosbag_version}] on {args.topic}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
