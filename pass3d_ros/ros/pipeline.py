"""`pass3d_pipeline`: both nodes in one process, for machines without `ros2 launch`."""

from __future__ import annotations

import sys

from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.run import run_nodes
from pass3d_ros.ros.segmentation_node import SegmentationNode


def main(argv: list[str] | None = None) -> int:
    """Run both nodes together; `--ros-args --params-file launch_configs/pass3d_params.yaml` sets parameters."""
    return run_nodes("pass3d_pipeline", [ClusterProposalNode, SegmentationNode], argv)


if __name__ == "__main__":
    sys.exit(main())
