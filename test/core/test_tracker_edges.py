"""The tracker on input at its edges: a detection that is not finite, footprint points that are not finite or lie
astronomically far apart, and remembered shapes a stamp jump carries hundreds of kilometres apart. Each scan must
leave the tracker running, its tracks finite and its memory bounded."""

from __future__ import annotations

import numpy as np
from pass3d_ros.core.stream.footprints import cell_sets, cells


def test_footprint_cells_of_points_not_finite_or_far_apart_are_found_without_a_crash() -> None:
    far = np.array([[-3e18, 0.0], [3e18, 0.0], [0.0, 0.0]])  # their cells' span overflows int64
    keys, starts = cell_sets(far, [3])
    assert starts.tolist() == [0, 3] and keys.tolist() == cells(far).tolist()
    keys, starts = cell_sets(np.array([[0.2, 0.3], [np.nan, np.nan], [np.inf, 0.0], [0.1, 0.1]]), [4])
    assert starts.tolist() == [0, len(keys)] and len(keys) <= 3
    assert np.isin(cells(np.array([[0.2, 0.3]])), keys).all()
