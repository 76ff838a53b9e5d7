"""PASS3D stage 1, accelerated cluster proposal: per-scan steps, one module each (ring, ground, scanline,
refinement, split, sensor_params), run in order by `propose` (pass3d_ros.core.stage1.proposals). Every parameter lives
in `Stage1Config` (pass3d_ros.core.stage1.config). What a stream holds across scans lives in pass3d_ros.core.stream.
"""

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.proposals import (
    STEPS,
    Stage1Result,
    proposal_members,
    propose,
    synthetic_scan,
    warm_up,
)

__all__ = ["STEPS", "Stage1Config", "Stage1Result", "proposal_members", "propose", "synthetic_scan", "warm_up"]
