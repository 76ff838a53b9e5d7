"""`pass3d_benchmark stage2`: its refusals."""

from __future__ import annotations

from pathlib import Path

import pytest

from pass3d_ros.bench import benchmark


def test_stage2_refuses_data_with_no_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--data that holds no frame is one line naming the spec, exit 2 (was a ZeroDivisionError traceback: the timing
    loop picked frame r % 0)."""
    (tmp_path / "velodyne").mkdir()
    for spec in ("synthetic:frames=0,seed=1", f"semantickitti:{tmp_path}"):
        assert benchmark.main(["stage2", "--data", spec, "--repeats", "1"]) == 2
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and "Traceback" not in err, err
        assert lines[0].startswith("pass3d_benchmark: error: ") and spec in lines[0] and "no frames" in lines[0], err
