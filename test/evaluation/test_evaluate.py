"""`pass3d_evaluate` full (offline) and live modes, run_live's repeated replay, and `pass3d_benchmark live`."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pass3d_ros.bench import benchmark
from pass3d_ros.bench import live as bench_live
from pass3d_ros.classes import CLASS_NAMES, FOREGROUND, IGNORE, NUM_CLASSES
from pass3d_ros.core import stage2
from pass3d_ros.core.metrics import ObjectRecall, SegmentationMetrics, format_objects
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.data.bag import iter_raw, read_bag, select_topic
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.evaluation.live import LiveFrame, LiveResult, cdr_stamp_ns, run_live, with_stamp
from pass3d_ros.evaluation.offline import background_proposals
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.tools import evaluate

pytestmark = pytest.mark.ros

SPEC = "synthetic:frames=2,seed=1"
METRIC_KEYS = {"precision", "recall", "iou", "points", "interval"}


@pytest.fixture(scope="module")
def labelled_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bags") / "labelled"
    convert([SPEC], out, with_labels=True, progress=False, log=lambda _: None)
    return out


def run_json(tmp_path: Path, name: str, *args: str) -> dict:
    out = tmp_path / f"{name}.json"
    assert evaluate.main([*args, "--json", str(out), "--no-progress"]) == 0
    return json.loads(out.read_text())


def test_full_mode_json_has_every_key_and_true_point_counts(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = run_json(tmp_path, "full", "--data", SPEC, "--classifier", "size_rules", "--per-frame")
    truth = np.concatenate([generate_frame(1, index).labels for index in range(2)])
    counts = np.bincount(truth, minlength=NUM_CLASSES)
    assert data["mode"] == "full" and data["frames"] == 2
    assert data["classifier"] == {"kind": "size_rules", "weights": None, "device": "cpu", "threads": 1}
    assert data["people_in_groups"] is PEOPLE_IN_GROUPS
    assert set(data["classes"]) == set(CLASS_NAMES)
    for c, name in enumerate(CLASS_NAMES):
        row = data["classes"][name]
        assert set(row) == METRIC_KEYS and row["points"] == int(counts[c])
        for key in ("precision", "recall", "iou"):
            assert 0.0 <= row[key] <= 1.0, (name, key)
        assert row["iou"] <= min(row["precision"], row["recall"]) + 1e-12
    assert data["classes"]["car"]["iou"] > 0.5, "size rules find the synthetic cars"
    ious = [data["classes"][CLASS_NAMES[c]]["iou"] for c in FOREGROUND]
    assert data["mean_iou"] == pytest.approx(float(np.mean(ious)))
    ms = data["ms_per_frame"]
    assert set(ms) == {"stage1", "stage2", "total"} and ms["stage1"] > 0 and ms["stage2"] > 0
    assert ms["total"] >= max(ms["stage1"], ms["stage2"])
    st = data["stage1"]
    assert 0.9 <= st["foreground_recall"] <= 1.0 and st["foreground_points"] == int(counts[list(FOREGROUND)].sum())
    rows = data["per_frame"]
    assert [r["points"] for r in rows] == [len(generate_frame(1, i).labels) for i in range(2)]
    assert all(r["proposals"] > 0 and r["total_ms"] == pytest.approx(r["stage1_ms"] + r["stage2_ms"]) for r in rows)
    background = data["background_proposals"]
    assert set(background) == {"front_view", "called_object"}
    assert background["called_object"] <= background["front_view"] <= sum(r["proposals"] for r in rows)
    assert background["front_view"] > 0
    objects = data["objects"]
    assert objects["frames_without_instances"] == 0 and objects["min_points"] == 10
    cars = objects["classes"]["car"]
    assert 0 < cars["found"] <= cars["objects"] and cars["recall"] == pytest.approx(cars["found"] / cars["objects"])
    printed = capsys.readouterr().out
    assert "mean IoU (car, pedestrian, cyclist)" in printed and "stage 2" in printed and "#000001" in printed
    assert f"car {cars['found']} of {cars['objects']}" in printed
    assert f"called an object: {background['called_object']} of {background['front_view']}" in printed


def test_background_proposals_counts_front_view_clutter_only() -> None:
    """Counted: proposals ahead whose labelled points are all background; called: those stage 2 made an object."""
    points = np.zeros((10, 4), np.float32)
    points[:, 0] = [10, 10, -10, -10, 10, 10, 10, 10, 10, 10]
    points[8:, 1] = 30.0  # 71 degrees to the left: outside the front view
    truth = np.array([0, 0, 0, 0, 0, 1, IGNORE, IGNORE, 0, 0], np.uint8)
    members = [np.array([0, 1]), np.array([2, 3]), np.array([4, 5]), np.array([6, 7]), np.array([8, 9]),
               np.array([1, 6])]
    proposal_class = np.array([1, 1, 1, 1, 1, 0])
    assert background_proposals(points, truth, members, proposal_class) == (2, 1)


def test_segmentation_metrics_pool_frames() -> None:
    metrics = SegmentationMetrics()
    metrics.update("a", np.array([0, 1, 1, 2]), np.array([0, 1, 0, 2]), 2.0, 10.0)
    metrics.update("b", np.array([1, 3]), np.array([1, 1]), 4.0, 30.0, total_ms=50.0)
    summary = metrics.summary()
    assert summary["frames"] == 2
    car = summary["classes"]["car"]
    assert {k: v for k, v in car.items() if k != "interval"} == {"precision": 2 / 3, "recall": 2 / 3, "iou": 0.5,
                                                                 "points": 3}
    assert car["interval"]["low"] <= car["iou"] <= car["interval"]["high"] and car["interval"]["level"] == 0.9
    assert summary["classes"]["cyclist"]["iou"] == 0.0 and summary["classes"]["pedestrian"]["iou"] == 1.0
    assert summary["mean_iou"] == pytest.approx(0.5)
    assert summary["ms_per_frame"] == {"stage1": 3.0, "stage2": 20.0, "total": 31.0}
    assert metrics.per_frame[0]["mean_iou"] == pytest.approx(0.75), "frame a: car 0.5, pedestrian 1"


@pytest.mark.parametrize("kind", ["size_rules", "network"])
def test_offline_and_live_lockstep_agree(kind: str, labelled_bag: Path, lite_weights: Path, tmp_path: Path) -> None:
    stage2 = ["--classifier", "size_rules"] if kind == "size_rules" else ["--weights", str(lite_weights)]
    offline = run_json(tmp_path, "offline", "--data", f"bag:{labelled_bag}", *stage2)
    # size_rules: the synthetic spec itself, converted to a temporary bag; network: the bag as it is.
    live_data = SPEC if kind == "size_rules" else f"bag:{labelled_bag}"
    record = tmp_path / "labeled"
    live = run_json(tmp_path, "live", "--live", "--lockstep", "--data", live_data, *stage2,
                    "--record-out", str(record))
    assert live["mode"] == "live" and live["frames"] == 2
    assert live["live"]["frames_in"] == live["live"]["frames_out"] == 2 and live["live"]["dropped"] == 0
    assert live["live"]["latency_ms"]["median"] > 0 and live["ms_per_frame"]["total"] > 0
    assert live["ms_per_frame"]["stage1"] < live["ms_per_frame"]["total"]
    assert live["bag"] == (None if kind == "size_rules" else str(labelled_bag))
    assert live["classifier"]["kind"] == kind
    assert offline["mean_iou"] is not None and abs(offline["mean_iou"] - live["mean_iou"]) <= 0.01
    for name in CLASS_NAMES:
        assert live["classes"][name]["points"] == offline["classes"][name]["points"]
        assert live["classes"][name]["iou"] == pytest.approx(offline["classes"][name]["iou"], abs=0.01)
    assert len(list(read_bag(record))) == 2


def test_user_errors_exit_2(labelled_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
                            monkeypatch: pytest.MonkeyPatch) -> None:
    assert evaluate.main(["--data", "nosuchformat:/x", "--classifier", "size_rules"]) == 2
    assert "unknown format" in capsys.readouterr().err

    monkeypatch.setattr(stage2, "DEFAULT_WEIGHTS", tmp_path / "pass3d_lite.pt")
    for extra in ([], ["--live"]):
        assert evaluate.main(["--data", SPEC, *extra]) == 2
        err = capsys.readouterr().err
        assert "pass3d_lite.pt" in err and "--classifier size_rules" in err and "--weights" in err
    nowhere = tmp_path / "nowhere.pt"
    assert evaluate.main(["--data", SPEC, "--weights", str(nowhere)]) == 2
    assert str(nowhere) in capsys.readouterr().err
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    assert evaluate.main(["--data", "synthetic:frames=1,seed=0", "--weights", str(garbage), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "not a pass3d checkpoint" in err and "weights_only" not in err

    unlabelled = tmp_path / "unlabelled"
    convert(["synthetic:frames=1,seed=2"], unlabelled, progress=False, log=lambda _: None)
    for extra in ([], ["--live"]):
        assert evaluate.main(["--data", f"bag:{unlabelled}", "--classifier", "size_rules", "--no-progress",
                              *extra]) == 2
        err = capsys.readouterr().err
        assert f"bag:{unlabelled}" in err and "no point labels" in err
    assert evaluate.main(["--data", SPEC, "--lockstep", "--classifier", "size_rules"]) == 2
    assert "only apply with --live" in capsys.readouterr().err
    toggled = "--no-people-in-groups" if PEOPLE_IN_GROUPS else "--people-in-groups"
    assert evaluate.main(["--data", SPEC, "--stage1-only", toggled]) == 2
    assert "full and tracking modes only" in capsys.readouterr().err
    assert evaluate.main(["--data", SPEC, "--classifier", "size_rules", "--weights", str(garbage)]) == 2
    assert "--weights applies to the network" in capsys.readouterr().err
    assert evaluate.main(["--data", SPEC, "--live", "--limit", "1", "--classifier", "size_rules"]) == 2


def test_with_stamp_rewrites_only_the_stamp(labelled_bag: Path) -> None:
    raw = next(raw for _, _, raw in iter_raw(labelled_bag, select_topic(labelled_bag, None)))
    new = with_stamp(raw, 1_800_000_000_987_654_321)
    assert cdr_stamp_ns(new) == 1_800_000_000_987_654_321
    assert len(new) == len(raw) and new[:4] == raw[:4] and new[12:] == raw[12:]


def test_run_live_repeat_replays_with_increasing_stamps(labelled_bag: Path) -> None:
    frames = list(read_bag(labelled_bag))
    result = run_live(labelled_bag, lockstep=True, repeat=3, timeout_s=30.0, keep_labels=False,
                      node_parameters={"segmentation_node": {"classifier": "size_rules"}})
    assert result.frames_in == result.frames_out == 6 and result.dropped == result.skipped == 0
    assert result.mismatched == result.unmatched_outputs == 0
    stamps = [f.stamp_ns for f in result.frames]
    spacing = frames[1].stamp_ns - frames[0].stamp_ns
    first_pass = [f.stamp_ns for f in frames]
    assert stamps == [s + lap * 2 * spacing for lap in range(3) for s in first_pass]
    assert [f.index for f in result.frames] == list(range(6))
    truth = np.concatenate([f.labels for f in frames])
    np.testing.assert_array_equal(result.confusion.matrix.sum(axis=1), 3 * np.bincount(truth, minlength=NUM_CLASSES))
    with pytest.raises(ValueError, match="repeat"):
        run_live(labelled_bag, repeat=0)


def test_memory_report_on_known_samples() -> None:
    samples = [(0.0, 50.0), (1.0, 100.0), (2.0, 100.0), (3.0, 101.0), (4.0, 102.0)]
    report = bench_live.memory_report(samples, warmup_s=1.0, span_s=1.0)
    assert report["after_warmup_mib"] == 100.0 and report["end_mib"] == 101.5 and report["peak_mib"] == 102.0
    assert report["growth_pct"] == pytest.approx(1.5) and report["slope_mib_per_min"] == pytest.approx(42.0)
    assert report["window_s"] == 3.0
    assert bench_live.memory_report([], 1.0) == {"available": False}
    rss = bench_live.rss_mib()
    assert rss is None or 10.0 < rss < 1e6


def test_window_rows_split_by_input_time() -> None:
    frames = [LiveFrame(index=i, stamp_ns=i, points=1, latency_ms=float(10 * (i // 10) + 5), stage1_ms=None,
                        stage2_ms=None, mismatch=False) for i in range(0, 30, 2)]
    result = LiveResult(lockstep=False, rate=1.0, frames_in=30, frames_out=len(frames), frames=frames, wall_s=3.0)
    jiffies = [[0, 0, 0, 0, 0, 0, 0, 0], [50, 0, 0, 50, 0, 0, 0, 0], [150, 0, 0, 50, 0, 0, 0, 0],
               [150, 0, 0, 150, 0, 0, 0, 0]]
    sampler = SimpleNamespace(cpu=[(1.0 + k, jiffies[k], 0.5 * k) for k in range(4)])
    rows = bench_live.window_rows(result, sampler, input_hz=10.0, window_s=1.0)
    assert [r["from_s"] for r in rows] == [0.0, 1.0, 2.0]
    assert [r["frames_in"] for r in rows] == [10, 10, 10] and [r["frames_out"] for r in rows] == [5, 5, 5]
    assert [r["latency_median_ms"] for r in rows] == [5.0, 15.0, 25.0]
    assert [r["busy_pct"] for r in rows] == [50.0, 100.0, 0.0], "samples aligned to the end of the replay"
    assert all(r["this_process_pct"] == pytest.approx(100 * 0.5 / (os.cpu_count() or 1)) for r in rows)


def test_benchmark_live_short_run(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    parser = argparse.ArgumentParser()
    bench_live.add_arguments(parser)
    out = tmp_path / "live.json"
    args = parser.parse_args(["--frames", "1", "--seconds", "2", "--warmup", "0.5", "--classifier", "size_rules",
                              "--json", str(out)])
    assert bench_live.run(args) == 0
    printed = capsys.readouterr().out
    assert "output rate" in printed and "resident memory" in printed and "target" in printed
    report = json.loads(out.read_text())
    live = report["live"]
    assert report["repeat"] == 20 and live["frames_in"] == 20, "1 frame x 20 passes = 2 s at 10 Hz"
    assert 1 <= live["frames_out"] <= 20 and live["dropped"] == 20 - live["frames_out"]
    assert live["lockstep"] is False and live["latency_ms"]["median"] > 0
    if report["memory"]["available"]:
        assert report["memory"]["after_warmup_mib"] > 10.0 and report["memory"]["end_mib"] > 10.0
    assert benchmark.main(["live", "--classifier", "size_rules", "--weights", "x.pt"]) == 2
    assert "pass3d_benchmark: error: --weights applies" in capsys.readouterr().err


def test_live_scoring_accepts_unknown_labels_from_kitti_layouts(tmp_path: Path) -> None:
    """KITTI-layout ground truth is unknown (IGNORE) outside the front view; the live path scores around it."""
    from pass3d_ros.classes import IGNORE
    from pass3d_ros.data.kitti_object import write_kitti_object_frame

    write_kitti_object_frame(tmp_path / "obj", generate_frame(1, 0))
    bag = tmp_path / "bag"
    convert([f"kitti_object:{tmp_path / 'obj'}"], bag, with_labels=True, progress=False, log=lambda _: None)
    (frame,) = list(read_bag(bag))
    assert np.any(frame.labels == IGNORE)
    result = run_live(bag, lockstep=True, node_parameters={"segmentation_node": {"classifier": "size_rules"}})
    assert (result.frames_in, result.frames_out, result.mismatched) == (1, 1, 0)
    known = frame.labels != IGNORE
    assert result.confusion.matrix.sum() == np.count_nonzero(known)


def test_object_recall_counts_objects_found_by_half_their_points() -> None:
    car, ped = CLASS_NAMES.index("car"), CLASS_NAMES.index("pedestrian")
    # car 0: 20 points, 10 called car (found at exactly half); car 1: 20 points, 9 called car (missed);
    # car 2: 5 points (too small to count); pedestrian 3: 12 points all called car (missed); 4 stray car points
    # without an instance id (not an object).
    truth = np.array([car] * 45 + [ped] * 12 + [car] * 4)
    instance = np.array([0] * 20 + [1] * 20 + [2] * 5 + [3] * 12 + [-1] * 4)
    predicted = np.zeros(len(truth), dtype=np.uint8)
    predicted[:10] = car
    predicted[20:29] = car
    predicted[40:45] = car
    predicted[45:57] = car
    predicted[57:] = car
    objects = ObjectRecall()
    objects.update(truth, predicted, instance)
    objects.update(truth, predicted, None)
    summary = objects.summary()
    assert summary["frames_without_instances"] == 1
    assert summary["classes"]["car"] | {"interval": None} == {"objects": 2, "found": 1, "recall": 0.5, "interval": None}
    assert summary["classes"]["pedestrian"]["found"] == 0 and summary["classes"]["pedestrian"]["objects"] == 1
    assert summary["classes"]["cyclist"]["recall"] is None
    assert "car 1 of 2 (50.0 %" in format_objects(summary)[0]
    with pytest.raises(ValueError, match="instance ids"):
        objects.update(truth, predicted, instance[:-1])
    assert ObjectRecall().summary() is None and format_objects(None) == []
