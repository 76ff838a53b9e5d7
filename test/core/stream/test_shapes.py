"""A car track's remembered shape (core/stream/shapes.py, `TrackerConfig.fill_shapes`, rule N of
docs/experiments/tracks.md): the voxels its objects' points filled over its last sightings, moved with the track, take
the scan's unproposed background points that fall in them."""

from __future__ import annotations

import dataclasses

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR
from pass3d_ros.core.objects import IMPLAUSIBLE_SCORE, FrameObjects, LabelledObject
from pass3d_ros.core.stage2.config import Stage2Config
from pass3d_ros.core.stream.shapes import SHAPE_POINTS, ShapeMemory
from pass3d_ros.core.stream.tracks import Tracker, TrackerConfig
from pass3d_ros.core.tracked_scan import NO_TRACK, track_scan

IDENTITY = (np.eye(3), np.zeros(3))
FILL = TrackerConfig(fill_shapes=True)  # off by default (rule N)


def car_points(x0: float = 10.0, y: float = 3.0) -> np.ndarray:
    """A car's side seen at y: 40 points from x0 to x0 + 4 m, 0.3-1.4 m up (sensor 1.7 m up), N x 4 float32."""
    x = np.repeat(np.linspace(x0, x0 + 4.0, 20), 2)
    z = np.tile([-1.4, -0.4], 20)
    return np.stack([x, np.full(40, y), z, np.full(40, 0.5)], axis=1).astype(np.float32)


def remembered(points: np.ndarray, memory: ShapeMemory, track: int, stamp_s: float) -> None:
    n = len(points)
    memory.remember([track], stamp_s, points, np.arange(n), np.full(n, CAR, np.uint8), np.full(n, track, np.int32),
                    CAR, IDENTITY)


def owners(memory: ShapeMemory, points: np.ndarray, velocity: tuple[float, float], stamp_s: float,
           cluster_id: np.ndarray | None = None, ground: np.ndarray | None = None) -> np.ndarray:
    n = len(points)
    cluster = np.full(n, -1, np.int32) if cluster_id is None else cluster_id
    return memory.owners(points, np.zeros(n, np.uint8), cluster, ground, IDENTITY, [7], np.array([velocity]),
                         stamp_s)


def test_a_shape_takes_what_falls_in_its_voxels_as_it_moves_with_its_track() -> None:
    memory = ShapeMemory(10)
    remembered(car_points(), memory, 7, 0.0)
    still = owners(memory, car_points(), (0.0, 0.0), 1.0)
    assert (still == 0).all(), "every point of the car where it was seen"
    moved = owners(memory, car_points(x0=12.0), (2.0, 0.0), 1.0)
    assert (moved == 0).all(), "a second later at 2 m/s the shape is 2 m further on"
    assert (owners(memory, car_points(x0=17.0), (2.0, 0.0), 1.0) == -1).all(), "beyond its end: nothing"
    assert (owners(memory, car_points(y=5.0), (0.0, 0.0), 1.0) == -1).all(), "two metres aside: nothing"


def test_a_shape_takes_no_point_in_a_proposal_or_on_the_ground() -> None:
    memory = ShapeMemory(10)
    remembered(car_points(), memory, 7, 0.0)
    points = car_points()
    cluster = np.full(40, -1, np.int32)
    cluster[:10] = 3  # stage 2 saw these in proposal 3 and called them background: its word stands
    ground = np.zeros(40, bool)
    ground[10:20] = True
    found = owners(memory, points, (0.0, 0.0), 0.1, cluster, ground)
    assert (found[:20] == -1).all() and (found[20:] == 0).all()


def test_a_shape_remembers_its_last_sightings_only() -> None:
    memory = ShapeMemory(2)
    remembered(car_points(), memory, 7, 0.0)
    remembered(car_points(y=-3.0), memory, 7, 0.1)
    remembered(car_points(y=-3.0), memory, 7, 0.2)  # the first sighting (y = 3) has left the window
    assert (owners(memory, car_points(), (0.0, 0.0), 0.3) == -1).all()
    assert (owners(memory, car_points(y=-3.0), (0.0, 0.0), 0.3) == 0).all()
    many = np.concatenate([car_points(x0=x) for x in range(0, 40, 4)])  # 400 points: strided down to the room
    remembered(many, memory, 8, 0.3)
    assert memory.counts[memory.rows_of([8])[0]].max() <= SHAPE_POINTS
    memory.keep_only({8})
    assert 7 not in memory and 8 in memory


def car_scan(points: np.ndarray, in_object: np.ndarray) -> FrameObjects:
    """The car's points in `in_object` are object 4 (car), the others background in no proposal."""
    labels = np.where(in_object, CAR, BACKGROUND).astype(np.uint8)
    cluster = np.where(in_object, 4, -1).astype(np.int32)
    xyz = points[in_object, :3]
    centre = tuple(float(v) for v in (xyz.min(axis=0) + xyz.max(axis=0)) / 2)
    size = tuple(float(v) for v in np.maximum(xyz.max(axis=0) - xyz.min(axis=0), 0.1))
    return FrameObjects(labels, cluster, [LabelledObject(centre, size, 0.0, CAR, 0.9, 4)])


def test_a_tracked_car_seen_in_part_takes_its_unproposed_points_back() -> None:
    tracker = Tracker(FILL)
    points = car_points()
    whole = np.ones(40, bool)
    for k in range(3):
        track_scan(tracker, car_scan(points, whole), 0.1 * k, points=points)
    half = np.arange(40) < 16  # stage 1 proposed the front 1.6 m only
    out = track_scan(tracker, car_scan(points, half), 0.3, points=points)
    (car,) = out.voted.objects
    assert car.track_id != NO_TRACK
    assert (out.voted.labels == CAR).all() and (out.track_id == car.track_id).all()
    assert (out.voted.cluster_id == 4).all(), "the points join the car's object"
    assert car.size[0] > 3.5, "its box fitted again over them"
    off = Tracker(dataclasses.replace(FILL, fill_shapes=False))
    for k in range(3):
        track_scan(off, car_scan(points, whole), 0.1 * k, points=points)
    plain = track_scan(off, car_scan(points, half), 0.3, points=points)
    assert (plain.voted.labels[~half] == BACKGROUND).all()


def waiting_car(fill: bool) -> tuple[Tracker, object]:
    """A car seen whole three scans, then its rear alone (its footprint: the rear's cells), then not proposed while
    only its front shows (the rear hidden): the hold finds no point on the rear's cells."""
    tracker = Tracker(dataclasses.replace(FILL, fill_shapes=fill))
    points = car_points()
    for k in range(3):
        track_scan(tracker, car_scan(points, np.ones(40, bool)), 0.1 * k, points=points)
    track_scan(tracker, car_scan(points, np.arange(40) >= 24), 0.3, points=points)
    front = points[:24]
    empty = FrameObjects(np.zeros(24, np.uint8), np.full(24, -1, np.int32), [])
    return tracker, track_scan(tracker, empty, 0.4, points=front)


def test_a_waiting_car_track_makes_an_object_of_its_unproposed_points() -> None:
    tracker, out = waiting_car(True)
    (car,) = out.voted.objects
    assert car.label == CAR and car.track_id == tracker.tracks[0].track_id
    assert (out.voted.labels == CAR).all() and (out.voted.cluster_id == car.cluster_id).all()
    assert car.score < 0.9 * 0.6, "scored as a held object: stage 2 did not see it"
    _, plain = waiting_car(False)
    assert not plain.voted.objects and (plain.voted.labels == BACKGROUND).all(), "without the shape, nothing"


def test_the_node_parameter_sets_the_fill() -> None:
    assert Stage2Config().tracker_config().fill_shapes == TrackerConfig().fill_shapes
    assert Stage2Config(track_fill_shapes=True).tracker_config().fill_shapes is True


def test_a_track_remembered_with_no_point_has_no_shape() -> None:
    memory = ShapeMemory(3)
    points = car_points()
    n = len(points)
    memory.remember([7], 0.0, points, np.arange(n), np.full(n, BACKGROUND, np.uint8), np.full(n, 7, np.int32), CAR,
                    IDENTITY)  # none of its points is a car's any more (shared out to a neighbour, say)
    remembered(car_points(x0=30.0), memory, 8, 0.0)
    found = memory.owners(np.concatenate([points, car_points(x0=30.0)]), np.zeros(2 * n, np.uint8),
                          np.full(2 * n, -1, np.int32), None, IDENTITY, [7, 8], np.zeros((2, 2)), 0.1)
    assert (found[:n] == -1).all() and (found[n:] == 1).all()


def long_car_points(x0: float, x1: float, extra: tuple[float, ...] = ()) -> np.ndarray:
    """A car's side at y = 3: 40 points from x0 to x1 (two heights), then one point at each x of `extra` (N x 4)."""
    x = np.concatenate([np.repeat(np.linspace(x0, x1, 20), 2), np.asarray(extra, dtype=np.float64)])
    z = np.concatenate([np.tile([-1.4, -0.4], 20), np.full(len(extra), -1.4)])
    return np.stack([x, np.full(len(x), 3.0), z, np.full(len(x), 0.5)], axis=1).astype(np.float32)


def grown_car(points: np.ndarray, seen: np.ndarray, part: np.ndarray, plausible: bool) -> object:
    """A car tracked with fill_shapes over three scans of its `seen` points (confidence 0.9), then proposed as `part`
    only (published with `plausible` and scored as `_voted` scores it); the tracked scan."""
    tracker = Tracker(FILL)
    for k in range(3):
        track_scan(tracker, car_scan(points[seen], np.ones(int(seen.sum()), bool)), 0.1 * k, points=points[seen])
    scan = car_scan(points, part)
    (obj,) = scan.objects
    score = 1.0 if plausible else IMPLAUSIBLE_SCORE
    scan = FrameObjects(scan.labels, scan.cluster_id, [dataclasses.replace(obj, plausible=plausible, score=score)])
    return track_scan(tracker, scan, 0.3, points=points)


def test_a_car_grown_by_its_shape_is_scored_for_its_new_box() -> None:
    # A 6.0 m car; this scan its front 3 m is proposed, its rear in no proposal, and a point 0.2 m past its end falls
    # in the last voxel of its shape: the grown box (6.25 m) is no plausible car, so its score is halved
    # (docs/outputs.md: "score ... halved when the box is implausible").
    points = long_car_points(10.05, 16.05, extra=(16.3,))
    seen = np.arange(len(points)) < 40
    out = grown_car(points, seen, points[:, 0] <= 13.1, plausible=True)
    (car,) = out.voted.objects
    assert (out.voted.labels == CAR).all() and max(car.size[:2]) > 6.21
    assert not car.plausible and car.score == out.tracked[0].score * IMPLAUSIBLE_SCORE
    # A 4 m car proposed as a 0.5 m sliver (implausible, its score halved): grown back to the whole car, plausible,
    # its score is its track's share again.
    points = long_car_points(10.0, 14.0)
    everything = np.ones(len(points), bool)
    out = grown_car(points, everything, points[:, 0] <= 10.5, plausible=False)
    (car,) = out.voted.objects
    assert (out.voted.labels == CAR).all() and max(car.size[:2]) > 3.9
    assert car.plausible and car.score == out.tracked[0].score
