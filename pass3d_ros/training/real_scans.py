"""Stage 1 over real scans for the label-free training tools (pseudo-labels, view consistency): per scan the
points the input checks keep, the non-empty proposals and the intensities stage 2 sees, with one stream state per
spec (pass3d_ros.core.stream), as the nodes hold one for a live stream."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.data.frame import Frame


@dataclass
class ProposedRealScan:
    """One scan after stage 1: its finite points (intensity on the training scale when matched), where they sit in
    the frame, their rings, and the non-empty proposals as indices into them."""

    frame: Frame
    kept: np.ndarray  # (M,) int64: positions in frame.points of the finite points
    points: np.ndarray  # (M, 4) float32
    ring: np.ndarray | None
    members: list[np.ndarray]


def proposed_scans(frames: Iterable[tuple[str, Frame]], config: Stage1Config | None = None,
                   intensity_match: bool = True) -> Iterator[ProposedRealScan]:
    """Stage 1 on each (spec, frame); a new spec starts a new stream (laser lines and intensity map)."""
    pipeline = ScanPipeline(config, intensity_match=intensity_match)
    for spec, frame in frames:
        pipeline.follow(spec)
        proposed = pipeline.propose(frame.points, frame.ring)
        scan = proposed.scan
        kept = np.arange(len(frame.points)) if scan.kept is None else scan.kept
        yield ProposedRealScan(frame, kept, proposed.points, scan.ring, proposed.nonempty_members())
