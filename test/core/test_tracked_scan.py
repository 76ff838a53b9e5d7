"""A scan's published objects through the stream's tracker (core/tracked_scan.py, ScanPipeline with tracking):
track ids published once confirmed, the vote applied to exactly the object's points, the levelled frame turned back,
and the pipeline holding one tracker per stream."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.objects import SPLIT_ID_STRIDE, FrameObjects, LabelledObject
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stream.tracks import Tracker
from pass3d_ros.core.tracked_scan import NO_TRACK, object_points, track_scan
from pass3d_ros.data.spec import open_dataset


def one_scan(person_label: int, person_score: float, x: float) -> FrameObjects:
    """Ten points: 0-3 a person (cluster 5), 4-5 background in proposal 5, 6-8 a car split off proposal 5
    (cluster 5 + SPLIT_ID_STRIDE), 9 in no proposal."""
    labels = np.array([person_label] * 4 + [BACKGROUND] * 2 + [CAR] * 3 + [BACKGROUND], np.uint8)
    cluster = np.array([5] * 6 + [5 + SPLIT_ID_STRIDE] * 3 + [-1], np.int32)
    objects = [LabelledObject((x, 2.0, -1.0), (0.6, 0.5, 1.7), 0.0, person_label, person_score, 5),
               LabelledObject((20.0, -3.0, -1.0), (4.0, 1.7, 1.5), 0.0, CAR, 0.9, 5 + SPLIT_ID_STRIDE)]
    return FrameObjects(labels, cluster, objects)


def test_object_points_are_each_object_s_points_split_ids_too() -> None:
    points, owner = object_points(one_scan(PEDESTRIAN, 0.8, 10.0))
    assert points.tolist() == [0, 1, 2, 3, 6, 7, 8] and owner.tolist() == [0, 0, 0, 0, 1, 1, 1]
    huge = one_scan(PEDESTRIAN, 0.8, 10.0)  # ids too far apart for the table: the binary search finds the same
    far = 3 * SPLIT_ID_STRIDE + 999_999
    huge.cluster_id[:6] = far
    huge.objects[0] = dataclasses.replace(huge.objects[0], cluster_id=far)
    points, owner = object_points(huge)
    assert points.tolist() == [0, 1, 2, 3, 6, 7, 8] and owner.tolist() == [0, 0, 0, 0, 1, 1, 1]


def test_the_vote_goes_onto_exactly_the_object_s_points_and_ids_wait_for_confirmation() -> None:
    tracker = Tracker()
    first = track_scan(tracker, one_scan(PEDESTRIAN, 0.9, 10.0), 0.0)
    assert first.track_id.tolist() == [NO_TRACK] * 10, "tentative tracks publish no id"
    assert [obj.track_id for obj in first.voted.objects] == [NO_TRACK, NO_TRACK]
    for k in range(1, 5):
        out = track_scan(tracker, one_scan(PEDESTRIAN, 0.9, 10.0 + 0.1 * k), 0.1 * k)
    weak = track_scan(tracker, one_scan(CYCLIST, 0.5, 10.5), 0.5)  # one weak rider sighting of the person
    assert weak.voted.labels.tolist() == [PEDESTRIAN] * 4 + [BACKGROUND] * 2 + [CAR] * 3 + [BACKGROUND]
    person, car = weak.voted.objects
    assert person.label == PEDESTRIAN and car.label == CAR
    assert person.track_id == out.voted.objects[0].track_id >= 0 and car.track_id >= 0
    assert person.track_id != car.track_id
    assert weak.track_id.tolist() == [person.track_id] * 4 + [NO_TRACK] * 2 + [car.track_id] * 3 + [NO_TRACK]
    assert weak.voted.cluster_id.tolist() == one_scan(CYCLIST, 0.5, 10.5).cluster_id.tolist()
    assert 0.5 < person.score < 1.0, "the voted class's share of the vote"


def test_a_levelled_scan_s_boxes_are_tracked_in_the_sensor_frame() -> None:
    tracker = Tracker()
    upside_down = np.diag([1.0, -1.0, -1.0])  # sensor -> level: a roll of 180 degrees
    track_scan(tracker, one_scan(PEDESTRIAN, 0.9, 10.0), 0.0, level=upside_down)
    assert np.allclose(tracker.tracks[0].state[:2], [10.0, -2.0])
    assert tracker.tracks[0].z == pytest.approx(1.0)


@pytest.fixture(scope="module")
def drive() -> list:
    return list(open_dataset("synthetic:drive=4,seed=5,sensor=hdl32e"))


def test_the_pipeline_holds_one_tracker_per_stream(drive: list) -> None:
    classifier = open_classifier(None, "size_rules")
    tracking = ScanPipeline(classifier=classifier, tracking=True)
    plain = ScanPipeline(classifier=classifier)
    ids = []
    for frame in drive:
        tracking.follow("a")
        out = tracking.run(frame.points, frame.ring, stamp_s=frame.stamp_ns * 1e-9, pose=frame.pose)
        alone = plain.run(frame.points, frame.ring)
        assert alone.tracked is None and alone.output is alone.published
        assert out.tracked is not None and out.output is out.tracked.voted
        # the same scan-by-scan objects; the vote changes points only into road-user classes: an object's points,
        # or background points a confirmed track held (with its id)
        assert np.array_equal(out.published.labels, alone.published.labels)
        changed = out.output.labels != out.published.labels
        assert np.all(out.output.labels[changed] != BACKGROUND)
        held = changed & (out.published.labels == BACKGROUND)
        assert np.all(out.tracked.track_id[held] >= 0)
        assert np.all(out.output.labels[out.tracked.track_id >= 0] != BACKGROUND)
        ids.append({obj.track_id for obj in out.output.objects} - {NO_TRACK})
    assert ids[0] == set() and len(ids[-1]) >= 3, ids
    assert len(ids[-1] & (ids[1] | ids[2])) >= 0.7 * len(ids[-1]), "most tracks of the last scan were seen before"
    tracking.follow("b")  # another stream: its tracks start over
    again = tracking.run(drive[0].points, drive[0].ring, stamp_s=0.0, pose=drive[0].pose)
    assert {obj.track_id for obj in again.output.objects} == {NO_TRACK}
    assert tracking.segmenter.tracker.born == 0


def person_scan(x: float, label: int, background: bool = False) -> tuple[FrameObjects, np.ndarray]:
    """A person of 40 points at (x, 2) standing on 30 ground points, as an object of class `label`, or (`background`)
    as points stage 2 called background in proposal 3; and the scan's points (level frame)."""
    rng = np.random.default_rng(int(x * 100))
    body = np.column_stack([rng.uniform(-0.25, 0.25, 40) + x, rng.uniform(-0.2, 0.2, 40) + 2.0,
                            rng.uniform(-1.7, 0.0, 40), np.full(40, 0.5)])
    floor = np.column_stack([rng.uniform(-3, 3, 30) + x, rng.uniform(-3, 3, 30) + 2.0, np.full(30, -1.75),
                             np.full(30, 0.5)])
    points = np.concatenate([body, floor]).astype(np.float32)
    labels = np.array([BACKGROUND if background else label] * 40 + [BACKGROUND] * 30, np.uint8)
    cluster = np.array([3] * 40 + [-1] * 30, np.int32)
    objects = [] if background else [LabelledObject((x, 2.0, -0.85), (0.5, 0.4, 1.7), 0.0, label, 0.9, 3)]
    return FrameObjects(labels, cluster, objects), points


def test_a_track_holds_the_background_points_stage_2_missed_on_its_footprint() -> None:
    tracker = Tracker()
    ground = np.array([False] * 40 + [True] * 30)
    for k in range(4):
        objects, points = person_scan(10.0 + 0.1 * k, PEDESTRIAN)
        seen = track_scan(tracker, objects, 0.1 * k, points=points, ground=ground)
    person = seen.voted.objects[0].track_id
    objects, points = person_scan(10.4, PEDESTRIAN, background=True)  # stage 2 missed the person
    held = track_scan(tracker, objects, 0.4, points=points, ground=ground)
    (obj,) = held.voted.objects
    assert obj.track_id == person and obj.label == PEDESTRIAN and obj.cluster_id == 3
    assert held.voted.labels.tolist() == [PEDESTRIAN] * 40 + [BACKGROUND] * 30, "the ground stays background"
    assert held.track_id.tolist() == [person] * 40 + [NO_TRACK] * 30
    assert tracker.tracks[0].misses == 0 and tracker.tracks[0].held == 1
    objects, points = person_scan(10.5, PEDESTRIAN, background=True)
    objects.cluster_id[:40] = -1  # stage 1 proposed none of it: the held object gets an id no point carries
    again = track_scan(tracker, objects, 0.5, points=points, ground=ground)
    assert [obj.cluster_id for obj in again.voted.objects] == [0] and again.voted.cluster_id[:40].tolist() == [0] * 40


def test_a_person_is_not_held_on_a_stream_slower_than_5_hz() -> None:
    """The same person seen four times and then missed by stage 2, at 2 Hz (nuScenes' key frames): a person walks more
    than their width between such scans, so the track waits instead of painting its old footprint (rule M2)."""
    tracker = Tracker()
    ground = np.array([False] * 40 + [True] * 30)
    for k in range(4):
        objects, points = person_scan(10.0, PEDESTRIAN)
        track_scan(tracker, objects, 0.5 * k, points=points, ground=ground)
    objects, points = person_scan(10.0, PEDESTRIAN, background=True)
    missed = track_scan(tracker, objects, 2.0, points=points, ground=ground)
    assert missed.voted.objects == [] and missed.voted.labels.tolist() == [BACKGROUND] * 70
    assert tracker.tracks[0].held == 0 and tracker.tracks[0].misses == 1


def test_a_track_of_unsure_sightings_is_not_held_and_a_held_track_runs_out() -> None:
    unsure = Tracker()
    for k in range(4):
        objects, points = person_scan(10.0, PEDESTRIAN)
        objects = FrameObjects(objects.labels, objects.cluster_id,
                               [dataclasses.replace(objects.objects[0], score=0.6)])
        track_scan(unsure, objects, 0.1 * k, points=points)
    objects, points = person_scan(10.0, PEDESTRIAN, background=True)
    assert track_scan(unsure, objects, 0.4, points=points).voted.objects == [], "mean confidence 0.6 < 0.8"
    sure = Tracker()
    for k in range(2):  # seen twice: held twice at most
        objects, points = person_scan(10.0, PEDESTRIAN)
        track_scan(sure, objects, 0.1 * k, points=points)
    held = []
    for k in range(2, 6):
        objects, points = person_scan(10.0, PEDESTRIAN, background=True)
        held.append(len(track_scan(sure, objects, 0.1 * k, points=points).voted.objects))
    assert held == [1, 1, 0, 0]


def test_a_track_found_again_is_held_only_once_seen_min_hits_times_more() -> None:
    """Clutter called a pedestrian twice, unseen until its track ended, then called a pedestrian once more: the track
    is found again (its id kept) but not held on the clutter's background points after that single sighting."""
    tracker = Tracker()
    stamps = iter(0.1 * k for k in range(100))

    def scan(background: bool = False):
        objects, points = person_scan(10.0, PEDESTRIAN, background)
        return track_scan(tracker, objects, next(stamps), points=points)

    scan(), scan()
    empty = FrameObjects(np.zeros(0, np.uint8), np.zeros(0, np.int32), [])
    for _ in range(tracker.config.max_misses + 1):
        track_scan(tracker, empty, next(stamps), points=np.zeros((0, 4), np.float32))
    assert tracker.lost == 1
    again = scan()
    assert again.tracked[0].track_id == 0 and again.tracked[0].confirmed
    assert scan(background=True).voted.objects == []
    scan()
    assert [obj.track_id for obj in scan(background=True).voted.objects] == [0], "seen min_hits times since: held"


def two_cars(merged: bool) -> tuple[FrameObjects, np.ndarray]:
    """Two parked cars side by side (x 10, y 0 and y 2.6; 60 points each on a 3.8 x 1.6 m box), as two objects
    (clusters 3 and 4) or, `merged`, as one object (cluster 3) that stage 1 joined; and the scan's points."""
    rng = np.random.default_rng(7)
    cars = [np.column_stack([rng.uniform(-1.9, 1.9, 60) + 10.0, rng.uniform(-0.8, 0.8, 60) + y,
                             rng.uniform(-1.7, -0.3, 60), np.full(60, 0.5)]) for y in (0.0, 2.6)]
    points = np.concatenate(cars).astype(np.float32)
    labels = np.full(120, CAR, np.uint8)
    if merged:
        cluster = np.full(120, 3, np.int32)
        objects = [LabelledObject((10.0, 1.3, -1.0), (3.8, 4.2, 1.4), 0.0, CAR, 0.9, 3)]
    else:
        cluster = np.repeat(np.array([3, 4], np.int32), 60)
        objects = [LabelledObject((10.0, y, -1.0), (3.8, 1.6, 1.4), 0.0, CAR, 0.9, c) for y, c in ((0.0, 3), (2.6, 4))]
    return FrameObjects(labels, cluster, objects), points


def test_an_object_stage_1_merged_is_shared_out_between_the_tracks_it_covers() -> None:
    tracker = Tracker()
    for k in range(3):
        objects, points = two_cars(merged=False)
        out = track_scan(tracker, objects, 0.1 * k, points=points)
    assert [o.track_id for o in out.voted.objects] == [0, 1]
    objects, points = two_cars(merged=True)
    out = track_scan(tracker, objects, 0.3, points=points)
    assert sorted(o.track_id for o in out.voted.objects) == [0, 1], "one object per car, each with its track"
    assert set(out.track_id[:60].tolist()) == {0} and set(out.track_id[60:].tolist()) == {1}
    ids = {o.track_id: o.cluster_id for o in out.voted.objects}
    assert ids[0] != ids[1] and set(out.voted.cluster_id[60:].tolist()) == {ids[1]}
    widths = sorted(min(o.size[:2]) for o in out.voted.objects)
    assert widths[-1] < 2.0, "each box fitted again to its car's points"
    assert tracker.alive == 2 and tracker.lost == 0


def test_a_merged_object_all_nearest_the_covered_track_stays_whole() -> None:
    """When every point of a merged object lies nearest the covered track's footprint, sharing it out would leave its
    own track an object of no point (a crash in box fitting once): the object stays whole, its own track's."""
    from pass3d_ros.core.stream.tracks import Tracked
    from pass3d_ros.core.tracked_scan import _PartIds, _shared_out

    objects, points = two_cars(merged=True)
    n = len(points)
    own, covered = Tracked(0, CAR, 0.9, True), Tracked(1, CAR, 0.8, True)
    far = np.array([[40.0, -20.0, -1.0]])  # the own track's footprint, nowhere near the points
    near = np.column_stack([points[:, :2], np.full(n, -1.0)])  # the covered track's, under every point
    voted = list(objects.objects)
    labels, cluster_id, track_id = objects.labels.copy(), objects.cluster_id.copy(), np.zeros(n, np.int32)
    made = _shared_out(points, voted, [own], np.arange(n), np.zeros(n, np.int64), {0: [(own, far), (covered, near)]},
                       None, labels, cluster_id, track_id, _PartIds(objects, objects.cluster_id))
    assert made == [] and voted == list(objects.objects)
    np.testing.assert_array_equal(cluster_id, objects.cluster_id)
