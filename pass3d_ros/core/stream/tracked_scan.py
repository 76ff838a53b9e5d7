"""A scan's published objects through the stream's tracker: each object's track id, the track's voted class and score,
and the vote applied to the object's points, so the labelled cloud, the markers and the detections tell one story.

The vote on points (docs/outputs.md, "With tracking on"): every point of an object (its cluster id and scan-by-scan
class, `core.objects.frame_objects`) takes the class its track voted (`Track.label`: a new track keeps its first
sighting's class; a change needs the new class to lead the confidence-weighted vote of the last `vote_window`
sightings). Background points and cluster ids stay as they are: the vote only chooses among road-user classes, and
an object stays one object. A track's id is published once it is confirmed (`min_hits` sightings); before, -1.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.objects import (
    IMPLAUSIBLE_SCORE,
    FrameObjects,
    LabelledObject,
    plausible_size,
)
from pass3d_ros.core.stream.tracks import Tracked, Tracker

NO_TRACK = -1  # the track id of a point or object in no confirmed track
MAX_TABLE = 1 << 16  # object_points looks cluster ids below this up in a table


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


def object_points(objects: FrameObjects) -> tuple[np.ndarray, np.ndarray]:
    """The points that belong to an object and, for each, its object's index in `objects.objects`: the road-user
    points whose cluster id is an object's (the one-object rule makes that exactly the object's points). Only the
    road-user points are looked up: ids below MAX_TABLE (a proposal's first object) in a table, the others (split
    parts, a few) by binary search (numpy's searchsorted took 1-2 ms for all of a scan's 18k road-user points)."""
    road = np.flatnonzero(objects.labels != BACKGROUND)
    if not objects.objects or len(road) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids = np.array([obj.cluster_id for obj in objects.objects], dtype=np.int64)
    point_ids = objects.cluster_id[road]
    small = (ids >= 0) & (ids < MAX_TABLE)
    table = np.full(int(ids[small].max(initial=-1)) + 1, -1, np.int64)
    table[ids[small]] = np.flatnonzero(small)
    owner = np.full(len(road), -1, np.int64)
    low = (point_ids >= 0) & (point_ids < len(table))
    owner[low] = table[point_ids[low]]
    rest = np.flatnonzero(~low)
    if len(rest) and not small.all():
        others = np.flatnonzero(~small)
        order = others[np.argsort(ids[others], kind="stable")]
        wanted = point_ids[rest].astype(np.int64)
        at = np.minimum(np.searchsorted(ids[order], wanted), len(order) - 1)
        owner[rest] = np.where(ids[order][at] == wanted, order[at], -1)
    hit = owner >= 0
    return road[hit], owner[hit]


def track_scan(tracker: Tracker, objects: FrameObjects, stamp_s: float, pose: np.ndarray | None = None,
               level: np.ndarray | None = None) -> TrackedScan:
    """Update `tracker` with one scan's published `objects` (boxes in stage 1's level frame, `level` the rotation from
    the sensor's frame to it, None when not levelled) at `stamp_s` seconds, with the sensor's pose (world from sensor,
    4 x 4) when known; return the objects, labels and per-point track ids with the vote applied."""
    started = time.perf_counter()
    centers = np.array([obj.center for obj in objects.objects], dtype=np.float64).reshape(-1, 3)
    sizes = np.array([obj.size for obj in objects.objects], dtype=np.float64).reshape(-1, 3)
    if level is not None:
        centers = centers @ np.asarray(level, dtype=np.float64)  # level -> sensor: rows times level = level^T applied
    tracked = tracker.update(centers, sizes, [obj.label for obj in objects.objects],
                             [obj.score for obj in objects.objects], stamp_s, pose)
    points, owner = object_points(objects)
    voted_class = np.array([t.label for t in tracked], dtype=np.uint8)
    published_id = np.array([t.track_id if t.confirmed else NO_TRACK for t in tracked], dtype=np.int32)
    labels = objects.labels.copy()
    labels[points] = voted_class[owner]
    track_id = np.full(len(labels), NO_TRACK, np.int32)
    track_id[points] = published_id[owner]
    voted_objects = [_voted(obj, t, int(published_id[k])) for k, (obj, t) in
                     enumerate(zip(objects.objects, tracked, strict=True))]
    voted = FrameObjects(labels, objects.cluster_id, voted_objects, objects.groups_split)
    return TrackedScan(voted, track_id, tracked, 1e3 * (time.perf_counter() - started))


def _voted(obj: LabelledObject, tracked: Tracked, track_id: int) -> LabelledObject:
    """`obj` with its track's class and id; its score the voted class's share of the vote, halved (IMPLAUSIBLE_SCORE)
    when the box cannot be one object of that class."""
    plausible = obj.plausible if tracked.label == obj.label else plausible_size(tracked.label, obj.size)
    score = tracked.score if plausible else tracked.score * IMPLAUSIBLE_SCORE
    return LabelledObject(obj.center, obj.size, obj.yaw, tracked.label, score, obj.cluster_id, plausible, track_id)
