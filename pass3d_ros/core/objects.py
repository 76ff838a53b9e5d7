"""The objects of a labelled frame: one oriented box per proposal stage 2 called car, pedestrian or cyclist, fitted to
that proposal's points of its class, with the points' mean confidence and the proposal's cluster id.

The segmentation node draws them as markers and publishes them as vision_msgs detections; pass3d_segment writes them
as JSON. Nothing here needs ROS.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pass3d_ros.classes import CLASS_NAMES, FOREGROUND
from pass3d_ros.core.stage2.canonical import fit_box_members
from pass3d_ros.data.frame import Box3D

MIN_SIZE = 0.01  # metres: the least box edge (one point, or points on a line, fit a box of no extent)


@dataclass(frozen=True)
class LabelledObject:
    """One object: its box (centre, length x width x height, yaw about z; sensor frame), class, score and cluster id."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    label: int  # class id: CAR, PEDESTRIAN or CYCLIST
    score: float  # mean confidence of the object's points
    cluster_id: int  # the proposal's cluster id (the labelled cloud's cluster_id)

    @property
    def class_id(self) -> str:
        """The class name: "car", "pedestrian" or "cyclist"."""
        return CLASS_NAMES[self.label]

    def box(self) -> Box3D:
        """The object's box as a Box3D (for markers and pictures)."""
        return Box3D(center=np.array(self.center), size=np.array(self.size), yaw=self.yaw, label=self.label)

    def to_json(self) -> dict[str, Any]:
        """The object as JSON: id (the cluster id, a string as in vision_msgs), class_id, score, center, size, yaw."""
        return {"id": str(self.cluster_id), "class_id": self.class_id, "score": self.score,
                "center": list(self.center), "size": list(self.size), "yaw": self.yaw}


def labelled_objects(
    points: np.ndarray,
    members: Sequence[np.ndarray],
    proposal_class: np.ndarray,
    labels: np.ndarray,
    confidence: np.ndarray,
    cluster_ids: np.ndarray | Sequence[int] | None = None,
) -> list[LabelledObject]:
    """The objects of a frame, in proposal order.

    `points` (N, >=3), `labels` and `confidence` (N,): the frame's points and their final labels (after any confidence
    threshold) and confidences; `members[p]`: point indices of proposal p; `proposal_class[p]`: the class stage 2 gave
    proposal p (-1 or 0: none); `cluster_ids[p]`: its id in the cloud (default p). A proposal of a class is an object
    when at least one of its points carries that class; its box is fitted to those points only.
    """
    labels, confidence = np.asarray(labels), np.asarray(confidence)
    if len(labels) != len(points) or len(confidence) != len(points):
        raise ValueError(f"{len(points)} points but {len(labels)} labels and {len(confidence)} confidences")
    if len(proposal_class) != len(members):
        raise ValueError(f"{len(members)} proposals but {len(proposal_class)} classes")
    ids = np.arange(len(members)) if cluster_ids is None else np.asarray(cluster_ids)
    if len(ids) != len(members):
        raise ValueError(f"{len(members)} proposals but {len(ids)} cluster ids")
    chosen: list[int] = []
    groups: list[np.ndarray] = []
    for p, cls in enumerate(np.asarray(proposal_class).tolist()):
        if cls not in FOREGROUND or len(members[p]) == 0:
            continue
        own = members[p][labels[members[p]] == cls]
        if len(own):
            chosen.append(p)
            groups.append(own)
    if not chosen:
        return []
    fitted = fit_box_members(points, groups)
    objects = []
    for k, p in enumerate(chosen):
        length, width, height = (float(v) for v in fitted.size[k])
        center = (float(fitted.center[k, 0]), float(fitted.center[k, 1]), float(fitted.zmin[k]) + height / 2)
        objects.append(LabelledObject(
            center=center,
            size=(max(length, MIN_SIZE), max(width, MIN_SIZE), max(height, MIN_SIZE)),
            yaw=float(fitted.yaw[k]),
            label=int(proposal_class[p]),
            score=float(np.mean(confidence[groups[k]], dtype=np.float64)),
            cluster_id=int(ids[p]),
        ))
    return objects


def objects_json(frame: str, objects: Sequence[LabelledObject]) -> str:
    """One frame's objects as a JSON document, one object a line: {"frame": name, "objects": [to_json(), ...]}, numbers
    rounded to JSON_DECIMALS."""
    lines = [json.dumps(_rounded(obj.to_json())) for obj in objects]
    body = "[]" if not lines else "[\n  " + ",\n  ".join(lines) + "\n ]"
    return f'{{\n "frame": {json.dumps(frame)},\n "objects": {body}\n}}\n'


JSON_DECIMALS = 4  # 0.1 mm, 0.0001 rad: far below what a LiDAR box can tell


def _rounded(value: Any) -> Any:
    """`value` with every float rounded to JSON_DECIMALS (lists and dicts followed)."""
    if isinstance(value, float):
        return round(value, JSON_DECIMALS)
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value
