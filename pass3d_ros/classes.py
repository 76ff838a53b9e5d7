"""Class ids, names and display colours: defined here once and imported everywhere else."""

from __future__ import annotations

import numpy as np

BACKGROUND, CAR, PEDESTRIAN, CYCLIST = 0, 1, 2, 3
CLASS_NAMES: tuple[str, ...] = ("background", "car", "pedestrian", "cyclist")
FOREGROUND: tuple[int, ...] = (CAR, PEDESTRIAN, CYCLIST)
NUM_CLASSES = len(CLASS_NAMES)

# Colours of the paper's figures: car green, pedestrian blue, cyclist pink, background grey.
CLASS_COLORS_RGB: np.ndarray = np.array(
    [[150, 150, 150], [0, 200, 0], [30, 90, 255], [255, 80, 200]], dtype=np.uint8
)


def packed_rgb(labels: np.ndarray) -> np.ndarray:
    """Per-point colours as float32 packing 0x00RRGGBB, the layout rviz's RGB8 transformer reads."""
    rgb = CLASS_COLORS_RGB[np.asarray(labels, dtype=np.intp)].astype(np.uint32)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    return packed.view(np.float32)
