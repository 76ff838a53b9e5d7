"""`pass3d_benchmark tracks` runs and says what it measured."""

from __future__ import annotations

import pytest

from pass3d_ros.bench import benchmark


def test_the_tracks_suite_prints_its_cost_and_keeps_every_id(capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["tracks", "--objects", "12", "--scans", "30"]) == 0
    out = capsys.readouterr().out
    assert "12 objects a scan, 30 scans" in out and "median" in out and "ids used 12 for 12 objects" in out
