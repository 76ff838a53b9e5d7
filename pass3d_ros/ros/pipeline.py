"""`pass3d_pipeline`: both nodes in one process, for machines without `ros2 launch`; `--help` says how to run it."""

from __future__ import annotations

import sys

from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.run import run_nodes


def main(argv: list[str] | None = None) -> int:
    """Run both nodes together, joined in memory; `--ros-args --params-file launch_configs/pass3d_params.yaml`
    sets parameters."""
    return run_nodes("pass3d_pipeline", in_memory_factories(), argv)


if __name__ == "__main__":
    sys.exit(main())
