"""`pass3d_benchmark stage1`: which of stage 1 and Patchwork++ it says is faster, and its refusals."""

from __future__ import annotations

import sys
import time
import types
from pathlib import Path

import pytest

from pass3d_ros.bench import benchmark


def fake_patchwork(seconds: float) -> types.ModuleType:
    """A stand-in for pypatchworkpp whose ground estimation takes `seconds`."""

    class Estimator:
        def __init__(self, params: object) -> None:
            self.params = params

        def estimateGround(self, cloud: object) -> None:  # noqa: N802 (pypatchworkpp's name)
            time.sleep(seconds)

    module = types.ModuleType("pypatchworkpp")
    module.Parameters = types.SimpleNamespace  # type: ignore[attr-defined]
    module.patchworkpp = Estimator  # type: ignore[attr-defined]
    return module


@pytest.mark.parametrize(("seconds", "word"), [(0.0, "slower"), (0.2, "faster")])
def test_stage1_says_which_ground_step_is_faster(seconds: float, word: str, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Against a Patchwork++ that takes no time stage 1's ground step is the slower one, against one that takes 200 ms
    the faster (it used to print "0.0x faster" for the first: pw / ground, always called faster)."""
    monkeypatch.setitem(sys.modules, "pypatchworkpp", fake_patchwork(seconds))
    assert benchmark.main(["stage1", "--repeat", "1", "--limit", "1"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "ground step" in line]
    assert len(lines) == 1 and word in lines[0], lines
    ratio = float(lines[0].split(f"x {word}")[0].split()[-1])
    assert ratio >= 1.0, lines


def test_stage1_names_the_data_that_holds_no_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A spec with no frames is one line naming it (was "no frames to time", naming nothing)."""
    (tmp_path / "velodyne").mkdir()
    for spec in ("synthetic:frames=0,seed=1", f"semantickitti:{tmp_path}"):
        assert benchmark.main(["stage1", "--data", spec, "--repeat", "1", "--no-patchwork"]) == 2
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and "Traceback" not in err, err
        assert lines[0].startswith("pass3d_benchmark: error: ") and spec in lines[0] and "no frames" in lines[0], err
