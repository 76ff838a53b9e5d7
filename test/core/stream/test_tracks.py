"""The stream's tracker (pass3d_ros.core.stream.tracks): ids that persist, classes voted over sightings, births after
min_hits, deaths after max_misses, ego motion from poses."""

from __future__ import annotations

import time

import numpy as np

from pass3d_ros.classes import CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.stream.footprints import Footprints, edge_shifts
from pass3d_ros.core.stream.tracks import Tracker, TrackerConfig

SIZE = {CAR: (4.0, 1.7, 1.5), PEDESTRIAN: (0.6, 0.6, 1.7), CYCLIST: (1.7, 0.6, 1.7)}


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
        label, conf = (CYCLIST, 0.55) if k in (3, 6, 9) else (PEDESTRIAN, 0.8)  # a weak rider sighting in every third
        labels.append(scan(tracker, [(10.0 + 0.13 * k, 2.0, label, conf)], 0.1 * k)[0].label)
    assert labels == [PEDESTRIAN] * 12
    for k in range(12, 40):
        out = scan(tracker, [(10.0 + 0.13 * k, 2.0, CYCLIST, 0.9)], 0.1 * k)[0]
    assert out.label == CYCLIST and out.track_id == 0


def test_a_car_and_a_person_never_match() -> None:
    """A person's track is not taken by a car detection on its place (nor a car's by a person's): a new track."""
    tracker = Tracker()
    for k in range(4):
        scan(tracker, [(10.0, 2.0, PEDESTRIAN, 0.9)], 0.1 * k)
    out = scan(tracker, [(10.0, 2.0, CAR, 0.9)], 0.4)[0]
    assert out.track_id != 0 and out.label == CAR and not out.confirmed
    allowed = Tracker(TrackerConfig(never_match=()))
    for k in range(4):
        scan(allowed, [(10.0, 2.0, PEDESTRIAN, 0.9)], 0.1 * k)
    assert scan(allowed, [(10.0, 2.0, CAR, 0.9)], 0.4)[0].track_id == 0, "without never_match the class penalty only"


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
    assert again.track_id == first.track_id and again.confirmed, "found again within reid_misses: the same object"
    for k in range(config.max_misses + config.reid_misses + 1):
        scan(tracker, [], 0.8 + 0.1 * k)
    later = scan(tracker, [(5.5, 5.0, PEDESTRIAN, 0.9)], 3.0)[0]
    assert later.track_id != first.track_id and not later.confirmed, "long gone: a new sighting is a new object"


def test_an_ended_track_is_found_again_only_by_an_object_no_live_track_takes() -> None:
    tracker = Tracker(TrackerConfig(max_misses=1))
    for k in range(5):  # a pedestrian at x = 5 and one at x = 6.2, both still
        scan(tracker, [(5.0, 0.0, PEDESTRIAN, 0.9), (6.2, 0.0, PEDESTRIAN, 0.9)], 0.1 * k)
    for k in range(5, 8):  # the first goes unseen and ends; the second stays
        out = scan(tracker, [(6.2, 0.0, PEDESTRIAN, 0.9)], 0.1 * k)
    assert [t.track_id for t in out] == [1] and tracker.lost == 1
    out = scan(tracker, [(5.0, 0.0, PEDESTRIAN, 0.9), (6.2, 0.0, PEDESTRIAN, 0.9)], 0.8)
    assert [t.track_id for t in out] == [0, 1]
    assert tracker.lost == 0 and tracker.alive == tracker.born - tracker.lost == 2, "found again: not lost"


def test_one_good_pair_beats_two_poor_ones() -> None:
    """A car cut in two fragments: its track takes the fragment on its place, though the other fragment lies within
    its gate too and a neighbour's track could then take this one (a least summed cost matches the most pairs)."""
    tracker = Tracker()
    for k in range(5):  # two parked cars, 2.8 m apart along y
        scan(tracker, [(20.0, 0.0, CAR, 0.9), (20.0, 2.8, CAR, 0.9)], 0.1 * k)
    out = scan(tracker, [(20.0, -2.0, CAR, 0.9), (20.0, 0.1, CAR, 0.9)], 0.5)  # the first car's two ends
    assert out[1].track_id == 0, "the fragment on the first car's place keeps its track"
    assert out[0].track_id != 1, "the second car's track does not take the first car's fragment"


def test_a_box_that_grows_moves_its_centre_without_making_the_object_move() -> None:
    """A parked car seen first by its rear (a 1 m box), then whole (4 m): the centre moves 1.5 m in a scan, the
    object does not; a new view corrects the position only, so the track's speed stays low."""
    speeds = {}
    for reshape in (None, 0.5):
        tracker = Tracker(TrackerConfig(reshape_m=reshape))
        for k, length in enumerate((1.0, 1.0, 4.0, 4.0)):
            centers = np.array([[20.0 + length / 2, 0.0, -1.0]])
            tracker.update(centers, np.array([[length, 1.7, 1.5]]), [CAR], [0.9], 0.1 * k)
        speeds[reshape] = float(np.hypot(*tracker.tracks[0].state[2:]))
    assert speeds[0.5] < 0.5 and speeds[None] > 3.0


def test_another_end_of_a_tracked_car_joins_its_track() -> None:
    """A parked car passed by: its rear is tracked, then its front comes into view as a detection of its own 0.3 m
    away; both fit one car, so the front takes the car's track and starts none. A car 6 m away is another car."""
    tracker = Tracker()

    def footprint(*boxes: tuple[float, float, float]) -> Footprints:
        grid = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 5), np.linspace(-0.5, 0.5, 5)), -1).reshape(-1, 2)
        return Footprints.of([grid * [length, 1.6] + [x, y] for x, y, length in boxes])

    for k in range(3):
        tracker.update(np.array([[20.0, 0.0, -1.0]]), np.array([[1.5, 1.6, 1.5]]), [CAR], [0.9], 0.1 * k,
                       footprints=footprint((20.0, 0.0, 1.5)))
    out = tracker.update(np.array([[20.0, 0.0, -1.0], [21.8, 0.0, -1.0], [27.0, 0.0, -1.0]]),
                         np.array([[1.5, 1.6, 1.5], [1.5, 1.6, 1.5], [1.5, 1.6, 1.5]]), [CAR, CAR, CAR], [0.9] * 3,
                         0.3, footprints=footprint((20.0, 0.0, 1.5), (21.8, 0.0, 1.5), (27.0, 0.0, 1.5)))
    assert out[0].track_id == out[1].track_id == 0
    assert out[2].track_id != 0


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


def test_a_moving_car_takes_no_fragment_beside_it() -> None:
    """A car driving east at 10 m/s passes a parked car's fragment 1.5 m to its side: together they would fit one
    car across the road, not along it, so the fragment is no end of the moving car."""
    tracker = Tracker()

    def footprint(*centres: tuple[float, float]) -> Footprints:
        grid = np.stack(np.meshgrid(np.linspace(-0.7, 0.7, 5), np.linspace(-0.3, 0.3, 3)), -1).reshape(-1, 2)
        return Footprints.of([grid + centre for centre in centres])

    for k in range(5):
        x = 10.0 + 1.0 * k
        tracker.update(np.array([[x, 0.0, -1.0]]), np.array([[1.4, 0.6, 1.5]]), [CAR], [0.9], 0.1 * k,
                       footprints=footprint((x, 0.0)))
    out = tracker.update(np.array([[15.0, 0.0, -1.0], [15.0, 1.5, -1.0]]), np.array([[1.4, 0.6, 1.5]] * 2),
                         [CAR, CAR], [0.9, 0.9], 0.5, footprints=footprint((15.0, 0.0), (15.0, 1.5)))
    assert out[0].track_id == 0 and out[1].track_id != 0


def test_another_view_of_a_waiting_car_track_is_its_sighting() -> None:
    """A parked car tracked by a 0.8 m piece of its rear, then seen only by its side, whose box centre lies 3.1 m away
    (past the 3 m gate, no cell shared): the side and the remembered piece fit one car, so the side is the waiting
    track's sighting (without waiting_views, a new track). A car whose points begin 4.2 m beyond is another car."""
    rng = np.random.default_rng(3)

    def piece(x0: float, x1: float, n: int) -> np.ndarray:
        return np.column_stack([rng.uniform(x0, x1, n), rng.uniform(-0.8, 0.8, n) + 4.0])

    def run(config: TrackerConfig, side: tuple[float, float]) -> tuple[int, int]:
        tracker = Tracker(config)
        for k in range(3):
            rear = piece(20.0, 20.8, 30)
            first = tracker.update([[20.4, 4.0, -1.0]], [(0.8, 1.6, 1.5)], [CAR], [0.9], 0.1 * k,
                                   footprints=Footprints.of([rear]))
        length = side[1] - side[0]
        later = tracker.update([[(side[0] + side[1]) / 2, 4.0, -1.0]], [(length, 1.6, 1.5)], [CAR], [0.9], 0.3,
                               footprints=Footprints.of([piece(*side, 60)]))
        return first[0].track_id, later[0].track_id

    first, later = run(TrackerConfig(waiting_views=True), (22.2, 24.8))
    assert later == first
    first, later = run(TrackerConfig(waiting_views=False), (22.2, 24.8))
    assert later != first, "without waiting_views the jump starts a new track"
    first, later = run(TrackerConfig(waiting_views=True), (25.0, 27.6))
    assert later != first, "a union longer than one car is another car"


def test_an_implausible_box_starts_no_track_but_still_matches_one() -> None:
    """A detection whose box cannot be one object of its class starts no track (rule M4): it has none this scan, no
    id is spent on it and nothing is born; a plausible detection of the same object later starts one, and an
    implausible one on a track's place keeps that track."""
    tracker = Tracker()
    centers, sizes = np.array([[10.0, 2.0, -1.0]]), np.array([[1.2, 0.2, 0.01]])  # a sliver of a car's roof
    for k in range(3):
        said = tracker.scan(centers, sizes, [CAR], [0.9], 0.1 * k, plausible=[False]).detections[0]
        assert said.track_id == -1 and not said.confirmed and said.label == CAR
    assert tracker.tracks == [] and tracker.born == 0
    for k in range(3, 6):
        said = tracker.scan(centers, np.array([SIZE[CAR]]), [CAR], [0.9], 0.1 * k, plausible=[True]).detections[0]
    assert said.track_id == 0 and said.confirmed
    said = tracker.scan(centers, sizes, [CAR], [0.9], 0.6, plausible=[False]).detections[0]
    assert said.track_id == 0, "an implausible box may still be its track's sighting"
    born = Tracker(TrackerConfig(implausible_births=True))
    assert born.scan(centers, sizes, [CAR], [0.9], 0.0, plausible=[False]).detections[0].track_id == 0


def _car_points(x0: float, x1: float, y: float = 0.0) -> np.ndarray:
    """A car's side seen from x0 to x1 (m) and its end at x0: footprint points."""
    side = np.column_stack([np.linspace(x0, x1, 30), np.full(30, y - 0.8)])
    end = np.column_stack([np.full(8, x0), np.linspace(y - 0.8, y + 0.8, 8)])
    return np.vstack([side, end])


def test_edge_shifts_read_a_move_from_the_edge_that_moved_least() -> None:
    """Both ends moved: the move; one end kept (another view of a parked car): no move; too few points: unread."""
    whole = _car_points(18.0, 22.0)
    state = np.array([[20.0, 0.0, 0.0, 0.0]])
    offsets = np.zeros((1, 128, 2))
    offsets[0, :len(whole)] = whole - state[0, :2]
    counts = np.array([len(whole)])
    rows = np.array([0])
    for seen, want in ((_car_points(19.0, 23.0), (1.0, 0.0)), (_car_points(18.0, 19.5), (0.0, 0.0))):
        shifts, _, read = edge_shifts(rows, state, offsets, counts, seen, np.array([0, len(seen)]))
        assert read[0] and np.allclose(shifts[0], want, atol=0.05), (shifts, want)
    _, _, read = edge_shifts(rows, state, offsets, counts, whole[:3], np.array([0, 3]))
    assert not read[0]


def test_a_parked_car_whose_box_jumps_between_views_does_not_start_driving() -> None:
    """A parked car 4 m long, tracked whole, then cut in two (both halves its track's) and seen by one half or the
    other: boxes of one size whose centres jump 2.2 m. Read from the edge its points kept, it stands still, so its
    track's speed stays low; without `edge_shift` the track takes up the jumps as a speed. A car driving 10 m/s
    seen whole keeps its speed."""
    speeds = {}
    for on in (False, True):
        tracker = Tracker(TrackerConfig(edge_shift=on))
        top = 0.0
        for k in range(14):
            if k < 3:
                views = [(18.0, 22.0)]
            elif k % 2:
                views = [(18.0, 19.8), (20.2, 22.0)]
            else:
                views = [(18.0, 19.8)] if k % 4 == 0 else [(20.2, 22.0)]
            out = tracker.update(np.array([[(a + b) / 2, 0.0, -1.0] for a, b in views]),
                                 np.array([[b - a, 1.6, 1.5] for a, b in views]), [CAR] * len(views),
                                 [0.9] * len(views), 0.1 * k, footprints=Footprints.of([_car_points(a, b)
                                                                                        for a, b in views]))
            assert {said.track_id for said in out} == {0}
            top = max(top, float(np.hypot(*tracker.tracks[0].state[2:])))
        speeds[on] = top
    assert speeds[True] < 1.0 and speeds[False] > 3.0, speeds
    tracker = Tracker(TrackerConfig(edge_shift=True))
    for k in range(12):
        x = 10.0 + 1.0 * k
        tracker.update(np.array([[x, 0.0, -1.0]]), np.array([[4.0, 1.6, 1.5]]), [CAR], [0.9], 0.1 * k,
                       footprints=Footprints.of([_car_points(x - 2.0, x + 2.0)]))
    assert abs(tracker.tracks[0].state[2] - 10.0) < 1.0 and len(tracker.tracks) == 1


def test_a_faint_fragment_beside_a_person_does_not_take_the_person_s_track() -> None:
    """A walking person tracked stops as a faint fragment (confidence 0.45) appears nearer the track's prediction
    than the person's own detection (0.99): matched in two rounds the person keeps the track; in one round (the most
    summed margin) the fragment takes it."""
    for first, keeps in ((0.6, True), (0.0, False)):  # 0.0, one round: the default (rule W)
        tracker = Tracker(TrackerConfig(first_score=first))
        for k in range(5):
            scan(tracker, [(10.0, 0.15 * k, PEDESTRIAN, 0.99)], 0.1 * k)  # walking 1.5 m/s: predicted at 0.75 m next
        out = scan(tracker, [(10.0, 0.6, PEDESTRIAN, 0.99), (10.0, 0.8, PEDESTRIAN, 0.45)], 0.5)  # stopped
        assert (out[0].track_id == 0) is keeps, (first, out)
