"""`pass3d_view`: a dataset or an output bag becomes a complete rerun recording (class colours, boxes), and the
bad cases exit 2 with one line and no partial file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.classes import CAR, CLASS_COLORS_RGB, IGNORE, PEDESTRIAN
from pass3d_ros.data.bag import TYPESTORE, BagWriter
from pass3d_ros.drawing.view import UNKNOWN_RGB, point_colors
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, columns_to_cloud, encode
from pass3d_ros.tools import view

SPEC = "synthetic:frames=2,seed=3"


def output_bag(path: Path, frames: int = 2) -> Path:
    """A bag of pass3d output clouds: `label` holds predictions, next to `confidence`."""
    rng = np.random.default_rng(0)
    with BagWriter(path) as writer:
        for k in range(frames):
            n = 500
            cloud = columns_to_cloud({
                "x": rng.uniform(-20, 20, n).astype(np.float32), "y": rng.uniform(-20, 20, n).astype(np.float32),
                "z": rng.uniform(-2, 1, n).astype(np.float32), "intensity": np.zeros(n, np.float32),
                "label": np.full(n, CAR, np.uint8), "confidence": np.ones(n, np.float32),
            })
            stamp = 1_600_000_000_000_000_000 + k * 100_000_000
            msg = encode(cloud, frame_id="velodyne", stamp_ns=stamp, typestore=TYPESTORE)
            writer.write_raw("/pass3d/labeled", POINTCLOUD2_TYPE, stamp, TYPESTORE.serialize_cdr(msg, POINTCLOUD2_TYPE))
    return path


def test_point_colors_follow_the_class_table() -> None:
    colors = point_colors(np.array([0, CAR, PEDESTRIAN, IGNORE]), 4)
    assert (colors[1] == CLASS_COLORS_RGB[CAR]).all() and (colors[2] == CLASS_COLORS_RGB[PEDESTRIAN]).all()
    assert (colors[3] == UNKNOWN_RGB).all()
    assert (point_colors(None, 2) == CLASS_COLORS_RGB[0]).all()


def test_dataset_and_output_bag_become_recordings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "synthetic.rrd"
    assert view.main(["--data", SPEC, "--out", str(out)]) == 0
    assert "2 frame(s) written" in capsys.readouterr().out and out.stat().st_size > 10_000
    bag = output_bag(tmp_path / "labeled")
    assert view._bag_labels(str(bag)) == "predicted", "an output bag shows its predictions"
    out2 = tmp_path / "labeled.rrd"
    assert view.main(["--data", f"bag:{bag}", "--out", str(out2), "--limit", "1"]) == 0
    assert "1 frame(s) written" in capsys.readouterr().out and out2.stat().st_size > 1_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labeled", "labeled.rrd", "synthetic.rrd"]


def test_bad_input_exits_2_without_a_partial_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert view.main(["--data", SPEC, "--out", str(a_file / "x.rrd")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert view.main(["--data", "nope:x", "--out", str(tmp_path / "y.rrd")]) == 2
    assert "unknown format" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert view.main(["--data", f"semantickitti:{empty}", "--out", str(tmp_path / "z.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pass3d_view: error:") and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "file"]
