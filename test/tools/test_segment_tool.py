"""pass3d_segment: offline labels in SemanticKITTI format, bird's-eye PNGs, summary, and its refusals."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

from pass3d_ros.core import stage2
from pass3d_ros.core.objects import frame_objects
from pass3d_ros.core.stage1 import proposal_members, propose
from pass3d_ros.core.stage2 import pointnet2
from pass3d_ros.core.stage2.segmentation import Segmenter, make_checkpoint, people_only
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.data.outputs import MARKER
from pass3d_ros.data.semantickitti import read_semantickitti
from pass3d_ros.drawing import bev
from pass3d_ros.evaluation.segmenting import SEMANTIC_KITTI_IDS
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.tools import segment

SPEC = "synthetic:frames=2,seed=4"
FIGURE_HEIGHT = bev.TITLE_PX + bev.PANEL_PX + bev.LEGEND_PX


def offline(points: np.ndarray, ring: np.ndarray | None, classifier) -> np.ndarray:
    """The labels the nodes publish for a scan (stage 2's, settled by core.objects.frame_objects)."""
    result = propose(points, ring)
    members = proposal_members(result.cluster_id, result.cluster_id2)
    segmented = people_only(classifier.segment(points, members), members, result.people_only())
    return frame_objects(points, result.cluster_id, segmented.proposal_class, segmented.labels,
                         segmented.confidence).labels


def read_label(path: Path) -> np.ndarray:
    return np.fromfile(path, dtype="<u4")


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def tool_frames() -> list:
    return [generate_frame(4, k) for k in range(2)]


def test_size_rules_labels_pngs_and_summary(
    tmp_path: Path, tool_frames: list, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    code = segment.main([f"--data={SPEC}", f"--out={out}", "--classifier=size_rules", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in (out / "labels").iterdir()) == ["000000.label", "000001.label"]
    lut = {0: 0, 10: 1, 30: 2, 31: 3}
    for frame in tool_frames:
        words = read_label(out / "labels" / f"{frame.name}.label")
        assert len(words) == len(frame.points)
        assert set(np.unique(words).tolist()) <= set(lut)
        expected = offline(frame.points, frame.ring, SizeRuleClassifier())
        assert np.count_nonzero(expected) > 0
        np.testing.assert_array_equal(words, SEMANTIC_KITTI_IDS[expected])
        assert png_size(out / "bev" / f"{frame.name}.png") == (2 * bev.PANEL_PX + bev.GAP_PX, FIGURE_HEIGHT), \
            "labeled data: ground truth | prediction"
        objects = json.loads((out / "objects" / f"{frame.name}.json").read_text())
        assert objects["frame"] == frame.name and objects["objects"], "the synthetic street has objects"
        for obj in objects["objects"]:
            assert set(obj) == {"id", "class_id", "score", "center", "size", "yaw", "plausible"}
            assert obj["class_id"] in {"car", "pedestrian", "cyclist"} and 0 < obj["score"] <= 1
            assert int(obj["id"]) >= 0 and all(v > 0 for v in obj["size"]) and len(obj["center"]) == 3
        stage1 = propose(frame.points, frame.ring)
        members = proposal_members(stage1.cluster_id, stage1.cluster_id2)
        segmented = SizeRuleClassifier().segment(frame.points, members)
        expected = frame_objects(frame.points, stage1.cluster_id, segmented.proposal_class, segmented.labels,
                                 segmented.confidence).objects
        assert [(o["id"], o["class_id"]) for o in objects["objects"]] == [
            (str(o.cluster_id), o.class_id) for o in expected], "one entry per object, as the node publishes them"
    assert not list(out.rglob(".*.partial-*")), "each file written beside its destination, then renamed"
    report = json.loads((out / "summary.json").read_text())
    assert report["frames"] == 2 and report["classifier"] == "size_rules" and report["weights"] is None
    assert report["labeled_frames"] == 2 and 0.0 <= report["per_class"]["car"]["iou"] <= 1.0
    truth = np.concatenate([f.labels for f in tool_frames])
    assert report["per_class"]["car"]["points"] == int(np.count_nonzero(truth == 1))
    assert report["ms_per_frame"]["stage1"] > 0 and report["ms_per_frame"]["stage2"] > 0
    printed = capsys.readouterr().out
    assert "segmented 2 frames" in printed and "mean IoU" in printed and str(out / "summary.json") in printed


def test_labels_read_back_through_semantickitti_reader(tmp_path: Path, tool_frames: list) -> None:
    """A .label written here is a SemanticKITTI label file: the reader maps it back to our classes."""
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    tool_frames[0].points.tofile(seq / "velodyne" / "000000.bin")
    out = tmp_path / "out"
    assert segment.main([f"--data=semantickitti:{seq}", f"--out={out}", "--classifier=size_rules",
                         "--no-progress", "--no-png"]) == 0
    assert not (out / "bev").exists()
    (seq / "labels").mkdir()
    (out / "labels" / "000000.label").rename(seq / "labels" / "000000.label")
    back = next(iter(read_semantickitti(seq)))
    np.testing.assert_array_equal(back.labels, offline(tool_frames[0].points, None, SizeRuleClassifier()))


def test_network_weights_and_nan_points(tmp_path: Path, tool_frames: list) -> None:
    torch.manual_seed(1)
    weights = tmp_path / "lite.pt"
    torch.save(make_checkpoint(pointnet2.PointNet2Seg(pointnet2.make_config("lite"))), weights)
    points = tool_frames[1].points.copy()
    nan_rows = np.arange(0, len(points), 997)
    points[nan_rows, :3] = np.nan
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    points.tofile(seq / "velodyne" / "000007.bin")
    out = tmp_path / "out"
    assert segment.main([f"--data=semantickitti:{seq}", f"--out={out}", f"--weights={weights}", "--no-progress"]) == 0
    words = read_label(out / "labels" / "000007.label")
    assert len(words) == len(points) and np.all(words[nan_rows] == 0)
    keep = np.ones(len(points), dtype=bool)
    keep[nan_rows] = False
    expected = offline(points[keep], None, Segmenter(str(weights)))
    np.testing.assert_array_equal(words[keep], SEMANTIC_KITTI_IDS[expected])
    report = json.loads((out / "summary.json").read_text())
    assert report["classifier"] == "network" and report["weights"] == str(weights)
    assert report["per_class"] is None and report["labeled_frames"] == 0
    assert png_size(out / "bev" / "000007.png") == (bev.PANEL_PX, FIGURE_HEIGHT), "no labels: the prediction alone"


def test_several_inputs_get_their_own_folders(tmp_path: Path) -> None:
    out = tmp_path / "out"
    specs = ["synthetic:frames=1,seed=4", "synthetic:frames=1,seed=4,start=1"]
    assert segment.main([*(f"--data={s}" for s in specs), f"--out={out}", "--classifier=size_rules",
                         "--no-progress", "--no-png"]) == 0
    assert (out / "00" / "labels" / "000000.label").is_file()
    assert (out / "01" / "labels" / "000001.label").is_file()
    assert (out / "00" / "objects" / "000000.json").is_file() and (out / "01" / "objects" / "000001.json").is_file()
    assert json.loads((out / "summary.json").read_text())["folders"] == [str(out / "00"), str(out / "01")]


def test_refusals_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("user data")

    def run(*args: str) -> tuple[int, str]:
        code = segment.main(["--no-progress", *args])
        return code, capsys.readouterr().err

    code, err = run(f"--data={SPEC}", f"--out={out}", "--classifier=size_rules")
    assert code == 2 and "not empty" in err and "--force" in err
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"], "a refused run writes nothing"
    code, err = run("--data=synthetic:frames=1,seed=4", f"--out={out}", "--classifier=size_rules", "--force")
    assert code == 2 and "not an output folder of pass3d_segment" in err, "--force writes only into its own output"
    (out / MARKER).write_text("written by pass3d_segment\n")
    code, err = run("--data=synthetic:frames=1,seed=4", f"--out={out}", "--classifier=size_rules", "--force")
    assert code == 0 and (out / "labels" / "000000.label").is_file() and (out / "keep.txt").is_file()

    fresh = tmp_path / "fresh"
    code, err = run("--data=nosuchformat:x", f"--out={fresh}", "--classifier=size_rules")
    assert code == 2 and "unknown format" in err
    code, err = run(f"--data={SPEC}", f"--out={fresh}", f"--weights={tmp_path / 'missing.pt'}")
    assert code == 2 and str(tmp_path / "missing.pt") in err
    code, err = run(f"--data={SPEC}", f"--out={fresh}", "--classifier=size_rules", "--weights=w.pt")
    assert code == 2 and "size_rules" in err
    code, err = run(f"--data=semantickitti:{tmp_path / 'nowhere'}", f"--out={fresh}", "--classifier=size_rules")
    assert code == 2 and "nowhere" in err
    a_file = tmp_path / "file"
    a_file.write_text("")
    code, err = run(f"--data={SPEC}", f"--out={a_file}", "--classifier=size_rules")
    assert code == 2 and "not a folder" in err


def test_default_weights_missing_is_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(stage2, "DEFAULT_WEIGHTS", tmp_path / "pass3d_lite.pt")
    assert segment.main([f"--data={SPEC}", f"--out={tmp_path / 'o'}", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "pass3d_lite.pt" in err and "--classifier size_rules" in err
