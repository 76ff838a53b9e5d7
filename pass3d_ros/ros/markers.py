"""Boxes as a visualization_msgs MarkerArray: a DELETEALL first, then one wire box (and text) per box."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from pass3d_ros.classes import CLASS_COLORS_RGB, CLASS_NAMES
from pass3d_ros.data.frame import Box3D

# The 12 edges of a box as pairs of corner indices; corners are ordered bottom ring then top ring.
_EDGES = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)])
_UNIT_CORNERS = np.array(
    [[1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1], [1, 1, 1], [1, -1, 1], [-1, -1, 1], [-1, 1, 1]], dtype=float
)
PROPOSAL_RGB = (255, 200, 0)


def box_corners(box: Box3D) -> np.ndarray:
    """The 8 corners (8 x 3) of an oriented box."""
    c, s = np.cos(box.yaw), np.sin(box.yaw)
    local = _UNIT_CORNERS * (np.asarray(box.size, dtype=float) / 2.0)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return local @ rot.T + np.asarray(box.center, dtype=float)


def boxes_to_markers(
    boxes: Sequence[Box3D],
    header: Header,
    namespace: str,
    labels: Sequence[int] | None = None,
    with_text: bool = False,
    level: np.ndarray | None = None,
    texts: Sequence[str] | None = None,
) -> MarkerArray:
    """MarkerArray for rviz2: DELETEALL, then a LINE_LIST per box coloured by class (or amber without labels), and
    with `with_text` a text above each labelled box: its class name, or `texts[k]` when given (class and track id).
    `level`: the rotation from the sensor's frame to the level frame the boxes are in (`Stage1Result.level`); the
    markers are drawn in the sensor's frame, the header's."""
    back = None if level is None else np.asarray(level, dtype=float)  # rows @ level = level^T applied: level -> sensor
    markers = [Marker(header=header, ns=namespace, action=Marker.DELETEALL)]
    for index, box in enumerate(boxes):
        label = None if labels is None else int(labels[index])
        rgb = PROPOSAL_RGB if label is None else tuple(int(v) for v in CLASS_COLORS_RGB[label])
        wire = Marker(header=header, ns=namespace, id=2 * index, type=Marker.LINE_LIST, action=Marker.ADD)
        wire.pose.orientation.w = 1.0
        wire.scale.x = 0.05
        wire.color.r, wire.color.g, wire.color.b, wire.color.a = (rgb[0] / 255, rgb[1] / 255, rgb[2] / 255, 1.0)
        wire.lifetime = Duration(sec=0, nanosec=0)
        corners = box_corners(box) if back is None else box_corners(box) @ back
        wire.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in corners[_EDGES.reshape(-1)]]
        markers.append(wire)
        if with_text and label is not None:
            text = Marker(header=header, ns=namespace, id=2 * index + 1, type=Marker.TEXT_VIEW_FACING)
            text.action = Marker.ADD
            top = np.asarray(box.center, dtype=float) + np.array([0.0, 0.0, box.size[2] / 2 + 0.4])
            top = top if back is None else top @ back
            text.pose.position.x, text.pose.position.y, text.pose.position.z = (float(v) for v in top)
            text.pose.orientation.w = 1.0
            text.scale.z = 0.6
            text.color.r = text.color.g = text.color.b = text.color.a = 1.0
            text.text = CLASS_NAMES[label] if texts is None else texts[index]
            markers.append(text)
    return MarkerArray(markers=markers)
