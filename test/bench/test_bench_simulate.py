"""`pass3d_benchmark simulate`: the target it judges against is the HDL-64E's."""

from __future__ import annotations

import pytest

from pass3d_ros.bench import benchmark


def test_simulate_judges_only_the_hdl64e_against_its_target(capsys: pytest.CaptureFixture[str]) -> None:
    """The 0.5 s target is an HDL-64E frame's (docs/performance.md); a VLP-16 frame (a fifth of the points) used to
    be judged "ok" or "SLOWER THAN TARGET" against it as well."""
    assert benchmark.main(["simulate", "--frames", "1", "--sensor", "vlp16"]) == 0
    out = capsys.readouterr().out
    target = [line for line in out.splitlines() if "target" in line]
    assert len(target) == 1 and "HDL-64E" in target[0] and "not judged" in target[0], out
    assert "SLOWER THAN TARGET" not in out and not target[0].rstrip().endswith("ok"), out
