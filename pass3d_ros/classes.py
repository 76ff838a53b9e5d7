"""Class ids, names and display colours: defined here once and imported everywhere else."""

from __future__ import annotations

import numpy as np

BACKGROUND, CAR, PEDESTRIAN, CYCLIST = 0, 1, 2, 3
CLASS_NAMES: tuple[str, ...] = ("background", "car", "pedestrian", "cyclist")
FOREGROUND: tuple[int, ...] = (CAR, PEDESTRIAN, CYCLIST)
NUM_CLASSES = len(CLASS_NAMES)
# Ground-truth label of a point nobody annotated (e.g. outside KITTI's camera view): scored and trained on by no one.
IGNORE = 255

TRUTH_IDS: np.ndarray = np.array([*range(NUM_CLASSES), IGNORE])  # what a ground-truth label may hold


def foreign_ids(values: np.ndarray) -> np.ndarray:
    """The distinct values of ground-truth labels `values` (any numeric type) that are neither a class id nor IGNORE:
    another scheme's ids, or corrupt data."""
    values = np.asarray(values)
    return np.unique(values[~np.isin(values, TRUTH_IDS)])


# Each class's mean box (length, width, height; metres) in KITTI's object labels as Frustum-PointNets tabulates them
# (docs: /work/shared/DESIGN.md, "KITTI object label statistics"): one object of the class, for the plausible sizes
# (core.objects) and the tracker's parts (core.stream.tracks).
MEAN_SIZE: dict[int, tuple[float, float, float]] = {
    CAR: (3.88, 1.63, 1.53), PEDESTRIAN: (0.84, 0.66, 1.76), CYCLIST: (1.76, 0.60, 1.74),
}

# Colours of the paper's figures: car green, pedestrian blue, cyclist pink, background grey.
CLASS_COLORS_RGB: np.ndarray = np.array(
    [[150, 150, 150], [0, 200, 0], [30, 90, 255], [255, 80, 200]], dtype=np.uint8
)


_PACKED_COLORS = (CLASS_COLORS_RGB.astype(np.uint32) @ np.array([1 << 16, 1 << 8, 1], np.uint32)).astype(np.uint32)
_PACKED_BY_BYTE = np.full(256, _PACKED_COLORS[BACKGROUND], dtype=np.uint32)  # any uint8 label; unknown ones grey
_PACKED_BY_BYTE[:NUM_CLASSES] = _PACKED_COLORS


def packed_rgb(labels: np.ndarray) -> np.ndarray:
    """Per-point colours as float32 packing 0x00RRGGBB, the layout rviz's RGB8 transformer reads; labels that are no
    class (>= NUM_CLASSES) take the background's."""
    labels = np.asarray(labels)
    if labels.dtype == np.uint8:  # the labeled cloud's column: one table lookup (a tenth of the general path)
        return np.take(_PACKED_BY_BYTE, labels).view(np.float32)
    labels = labels.astype(np.intp)
    return _PACKED_COLORS[np.where(labels < NUM_CLASSES, labels, BACKGROUND)].view(np.float32)
