"""`pass3d_benchmark tracks` runs and says what it measured."""

from __future__ import annotations

import pytest

from pass3d_ros.bench import benchmark


def test_the_tracks_suite_prints_its_cost_and_keeps_every_id(capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["tracks", "--objects", "12", "--scans", "30"]) == 0
    out = capsys.readouterr().out
    assert "12 objects a scan of 120000 points, 30 scans" in out and "ids used 12 for 12 objects" in out
    assert "tracker + vote on points (track_scan): median" in out and "tracker update alone: median" in out
    # the first 10 scans make the tracks and are not timed: the medians are over the other 20, and say so
    assert "timed: the last 20 of the 30 scans" in out


def test_the_tracks_suite_refuses_a_scan_too_small_for_its_objects(capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["tracks", "--objects", "12", "--points", "100"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--points >= 300 x --objects" in err[0]


def test_the_tracks_suite_times_a_tracker_setting(capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["tracks", "--objects", "12", "--scans", "30", "--track", "track_fill_shapes=true"]) == 0
    assert "30 scans at 10 Hz (track_fill_shapes=true)" in capsys.readouterr().out
    assert benchmark.main(["tracks", "--objects", "12", "--scans", "30", "--track", "fill=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "track_fill_shapes" in err[0]
