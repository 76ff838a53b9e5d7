"""Stage 1 over real scans for the label-free training tools (pseudo-labels, view consistency): per scan the
finite points, the non-empty proposals and the intensities stage 2 sees, with the laser lines and the intensity map
held per spec as the segmentation node holds them for a stream."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from pass3d_ros.core.stage1 import proposal_members
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.held_lines import LineHolder
from pass3d_ros.core.stage2.intensity_match import StreamIntensityMatch
from pass3d_ros.data.frame import Frame


@dataclass
class ProposedScan:
    """One scan after stage 1: its finite points (intensity on the training scale when matched), where they sit in
    the frame, their rings, and the non-empty proposals as indices into them."""

    frame: Frame
    kept: np.ndarray  # (M,) int64: positions in frame.points of the finite points
    points: np.ndarray  # (M, 4) float32
    ring: np.ndarray | None
    members: list[np.ndarray]


def proposed_scans(frames: Iterable[tuple[str, Frame]], config: Stage1Config | None = None,
                   intensity_match: bool = True) -> Iterator[ProposedScan]:
    """Stage 1 on each (spec, frame); a new spec starts a new stream (laser lines and intensity map)."""
    lines, intensity, current = LineHolder(), StreamIntensityMatch(), None
    for spec, frame in frames:
        lines.follow(spec)
        if spec != current:
            intensity.reset()
            current = spec
        kept = np.flatnonzero(np.isfinite(frame.points[:, :3]).all(axis=1))
        points = np.ascontiguousarray(frame.points[kept])
        ring = None if frame.ring is None else frame.ring[kept]
        result = lines.propose(points, ring, config)
        members = [m for m in proposal_members(result.cluster_id, result.cluster_id2, result.n_proposals) if len(m)]
        if intensity_match:
            intensity.update(points[:, 3])
            points = intensity.on_training_scale(points)  # as stage 2 sees it
        yield ProposedScan(frame, kept, points, ring, members)
