"""Process entry for the node executables: init, spin on one executor, clean shutdown, exit 2 on bad set-up."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from pass3d_ros.ros.node_base import PointCloudNode


def run_nodes(program: str, factories: Sequence[Callable[[], Node]], argv: list[str] | None = None) -> int:
    """Create the nodes and spin them until Ctrl-C; missing weights or bad parameters print one line and exit 2.

    Ctrl-C shuts the context down at once; a worker whose publish then fails stops quietly (no error line).
    One single-threaded executor is enough: callbacks only hand frames to each node's worker thread, and rclpy
    7.1.6's MultiThreadedExecutor stalls on long runs (ros2/rclpy#1452).
    """
    rclpy.init(args=argv if argv is not None else sys.argv)
    nodes: list[Node] = []
    executor = SingleThreadedExecutor()
    try:
        for factory in factories:
            nodes.append(factory())
            executor.add_node(nodes[-1])
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, ParameterException) as exc:
        print(f"{program}: {exc}", file=sys.stderr)
        return 2
    finally:
        for node in nodes:  # workers first: a frame in hand must not publish into a finished executor or context
            if isinstance(node, PointCloudNode):
                node.stop_worker()
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
