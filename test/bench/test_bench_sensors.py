"""`pass3d_benchmark sensors`: the sensor x mount table of stage-1 recall (and mean IoU), with the ring field dropped
for sensors whose driver has one; its JSON and its refusals."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pass3d_ros.bench import benchmark
from pass3d_ros.bench.sensors import MOUNTS


def test_sensors_suite_prints_a_row_per_sensor_and_a_column_per_mount(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sensors.json"
    argv = ["sensors", "--frames", "1", "--sensors", "vlp16,hdl64e", "--mounts", "level,inverted", "--stage1-only",
            "--json", str(out)]
    assert benchmark.main(argv) == 0
    printed = capsys.readouterr().out
    assert "level" in printed and "inverted" in printed and "no ring field" in printed and "difference" in printed
    report = json.loads(out.read_text())
    assert report["seed"] == 97 and report["mounts"] == {"level": "", "inverted": "roll=180"}
    cells = {(c["sensor"], c["mount"], c["ring_field"]): c for c in report["cells"]}
    # the KITTI-like HDL-64E (a .bin: no ring field) is scored once, the VLP-16 with and without its field
    assert set(cells) == {("vlp16", "level", True), ("vlp16", "level", False), ("vlp16", "inverted", True),
                          ("vlp16", "inverted", False), ("hdl64e", "level", True), ("hdl64e", "inverted", True)}
    assert cells[("vlp16", "level", True)]["foreground_recall"] > 0.5
    assert cells[("vlp16", "level", True)]["spec"] == "synthetic:sensor=vlp16,frames=1,seed=97"
    assert cells[("vlp16", "inverted", True)]["spec"].endswith(",roll=180")
    assert all(c["mean_iou"] is None for c in report["cells"])


@pytest.mark.parametrize("argv, word", [(["--sensors", "vlp99"], "--sensors"), (["--mounts", "sideways"], "--mounts"),
                                        (["--frames", "0"], "--frames")])
def test_sensors_suite_refuses_unknown_names(argv: list[str], word: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["sensors", *argv]) == 2
    assert word in capsys.readouterr().err


def test_every_mount_is_a_valid_synthetic_spec() -> None:
    from pass3d_ros.synthetic.specs import parse_synthetic_spec

    for items in MOUNTS.values():
        parse_synthetic_spec(",".join(filter(None, ("frames=1,seed=97", items))))
