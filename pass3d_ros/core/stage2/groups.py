"""People in groups: a proposal stage 2 calls background that holds two people or more, read again person by person.

Two people side by side read to the network as one thing that is no person: real people it is sure of alone are
called pedestrian 71 % of the time 0.5 m apart (docs/experiments/sensors.md, rule C5). A proposal of a group's height
and width that stage 2 called mostly something else is parted by heads, as stage 1's crowd step parts a group
(pass3d_ros.core.stage1.crowd), and each part is given to the classifier as a proposal of its own. Only when the
classifier calls every part, two at least, mostly pedestrian do the parts' pedestrian points become pedestrian: one
person-like part in clutter (a post beside a hedge) changes nothing.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from pass3d_ros.classes import PEDESTRIAN
from pass3d_ros.core.stage1.crowd import people_apart
from pass3d_ros.core.stage2.segmentation import SegmentResult

DEFAULT_ENABLED = False  # Stage2Config.people_in_groups (off by rule C5: docs/experiments/sensors.md)
MIN_POINTS = 10  # a proposal with fewer is no group
RISE_M = (1.0, 2.4)  # a group's lowest to highest point: people's height, the ground ring stage 1 adds below them
EXTENT_M = (0.7, 3.0)  # a group's longer x-y extent: more than one person, no longer than a few abreast
MIN_PART_POINTS = 5  # a part with fewer is left out (an arm, a bag)


class Segments(Protocol):
    """What the step needs of a classifier (pass3d_ros.core.stage2.Classifier)."""

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult: ...


def looks_like_group(points: np.ndarray, member: np.ndarray, labels: np.ndarray) -> bool:
    """Whether a proposal (`member`: indices into `points`) is one to read again: MIN_POINTS or more, under half of them
    called pedestrian, of a group's rise (RISE_M) and longer x-y extent (EXTENT_M)."""
    if len(member) < MIN_POINTS or 2 * np.count_nonzero(labels[member] == PEDESTRIAN) >= len(member):
        return False
    xyz = points[member, :3]
    rise = float(xyz[:, 2].max() - xyz[:, 2].min())
    extent = float((xyz[:, :2].max(axis=0) - xyz[:, :2].min(axis=0)).max())
    return RISE_M[0] <= rise <= RISE_M[1] and EXTENT_M[0] <= extent <= EXTENT_M[1]


def group_parts(points: np.ndarray, member: np.ndarray) -> list[np.ndarray]:
    """The proposal's people by heads (each a part of MIN_PART_POINTS or more; heights read from its lowest point),
    or none when fewer than two are found."""
    z = points[member, 2].astype(np.float64)
    person, _, n_people = people_apart(points[member], np.zeros(len(member), dtype=np.int64), 1, np.zeros(1, np.int64),
                                       z - z.min())
    parts = [member[person == 1 + p] for p in range(n_people)]
    parts = [part for part in parts if len(part) >= MIN_PART_POINTS]
    return parts if len(parts) >= 2 else []


def people_in_groups(points: np.ndarray, members: list[np.ndarray], result: SegmentResult,
                     classifier: Segments) -> tuple[SegmentResult, int]:
    """`result` with the groups read again (module docstring), and how many parts the classifier read. `points` and
    `members` as the classifier read them for `result`; its parts are read in one more call (its `max_proposals`
    bound holds: a part it leaves unread is not called pedestrian)."""
    groups = [(k, parts) for k, member in enumerate(members)
              if result.proposal_class[k] >= 0 and looks_like_group(points, member, result.labels)
              and (parts := group_parts(points, member))]
    if not groups:
        return result, 0
    flat = [part for _, parts in groups for part in parts]
    read = classifier.segment(points, flat)
    labels, confidence = result.labels.copy(), result.confidence.copy()
    proposal_class = result.proposal_class.copy()
    first = 0
    for k, parts in groups:
        called = [read.proposal_class[first + i] >= 0 and 2 * np.count_nonzero(read.labels[part] == PEDESTRIAN) >
                  len(part) for i, part in enumerate(parts)]
        first += len(parts)
        if not all(called):
            continue
        for part in parts:
            person = part[read.labels[part] == PEDESTRIAN]
            labels[person] = PEDESTRIAN
            confidence[person] = read.confidence[person]
        if 2 * np.count_nonzero(labels[members[k]] == PEDESTRIAN) > len(members[k]):
            proposal_class[k] = PEDESTRIAN
    return SegmentResult(labels, confidence, proposal_class, result.people_share), len(flat)
