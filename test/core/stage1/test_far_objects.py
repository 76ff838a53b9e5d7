"""Far sparse objects (issue 27): the height gates read the local ground, not only a segment plane extrapolated
from the near road, and a kept box takes in the ground band under it."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stage1 import ground, propose, refinement, synthetic_scan
from pass3d_ros.core.stage1.config import Stage1Config

SENSOR_HEIGHT = 1.73
RAMP_START, RAMP_SLOPE = 45.0, 0.08  # the road is flat to x = 45 m, then climbs 8 %
CAR_X, CAR_Y = 62.0, 2.0  # 17 m up the climb: the road there is 1.4 m above the flat road


def _road_z(x: np.ndarray) -> np.ndarray:
    return -SENSOR_HEIGHT + RAMP_SLOPE * np.clip(x - RAMP_START, 0.0, None)


def _ramp_scene() -> tuple[np.ndarray, np.ndarray, int]:
    """A flat road that turns into a climb, a far sparse car (15 points, 0.5-1.5 m above the road) on the climb and
    four ground-band points (a wheel) under it: (points, cluster labels (the car is cluster 0, the rest -1),
    index of the first wheel point)."""
    rng = np.random.default_rng(27)
    gx, gy = np.meshgrid(np.arange(3.0, 75.0, 0.5), np.arange(-12.0, 12.0, 0.5), indexing="ij")
    gx, gy = gx.ravel(), gy.ravel()
    thin = rng.random(gx.size) < (15.0 / np.hypot(gx, gy)) ** 2  # a scan's density falls with range
    gx, gy = gx[thin], gy[thin]
    road = np.stack([gx, gy, _road_z(gx) + rng.normal(0.0, 0.02, gx.size), np.full(gx.size, 0.3)], axis=1)
    off = (np.abs(gx - CAR_X) < 2.5) & (np.abs(gy - CAR_Y) < 1.2)  # the car hides the road under it
    road = road[~off]
    car_x = CAR_X - 1.8 + 3.6 * rng.random(15)
    car_y = CAR_Y - 0.8 + 1.6 * rng.random(15)
    car = np.stack([car_x, car_y, _road_z(car_x) + 0.5 + rng.random(15), np.full(15, 0.5)], axis=1)
    wheel_x = np.array([CAR_X - 1.3, CAR_X - 1.2, CAR_X + 1.2, CAR_X + 1.3])
    wheel = np.stack([wheel_x, np.full(4, CAR_Y - 0.7), _road_z(wheel_x) + 0.1, np.full(4, 0.2)], axis=1)
    points = np.concatenate([car, wheel, road]).astype(np.float32)
    label = np.full(len(points), -1, dtype=np.int32)
    label[:15] = 0
    return points, label, 15


def test_the_extrapolated_plane_is_wrong_under_the_far_car():
    """The premise: the plane of the far segment follows the near, flat road, and sits far below the climb."""
    points, _, _ = _ramp_scene()
    fit = ground.fit_ground(points, Stage1Config())
    a, b, c, d = fit.planes[-1]
    plane_z = -(a * CAR_X + b * CAR_Y + d) / c
    assert _road_z(np.array([CAR_X]))[0] - plane_z > 0.8, plane_z
    local_z = fit.local.heights(np.array([[CAR_X, CAR_Y]]))[0]
    # the window's lowest layer: on a climb, its downhill side (7 m down an 8 % climb: 0.2-0.3 m low)
    assert -0.3 < local_z - _road_z(np.array([CAR_X]))[0] < 0.05


def test_far_sparse_car_on_a_climb_is_kept_with_the_local_ground_only():
    points, label, _ = _ramp_scene()
    fit = ground.fit_ground(points, Stage1Config())
    config = Stage1Config()
    _, kept_plane = refinement.select_proposals(points, label, 1, fit.planes, fit.segment_edges, config)
    _, kept_local = refinement.select_proposals(points, label, 1, fit.local, fit.segment_edges, config)
    assert len(kept_plane) == 0  # too tall above the plane: its top is 2.8 m above it
    assert kept_local.tolist() == [0]
    assert ground.fit_ground(points, Stage1Config(local_ground=False)).local is None


def test_ground_band_under_a_kept_car_is_in_its_membership():
    """The wheel points sit 0.1 m above the road, 0.4 m or more under the car's lowest point: below the enlarged
    box (z margin 0.4 m) they are lost; the ground band under the box takes them in."""
    points, label, wheel = _ramp_scene()
    config = Stage1Config()
    fit = ground.fit_ground(points, config)
    boxes, kept = refinement.select_proposals(points, label, 1, fit.local, fit.segment_edges, config)
    assert len(boxes) == 1
    plain, _ = refinement.enlarged_membership(points, label, kept, boxes, config.enlarge)
    floors = refinement.ground_floors(boxes, fit.local, config.th_dist)
    banded, _ = refinement.enlarged_membership(points, label, kept, boxes, config.enlarge, floors=floors)
    wheels = slice(wheel, wheel + 4)
    assert (plain[wheels] < 0).sum() >= 2
    assert (banded[wheels] == 0).all()
    assert (banded[:wheel] == 0).all()
    # the road beside the car's footprint stays out
    beside = (np.abs(points[:, 1] - CAR_Y) > 2.0) & (np.abs(points[:, 0] - CAR_X) < 2.0)
    assert (banded[beside] < 0).all()


def test_floors_must_match_the_boxes():
    points, label, _ = _ramp_scene()
    config = Stage1Config()
    fit = ground.fit_ground(points, config)
    boxes, kept = refinement.select_proposals(points, label, 1, fit.local, fit.segment_edges, config)
    with pytest.raises(ValueError, match="floors"):
        refinement.enlarged_membership(points, label, kept, boxes, config.enlarge, floors=np.zeros(3))


def test_local_ground_is_the_plane_on_flat_ground():
    """On the flat synthetic scan the local ground agrees with the plane, and stage 1 keeps the same object."""
    scan = synthetic_scan()
    fit = ground.fit_ground(scan, Stage1Config())
    xy = np.array([[10.0, 0.0], [20.0, 5.0], [-15.0, -3.0]])
    assert np.all(np.abs(fit.local.offsets(xy)) <= 0.1)
    on = propose(scan, config=Stage1Config())
    off = propose(scan, config=Stage1Config(local_ground=False))
    assert on.n_proposals == off.n_proposals == 1
    np.testing.assert_allclose(on.boxes[0].center, off.boxes[0].center)


def test_offsets_fall_back_to_the_plane_without_points():
    fit = ground.fit_ground(np.zeros((0, 4), np.float32), Stage1Config())
    assert fit.local is not None
    np.testing.assert_array_equal(fit.local.offsets(np.array([[50.0, 0.0]])), [0.0])
    far = ground.fit_ground(synthetic_scan(), Stage1Config())
    np.testing.assert_array_equal(far.local.offsets(np.array([[500.0, 0.0]])), [0.0])
