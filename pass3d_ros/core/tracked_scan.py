"""A scan's published objects through the stream's tracker: each object's track id, the track's voted class and score,
and the vote applied to the object's points, so the labelled cloud, the markers and the detections tell one story.

The vote on points (docs/outputs.md, "With tracking on"): every point of an object (its cluster id and scan-by-scan
class, `core.objects.frame_objects`) takes the class its track voted (`Track.label`: a new track keeps its first
sighting's class; a change needs the new class to lead the confidence-weighted vote of the last `vote_window`
sightings). A part of a tracked object (stage 1 cut it in two) takes that object's track. With the scan's points, a
confirmed track that no object matched may be held by the points stage 2 called background on its predicted
footprint (core.stream.tracks): they become one object of the track's class and id, with a cluster id of its own (the
proposal holding most of them, as its next split part). With `fill_shapes` (off by default), a confirmed car track's
remembered shape (core.stream.shapes) also takes the points stage 2 left background, in no proposal and off the
ground, that fall in it: into the track's object, or an object of their own as held points are. Cluster ids
otherwise stay; an object stays one object. A track's id is published once it is confirmed (`min_hits` sightings);
before, -1.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.objects import (
    IMPLAUSIBLE_SCORE,
    MIN_OBJECT_POINTS,
    SPLIT_ID_STRIDE,
    FrameObjects,
    LabelledObject,
    boxed_objects,
    plausible_size,
)
from pass3d_ros.core.point_owners import object_points, paint, take_rows
from pass3d_ros.core.stream.footprints import MAX_POINTS, Footprints, footprint_members, nearest_owner
from pass3d_ros.core.stream.track_store import Track
from pass3d_ros.core.stream.tracks import NO_TRACK, Tracked, Tracker, TrackerConfig, TrackingFrame

HELD_SCORE = 0.5  # a held object's score is its track's vote share times this (stage 2 did not see it)


@dataclass(frozen=True)
class TrackedScan:
    """A scan's objects after the tracker: `voted` is what the nodes publish with tracking on (labels with the vote
    applied, the same cluster ids, objects with the voted class and score and their track id); `track_id` per point
    (NO_TRACK: in no object, or in a tentative track's); `tracked` what the tracker said of each object, in order;
    `ms` the time the tracker and the vote took."""

    voted: FrameObjects
    track_id: np.ndarray  # (N,) int32
    tracked: list[Tracked]
    ms: float = 0.0


def track_scan(tracker: Tracker, objects: FrameObjects, stamp_s: float, pose: np.ndarray | None = None,
               level: np.ndarray | None = None, points: np.ndarray | None = None,
               ground: np.ndarray | None = None) -> TrackedScan:
    """Update `tracker` with one scan's published `objects` (boxes in stage 1's level frame, `level` the rotation from
    the sensor's frame to it, None when not levelled) at `stamp_s` seconds, with the sensor's pose (world from sensor,
    4 x 4) when known; return the objects, labels and per-point track ids with the vote applied. With the scan's
    `points` (level frame, as the objects were fitted; `ground`: stage 1's ground mask, when known) the tracker also
    matches by footprints, takes parts of a tracked object as that object, and lets a confirmed track no object
    matched be held by the points stage 2 called background on its footprint (module docstring). Points or a ground
    mask of another length than the objects' labels are refused (ValueError) before the tracker is touched: they
    would be read out of bounds, or fail half way through its update."""
    n = len(objects.labels)
    if points is not None and (len(points) != n or (ground is not None and len(ground) != n)):
        raise ValueError(f"{n} labels but {len(points)} points and {'no' if ground is None else len(ground)} ground "
                         "flags")
    started = time.perf_counter()
    boxes = np.array([(*obj.center, *obj.size, obj.label, obj.score) for obj in objects.objects],
                     dtype=np.float64).reshape(-1, 8)  # one pass over the objects: centre, size, class, score
    centers, sizes = np.ascontiguousarray(boxes[:, :3]), np.ascontiguousarray(boxes[:, 3:6])
    back = None if level is None else np.asarray(level, dtype=np.float64)  # rows @ level: level -> sensor
    if back is not None:
        centers = centers @ back
    members, owner = object_points(objects)
    footprints = background = None
    if points is not None:
        footprints = _footprints(points, members, owner, len(objects.objects), back)
        background = Background(objects, points, ground, back)
    said = tracker.scan(centers, sizes, boxes[:, 6].astype(np.int64), boxes[:, 7], stamp_s, pose, footprints,
                        background, [obj.plausible for obj in objects.objects])
    tracked = said.detections
    voted_class = np.array([t.label for t in tracked], dtype=np.uint8)
    published_id = np.array([t.track_id if t.confirmed else NO_TRACK for t in tracked], dtype=np.int32)
    labels, track_id = paint(objects.labels, members, owner, voted_class, published_id, NO_TRACK)
    voted_objects = [_voted(obj, t, k) for obj, t, k in zip(objects.objects, tracked, published_id.tolist(),
                                                             strict=True)]
    cluster_id = objects.cluster_id
    filling = tracker.filling() if points is not None else []
    held_ids: set[int] = set()  # the cluster ids of this scan's held objects (scored as held, whatever their size)
    if points is not None and (said.held or said.merged or filling):
        cluster_id = cluster_id.copy()
        ids = _PartIds(objects, cluster_id)
        if said.merged:
            voted_objects += _shared_out(points, voted_objects, tracked, members, owner, said.merged, back, labels,
                                         cluster_id, track_id, ids)
        if said.held and background is not None:
            held_objects = _held_objects(points, objects, [(t, background.index[m]) for t, m in said.held],
                                         labels, cluster_id, track_id, ids)
            held_ids = {obj.cluster_id for obj in held_objects}
            voted_objects += held_objects
    if points is not None and tracker.config.fill_shapes:
        to_tracking = TrackingFrame(pose).after(None if back is None else back.T)  # level -> sensor -> tracking
        held = [background.index[m] for _, m in said.held] if said.held and background is not None else []
        road = np.concatenate([members, *held])
        confirmed_cars = [t.track_id for t, c in zip(tracked, voted_class.tolist(), strict=True)
                          if t.confirmed and c == CAR] + [t.track_id for t, _ in said.held if t.label == CAR]
        tracker.shapes.remember(confirmed_cars, stamp_s, points, road, labels, track_id, CAR, to_tracking)
        if filling:
            voted_objects += _filled(tracker, filling, road, points, ground, labels, cluster_id, track_id,
                                     voted_objects, to_tracking, stamp_s, ids, held_ids)
    voted = FrameObjects(labels, cluster_id, voted_objects, objects.groups_split)
    return TrackedScan(voted, track_id, tracked, 1e3 * (time.perf_counter() - started))


def _sensor_xy(points: np.ndarray, back: np.ndarray | None) -> np.ndarray:
    """The points' x, y in the sensor's frame (level-frame points turned back when the scan was levelled)."""
    xyz = np.asarray(points[:, :3], dtype=np.float64)
    return xyz[:, :2] if back is None else (xyz @ back)[:, :2]


def _footprints(points: np.ndarray, members: np.ndarray, owner: np.ndarray, count: int,
                back: np.ndarray | None) -> Footprints:
    """Each object's footprint points (x, y in the sensor frame): footprints.MAX_POINTS of its points at most, spread
    over it (`footprint_members`)."""
    if not count:
        return Footprints(np.zeros((0, 2)), np.zeros(0, np.int64))
    chosen, counts = footprint_members(members, owner, count, MAX_POINTS)
    return Footprints(_sensor_xy(take_rows(points, chosen), back), counts)


class Background:
    """The points a waiting track may be held by: those labelled background, off the ground (stage 1's mask, when
    known), near the waiting tracks; made only when a track waits. `index`: the returned points' indices into the
    scan."""

    def __init__(self, objects: FrameObjects, points: np.ndarray, ground: np.ndarray | None,
                 back: np.ndarray | None) -> None:
        self.objects, self.points, self.ground, self.back = objects, points, ground, back
        self.index = np.zeros(0, np.int64)

    def __call__(self, centers: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """The points within `reach` (T,) metres in x and y of any of `centers` (T, 3; sensor frame), x, y, z in the
        sensor's frame."""
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        if self.back is not None:
            centers = centers @ self.back.T  # sensor -> level, where the points are
        reach = np.asarray(reach, dtype=np.float64)
        low, high = (centers[:, :2] - reach[:, None]).min(axis=0), (centers[:, :2] + reach[:, None]).max(axis=0)
        xy = self.points[:, :2]
        index = np.flatnonzero((xy[:, 0] >= low[0]) & (xy[:, 0] <= high[0]) & (xy[:, 1] >= low[1])
                               & (xy[:, 1] <= high[1]))  # one pass over the scan, then only the points near them
        keep = self.objects.labels[index] == BACKGROUND
        if self.ground is not None:
            keep &= ~np.asarray(self.ground, dtype=bool)[index]
        index = index[keep]
        near = np.zeros(len(index), bool)
        for center, r in zip(centers, reach, strict=True):
            near |= (np.abs(xy[index, 0] - center[0]) <= r) & (np.abs(xy[index, 1] - center[1]) <= r)
        self.index = index[near]
        xyz = np.asarray(self.points[self.index, :3], dtype=np.float64)
        return xyz if self.back is None else xyz @ self.back


class _PartIds:
    """Cluster ids for objects made after stage 2 (held, shared out): a proposal's next free part
    (base + part x SPLIT_ID_STRIDE, core.objects' split ids), or a proposal id no point of the scan carries."""

    def __init__(self, objects: FrameObjects, cluster_id: np.ndarray) -> None:
        self.used: dict[int, set[int]] = {}
        for obj in objects.objects:
            self.used.setdefault(obj.proposal_id, set()).add(obj.cluster_id // SPLIT_ID_STRIDE)
        known = cluster_id[cluster_id >= 0] % SPLIT_ID_STRIDE
        self.fresh = int(known.max(initial=-1)) + 1

    def next(self, base: int) -> int:
        """A new cluster id in proposal `base` (a fresh proposal id when `base` is none)."""
        if base < 0 or base >= SPLIT_ID_STRIDE:
            base, self.fresh = self.fresh, self.fresh + 1
        taken = self.used.setdefault(base, set())
        part = 0 if 0 not in taken else max(taken) + 1
        taken.add(part)
        return base + part * SPLIT_ID_STRIDE


def _held_objects(points: np.ndarray, objects: FrameObjects, held: list[tuple[Tracked, np.ndarray]],
                  labels: np.ndarray, cluster_id: np.ndarray, track_id: np.ndarray,
                  ids: _PartIds) -> list[LabelledObject]:
    """The background points that held a track as one object each, of the track's class and id: their labels,
    track ids and cluster ids set (the proposal holding most of them, as its next free part), a box fitted to them,
    score the track's vote share times HELD_SCORE."""
    parts = []
    for tracked, members in held:
        found, counts = np.unique(cluster_id[members], return_counts=True)
        parts.append((tracked.label, ids.next(int(found[np.argmax(counts)])), members))
    out = []
    for obj, (tracked, members) in zip(boxed_objects(points, parts, np.ones(len(points), np.float32)), held,
                                       strict=True):
        labels[members] = tracked.label
        track_id[members] = tracked.track_id
        cluster_id[members] = obj.cluster_id
        out.append(LabelledObject(obj.center, obj.size, obj.yaw, tracked.label, tracked.score * HELD_SCORE,
                                  obj.cluster_id, obj.plausible, tracked.track_id))
    return out


def _shared_out(points: np.ndarray, voted: list[LabelledObject], tracked: list[Tracked], members: np.ndarray,
                owner: np.ndarray, merged: dict[int, list[tuple[Tracked, np.ndarray]]], back: np.ndarray | None,
                labels: np.ndarray, cluster_id: np.ndarray, track_id: np.ndarray,
                ids: _PartIds) -> list[LabelledObject]:
    """A merged object's points shared out (`Tracker._covered`): each point goes to the track whose predicted
    footprint is nearest; a covered track's share of MIN_OBJECT_POINTS or more becomes an object of its own (its
    track's class, id and score; a new part id of the proposal), the rest stays the object; both boxes fitted again
    and scored as `_voted` scores them. An object none of whose points is nearest its own track's footprint stays
    whole (its matched track's): sharing it out would leave that track an object of no point. `voted` is updated in
    place; the new objects are returned."""
    out = []
    for d, entries in merged.items():
        mine = members[owner == d]
        prints = [xyz if back is None else xyz @ back.T for _, xyz in entries]  # sensor -> level, as the points
        near = nearest_owner(points[mine, :2], prints)
        keep = near == 0
        made = []
        for k, (said, _) in enumerate(entries[1:], start=1):
            share = mine[near == k]
            if len(share) < MIN_OBJECT_POINTS:
                keep |= near == k
                continue
            made.append((said, share))
        if not made or not keep.any():
            continue
        obj = voted[d]
        parts = [(obj.label, obj.cluster_id, mine[keep])] + [(t.label, ids.next(obj.proposal_id), m) for t, m in made]
        boxes = boxed_objects(points, parts, np.ones(len(points), np.float32))
        voted[d] = _voted(boxes[0], tracked[d], obj.track_id)
        for box, (said, share) in zip(boxes[1:], made, strict=True):
            published = said.track_id if said.confirmed else NO_TRACK
            labels[share] = said.label
            track_id[share] = published
            cluster_id[share] = box.cluster_id
            out.append(_voted(box, said, published))
    return out


def _filled(tracker: Tracker, filling: list[Track], road: np.ndarray, points: np.ndarray,
            ground: np.ndarray | None, labels: np.ndarray, cluster_id: np.ndarray, track_id: np.ndarray,
            voted: list[LabelledObject], to_tracking: tuple[np.ndarray, np.ndarray], stamp_s: float,
            ids: _PartIds, held_ids: set[int]) -> list[LabelledObject]:
    """The scan's points stage 2 left background, in no proposal and off the ground, that fall in a voxel of a
    filling track's remembered shape (`shapes`) taken by that track: a track with an object this scan (its points
    among `road`) adds them to its object holding most of its points (its box fitted again and scored again,
    `_refitted`; `voted` updated in place; `held_ids`: the cluster ids of the scan's held objects); another, with
    MIN_OBJECT_POINTS of them or more, makes a new object of them, scored as a held one. Returns the new objects."""
    owner = tracker.shapes.owners(points, labels, cluster_id, ground, to_tracking, [t.track_id for t in filling],
                                  np.array([t.state[2:4] for t in filling]), stamp_s)
    taken_all = np.flatnonzero(owner >= 0)
    if not len(taken_all):
        return []
    grown, made = [], []
    object_of = {obj.cluster_id: d for d, obj in enumerate(voted)}
    by_track = owner[taken_all]
    for k in np.unique(by_track).tolist():
        track, taken = filling[k], taken_all[by_track == k]
        mine = road[track_id[road] == track.track_id]
        if len(mine):
            found, counts = np.unique(cluster_id[mine], return_counts=True)
            biggest = int(found[np.argmax(counts)])
            d = object_of[biggest]
            grown.append((d, np.concatenate([mine[cluster_id[mine] == biggest], taken])))
            labels[taken], cluster_id[taken], track_id[taken] = voted[d].label, biggest, track.track_id
        elif len(taken) >= MIN_OBJECT_POINTS:
            made.append((track, taken, ids.next(-1)))
    ones = np.ones(len(points), np.float32)
    for (d, _), box in zip(grown, boxed_objects(points, [(voted[d].label, voted[d].cluster_id, m) for d, m in grown],
                                                ones), strict=True):
        voted[d] = _refitted(voted[d], box, voted[d].cluster_id in held_ids)
    out = []
    for (track, taken, object_id), box in zip(made, boxed_objects(points, [(track.label(), object_id, taken)
                                                                        for track, taken, object_id in made], ones),
                                               strict=True):
        labels[taken], cluster_id[taken], track_id[taken] = box.label, object_id, track.track_id
        out.append(LabelledObject(box.center, box.size, box.yaw, box.label, track.score() * HELD_SCORE, object_id,
                                  box.plausible, track.track_id))
    return out


def _refitted(obj: LabelledObject, box: LabelledObject, held: bool) -> LabelledObject:
    """`obj` with the box `box` fitted again over its grown points and `box`'s plausibility; the score follows the
    flag as `_voted` scores it (halved when the grown box is no longer plausible, whole again when it has become
    plausible), except a held object's, its track's share times HELD_SCORE whatever its size."""
    score = obj.score
    if not held and box.plausible != obj.plausible:
        score = score * IMPLAUSIBLE_SCORE if not box.plausible else score / IMPLAUSIBLE_SCORE
    return LabelledObject(box.center, box.size, box.yaw, obj.label, score, obj.cluster_id, box.plausible,
                          obj.track_id)


def _voted(obj: LabelledObject, tracked: Tracked, track_id: int) -> LabelledObject:
    """`obj` with its track's class and id; its score the voted class's share of the vote, halved (IMPLAUSIBLE_SCORE)
    when the box cannot be one object of that class."""
    plausible = obj.plausible if tracked.label == obj.label else plausible_size(tracked.label, obj.size)
    score = tracked.score if plausible else tracked.score * IMPLAUSIBLE_SCORE
    return LabelledObject(obj.center, obj.size, obj.yaw, tracked.label, score, obj.cluster_id, plausible, track_id)


def warm_up() -> None:
    """Compile the tracker's numba kernels (association, footprints, the Kalman rows, the track store, the point
    owners) on a tiny stream with stage 1's and stage 2's dtypes: a car and a person seen for eight scans, the car
    then missed (its points left background: held), then both in one object (shared out). A node's first tracked
    scans then run compiled code, not seconds of compiling on a fresh install."""
    rng = np.random.default_rng(0)
    n_each = 60
    sizes = np.array([[4.0, 1.8, 1.5], [0.6, 0.6, 1.7]])
    place = rng.uniform(-0.5, 0.5, (2 * n_each, 3))
    owner = np.repeat(np.arange(2), n_each)
    background = np.column_stack([rng.uniform(-20.0, 20.0, (200, 2)), rng.uniform(-1.5, 0.5, 200)])
    tracker = Tracker(TrackerConfig(fill_shapes=True))
    for k in range(12):
        centres = np.array([[8.0 + 0.8 * k, 2.0, -0.9], [6.0, -3.0 + 0.12 * k, -0.8]])
        if k == 11:
            centres[1, :2] = centres[0, :2] + [2.6, 0.0]  # the person beside the car's front
        road = centres[owner] + place * sizes[owner]
        points = np.vstack([road, background]).astype(np.float32)
        labels = np.zeros(len(points), np.uint8)
        cluster_id = np.full(len(points), -1, np.int32)
        objects = []
        for j, label in enumerate((CAR, PEDESTRIAN)):
            if k == 10 and j == 0:
                continue  # the car missed: its points stay background, in no proposal
            mine = np.flatnonzero(owner == j) if k < 11 else np.arange(2 * n_each)
            if k == 11 and j == 1:
                break
            labels[mine], cluster_id[mine] = label, j
            box = road[mine]
            low, high = box.min(axis=0), box.max(axis=0)
            objects.append(LabelledObject(tuple((0.5 * (low + high)).tolist()), tuple((high - low).tolist()), 0.0,
                                          label, 0.8, j, plausible_size(label, high - low)))
        ground = np.zeros(len(points), bool)
        track_scan(tracker, FrameObjects(labels, cluster_id, objects), 0.1 * k, points=points, ground=ground)
    nearest_owner(np.zeros((2, 2)), [np.zeros((3, 2)), np.ones((2, 3))])
