"""The objects of a labelled frame and the labels and cluster ids published with them (core/objects.py
frame_objects), as /pass3d/labeled, /pass3d/detections, the markers and pass3d_segment's files carry them: one object
concept (every road-user point belongs to exactly one object of its class), boxes fitted to exactly an object's
points, implausible sizes flagged, groups of people split; no ROS needed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.objects import assert_one_object_per_point_group

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.objects import (
    IMPLAUSIBLE_SCORE,
    MIN_OBJECT_POINTS,
    MIN_SIZE,
    PLAUSIBLE_SIZE,
    SPLIT_ID_STRIDE,
    FrameObjects,
    frame_objects,
    objects_json,
    plausible_size,
)


def rectangle(center: tuple[float, float], size: tuple[float, float, float], yaw: float, n: int = 400,
              seed: int = 0) -> np.ndarray:
    """`n` points (x, y, z, intensity) filling an oriented box standing on z = 0."""
    rng = np.random.default_rng(seed)
    local = rng.uniform(-0.5, 0.5, (n, 3)) * np.asarray(size)
    local[:, 2] += size[2] / 2
    c, s = np.cos(yaw), np.sin(yaw)
    xy = local[:, :2] @ np.array([[c, s], [-s, c]]) + np.asarray(center)
    return np.column_stack([xy, local[:, 2], np.full(n, 0.5)]).astype(np.float32)


@pytest.fixture
def scan5() -> dict[str, np.ndarray | list]:
    """A car (with ground points of its enlarged box labelled background), a pedestrian, a proposal called
    background, one cut by the budget (-1) and a cyclist proposal none of whose points kept the class."""
    car = rectangle((10.0, 2.0), (4.0, 1.6, 1.5), 0.3)
    ground = np.column_stack([np.random.default_rng(1).uniform(7, 13, (100, 2)), np.zeros(100), np.full(100, 0.1)])
    person = rectangle((5.0, -3.0), (0.6, 0.5, 1.7), 0.0, n=80, seed=2)
    pole = rectangle((20.0, 0.0), (0.2, 0.2, 3.0), 0.0, n=50, seed=3)
    far = rectangle((40.0, 0.0), (4.0, 1.6, 1.5), 0.0, n=30, seed=4)
    lost = rectangle((15.0, 5.0), (1.7, 0.6, 1.7), 0.0, n=40, seed=5)
    parts = [car, ground.astype(np.float32), person, pole, far, lost]
    points = np.concatenate(parts)
    starts = np.cumsum([0] + [len(p) for p in parts])
    span = [np.arange(starts[k], starts[k + 1]) for k in range(len(parts))]
    labels = np.zeros(len(points), np.uint8)
    labels[span[0]], labels[span[2]] = CAR, PEDESTRIAN
    confidence = np.full(len(points), 0.5, np.float32)
    confidence[span[0]] = np.linspace(0.6, 1.0, len(span[0]))
    confidence[span[2]] = 0.8
    owner = np.repeat([0, 0, 1, 2, 3, 4], [len(p) for p in parts])
    proposal_class = np.array([CAR, PEDESTRIAN, BACKGROUND, -1, CYCLIST], np.int16)
    return {"points": points, "labels": labels, "confidence": confidence, "owner": owner,
            "proposal_class": proposal_class, "span": span}


def objects_of(scan5: dict, ids: list[int] | None = None) -> FrameObjects:
    point_ids = None if ids is None else np.asarray(ids)[scan5["owner"]]
    return frame_objects(scan5["points"], scan5["owner"], scan5["proposal_class"], scan5["labels"],
                         scan5["confidence"], point_ids)


def check(out: FrameObjects) -> None:
    assert_one_object_per_point_group(out.labels, out.cluster_id, [(o.cluster_id, o.label) for o in out.objects])


def test_one_object_per_labelled_proposal_boxed_on_its_points_of_that_class(scan5: dict) -> None:
    out = objects_of(scan5, ids=[7, 3, 11, 12, 20])
    check(out)
    assert [(o.class_id, o.cluster_id) for o in out.objects] == [("car", 7), ("pedestrian", 3)], \
        "background, unclassified and classless proposals give no object"
    car, person = out.objects
    np.testing.assert_array_equal(out.labels, scan5["labels"])  # nothing to resolve: the labels stay
    np.testing.assert_array_equal(out.cluster_id, np.asarray([7, 3, 11, 12, 20])[scan5["owner"]])
    np.testing.assert_allclose(car.center, (10.0, 2.0, 0.75), atol=0.1)
    np.testing.assert_allclose(car.size, (4.0, 1.6, 1.5), atol=0.1)  # the ground points of its enlarged box left out
    assert car.yaw == pytest.approx(0.3, abs=0.02)
    assert car.score == pytest.approx(float(np.mean(scan5["confidence"][scan5["span"][0]], dtype=np.float64)))
    assert person.score == pytest.approx(0.8) and car.plausible and person.plausible
    assert car.box().contains(scan5["points"][scan5["span"][0], :3], margin=(1e-4, 1e-4, 1e-4)).all()


def test_confidence_threshold_and_default_ids(scan5: dict) -> None:
    labels = scan5["labels"].copy()
    labels[scan5["span"][2]] = BACKGROUND  # the pedestrian's points fell below min_confidence
    scan5["labels"] = labels
    out = objects_of(scan5)
    assert [(o.class_id, o.cluster_id) for o in out.objects] == [("car", 0)]
    check(out)


def test_mixed_proposals_resolve_to_one_object_per_point_group(scan5: dict) -> None:
    """Stray points of another class take the proposal's class; enough of them are an object of their own (id +
    SPLIT_ID_STRIDE); road-user points of a background proposal are an object when enough, else background; points of
    an unclassified proposal (a point whose label came from a second proposal) are background."""
    labels, span = scan5["labels"].copy(), scan5["span"]
    labels[span[0][:3]] = PEDESTRIAN  # 3 stray pedestrian points in the car: car
    labels[span[0][3:3 + MIN_OBJECT_POINTS]] = CYCLIST  # enough cyclist points in the car: an object of their own
    labels[span[3][:MIN_OBJECT_POINTS + 5]] = CAR  # a background proposal with car points: a car
    labels[span[3][-2:]] = PEDESTRIAN  # and two stray pedestrian points: background
    labels[span[4][:5]] = CAR  # labelled through another proposal, published with an unclassified one: background
    labels[span[5][:4]] = PEDESTRIAN  # a cyclist proposal whose only road-user points are 4 pedestrian ones
    scan5["labels"] = labels
    out = objects_of(scan5, ids=[7, 3, 11, 12, 20])
    check(out)
    assert [(o.class_id, o.cluster_id) for o in out.objects] == [
        ("car", 7), ("cyclist", 7 + SPLIT_ID_STRIDE), ("pedestrian", 3), ("car", 11)]
    assert (out.labels[span[0][:3]] == CAR).all()
    assert (out.labels[span[0][3:3 + MIN_OBJECT_POINTS]] == CYCLIST).all()
    assert (out.cluster_id[span[0][3:3 + MIN_OBJECT_POINTS]] == 7 + SPLIT_ID_STRIDE).all()
    assert (out.labels[span[3][-2:]] == BACKGROUND).all() and (out.labels[span[4]] == BACKGROUND).all()
    assert (out.labels[span[5]] == BACKGROUND).all()
    assert out.objects[0].proposal_id == out.objects[1].proposal_id == 7


def test_a_point_belongs_to_the_proposal_it_is_published_with() -> None:
    """Two proposals overlap: the boxes hold only the points each one publishes."""
    left, right = rectangle((5, 0), (0.6, 0.5, 1.7), 0.0, n=60, seed=1), rectangle((5, 1.5), (0.6, 0.5, 1.7), 0.0,
                                                                                   n=60, seed=2)
    points = np.concatenate([left, right])
    owner = np.repeat([0, 1], 60)
    labels = np.full(120, PEDESTRIAN, np.uint8)
    out = frame_objects(points, owner, np.array([PEDESTRIAN, PEDESTRIAN]), labels, np.ones(120, np.float32))
    check(out)
    assert [o.size[0] < 0.8 for o in out.objects] == [True, True]


def test_degenerate_groups_get_positive_sizes() -> None:
    points = np.array([[1, 2, 0, 0.5], [5, 5, 1, 0.5], [6, 5, 1, 0.5]], np.float32)
    out = frame_objects(points, np.array([0, 1, 1]), np.array([PEDESTRIAN, CYCLIST]),
                        np.array([PEDESTRIAN, CYCLIST, CYCLIST]), np.array([0.9, 0.7, 0.5]))
    assert len(out.objects) == 2
    first, second = out.objects
    assert first.size == (MIN_SIZE, MIN_SIZE, MIN_SIZE) and first.center == pytest.approx((1, 2, 0))
    assert not first.plausible and first.score == pytest.approx(0.9 * IMPLAUSIBLE_SCORE)
    assert second.size == pytest.approx((1.0, MIN_SIZE, MIN_SIZE)) and second.score == pytest.approx(0.6 * 0.5)
    empty = frame_objects(points, np.full(3, -1), np.zeros(0, np.int16), np.zeros(3), np.zeros(3))
    assert empty.objects == [] and (empty.labels == 0).all() and (empty.cluster_id == -1).all()


def test_mismatched_inputs_are_refused(scan5: dict) -> None:
    with pytest.raises(ValueError, match="labels"):
        frame_objects(scan5["points"], scan5["owner"], scan5["proposal_class"], scan5["labels"][:-1],
                      scan5["confidence"])
    with pytest.raises(ValueError, match="proposal classes"):
        frame_objects(scan5["points"], scan5["owner"], scan5["proposal_class"][:-1], scan5["labels"],
                      scan5["confidence"])
    with pytest.raises(ValueError, match="cluster ids"):
        frame_objects(scan5["points"], scan5["owner"], scan5["proposal_class"], scan5["labels"],
                      scan5["confidence"], np.zeros(3))


def test_sizes_outside_their_class_are_flagged() -> None:
    """The two boxes of the issue: a "car" 0.47 x 0.09 x 0.27 m and a "pedestrian" 2.49 x 0.88 x 1.76 m whose points
    do not fall apart (no split): both flagged, score halved; the class means themselves are plausible."""
    assert not plausible_size(CAR, (0.47, 0.09, 0.27)) and not plausible_size(PEDESTRIAN, (2.49, 0.88, 1.76))
    assert plausible_size(CAR, (3.88, 1.63, 1.53)) and plausible_size(CAR, (1.90, 5.07, 2.21))  # a van, sideways
    assert plausible_size(PEDESTRIAN, (0.66, 0.84, 1.76)) and plausible_size(CYCLIST, (1.76, 0.60, 1.74))
    assert set(PLAUSIBLE_SIZE) == {CAR, PEDESTRIAN, CYCLIST}
    small = rectangle((8, 0), (0.47, 0.09, 0.27), 0.0, n=40, seed=1)
    crowd = rectangle((4, 3), (2.49, 0.88, 1.76), 0.0, n=400, seed=2)  # dense: no gap to split at
    points = np.concatenate([small, crowd])
    labels = np.repeat(np.array([CAR, PEDESTRIAN], np.uint8), [40, 400])
    out = frame_objects(points, np.repeat([0, 1], [40, 400]), np.array([CAR, PEDESTRIAN]), labels,
                        np.full(440, 0.8, np.float32))
    check(out)
    assert [(o.class_id, o.plausible) for o in out.objects] == [("car", False), ("pedestrian", False)]
    assert out.objects[0].score == pytest.approx(0.8 * IMPLAUSIBLE_SCORE) and out.groups_split == 0
    assert json.loads(objects_json("f", out.objects))["objects"][1]["plausible"] is False


def test_a_group_of_people_is_split_into_one_object_per_person() -> None:
    """Three people 0.9 m apart in one pedestrian proposal (a 2.3 m wide box): three objects, one per person, the
    largest keeping the cluster id, the others cluster id + k * SPLIT_ID_STRIDE, in the cloud too; a lone person and
    a group whose points touch are left whole."""
    people = [rectangle((6, y), (0.5, 0.4, 1.7), 0.0, n=n, seed=k) for k, (y, n) in enumerate([(0, 70), (0.9, 90),
                                                                                              (1.8, 50)])]
    alone = rectangle((12, -4), (0.6, 0.5, 1.75), 0.0, n=60, seed=7)
    points = np.concatenate([*people, alone])
    owner = np.repeat([0, 1], [210, 60])
    labels = np.full(270, PEDESTRIAN, np.uint8)
    out = frame_objects(points, owner, np.array([PEDESTRIAN, PEDESTRIAN]), labels, np.ones(270, np.float32),
                        point_ids=np.where(owner == 0, 4, 9))
    check(out)
    assert out.groups_split == 1
    ids = [o.cluster_id for o in out.objects]
    assert ids == [4, 4 + SPLIT_ID_STRIDE, 4 + 2 * SPLIT_ID_STRIDE, 9], "proposal order, a group's people together"
    assert all(o.plausible and o.class_id == "pedestrian" for o in out.objects)
    assert [o.proposal_id for o in out.objects] == [4, 4, 4, 9]
    by_id = {o.cluster_id: o for o in out.objects}
    assert by_id[4].center[1] == pytest.approx(0.9, abs=0.1), "the largest person keeps the proposal's id"
    assert np.count_nonzero(out.cluster_id == 4) == 90 and np.count_nonzero(out.cluster_id == 9) == 60


def test_json_has_the_detection_fields(scan5: dict) -> None:
    document = json.loads(objects_json("000042", objects_of(scan5, ids=[7, 3, 11, 12, 20]).objects))
    assert document["frame"] == "000042"
    car = document["objects"][0]
    assert set(car) == {"id", "class_id", "score", "center", "size", "yaw", "plausible"}
    assert car["id"] == "7" and car["class_id"] == "car" and len(car["center"]) == len(car["size"]) == 3
    assert all(v > 0 for v in car["size"]) and 0 < car["score"] <= 1 and car["plausible"] is True
    assert json.loads(objects_json("empty", [])) == {"frame": "empty", "objects": []}
