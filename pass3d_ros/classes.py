"""Class ids, names and display colours: defined here once and imported everywhere else."""

from __future__ import annotations

import numpy as np

BACKGROUND, CAR, PEDESTRIAN, CYCLIST = 0, 1, 2, 3
CLASS_NAMES: tuple[str, ...] = ("background", "car", "pedestrian", "cyclist")
FOREGROUND: tuple[int, ...] = (CAR, PEDESTRIAN, CYCLIST)
NUM_CLASSES = len(CLASS_NAMES)
# Ground-truth label of a point nobody annotated (e.g. outside KITTI's camera view): scored and trained on by no one.
IGNORE = 255

# Colours of the paper's figures: car green, pedestrian blue, cyclist pink, background grey.
CLASS_COLORS_RGB: np.ndarray = np.array(
    [[150, 150, 150], [0, 200, 0], [30, 90, 255], [255, 80, 200]], dtype=np.uint8
)


def packed_rgb(labels: np.ndarray) -> np.ndarray:
    """Per-point colours as float32 packing 0x00RRGGBB, the layout rviz's RGB8 transformer reads."""
    labels = np.asarray(labels, dtype=np.intp)
    rgb = CLASS_COLORS_RGB[np.where(labels < NUM_CLASSES, labels, BACKGROUND)].astype(np.uint32)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    return packed.view(np.float32)
