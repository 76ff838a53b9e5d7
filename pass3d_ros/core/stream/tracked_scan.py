"""A scan's published objects through the stream's tracker: each object's track id, the track's voted class and score,
and the vote applied to the object's points, so the labelled cloud, the markers and the detections tell one story.

The vote on points (docs/outputs.md, "With tracking on"): every point of an object (its cluster id and scan-by-scan
class, `core.objects.frame_objects`) takes the class its track voted (`Track.label`: a new track keeps its first
sighting's class; a change needs the new class to lead the confidence-weighted vote of the last `vote_window`
sightings). Background points and cluster ids stay as they are: the vote only chooses among road-user classes, and
an object stays one object. A track's id is published once it is confirmed (`min_hits` sightings); before, -1.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.objects import IMPLAUSIBLE_SCORE, FrameObjects, LabelledObject, plausible_size
from pass3d_ros.core.stream.tracks import Tracked, Tracker

NO_TRACK = -1  # the track id of a point or object in no confirmed track


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


def object_index(objects: FrameObjects) -> np.ndarray:
    """Per point the index of the object it belongs to in `objects.objects` (-1: none): its road-user points are
    exactly the points whose cluster id is an object's (the one-object rule)."""
    n = len(objects.labels)
    out = np.full(n, -1, np.int64)
    if not objects.objects:
        return out
    ids = np.array([obj.cluster_id for obj in objects.objects], dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    road = np.flatnonzero(objects.labels != BACKGROUND)
    point_ids = objects.cluster_id[road].astype(np.int64)
    at = np.minimum(np.searchsorted(ids[order], point_ids), len(ids) - 1)
    hit = ids[order][at] == point_ids
    out[road[hit]] = order[at[hit]]
    return out


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
    index = object_index(objects)
    voted_class = np.array([t.label for t in tracked], dtype=np.uint8)
    published_id = np.array([t.track_id if t.confirmed else NO_TRACK for t in tracked], dtype=np.int32)
    inside = index >= 0
    labels = objects.labels.copy()
    labels[inside] = voted_class[index[inside]]
    track_id = np.full(len(labels), NO_TRACK, np.int32)
    track_id[inside] = published_id[index[inside]]
    voted_objects = [_voted(obj, t, int(published_id[k])) for k, (obj, t) in
                     enumerate(zip(objects.objects, tracked, strict=True))]
    voted = FrameObjects(labels, objects.cluster_id, voted_objects, objects.groups_split)
    return TrackedScan(voted, track_id, tracked, 1e3 * (time.perf_counter() - started))


def _voted(obj: LabelledObject, tracked: Tracked, track_id: int) -> LabelledObject:
    """`obj` with its track's class and id; its score the voted class's share of the vote, halved (IMPLAUSIBLE_SCORE)
    when the box cannot be one object of that class."""
    plausible = plausible_size(tracked.label, obj.size)
    score = tracked.score if plausible else tracked.score * IMPLAUSIBLE_SCORE
    return dataclasses.replace(obj, label=tracked.label, score=score, plausible=plausible, track_id=track_id)
