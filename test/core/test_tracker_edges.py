"""The tracker on input at its edges: a detection that is not finite, footprint points that are not finite or lie
astronomically far apart, and remembered shapes a stamp jump carries hundreds of kilometres apart. Each scan must
leave the tracker running, its tracks finite and its memory bounded."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pass3d_ros.classes import CAR
from pass3d_ros.core.objects import FrameObjects, LabelledObject
from pass3d_ros.core.stream.footprints import cell_sets, cells
from pass3d_ros.core.stream.shapes import ShapeMemory
from pass3d_ros.core.stream.tracks import NO_TRACK, Tracker
from pass3d_ros.core.tracked_scan import track_scan


def car_scan(x: float) -> tuple[FrameObjects, np.ndarray]:
    """Forty points of a car at (x, 2) (cluster 0) and ten of background, and the car's object."""
    rng = np.random.default_rng(int(10 * x))
    car = np.array([x, 2.0, -0.9]) + rng.uniform(-0.5, 0.5, (40, 3)) * [4.0, 1.8, 1.5]
    points = np.vstack([car, rng.uniform(-20.0, 20.0, (10, 3))]).astype(np.float32)
    labels = np.array([CAR] * 40 + [0] * 10, np.uint8)
    cluster_id = np.array([0] * 40 + [-1] * 10, np.int32)
    low, high = car.min(axis=0), car.max(axis=0)
    obj = LabelledObject(tuple((0.5 * (low + high)).tolist()), tuple((high - low).tolist()), 0.0, CAR, 0.9, 0)
    return FrameObjects(labels, cluster_id, [obj]), points


@pytest.mark.parametrize("field, value", [("center", (np.nan, 2.0, -0.9)), ("center", (np.inf, 2.0, -0.9)),
                                          ("size", (np.nan, 1.8, 1.5)), ("size", (4.0, np.inf, 1.5)),
                                          ("score", np.nan), ("score", np.inf)])
def test_a_detection_not_finite_is_in_no_track_and_the_track_goes_on(field: str, value: object) -> None:
    tracker = Tracker()
    for k in range(4):
        objects, points = car_scan(8.0 + 0.5 * k)
        seen = track_scan(tracker, objects, 0.1 * k, points=points)
    track = seen.voted.objects[0].track_id
    assert track >= 0
    objects, points = car_scan(10.0)
    bad = FrameObjects(objects.labels, objects.cluster_id, [dataclasses.replace(objects.objects[0], **{field: value})])
    out = track_scan(tracker, bad, 0.4, points=points)
    assert out.tracked[0].track_id == NO_TRACK and out.voted.objects[0].track_id == NO_TRACK
    assert np.isfinite(tracker.store.state[tracker._live()]).all() and np.isfinite(tracker.store.box).all()
    objects, points = car_scan(10.5)
    after = track_scan(tracker, objects, 0.5, points=points)
    assert after.voted.objects[0].track_id == track, "the scan after one bad object finds its track again"
    assert np.isfinite(after.voted.objects[0].score)


def test_footprint_cells_of_points_not_finite_or_far_apart_are_found_without_a_crash() -> None:
    far = np.array([[-3e18, 0.0], [3e18, 0.0], [0.0, 0.0]])  # their cells' span overflows int64
    keys, starts = cell_sets(far, [3])
    assert starts.tolist() == [0, 3] and keys.tolist() == cells(far).tolist()
    keys, starts = cell_sets(np.array([[0.2, 0.3], [np.nan, np.nan], [np.inf, 0.0], [0.1, 0.1]]), [4])
    assert starts.tolist() == [0, len(keys)] and len(keys) <= 3
    assert np.isin(cells(np.array([[0.2, 0.3]])), keys).all()


def two_moving_shapes() -> ShapeMemory:
    """Two car tracks' shapes (ids 0 and 1) of one sighting each at stamp 0, a cube about (1, 1)."""
    memory = ShapeMemory(2)
    cube = np.array([[1.0, 1.0, 0.0], [1.5, 1.2, 0.5], [0.0, 0.0, 0.0], [0.1, 0.1, 0.0]], np.float32)
    identity = (np.eye(3), np.zeros(3))
    memory.remember([0, 1], 0.0, cube, np.arange(4), np.full(4, CAR, np.uint8), np.array([0, 0, 1, 1], np.int32),
                    CAR, identity)
    return memory


def test_shapes_a_stamp_jump_carries_far_apart_are_searched_in_bounded_memory() -> None:
    memory = two_moving_shapes()
    hours = 36000.0  # ten hours at 10 m/s: the two shapes 360 km apart, once a grid of 10^11 cells
    points = np.array([[1.0 + 10.0 * hours, 1.0, 0.0], [0.0, 10.0 * hours, 0.0], [1.0, 1.0, 0.0]], np.float32)
    owner = memory.owners(points, np.zeros(3, np.uint8), np.full(3, -1, np.int32), None, (np.eye(3), np.zeros(3)),
                          [0, 1], np.array([[10.0, 0.0], [0.0, 10.0]]), hours)
    assert owner.tolist() == [0, 1, -1]


def test_shapes_skip_points_not_finite() -> None:
    memory = two_moving_shapes()
    points = np.array([[np.nan, np.nan, np.nan], [np.inf, 1.0, 0.0], [1.0, 1.0, 0.0]], np.float32)
    owner = memory.owners(points, np.zeros(3, np.uint8), np.full(3, -1, np.int32), None, (np.eye(3), np.zeros(3)),
                          [0, 1], np.zeros((2, 2)), 0.1)
    assert owner.tolist() == [-1, -1, 0]


@pytest.mark.parametrize("points_kept, ground_kept", [(50, 5), (50, 49), (45, None)])
def test_points_or_ground_of_another_length_are_refused_before_the_tracker_is_touched(
        points_kept: int, ground_kept: int | None) -> None:
    tracker = Tracker()
    for k in range(4):
        objects, points = car_scan(8.0 + 0.5 * k)
        track_scan(tracker, objects, 0.1 * k, points=points)
    state = tracker.store.state.copy()
    objects, points = car_scan(30.0)  # the car missed: its track waits on the background points
    missed = FrameObjects(np.zeros(50, np.uint8), np.full(50, -1, np.int32), [])
    ground = None if ground_kept is None else np.zeros(ground_kept, bool)
    with pytest.raises(ValueError, match="50 labels"):
        track_scan(tracker, missed, 0.4, points=points[:points_kept], ground=ground)
    assert np.array_equal(tracker.store.state, state)
    objects, points = car_scan(10.0)
    assert track_scan(tracker, objects, 0.4, points=points).voted.objects[0].track_id >= 0
