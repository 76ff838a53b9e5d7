"""The points' owners (pass3d_ros.core.point_owners): the compiled passes give what numpy's masks and lookups give."""

from __future__ import annotations

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.objects import SPLIT_ID_STRIDE, FrameObjects, LabelledObject
from pass3d_ros.core.point_owners import object_points, paint, take_rows


def _plain_owners(objects: FrameObjects) -> tuple[np.ndarray, np.ndarray]:
    """Each road-user point whose cluster id is an object's, and that object (the ids here are distinct)."""
    ids = [obj.cluster_id for obj in objects.objects]
    road = np.flatnonzero(objects.labels != BACKGROUND)
    owner = np.array([ids.index(c) if c in ids else -1 for c in objects.cluster_id[road].tolist()], dtype=np.int64)
    return road[owner >= 0], owner[owner >= 0]


def test_object_points_are_the_plain_lookups() -> None:
    rng = np.random.default_rng(11)
    for _ in range(20):
        n = 2000
        base = rng.integers(-1, 40, n)
        split = rng.random(n) < 0.2
        cluster = np.where(split & (base >= 0), base + SPLIT_ID_STRIDE * rng.integers(1, 3, n), base).astype(np.int32)
        labels = rng.choice([BACKGROUND, CAR, PEDESTRIAN], n, p=[0.6, 0.2, 0.2]).astype(np.uint8)
        chosen = rng.choice(np.unique(cluster[cluster >= 0]), 25, replace=False)
        objects = [LabelledObject((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0.0, CAR, 0.9, int(c)) for c in chosen]
        frame = FrameObjects(labels, cluster, objects)
        members, owner = object_points(frame)
        expected_members, expected_owner = _plain_owners(frame)
        assert np.array_equal(members, expected_members) and np.array_equal(owner, expected_owner)


def test_paint_and_take_rows_are_numpys_scatter_and_gather() -> None:
    rng = np.random.default_rng(12)
    labels = rng.integers(0, 4, 500).astype(np.uint8)
    members = np.sort(rng.choice(500, 120, replace=False))
    owner = rng.integers(0, 7, 120)
    voted = rng.integers(0, 4, 7).astype(np.uint8)
    published = rng.integers(-1, 30, 7).astype(np.int32)
    painted, track_id = paint(labels, members, owner, voted, published, -1)
    expected = labels.copy()
    expected[members] = voted[owner]
    expected_ids = np.full(500, -1, np.int32)
    expected_ids[members] = published[owner]
    assert np.array_equal(painted, expected) and painted.dtype == np.uint8
    assert np.array_equal(track_id, expected_ids) and track_id.dtype == np.int32
    scan = rng.normal(size=(500, 5))[:, :3]  # a strided view, as a scan's x, y, z columns may be
    rows = rng.choice(500, 60, replace=False)
    taken = take_rows(scan, rows)
    assert np.array_equal(taken, scan[rows]) and taken.flags.c_contiguous and taken.dtype == scan.dtype
