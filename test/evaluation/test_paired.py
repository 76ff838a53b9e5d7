"""Paired comparisons of two evaluations of the same frames (`pass3d_evaluate --paired-with`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pass3d_ros.classes import CAR, NUM_CLASSES, PEDESTRIAN
from pass3d_ros.core.metrics import bootstrap_iou, paired_iou_difference


def _frame(car_hit: int, car_miss: int, ped_hit: int = 5) -> np.ndarray:
    """A confusion matrix: car_hit car points called car, car_miss called background, ped_hit pedestrians found."""
    m = np.zeros((NUM_CLASSES, NUM_CLASSES), dtype=np.int64)
    m[0, 0], m[CAR, CAR], m[CAR, 0], m[PEDESTRIAN, PEDESTRIAN] = 1000, car_hit, car_miss, ped_hit
    return m


def test_a_small_steady_gain_is_told_from_frame_noise():
    """Frames of very different difficulty, the second run 2 car points better on each: the unpaired intervals of
    the two runs overlap, the paired difference's interval lies above 0 and holds the pooled difference."""
    rng = np.random.default_rng(0)
    hits = rng.integers(20, 100, 12)
    first = [_frame(int(h), 100 - int(h)) for h in hits]
    second = [_frame(int(h) + 2, 98 - int(h)) for h in hits]
    one, two = (bootstrap_iou(runs)["per_class"][CAR] for runs in (first, second))
    assert one["high"] > two["low"]  # frame to frame, the runs' own intervals cannot tell them apart
    result = paired_iou_difference(first, second)
    car = result[CAR]
    assert car["difference"] == pytest.approx((hits.sum() + 24) / 1200 - hits.sum() / 1200)
    assert 0 < car["low"] <= car["difference"] <= car["high"]
    assert result[PEDESTRIAN]["difference"] == 0.0 and result[PEDESTRIAN]["low"] == result[PEDESTRIAN]["high"] == 0.0
    with pytest.raises(ValueError, match="same F x k x k"):
        paired_iou_difference(first, second[:-1])


def test_evaluate_paired_with_another_run(tmp_path, capsys):
    """The network against the size rules on the same synthetic frame: a difference line per class, the JSON's
    "paired" block; another frame set, a file that is not a full run's JSON, or another mode: one line, exit 2."""
    from pass3d_ros.tools import evaluate

    data = ["--data", "synthetic:frames=2,seed=3", "--no-progress"]
    rules = tmp_path / "rules.json"
    assert evaluate.main([*data, "--classifier", "size_rules", "--json", str(rules)]) == 0
    ours = tmp_path / "net.json"
    assert evaluate.main([*data, "--paired-with", str(rules), "--json", str(ours)]) == 0
    out = capsys.readouterr().out
    assert f"this run minus {rules}" in out and "  car " in out
    summary, base = json.loads(ours.read_text()), json.loads(rules.read_text())
    car = summary["paired"]["classes"]["car"]
    assert car["difference"] == pytest.approx(summary["classes"]["car"]["iou"] - base["classes"]["car"]["iou"])
    assert evaluate.main(["--data", "synthetic:frames=1,seed=3", "--no-progress", "--paired-with", str(rules)]) == 2
    assert "scored other frames" in capsys.readouterr().err
    stage1 = tmp_path / "stage1.json"
    assert evaluate.main([*data, "--stage1-only", "--json", str(stage1)]) == 0
    assert evaluate.main([*data, "--paired-with", str(stage1)]) == 2
    assert "not a full evaluation's --json" in capsys.readouterr().err
    assert evaluate.main([*data, "--stage1-only", "--paired-with", str(rules)]) == 2
    assert "--paired-with applies to the full evaluation only" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["[]", "3", '"full"', '{"mode": "full", "per_frame": [1]}',
                                  '{"mode": "full", "per_frame": {"confusion": 1}}'])
def test_a_baseline_that_is_other_json_is_named(text, tmp_path):
    """Valid JSON of another shape (a list, a number, rows that are no objects) is the one-line UserError naming the
    file, not an AttributeError / TypeError traceback."""
    from pass3d_ros.evaluation.paired import read_baseline
    from pass3d_ros.msgs.errors import UserError

    path = tmp_path / "other.json"
    path.write_text(text)
    with pytest.raises(UserError, match=r"--paired-with .*other\.json: not a full evaluation's --json"):
        read_baseline(path)


def test_a_pair_whose_frames_hold_other_labels_under_the_same_names_is_refused() -> None:
    """Two runs of frames named alike whose labelled points differ (a dataset copy or a synthetic world changed between
    the runs) are not a pair: the one-line UserError names the frame, before any difference is read."""
    from pass3d_ros.evaluation.paired import paired
    from pass3d_ros.msgs.errors import UserError

    def run(car_points: int) -> dict:
        confusion = [[900, 0, 0, 0], [10, car_points, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]
        return {"per_frame": [{"frame": "synthetic:frames=1,seed=3#000000", "confusion": confusion}]}

    assert paired(run(90), run(90), "base.json")["classes"]["car"]["difference"] == pytest.approx(0.0)
    with pytest.raises(UserError, match=r"base\.json: frame synthetic:frames=1,seed=3#000000 holds other labelled"):
        paired(run(90), run(95), "base.json")
