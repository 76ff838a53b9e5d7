"""One LiDAR scan as every reader yields it and every tool consumes it."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass
class Box3D:
    """An oriented 3D box in the sensor frame: z up, yaw about z, size = (length, width, height)."""

    center: np.ndarray
    size: np.ndarray
    yaw: float
    label: int = 0
    instance: int = -1
    kind: str = ""  # source class name, e.g. KITTI's "Car", "Van", "Pedestrian"

    def contains(self, xyz: np.ndarray, margin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """Mask of the points of `xyz` (N x 3) inside the box enlarged by `margin` on each side."""
        d = np.asarray(xyz, dtype=np.float64)[:, :3] - self.center
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        local_x = d[:, 0] * c + d[:, 1] * s
        local_y = -d[:, 0] * s + d[:, 1] * c
        half = np.asarray(self.size, dtype=np.float64) / 2.0 + np.asarray(margin, dtype=np.float64)
        return (np.abs(local_x) <= half[0]) & (np.abs(local_y) <= half[1]) & (np.abs(d[:, 2]) <= half[2])


@dataclass
class Frame:
    """A scan: points N x 4 float32 (x, y, z, intensity in [0,1]) in firing order, nothing dropped.

    Optional per-point arrays are None when the source does not know them.
    """

    name: str
    points: np.ndarray
    stamp_ns: int = 0
    ring: np.ndarray | None = None  # (N,) uint16
    labels: np.ndarray | None = None  # (N,) uint8, 0 background, 1 car, 2 pedestrian, 3 cyclist
    ground: np.ndarray | None = None  # (N,) bool
    instance: np.ndarray | None = None  # (N,) int32, -1 none
    # Boxes have a yaw only, so they lie in a level frame: the points' frame for a level sensor; a synthetic frame of
    # a tilted or inverted mount (`synthetic:...,roll=,pitch=`) keeps them level at the sensor's origin.
    boxes: list[Box3D] = field(default_factory=list)
    # (N,) bool: points of a vehicle that is no car (KITTI Van / Truck boxes, SemanticKITTI bus / truck /
    # other-vehicle), background under the SqueezeSeg rule; None when the source does not tell
    vehicle_other: np.ndarray | None = None
    # 4 x 4 float64 world-from-sensor transform: a point p of this scan lies at pose[:3, :3] @ p + pose[:3, 3] in a
    # world frame fixed for the whole sequence, so consecutive scans can be put side by side and ego motion measured
    # (synthetic drives give it; None when the source does not know it). Boxes lie in the points' frame for a level
    # mount; for a tilted one they stay level (see above): world = pose[:3, :3] @ R_mount^T @ box + pose[:3, 3].
    pose: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float32)
        if self.points.ndim != 2 or self.points.shape[1] != 4:
            raise ValueError(f"frame {self.name}: points must be N x 4, got shape {self.points.shape}")
        n = len(self.points)
        for key in ("ring", "labels", "ground", "instance", "vehicle_other"):
            value = getattr(self, key)
            if value is not None and len(value) != n:
                raise ValueError(f"frame {self.name}: {key} has {len(value)} entries for {n} points")
        if self.pose is not None:
            self.pose = np.asarray(self.pose, dtype=np.float64)
            if self.pose.shape != (4, 4):
                raise ValueError(f"frame {self.name}: pose must be 4 x 4, got shape {self.pose.shape}")


def front_view_mask(points: np.ndarray, half_angle_deg: float) -> np.ndarray:
    """Mask of the points ahead of the sensor (x > 0) within `half_angle_deg` of the +x axis in azimuth."""
    xyz = np.asarray(points)
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    return (xyz[:, 0] > 0) & (np.abs(azimuth) <= half_angle_deg)


def crop_frame(frame: Frame, keep: np.ndarray) -> Frame:
    """The frame with only the points `keep` (a mask) selects, in their order, every per-point array cut alike.

    Boxes with no kept point inside are dropped; a kept box with an instance id takes its new position in the list
    (the readers' rule) and the points' instance ids follow their box (-1 where it was dropped; ids that name no
    box, SemanticKITTI's, are kept as they are).
    """
    keep = np.asarray(keep, dtype=bool)
    if keep.shape != (len(frame.points),):
        raise ValueError(f"frame {frame.name}: crop mask has shape {keep.shape} for {len(frame.points)} points")
    points = frame.points[keep]
    instance = None if frame.instance is None else frame.instance[keep]
    boxes: list[Box3D] = []
    renumber: dict[int, int] = {}  # a box's instance id -> its new one, -1 when the box is dropped
    for box in frame.boxes:
        if box.instance >= 0:
            renumber[box.instance] = -1
        if not box.contains(points[:, :3]).any():
            continue
        if box.instance >= 0:
            renumber[box.instance] = len(boxes)
            box = replace(box, instance=len(boxes))
        boxes.append(box)
    if instance is not None and any(old != new for old, new in renumber.items()):
        olds = np.array(sorted(renumber), dtype=np.int64)
        news = np.array([renumber[old] for old in olds], dtype=instance.dtype)
        named = np.isin(instance, olds)
        instance = instance.copy()
        instance[named] = news[np.searchsorted(olds, instance[named])]
    return Frame(
        name=frame.name, points=points, stamp_ns=frame.stamp_ns,
        ring=None if frame.ring is None else frame.ring[keep],
        labels=None if frame.labels is None else frame.labels[keep],
        ground=None if frame.ground is None else frame.ground[keep],
        instance=instance, boxes=boxes,
        vehicle_other=None if frame.vehicle_other is None else frame.vehicle_other[keep],
        pose=frame.pose,
    )
