"""The objects of a labelled frame, and the labels and cluster ids the labelled cloud publishes with them: one rule,
`frame_objects`, so that the cloud, the markers, the detections and pass3d_segment's files cannot disagree.

The rule (docs/outputs.md, "One object concept"): a point belongs to the proposal it is published with (its primary
cluster id); within a proposal stage 2 called car, pedestrian or cyclist, its road-user points take the proposal's
class, except that the points of another road-user class form an object of their own when there are at least
MIN_OBJECT_POINTS of them; in a proposal called background, the points of a road-user class are an object of it when
there are at least MIN_OBJECT_POINTS of them, else background. A pedestrian object wider than one person
(PLAUSIBLE_SIZE) is split into per-person objects by a 2D clustering of its points where they fall apart by at least
PERSON_GAP. Each object's box is fitted to exactly its points; a box outside its class's PLAUSIBLE_SIZE is flagged
(`plausible` False, score times IMPLAUSIBLE_SCORE). Ids: a proposal's first object carries the proposal's cluster id;
its further objects (another class, more people of a group) carry cluster id + k * SPLIT_ID_STRIDE, k = 1, 2, ...,
in the cloud's cluster_id too. Nothing here needs ROS.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba as nb
import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_NAMES, FOREGROUND, MEAN_SIZE, PEDESTRIAN
from pass3d_ros.core.stage2.canonical import fit_box_members
from pass3d_ros.data.frame import Box3D

MIN_SIZE = 0.01  # metres: the least box edge (one point, or points on a line, fit a box of no extent)
MIN_OBJECT_POINTS = 10  # points of a road-user class that make an object of their own beside a proposal's class
PERSON_GAP = 0.25  # metres (x-y): points of a too-wide pedestrian object this far apart belong to different people
MIN_PERSON_POINTS = 5  # a split-off part with fewer points joins the nearest person
SPLIT_ID_STRIDE = 1_000_000  # id of a proposal's k-th further object: cluster id + k * SPLIT_ID_STRIDE
IMPLAUSIBLE_SCORE = 0.5  # an implausible box's score is its points' mean confidence times this

# PLAUSIBLE_SIZE comes from classes.MEAN_SIZE, KITTI's mean box of each class.
PLAUSIBLE_MAX = 1.6  # each edge at most this times the class mean (a KITTI Van, 5.07 x 1.90 x 2.21, is a plausible car)
PLAUSIBLE_MIN_LENGTH = 0.25  # the longer horizontal edge at least this times the mean length (a partial view)
PLAUSIBLE_MIN_HEIGHT = 0.3  # the height at least this times the mean height (a child, an occluded lower body)
# Per class: (min, max) of the longer horizontal edge, of the shorter one and of the height, in metres. Generous on
# purpose: a box outside them is no single object of its class (a "car" 0.47 x 0.09 x 0.27, a group of people).
PLAUSIBLE_SIZE: dict[int, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    label: ((PLAUSIBLE_MIN_LENGTH * length, PLAUSIBLE_MAX * length), (0.0, PLAUSIBLE_MAX * width),
            (PLAUSIBLE_MIN_HEIGHT * height, PLAUSIBLE_MAX * height))
    for label, (length, width, height) in MEAN_SIZE.items()
}


def plausible_size(label: int, size: Sequence[float]) -> bool:
    """Whether a box of `size` (length, width, height; either horizontal edge may be the longer) can be one object
    of class `label` (PLAUSIBLE_SIZE)."""
    edges = (max(size[0], size[1]), min(size[0], size[1]), size[2])
    return all(low <= edge <= high for edge, (low, high) in zip(edges, PLAUSIBLE_SIZE[label], strict=True))


@dataclass(frozen=True)
class LabelledObject:
    """One object: its box (centre, length x width x height, yaw about z; sensor frame), class, score and id."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    label: int  # class id: CAR, PEDESTRIAN or CYCLIST
    score: float  # mean confidence of the object's points (times IMPLAUSIBLE_SCORE when not plausible)
    cluster_id: int  # the labelled cloud's cluster_id of exactly this object's points (the proposal's, or split)
    plausible: bool = True  # the box's size fits its class (PLAUSIBLE_SIZE)
    track_id: int = -1  # with tracking on, the object's confirmed track (pass3d_ros.core.tracked_scan); -1 none

    @property
    def class_id(self) -> str:
        """The class name: "car", "pedestrian" or "cyclist"."""
        return CLASS_NAMES[self.label]

    @property
    def proposal_id(self) -> int:
        """The cluster id of the proposal the object came from (its id less the split part)."""
        return self.cluster_id % SPLIT_ID_STRIDE

    def box(self) -> Box3D:
        """The object's box as a Box3D (for markers and pictures)."""
        return Box3D(center=np.array(self.center), size=np.array(self.size), yaw=self.yaw, label=self.label)

    def to_json(self) -> dict[str, Any]:
        """The object as JSON: id (the cluster id, a string as in vision_msgs), class_id, score, center, size, yaw,
        plausible."""
        return {"id": str(self.cluster_id), "class_id": self.class_id, "score": self.score,
                "center": list(self.center), "size": list(self.size), "yaw": self.yaw, "plausible": self.plausible}


@dataclass(frozen=True)
class FrameObjects:
    """What a labelled frame publishes: per point the label and cluster id of the labelled cloud, and the objects;
    every road-user point's (cluster_id, label) is exactly one object's (cluster_id, label), and every object has
    points."""

    labels: np.ndarray  # (N,) uint8
    cluster_id: np.ndarray  # (N,) int32, -1 = in no proposal
    objects: list[LabelledObject]
    groups_split: int = 0  # pedestrian objects split into several people


def frame_objects(
    points: np.ndarray,
    owner: np.ndarray,
    proposal_class: np.ndarray,
    labels: np.ndarray,
    confidence: np.ndarray,
    point_ids: np.ndarray | None = None,
) -> FrameObjects:
    """The published labels, cluster ids and objects of a frame (the module's rule).

    `points` (N, >=3) in the frame the boxes stand in (stage 1's level frame); `owner` (N,): the index of the
    proposal each point is published with (-1: none, or not classified); `proposal_class` (P,): stage 2's class of
    each proposal (-1: not classified, 0: background); `labels`, `confidence` (N,): stage 2's per-point labels (after
    any confidence threshold) and confidences; `point_ids` (N,): the cluster id each point is published with (default
    `owner`; it must be one id per owner).
    """
    points = np.asarray(points)
    labels, confidence = np.asarray(labels), np.asarray(confidence)
    owner = np.asarray(owner, dtype=np.int64)
    proposal_class = np.asarray(proposal_class)
    n = len(points)
    if len(labels) != n or len(confidence) != n or len(owner) != n:
        raise ValueError(f"{n} points but {len(labels)} labels, {len(confidence)} confidences and {len(owner)} owners")
    if len(owner) and int(owner.max(initial=-1)) >= len(proposal_class):
        raise ValueError(f"{len(proposal_class)} proposal classes but owners up to {int(owner.max())}")
    ids = owner if point_ids is None else np.asarray(point_ids)
    if len(ids) != n:
        raise ValueError(f"{n} points but {len(ids)} cluster ids")
    out_labels = np.full(n, BACKGROUND, np.uint8)
    out_ids = ids.astype(np.int32, copy=True)
    road = (owner >= 0) & np.isin(labels, FOREGROUND)
    road[road] = proposal_class[owner[road]] >= 0  # a proposal stage 2 did not classify has no road-user point
    index = np.flatnonzero(road)
    parts: list[tuple[int, int, np.ndarray]] = []  # (class, cluster id, point indices) per object
    groups_split = 0
    if len(index):
        order = np.argsort(owner[index], kind="stable")
        index = index[order]
        starts = np.flatnonzero(np.r_[True, np.diff(owner[index]) != 0])
        for own in np.split(index, starts[1:]):
            base = int(ids[own[0]])
            splittable = 0 <= base < SPLIT_ID_STRIDE
            pieces = _proposal_parts(int(proposal_class[owner[own[0]]]), labels[own], own, splittable)
            k = 0
            for cls, members in pieces:
                people = _people(points, members) if cls == PEDESTRIAN and splittable else [members]
                groups_split += len(people) > 1
                for person in people:
                    parts.append((cls, base + k * SPLIT_ID_STRIDE, person))
                    k += 1
    for cls, object_id, members in parts:
        out_labels[members] = cls
        out_ids[members] = object_id
    return FrameObjects(out_labels, out_ids, boxed_objects(points, parts, confidence), groups_split)


def _proposal_parts(proposal: int, labels: np.ndarray, members: np.ndarray, splittable: bool
                    ) -> list[tuple[int, np.ndarray]]:
    """The objects (class, point indices) of one proposal's road-user points `members` (their stage-2 `labels`): the
    proposal's own class first, holding its points and the other classes' too few for an object of their own, then
    each other class of at least MIN_OBJECT_POINTS, most points first. In a proposal called background (or whose
    class kept no point) only those classes are objects; its other road-user points are background. `splittable`
    False (a cluster id of SPLIT_ID_STRIDE or more): one object at most."""
    counts = {cls: int(np.count_nonzero(labels == cls)) for cls in FOREGROUND}
    main = proposal if proposal in FOREGROUND and counts[proposal] else None
    own = sorted((cls for cls in FOREGROUND if cls != main and counts[cls] >= MIN_OBJECT_POINTS),
                 key=lambda cls: -counts[cls])
    if main is None:
        return [(cls, members[labels == cls]) for cls in own[:None if splittable else 1]]
    if not splittable:
        own = []
    return [(main, members[~np.isin(labels, own)])] + [(cls, members[labels == cls]) for cls in own]


def _people(points: np.ndarray, members: np.ndarray) -> list[np.ndarray]:
    """A pedestrian object's points as one array per person: split by a 2D clustering (PERSON_GAP) when its box is
    wider than one person and the points fall apart into at least two parts of MIN_PERSON_POINTS; largest first."""
    if len(members) < 2 * MIN_PERSON_POINTS:
        return [members]
    box = fit_box_members(points, [members])
    (_, long_high), (_, short_high), _ = PLAUSIBLE_SIZE[PEDESTRIAN]
    if box.size[0, 0] <= long_high and box.size[0, 1] <= short_high:
        return [members]
    xy = np.asarray(points[members, :2], dtype=np.float64)
    component = _components_2d(xy, PERSON_GAP)
    sizes = np.bincount(component)
    people = np.flatnonzero(sizes >= MIN_PERSON_POINTS)
    if len(people) < 2:
        return [members]
    people = people[np.argsort(-sizes[people], kind="stable")]
    centres = np.stack([xy[component == c].mean(axis=0) for c in people])
    small = ~np.isin(component, people)
    nearest = np.argmin(((xy[small, None, :] - centres[None]) ** 2).sum(axis=-1), axis=1)
    rank = np.full(len(sizes), -1, np.int64)
    rank[people] = np.arange(len(people))
    person = rank[component]
    person[small] = nearest
    return [members[person == k] for k in range(len(people))]


@nb.njit(cache=True, nogil=True)
def _components_2d(xy: np.ndarray, gap: float) -> np.ndarray:
    """Connected components (0..C-1, in order of first point) of x-y points linked when closer than `gap`: a sweep
    along x with union-find."""
    n = len(xy)
    order = np.argsort(xy[:, 0])
    parent = np.arange(n)
    gap2 = gap * gap
    for a in range(n):
        i = order[a]
        for b in range(a + 1, n):
            j = order[b]
            dx = xy[j, 0] - xy[i, 0]
            if dx > gap:
                break
            dy = xy[j, 1] - xy[i, 1]
            if dx * dx + dy * dy < gap2:
                ri, rj = i, j
                while parent[ri] != ri:
                    ri = parent[ri]
                while parent[rj] != rj:
                    rj = parent[rj]
                if ri != rj:
                    parent[max(ri, rj)] = min(ri, rj)
    label = np.full(n, -1, np.int64)
    count = 0
    for i in range(n):
        r = i
        while parent[r] != r:
            r = parent[r]
        if label[r] < 0:
            label[r] = count
            count += 1
        label[i] = label[r]
    return label


def boxed_objects(points: np.ndarray, parts: list[tuple[int, int, np.ndarray]], confidence: np.ndarray
           ) -> list[LabelledObject]:
    """One LabelledObject per (class, id, points) part: the minimal box of its points, the plausibility flag."""
    if not parts:
        return []
    fitted = fit_box_members(points, [members for _, _, members in parts])
    objects = []
    for k, (cls, object_id, members) in enumerate(parts):
        length, width, height = (float(v) for v in fitted.size[k])
        size = (max(length, MIN_SIZE), max(width, MIN_SIZE), max(height, MIN_SIZE))
        center = (float(fitted.center[k, 0]), float(fitted.center[k, 1]), float(fitted.zmin[k]) + height / 2)
        plausible = plausible_size(cls, size)
        score = float(np.mean(confidence[members], dtype=np.float64))
        objects.append(LabelledObject(center=center, size=size, yaw=float(fitted.yaw[k]), label=cls,
                                      score=score if plausible else score * IMPLAUSIBLE_SCORE,
                                      cluster_id=object_id, plausible=plausible))
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


def warm_up() -> None:
    """Compile the person split's kernel (x-y as `_people` gives it: float64, contiguous)."""
    _components_2d(np.zeros((4, 2)), PERSON_GAP)
