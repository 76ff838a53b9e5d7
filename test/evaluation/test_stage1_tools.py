"""Stage 1 metrics, `pass3d_evaluate --stage1-only`, `pass3d_benchmark stage1`, and the real KITTI frames."""

from __future__ import annotations

import argparse
import builtins
import json

import numpy as np
import pytest

from pass3d_ros.bench import benchmark
from pass3d_ros.bench import stage1 as bench
from pass3d_ros.core.metrics import ConfusionAccumulator, Stage1Metrics, format_metrics
from pass3d_ros.core.stage1 import Stage1Config, propose, synthetic_scan
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.offline import evaluate_stage1
from pass3d_ros.evaluation.report import format_stage1
from pass3d_ros.tools import evaluate

TIMINGS = {"ring": 0.1, "ground": 0.2, "clustering": 0.3, "refinement": 0.4, "total": 1.0}


def test_confusion_accumulator_precision_recall_iou():
    acc = ConfusionAccumulator()
    acc.update(np.array([0, 0, 1, 1, 1, 2]), np.array([0, 1, 1, 1, 0, 0]))
    acc.update(np.array([3]), np.array([3]))
    assert acc.precision()[1] == pytest.approx(2 / 3) and acc.recall()[1] == pytest.approx(2 / 3)
    assert acc.iou()[1] == pytest.approx(2 / 4) and acc.iou()[2] == 0.0 and acc.iou()[3] == 1.0
    summary = acc.summary()
    assert summary["per_class"]["pedestrian"]["points"] == 1
    assert summary["mean_iou"] == pytest.approx((0.5 + 0.0 + 1.0) / 3)
    assert ConfusionAccumulator().summary()["mean_iou"] is None
    with pytest.raises(ValueError):
        acc.update(np.array([0, 1]), np.array([0]))
    with pytest.raises(ValueError):
        acc.update(np.array([4]), np.array([0]))


def test_mean_iou_line_names_the_classes_it_averages():
    """No cyclist in the ground truth, a few points called cyclist: the cyclist row reads IoU 0 and the mean leaves it
    out, so the line names car and pedestrian only (it said "car, pedestrian, cyclist" over a two-class mean)."""
    acc = ConfusionAccumulator()
    acc.update(np.array([0, 0, 1, 1, 2, 2]), np.array([3, 0, 1, 0, 2, 2]))
    summary = acc.summary()
    assert summary["per_class"]["cyclist"]["iou"] == 0.0 and summary["mean_iou"] == pytest.approx((0.5 + 1.0) / 2)
    line = format_metrics(summary["per_class"], summary["mean_iou"])[-1]
    assert line == "mean IoU (car, pedestrian; no ground-truth cyclist points): 75.0 %"
    full = ConfusionAccumulator()
    full.update(np.array([1, 2, 3]), np.array([1, 2, 3]))
    assert format_metrics(full.summary()["per_class"], 1.0)[-1] == "mean IoU (car, pedestrian, cyclist): 100.0 %"


def test_stage1_metrics_accumulate_over_frames():
    m = Stage1Metrics()
    labels = np.array([0, 1, 1, 2, 0, 3], dtype=np.uint8)
    cid = np.array([-1, 0, -1, 1, 0, -1], dtype=np.int32)
    cid2 = np.array([-1, -1, -1, -1, -1, 1], dtype=np.int32)
    ground = np.array([True, False, False, False, True, True])
    truth = np.array([True, False, False, False, False, True])
    row = m.update("a", 2, cid, cid2, ground, TIMINGS, labels, truth)
    assert row["foreground_recall"] == pytest.approx(3 / 4)
    assert row["ground_precision"] == pytest.approx(2 / 3) and row["ground_recall"] == 1.0
    m.update("b", 4, np.full(3, -1), np.full(3, -1), np.zeros(3, bool), {**TIMINGS, "total": 3.0})
    s = m.summary()
    assert s["frames"] == 2
    st = s["stage1"]
    assert st["foreground_recall"] == pytest.approx(3 / 4) and st["foreground_points"] == 4
    assert st["class_recall"] == {"car": 0.5, "pedestrian": 1.0, "cyclist": 1.0}
    assert st["proposals_per_frame"] == {"median": 3.0, "mean": 3.0}
    assert st["ms_per_frame"]["median"] == pytest.approx(2.0) and st["ms_per_step"]["ring"] == pytest.approx(0.1)
    assert st["ground"] == {"precision": pytest.approx(2 / 3), "recall": 1.0} and st["ground_frames"] == 1
    empty = Stage1Metrics()
    empty.update("c", 0, np.full(2, -1), np.full(2, -1), np.zeros(2, bool), TIMINGS)
    st = empty.summary()["stage1"]
    assert st["foreground_recall"] is None and st["ground"] == {"precision": None, "recall": None}


def test_evaluate_stage1_on_constructed_frames():
    pts = synthetic_scan()
    result = propose(pts)
    labels = np.zeros(len(pts), np.uint8)
    labels[result.cluster_id >= 0] = 1
    frames = iter([("mem", Frame("f0", pts, labels=labels, ground=result.ground))])
    summary = evaluate_stage1(frames, Stage1Config())
    st = summary["stage1"]
    assert summary["frames"] == 1 and st["foreground_recall"] == 1.0
    assert st["ground"] == {"precision": 1.0, "recall": 1.0}
    assert summary["per_frame"][0]["ring_source"] == "azimuth_wrap"
    assert "foreground recall" in format_stage1(summary, per_frame=True)


def test_stage1_recall_counts_labelled_points_the_checks_leave_out_as_misses():
    """Car points with non-finite coordinates never reach stage 1: they are in no proposal, so stage-1 recall counts
    them in its denominator, as the full evaluation counts them as missed (they were silently dropped)."""
    pts = synthetic_scan()
    result = propose(pts)
    covered = result.cluster_id >= 0
    lost = np.full((100, 4), np.nan, np.float32)
    lost[:, 3] = 0.5
    labels = np.concatenate([covered.astype(np.uint8), np.ones(100, np.uint8)])
    ground = np.concatenate([result.ground, np.ones(100, bool)])
    frame = Frame("f0", np.vstack([pts, lost]), labels=labels, ground=ground)
    summary = evaluate_stage1(iter([("mem", frame)]), Stage1Config())
    st, row = summary["stage1"], summary["per_frame"][0]
    fg = int(covered.sum())
    assert st["foreground_points"] == fg + 100 and row["points"] == len(pts) + 100
    assert st["foreground_recall"] == pytest.approx(fg / (fg + 100)) == row["foreground_recall"]
    assert st["ground"]["recall"] == pytest.approx(result.ground.sum() / (result.ground.sum() + 100))


def test_evaluate_cli_errors(capsys):
    assert evaluate.main(["--stage1-only", "--data", "nosuchformat:/x"]) == 2
    assert "unknown format" in capsys.readouterr().err
    assert evaluate.main(["--stage1-only", "--data", "kitti_object"]) == 2
    assert evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--param", "th_dist=-2"]) == 2
    assert "th_dist" in capsys.readouterr().err
    assert evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--param", "bogus"]) == 2


def test_evaluate_cli_writes_nested_json(tmp_path, capsys):
    out = tmp_path / "eval.json"
    code = evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--json", str(out), "--no-progress",
                          "--param", "th_num_floor=6"])
    assert code == 0
    data = json.loads(out.read_text())
    st = data["stage1"]
    assert data["frames"] == 1 and data["mode"] == "stage1" and data["config"]["th_num_floor"] == 6
    for key in ("median", "mean"):
        assert isinstance(st["proposals_per_frame"][key], float)
    assert st["ms_per_frame"]["median"] > 0 and st["foreground_recall"] > 0.8
    assert 0.9 < st["ground"]["precision"] <= 1.0 and 0.9 < st["ground"]["recall"] <= 1.0
    assert set(st["ms_per_step"]) == {"ring", "ground", "clustering", "refinement", "total"}
    assert "ground precision" in capsys.readouterr().out


def test_benchmark_runs_and_reports_missing_patchwork(tmp_path, capsys, monkeypatch):
    real_import = builtins.__import__

    def no_patchwork(name, *args, **kwargs):
        if name == "pypatchworkpp":
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_patchwork)
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "bench.json"
    assert bench.run(parser.parse_args(["--repeat", "2", "--json", str(out)])) == 0
    text = capsys.readouterr().out
    assert "clustering" in text and "pip install pypatchworkpp" in text
    report = json.loads(out.read_text())
    assert report["patchwork_ms_median"] is None and report["stage1_ms_median"]["total"] > 0
    assert benchmark.main(["stage1", "--data", "nosuch:x"]) == 2
    assert capsys.readouterr().err.startswith("pass3d_benchmark: error: ")


# Measured on the six kitti_dev frames (this 2-core machine): foreground recall 0.981 (car 0.981, pedestrian
# 0.992, cyclist 1.000), proposals per frame median 36.5 / mean 31.5 (33.5 / 28.5 without rerun_dropped, on by
# default since rule R3: two person-shaped parts a frame; 35.5 / 30.5 before rule R4 let a part's top reach the
# gates' max_top), ground precision 0.912, recall 0.994.
# The floors below sit a little under those numbers, so a regression shows. They are regression floors, not the
# targets (recall >= 0.90, <= 35 proposals, ground precision >= 0.93): the proposals floor (<= 37 vs 36.5) is 1.5
# proposals over the target since rules R3 and R4 (docs/experiments/sensors.md). A deliberate change to stage 1
# (order-free rings, parameters that follow the sensor) may move these numbers: re-measure with
# `pass3d_evaluate --stage1-only` on the same frames and move a floor in the same commit.
def test_real_kitti_frames_meet_the_measured_floors(kitti_dev, tmp_path):
    out = tmp_path / "real.json"
    specs = [f"kitti_object:{kitti_dev / 'object' / 'training'}",
             f"semantickitti:{kitti_dev / 'semantickitti' / 'sequences' / '00'}"]
    args = ["--stage1-only", "--no-progress", "--json", str(out)]
    for spec in specs:
        args += ["--data", spec]
    assert evaluate.main(args) == 0
    data = json.loads(out.read_text())
    st = data["stage1"]
    assert data["frames"] == 6
    assert st["foreground_recall"] >= 0.97
    assert st["class_recall"]["pedestrian"] >= 0.95
    assert st["proposals_per_frame"]["median"] <= 37 and st["proposals_per_frame"]["mean"] <= 32
    assert st["ground"]["precision"] >= 0.90 and st["ground"]["recall"] >= 0.99
    assert all(row["ring_source"] == "azimuth_wrap" for row in data["per_frame"])
    assert st["ms_per_frame"]["median"] < 100.0  # a loose sanity bound: timing here is shared and noisy


def test_ground_metrics_without_ground_truth_are_null(tmp_path, capsys):
    """A SemanticKITTI-layout sequence whose labels hold no ground class has no ground truth: ground precision
    and recall are null in the JSON and n/a in the table, never 0.0."""
    from pass3d_ros.tools import simulate

    seq = tmp_path / "seq"
    assert simulate.main(["--frames", "2", "--seed", "3", "--out", str(seq)]) == 0
    for path in (seq / "labels").iterdir():
        raw = np.fromfile(path, dtype="<u4")
        raw[(raw & 0xFFFF) == 40] = (raw[(raw & 0xFFFF) == 40] & 0xFFFF0000) | 99  # road -> background
        raw.tofile(path)
    out = tmp_path / "eval.json"
    capsys.readouterr()
    assert evaluate.main(["--stage1-only", "--data", f"semantickitti:{seq}", "--json", str(out), "--no-progress",
                          "--per-frame"]) == 0
    st = json.loads(out.read_text())["stage1"]
    assert st["ground"] == {"precision": None, "recall": None} and st["ground_frames"] == 0
    table = capsys.readouterr().out
    rows = {name: [line.split()[2] for line in table.splitlines() if line.strip().startswith(name)]
            for name in ("ground precision", "ground recall")}
    assert rows == {"ground precision": ["n/a"], "ground recall": ["n/a"]}, table
    m = Stage1Metrics()
    row = m.update("f", 0, np.full(3, -1), np.full(3, -1), np.ones(3, bool), TIMINGS, None, np.zeros(3, bool))
    assert "ground_precision" not in row and m.summary()["stage1"]["ground"]["precision"] is None


def test_benchmark_times_stage1_with_a_parameter_changed(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    out = tmp_path / "bench.json"
    args = ["--repeat", "1", "--no-patchwork", "--param", "join_fragments=true", "--json", str(out)]
    assert bench.run(parser.parse_args(args)) == 0
    report = json.loads(out.read_text())
    assert report["config"]["join_fragments"] is True and report["stage1_ms_median"]["total"] > 0
    assert benchmark.main(["stage1", "--param", "no_such_parameter=1"]) == 2
    assert "no_such_parameter" in capsys.readouterr().err
