"""The tracker on input at its edges: a detection that is not finite, footprint points that are not finite or lie
astronomically far apart, and remembered shapes a stamp jump carries hundreds of kilometres apart. Each scan must
leave the tracker running, its tracks finite and its memory bounded."""

from __future__ import annotations

import numpy as np
from pass3d_ros.classes import CAR
from pass3d_ros.core.stream.footprints import cell_sets, cells
from pass3d_ros.core.stream.shapes import ShapeMemory


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
