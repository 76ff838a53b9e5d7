"""`pass3d_pipeline`: both nodes in one process, for machines without `ros2 launch`.

One single-threaded executor is enough: callbacks only hand frames to each node's worker thread, and rclpy
7.1.6's MultiThreadedExecutor stalls on long runs (ros2/rclpy#1452).
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.segmentation_node import SegmentationNode


def main(argv: list[str] | None = None) -> int:
    """Run both nodes together; `--ros-args --params-file launch_configs/pass3d_params.yaml` sets parameters."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    nodes = []
    executor = SingleThreadedExecutor()
    try:
        nodes = [ClusterProposalNode(), SegmentationNode()]
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, OSError, ParameterException) as exc:
        print(f"pass3d_pipeline: {exc}", file=sys.stderr)
        return 2
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
