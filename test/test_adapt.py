"""Issue 39's pieces for adapting to a user's sensor: the recording split into scans to adapt on and held-out
stretches to check on, and the label-free check (view agreement over draws, proposals per scan, class shares by
range)."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.adapt.check import check_scans, majority
from pass3d_ros.adapt.holdout import MIN_SCANS_EACH, split_scans
from pass3d_ros.adapt.sensor import fitting_table, nearest_simulated, read_sensor
from pass3d_ros.classes import CLASS_NAMES
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.data.errors import UserError
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.agreement import evaluate_agreement
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.synthetic.sensor import SENSOR_NAMES


@pytest.mark.parametrize(("count", "share", "stretches", "gap"), [(8, 0.25, 2, 1), (40, 0.25, 2, 1), (101, 0.3, 3, 2),
                                                                   (20, 0.1, 1, 0)])
def test_split_holds_out_whole_stretches_away_from_the_scans_adapted_on(count, share, stretches, gap):
    split = split_scans(count, share, stretches, gap)
    everything = np.concatenate([split.adapt, split.check, split.left_out])
    assert sorted(everything.tolist()) == list(range(count)), "every scan on exactly one side"
    assert len(split.check) == max(MIN_SCANS_EACH, round(share * count))
    runs = np.split(split.check, np.flatnonzero(np.diff(split.check) > 1) + 1)
    assert len(runs) == min(stretches, len(split.check)), f"held out in {len(runs)} stretches: {split.describe()}"
    distance = np.abs(split.adapt[:, None] - split.check[None, :]).min(axis=1)
    assert distance.min() > gap, "a scan adapted on lies within the gap of a held-out one"
    assert len(split.adapt) >= MIN_SCANS_EACH


def test_a_recording_too_short_to_split_says_how_many_scans_it_needs():
    with pytest.raises(UserError, match=r"has 7 scans; adapting needs at least 8"):
        split_scans(7)
    split_scans(8)


def test_majority_breaks_ties_to_the_lower_class():
    views = np.array([[1] * 8, [2, 2, 2, 2, 3, 3, 3, 3], [0, 3, 3, 3, 3, 3, 1, 1]])
    assert majority(views).tolist() == [1, 2, 3]


def test_label_free_check_reads_no_labels_and_agrees_with_the_view_agreement_evaluator(shipped):
    frames = [generate_frame(seed=9, index=i, sensor="vlp16") for i in range(2)]
    blind = [type(f)(name=f.name, points=f.points, ring=f.ring) for f in frames]  # no labels at all
    config = Stage1Config()
    report = check_scans((("synthetic:vlp16", f) for f in blind), config, shipped, draws=2)
    assert report["scans"] == 2 and report["draws"] == 2
    reference = evaluate_agreement((("synthetic:vlp16", f) for f in blind), config, shipped)
    for name in ("car", "pedestrian", "cyclist"):
        row = report["agreement"][name]
        assert len(row["agreement"]) == 2 and len(row["proposals"]) == 2
        assert row["proposals"][0] == reference["agreement"][name]["proposals"]
        assert row["agreement"][0] == reference["agreement"][name]["agreement"], name
    assert report["agreement"]["car"]["proposals"][0] > 0
    proposals = [f["proposals"] for f in reference["per_frame"]]
    assert report["proposals_per_scan"]["mean"] == pytest.approx(np.mean(proposals))
    counted = sum(b["proposals"] for b in report["class_shares"].values())
    assert counted == sum(proposals)
    for shares in report["class_shares"].values():
        if shares["proposals"]:
            assert sum(shares[c] for c in CLASS_NAMES) == pytest.approx(1.0)
    assert shipped.draw == 0, "the classifier is left on draw 0"


@pytest.mark.parametrize("name", SENSOR_NAMES)
def test_each_simulated_sensor_is_read_as_itself(name):
    """A recording of a simulated sensor reads as that sensor and fits its laser table; without its ring field
    (rings then come from the laser lines) too, for the sensors sent column by column."""
    frame = generate_frame(seed=11, index=0, sensor=name)
    reading = read_sensor([("synthetic", frame)], Stage1Config())
    assert reading.nearest_simulated == name and reading.distance < 0.5, reading
    assert reading.laser_table == name and reading.n_rings == len(np.unique(frame.ring)), reading
    if name in ("vlp16", "hdl32e", "pandar64"):
        blind = Frame(name=frame.name, points=frame.points)
        reading = read_sensor([("synthetic", blind)], Stage1Config())
        assert reading.nearest_simulated == name and reading.ring_source != "field", reading


def test_a_guessed_ring_count_is_left_out_of_the_comparison():
    """Rings binned by elevation only guess the count: a 32-laser HDL-32E binned into 64 rings still reads as the
    HDL-32E by its azimuth step and lowest laser, where counting the guess would call it a 64-laser sensor."""
    assert nearest_simulated(0, np.nan, 0.166, -30.7)[0] == "hdl32e"
    assert nearest_simulated(64, 0.665, 0.166, -30.7)[0] != "hdl32e"


def test_a_laser_table_is_named_only_when_exactly_one_fits():
    assert fitting_table(64, 2.9, -23.9) == "hdl64e"  # Pandar64's top laser (+15) would be far above the returns
    assert fitting_table(64, 11.0, -24.9) == "pandar64"  # its top lasers see sky: returns up to 11 degrees
    assert fitting_table(32, 10.0, -10.5) == "auto"  # no 32-laser table reaches only -10.5 degrees
    assert fitting_table(48, 10.0, -20.0) == "auto"


def test_a_recording_without_points_is_refused():
    empty = Frame(name="e", points=np.zeros((0, 4), np.float32))
    with pytest.raises(UserError, match="no scan of the recording holds a point"):
        read_sensor([("x", empty)], Stage1Config())
