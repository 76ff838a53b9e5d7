"""Labeled scans for the rerun viewer (rerun-sdk): points in class colours and object boxes on one frame timeline,
for users without rviz2. rerun shows a colour per point, which the packed `rgb` float of our clouds cannot give it."""

from __future__ import annotations

from typing import Any

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_COLORS_RGB, CLASS_NAMES, NUM_CLASSES
from pass3d_ros.data.frame import Frame

UNKNOWN_RGB = np.array([60, 60, 60], dtype=np.uint8)  # points without a label (KITTI's unannotated view)
POINT_RADIUS_M = 0.03


def point_colors(labels: np.ndarray | None, count: int) -> np.ndarray:
    """(N, 3) uint8 class colours; points without labels or with an unknown label (255) are dark grey."""
    if labels is None:
        return np.tile(CLASS_COLORS_RGB[BACKGROUND], (count, 1))
    labels = np.asarray(labels, dtype=np.intp)
    known = labels < NUM_CLASSES
    colors = np.tile(UNKNOWN_RGB, (count, 1))
    colors[known] = CLASS_COLORS_RGB[labels[known]]
    return colors


def log_frame(recording: Any, frame: Frame, sequence: int) -> None:
    """One frame on the `frame` timeline: `lidar/points` (class colours) and `lidar/boxes` (the frame's
    labelled boxes, if it has any)."""
    import rerun as rr

    recording.set_time("frame", sequence=sequence)
    points = frame.points[:, :3]
    recording.log("lidar/points", rr.Points3D(points, colors=point_colors(frame.labels, len(points)),
                                               radii=POINT_RADIUS_M))
    boxes = [b for b in frame.boxes or [] if 0 < b.label < NUM_CLASSES]
    if boxes:
        recording.log("lidar/boxes", rr.Boxes3D(
            centers=[b.center for b in boxes],
            half_sizes=[np.asarray(b.size) / 2 for b in boxes],
            rotation_axis_angles=[rr.RotationAxisAngle(axis=[0, 0, 1], radians=b.yaw) for b in boxes],
            colors=[CLASS_COLORS_RGB[b.label] for b in boxes],
            labels=[CLASS_NAMES[b.label] for b in boxes],
        ))
    else:
        recording.log("lidar/boxes", rr.Clear(recursive=False))
