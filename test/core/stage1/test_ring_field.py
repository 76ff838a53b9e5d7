"""A driver's ring field in any numbering gives the proposals of stage 1's own rings: top-down (Ouster), bottom-up
(velodyne_pointcloud, Hesai) and a driver's own order are measured from the points' elevations; a field that does
not fit the points is ignored."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.core.stage1 import proposal_members, propose, synthetic_scan
from pass3d_ros.core.stage1.ring_field import RING_CONVENTIONS, field_rings, measure_ring_order
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stream.lines import LineHolder

N_RINGS = 64


def numberings(ring: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    """Stage 1's top-down rings renumbered as drivers do, and a random field, by the convention expected."""
    rng = np.random.default_rng(seed)
    top = int(ring.max())
    return {
        "top_down": ring.astype(np.uint16),
        "bottom_up": (top - ring).astype(np.uint16),
        "driver_order": rng.permutation(top + 1)[ring].astype(np.uint16),
        "unfit": rng.integers(0, top + 1, len(ring)).astype(np.uint16),
    }


def kitti_dev_scans(root: Path) -> list[np.ndarray]:
    """The six real KITTI dev scans (firing order, no ring field)."""
    files = sorted(root.glob("**/velodyne/*.bin"))
    assert len(files) == 6, files
    return [np.fromfile(f, dtype=np.float32).reshape(-1, 4) for f in files]


def test_every_numbering_is_recognised_on_a_synthetic_scan() -> None:
    pts = synthetic_scan(points_per_ring=360)
    ring = np.repeat(np.arange(N_RINGS), 360).astype(np.uint16)
    for expected, field in numberings(ring).items():
        order = measure_ring_order(pts, field)
        assert order.convention == expected
        rings = order.rings(field)
        if expected == "unfit":
            assert rings is None and order.fit_share < 0.2
        else:
            np.testing.assert_array_equal(rings, ring)
    assert set(RING_CONVENTIONS) == set(numberings(ring))


def test_held_order_is_reused_and_measured_again_for_a_value_it_never_saw() -> None:
    pts = synthetic_scan(points_per_ring=360)
    ring = np.repeat(np.arange(N_RINGS), 360).astype(np.uint16)
    bottom_up = (N_RINGS - 1 - ring).astype(np.uint16)
    fewer = bottom_up < 40  # a scan whose top 24 lasers returned nothing: values 0..39 only
    _, held = field_rings(pts[fewer], bottom_up[fewer])
    assert held.convention == "bottom_up" and held.n_values == 40
    _, same = field_rings(pts[fewer], bottom_up[fewer], held)
    assert same is held
    rings, measured = field_rings(pts, bottom_up, held)
    assert measured is not held and measured.n_values == N_RINGS
    np.testing.assert_array_equal(rings, ring)


def test_an_unfit_field_stays_ignored_for_the_stream() -> None:
    pts = synthetic_scan(points_per_ring=360)
    field = np.random.default_rng(1).integers(0, 70, len(pts)).astype(np.uint16)
    rings, order = field_rings(pts, field)
    assert rings is None and not order.fits
    assert field_rings(pts, field + 1, order) == (None, order)


@pytest.mark.parametrize("value", [0, 7, 63])
def test_a_field_of_one_value_for_every_laser_is_ignored(value: int) -> None:
    """A driver that declares a ring field but fills it with one value (every point ring 0) gives the proposals of
    no field at all, not one ring's worth of runs: the points' elevations span every laser."""
    pts = synthetic_scan(points_per_ring=900)
    field = np.full(len(pts), value, dtype=np.uint16)
    order = measure_ring_order(pts, field)
    assert order.convention == "unfit" and order.fit_share < 0.2
    np.testing.assert_array_equal(propose(pts, field).cluster_id, propose(pts).cluster_id)


def test_one_laser_with_its_one_value_fits() -> None:
    """A scan of a single laser's returns (a crop, a one-laser sensor) with its one ring value: the field fits."""
    pts = synthetic_scan(points_per_ring=360)
    ring = np.repeat(np.arange(N_RINGS), 360)
    one = pts[ring == 40]
    order = measure_ring_order(one, np.full(len(one), 3, dtype=np.uint16))
    assert order.fits and order.fit_share > 0.9


def test_stage1_reports_the_numbering_and_gives_the_same_proposals() -> None:
    pts = synthetic_scan(points_per_ring=900)
    ring = np.repeat(np.arange(N_RINGS), 900).astype(np.uint16)
    base = propose(pts, ring)
    for expected, field in numberings(ring).items():
        result = propose(pts, field)
        assert result.ring_order.convention == expected
        np.testing.assert_array_equal(result.cluster_id, base.cluster_id)
        np.testing.assert_array_equal(result.ring, base.ring)


def test_real_kitti_frames_give_the_same_proposals_in_every_numbering(kitti_dev: Path) -> None:
    """The six dev frames: no ring field, and the field numbered top-down, bottom-up, in a driver's own order or
    at random (ignored), give exactly the proposals (so the labels) of stage 1's own rings."""
    for k, pts in enumerate(kitti_dev_scans(kitti_dev)):
        base = propose(pts)
        assert base.ring_source == "azimuth_wrap"
        for expected, field in numberings(base.ring, seed=k).items():
            holder = LineHolder()
            result = holder.propose(pts, field)
            assert holder.ring_order.convention == expected, (k, expected)
            np.testing.assert_array_equal(result.cluster_id, base.cluster_id, err_msg=f"frame {k} {expected}")
            np.testing.assert_array_equal(result.cluster_id2, base.cluster_id2, err_msg=f"frame {k} {expected}")


def test_real_kitti_labels_are_the_same_with_a_bottom_up_field(kitti_dev: Path) -> None:
    """Stage 2 on top: the shipped weights label a real frame identically with and without a bottom-up field."""
    classifier = open_classifier(None)
    pts = kitti_dev_scans(kitti_dev)[0]
    base = propose(pts)
    flipped = propose(pts, (N_RINGS - 1 - base.ring).astype(np.uint16))
    results = [classifier.segment(pts, proposal_members(r.cluster_id, r.cluster_id2, r.n_proposals))
               for r in (base, flipped)]
    assert np.count_nonzero(results[0].labels) > 0
    np.testing.assert_array_equal(results[0].labels, results[1].labels)


@pytest.mark.parametrize("sensor_top", [31, 127])
def test_negative_or_empty_fields_do_not_break_the_measurement(sensor_top: int) -> None:
    pts = synthetic_scan(n_rings=8, points_per_ring=90)
    assert measure_ring_order(pts[:0], np.zeros(0, np.uint16)).convention == "top_down"
    assert measure_ring_order(pts, np.full(len(pts), -1, np.int32)).convention == "unfit"
    assert measure_ring_order(pts, np.full(len(pts), sensor_top, np.uint16)).convention == "unfit"  # 8 lasers
    laser = pts[:90]  # one laser's returns, with a value far past the lasers there are
    one = measure_ring_order(laser, np.full(len(laser), sensor_top, np.uint16))
    assert one.convention == "top_down" and one.rings(np.full(3, sensor_top, np.uint16)).tolist() == [sensor_top] * 3
