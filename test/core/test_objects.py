"""The objects of a labelled frame (core/objects.py), as /pass3d/detections, the markers and pass3d_segment's JSON
carry them: one box per labelled proposal, fitted to its points of its class; no ROS needed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.objects import MIN_SIZE, LabelledObject, labelled_objects, objects_json


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
    members = [np.concatenate([span[0], span[1]]), span[2], span[3], span[4], span[5]]
    proposal_class = np.array([CAR, PEDESTRIAN, BACKGROUND, -1, CYCLIST], np.int16)
    return {"points": points, "labels": labels, "confidence": confidence, "members": members,
            "proposal_class": proposal_class, "span": span}


def objects_of(scan5: dict, **kwargs) -> list[LabelledObject]:
    return labelled_objects(scan5["points"], scan5["members"], scan5["proposal_class"], scan5["labels"],
                            scan5["confidence"], **kwargs)


def test_one_object_per_labelled_proposal_boxed_on_its_points_of_that_class(scan5: dict) -> None:
    objects = objects_of(scan5, cluster_ids=[7, 3, 11, 12, 20])
    assert [(o.class_id, o.cluster_id) for o in objects] == [("car", 7), ("pedestrian", 3)], \
        "background, unclassified and classless proposals give no object"
    car, person = objects
    assert car.label == CAR and person.label == PEDESTRIAN
    np.testing.assert_allclose(car.center, (10.0, 2.0, 0.75), atol=0.1)
    np.testing.assert_allclose(car.size, (4.0, 1.6, 1.5), atol=0.1)  # the ground points of its enlarged box left out
    assert car.yaw == pytest.approx(0.3, abs=0.02)
    assert car.score == pytest.approx(float(np.mean(scan5["confidence"][scan5["span"][0]], dtype=np.float64)))
    assert person.score == pytest.approx(0.8)
    assert car.box().contains(scan5["points"][scan5["span"][0], :3], margin=(1e-4, 1e-4, 1e-4)).all()


def test_confidence_threshold_and_default_ids(scan5: dict) -> None:
    labels = scan5["labels"].copy()
    labels[scan5["span"][2]] = BACKGROUND  # the pedestrian's points fell below min_confidence
    scan5["labels"] = labels
    objects = objects_of(scan5)
    assert [(o.class_id, o.cluster_id) for o in objects] == [("car", 0)]


def test_degenerate_groups_get_positive_sizes() -> None:
    points = np.array([[1, 2, 0, 0.5], [5, 5, 1, 0.5], [6, 5, 1, 0.5]], np.float32)
    objects = labelled_objects(points, [np.array([0]), np.array([1, 2])], np.array([PEDESTRIAN, CYCLIST]),
                               np.array([PEDESTRIAN, CYCLIST, CYCLIST]), np.array([0.9, 0.7, 0.5]))
    assert len(objects) == 2
    assert objects[0].size == (MIN_SIZE, MIN_SIZE, MIN_SIZE) and objects[0].center == pytest.approx((1, 2, 0))
    assert objects[1].size == pytest.approx((1.0, MIN_SIZE, MIN_SIZE)) and objects[1].score == pytest.approx(0.6)
    assert labelled_objects(points, [], np.zeros(0, np.int16), np.zeros(3), np.zeros(3)) == []


def test_mismatched_inputs_are_refused(scan5: dict) -> None:
    with pytest.raises(ValueError, match="labels"):
        labelled_objects(scan5["points"], scan5["members"], scan5["proposal_class"], scan5["labels"][:-1],
                         scan5["confidence"])
    with pytest.raises(ValueError, match="classes"):
        labelled_objects(scan5["points"], scan5["members"], scan5["proposal_class"][:-1], scan5["labels"],
                         scan5["confidence"])
    with pytest.raises(ValueError, match="cluster ids"):
        objects_of(scan5, cluster_ids=[1, 2])


def test_json_has_the_detection_fields(scan5: dict) -> None:
    document = json.loads(objects_json("000042", objects_of(scan5, cluster_ids=[7, 3, 11, 12, 20])))
    assert document["frame"] == "000042"
    car = document["objects"][0]
    assert set(car) == {"id", "class_id", "score", "center", "size", "yaw"}
    assert car["id"] == "7" and car["class_id"] == "car" and len(car["center"]) == len(car["size"]) == 3
    assert all(v > 0 for v in car["size"]) and 0 < car["score"] <= 1
    assert json.loads(objects_json("empty", [])) == {"frame": "empty", "objects": []}
