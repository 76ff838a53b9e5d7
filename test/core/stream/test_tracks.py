"""The stream's tracker (pass3d_ros.core.stream.tracks): ids that persist, classes voted over sightings, births after
min_hits, deaths after max_misses, ego motion from poses."""

from __future__ import annotations

import time

import numpy as np

from pass3d_ros.classes import CAR, PEDESTRIAN
from pass3d_ros.core.stream.footprints import Footprints
from pass3d_ros.core.stream.tracks import Tracker, TrackerConfig

SIZE = {CAR: (4.0, 1.7, 1.5), PEDESTRIAN: (0.6, 0.6, 1.7)}


def scan(tracker: Tracker, objects: list[tuple[float, float, int, float]], stamp: float, pose=None):
    centers = np.array([[x, y, -1.0] for x, y, _, _ in objects]).reshape(-1, 3)
    sizes = np.array([SIZE[label] for _, _, label, _ in objects]).reshape(-1, 3)
    return tracker.update(centers, sizes, [o[2] for o in objects], [o[3] for o in objects], stamp, pose)


def test_two_cars_crossing_keep_their_ids() -> None:
    tracker = Tracker()
    ids = []
    for k in range(30):  # 10 Hz: one car east at 10 m/s, one north at 8 m/s, their paths cross at (15, 0)
        t = 0.1 * k
        out = scan(tracker, [(0.0 + 10 * t, 0.0, CAR, 0.9), (15.0, -12.0 + 8 * t, CAR, 0.9)], t)
        ids.append((out[0].track_id, out[1].track_id))
    assert len(set(ids)) == 1 and ids[0][0] != ids[0][1]
    assert tracker.alive == 2 and tracker.born == 2 and tracker.lost == 0


def test_a_class_that_flickers_holds_the_vote_and_a_real_change_wins() -> None:
    tracker = Tracker()
    labels = []
    for k in range(12):
        label, conf = (CAR, 0.55) if k in (3, 6, 9) else (PEDESTRIAN, 0.8)  # a weak car sighting in every third
        labels.append(scan(tracker, [(10.0 + 0.13 * k, 2.0, label, conf)], 0.1 * k)[0].label)
    assert labels == [PEDESTRIAN] * 12
    for k in range(12, 40):
        out = scan(tracker, [(10.0 + 0.13 * k, 2.0, CAR, 0.9)], 0.1 * k)[0]
    assert out.label == CAR and out.track_id == 0


def test_births_wait_for_min_hits_and_tracks_end_after_max_misses() -> None:
    config = TrackerConfig(min_hits=2, max_misses=3)
    tracker = Tracker(config)
    first = scan(tracker, [(5.0, 5.0, PEDESTRIAN, 0.9)], 0.0)[0]
    assert not first.confirmed and tracker.born == 0
    assert scan(tracker, [(5.1, 5.0, PEDESTRIAN, 0.9)], 0.1)[0].confirmed and tracker.born == 1
    for k in range(config.max_misses):
        scan(tracker, [], 0.2 + 0.1 * k)
    assert tracker.alive == 1 and tracker.lost == 0
    scan(tracker, [], 0.6)
    assert tracker.alive == 0 and tracker.lost == 1
    again = scan(tracker, [(5.5, 5.0, PEDESTRIAN, 0.9)], 0.7)[0]
    assert again.track_id != first.track_id, "a new sighting after the track ended is a new object"


def test_with_poses_a_parked_car_stays_one_track_while_the_ego_drives_past() -> None:
    tracker = Tracker(TrackerConfig(gate_m=((CAR, 1.0),)))  # a tight gate: only the poses can keep it matched
    ids = set()
    for k in range(20):
        ego_x = 1.5 * k  # 15 m/s
        pose = np.eye(4)
        pose[0, 3] = ego_x
        out = scan(tracker, [(30.0 - ego_x, 4.0, CAR, 0.9)], 0.1 * k, pose)  # parked at world x = 30
        ids.add(out[0].track_id)
    assert ids == {0}


def test_sixty_objects_a_scan_cost_well_under_ten_milliseconds() -> None:
    """A smoke bound on the tracker's cost (its number lives in the benchmark, not here)."""
    rng = np.random.default_rng(0)
    start = rng.uniform(-40, 40, (60, 2))
    velocity = rng.uniform(-2, 2, (60, 2))
    tracker = Tracker()
    took = []
    for k in range(30):
        xy = start + velocity * 0.1 * k
        objects = [(x, y, CAR if j % 2 else PEDESTRIAN, 0.8) for j, (x, y) in enumerate(xy)]
        began = time.perf_counter()
        out = scan(tracker, objects, 0.1 * k)
        took.append(time.perf_counter() - began)
    assert len({o.track_id for o in out}) == 60
    assert np.median(took) < 0.01


def car_points(x: float, y: float, rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """x, y of `n` points on a 4 x 1.7 m car centred at (x, y)."""
    return np.column_stack([rng.uniform(-2.0, 2.0, n) + x, rng.uniform(-0.85, 0.85, n) + y])


def test_a_car_cut_in_two_stays_one_track_and_a_jumping_box_keeps_its_id() -> None:
    rng = np.random.default_rng(1)
    tracker = Tracker()
    for k in range(3):
        whole = car_points(20.0, 4.0, rng)
        out = tracker.update([[20.0, 4.0, -1.0]], [SIZE[CAR]], [CAR], [0.9], 0.1 * k, footprints=Footprints.of([whole]))
    car = out[0].track_id
    front, back = car_points(21.0, 4.0, rng, 30), car_points(19.0, 4.0, rng, 30)
    front, back = front[front[:, 0] > 20.0], back[back[:, 0] <= 20.0]
    cut = tracker.update([[21.0, 4.0, -1.0], [19.0, 4.0, -1.0]], [(2.0, 1.7, 1.5)] * 2, [CAR, PEDESTRIAN],
                         [0.9, 0.6], 0.3, footprints=Footprints.of([front, back]))
    assert [t.track_id for t in cut] == [car, car] and [t.label for t in cut] == [CAR, CAR]
    assert len(tracker.tracks) == 1, "a part starts no track of its own"
    # only the car's rear seen, its box centre 3.5 m from the prediction (beyond the 3 m gate): its points match
    rear = car_points(20.0, 4.0, rng)
    rear = rear[rear[:, 0] < 18.5]
    jumped = tracker.update([[16.5, 4.0, -1.0]], [(1.0, 1.7, 1.5)], [CAR], [0.9], 0.4, footprints=Footprints.of([rear]))
    assert jumped[0].track_id == car
    without = Tracker()  # without footprints the same jump is a new object
    for k in range(3):
        without.update([[20.0, 4.0, -1.0]], [SIZE[CAR]], [CAR], [0.9], 0.1 * k)
    assert without.update([[16.5, 4.0, -1.0]], [(1.0, 1.7, 1.5)], [CAR], [0.9], 0.4)[0].track_id != car
