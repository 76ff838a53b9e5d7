"""Process entry for the node executables: usage on -h/--help, init, spin on one executor, clean shutdown,
exit 2 on bad set-up."""

from __future__ import annotations

import itertools
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import rclpy
import rclpy.logging
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from pass3d_ros.ros.dds_profile import apply_shipped_profile
from pass3d_ros.ros.node_base import PointCloudNode
from pass3d_ros.ros.params import warn_unknown_overrides

HELP_FLAGS = ("-h", "--help")
_SOURCE_LOCATION = re.compile(r",? at /\S+:\d+")


def usage(program: str, factories: Sequence[Callable[[], Node]]) -> str:
    """The -h/--help text: what the executable runs and how ROS arguments reach it."""
    lines = [f"usage: {program} [-h] [--ros-args ROS_ARGUMENTS ...]", "",
             "Runs in this process, until Ctrl-C:"]
    for factory in factories:
        module = sys.modules.get(getattr(factory, "__module__", ""))
        name = re.sub(r"(?<!^)(?=[A-Z])", "_", getattr(factory, "__name__", "node")).lower()  # ClassName: class_name
        summary = ((getattr(module, "__doc__", None) or "").strip().splitlines() or [""])[0]
        lines.append(f"  {name}: {summary}" if summary else f"  {name}")
    lines += [
        "",
        "Parameters, remappings and logging go after --ros-args (ROS 2 syntax), for example:",
        f"  {program} --ros-args --params-file launch_configs/pass3d_params.yaml",
        f"  {program} --ros-args -p input_qos:=reliable -r /velodyne_points:=/points_raw",
        f"  {program} --ros-args --log-level debug",
        "Every parameter, with its default, is in launch_configs/pass3d_params.yaml.",
    ]
    return "\n".join(lines)


def ros_message(exc: BaseException) -> str:
    """An rcl error as one line: without the C source locations (`, at /project/src/parse.c:841`) and newlines."""
    text = f"unknown ROS arguments {exc}" if type(exc).__name__ == "UnknownROSArgsError" else str(exc)
    return " ".join(_SOURCE_LOCATION.sub("", text).split())


def params_file_problem(args: Sequence[str]) -> str:
    """Why a `--params-file` among the ROS arguments cannot be read (missing, a folder, unreadable), or ''."""
    ros = list(args)[list(args).index("--ros-args"):] if "--ros-args" in args else []
    for flag, value in itertools.pairwise(ros):
        if flag != "--params-file":
            continue
        path = Path(value)
        if not path.is_file():
            return f"--params-file {value}: {'is a folder' if path.is_dir() else 'no such file'}"
        try:
            path.read_bytes()
        except OSError as exc:
            return f"--params-file {value}: cannot read it ({exc.strerror})"
    return ""


def wants_help(args: Sequence[str]) -> bool:
    """Whether -h/--help comes before any --ros-args (after it, the arguments are ROS's)."""
    for arg in args:
        if arg == "--ros-args":
            return False
        if arg in HELP_FLAGS:
            return True
    return False


def run_nodes(program: str, factories: Sequence[Callable[[], Node]], argv: list[str] | None = None) -> int:
    """Create the nodes and spin them until Ctrl-C; missing weights or bad parameters print one line and exit 2.

    -h/--help (before --ros-args) prints `usage` and exits 0 without starting anything.

    Ctrl-C shuts the context down at once; a worker whose publish then fails stops quietly (no error line).
    One single-threaded executor is enough: callbacks only hand frames to each node's worker thread, and rclpy
    7.1.6's MultiThreadedExecutor stalls on long runs (ros2/rclpy#1452). The shipped Fast DDS profile is applied
    first unless the user chose one (`apply_shipped_profile`), and the line about it logged.
    """
    args = argv if argv is not None else sys.argv
    if wants_help(args):
        print(usage(program, factories))
        return 0
    problem = params_file_problem(args)
    if problem:
        print(f"{program}: {problem}", file=sys.stderr)
        return 2
    profile_note = apply_shipped_profile()
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rclpy's RCLError, UnknownROSArgsError: unparsable or unknown ROS arguments
        print(f"{program}: {ros_message(exc)}", file=sys.stderr)
        return 2
    if profile_note:
        rclpy.logging.get_logger(program).info(profile_note)
    nodes: list[Node] = []
    executor = SingleThreadedExecutor()
    try:
        for factory in factories:
            nodes.append(factory())
            executor.add_node(nodes[-1])
        warn_unknown_overrides(nodes)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, ParameterException) as exc:
        print(f"{program}: {ros_message(exc)}", file=sys.stderr)
        return 2
    except RuntimeError:  # rclpy's RCLError: Ctrl-C shut the context down after the executor's check, before its
        if rclpy.ok():  # wait set was made ("the given context is not valid"); a shutdown, as above
            raise
    finally:
        for node in nodes:  # workers first: a frame in hand must not publish into a finished executor or context
            if isinstance(node, PointCloudNode):
                node.stop_worker()
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
