"""View agreement (pass3d_ros.evaluation.agreement): the network's class of a proposal in each of the 8 views."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.metrics import bootstrap_ratio
from pass3d_ros.core.stage2 import canonical
from pass3d_ros.core.stage2.pointnet2 import PointNet2Seg, make_config
from pass3d_ros.core.stage2.segmentation import Segmenter, make_checkpoint
from pass3d_ros.evaluation.agreement import ViewAgreement
from pass3d_ros.tools import evaluate


def test_counts_follow_the_majority_and_unanimity() -> None:
    views = np.array([
        [CAR] * 8,  # unanimous car
        [CAR] * 6 + [BACKGROUND] * 2,  # car by majority, not unanimous
        [PEDESTRIAN] * 8,
        [BACKGROUND] * 8,  # background: not counted
    ])
    agreement = ViewAgreement()
    row = agreement.update(views)
    assert row.tolist() == [[2, 1], [1, 1], [0, 0]]
    agreement.update(np.zeros((0, 8), dtype=np.int16))
    summary = agreement.summary()
    assert summary["car"]["proposals"] == 2 and summary["car"]["agreement"] == 0.5
    assert summary["cyclist"]["agreement"] is None
    assert summary["car"]["interval"]["frames"] == 2


def test_bootstrap_ratio_brackets_the_pooled_ratio() -> None:
    interval = bootstrap_ratio(np.array([9, 8, 10, 7]), np.array([10, 10, 10, 10]))
    assert interval["low"] <= 0.85 <= interval["high"] and interval["low"] >= 0.7 and interval["high"] <= 1.0
    same = bootstrap_ratio(np.array([5]), np.array([10]))
    assert same["degenerate"] and same["low"] == same["high"] == 0.5


def test_view_classes_include_the_inference_view() -> None:
    """Column v of a proposal is what segment() gives it when v is its inference view: the same points, the
    same network, only the view differs."""
    torch.manual_seed(5)
    segmenter = Segmenter(make_checkpoint(PointNet2Seg(make_config("lite")), data={}, epoch=0))
    rng = np.random.default_rng(0)
    car = np.c_[rng.uniform([6, -1, -1.7], [10, 1, -0.3], (700, 3)), rng.random(700)]
    person = np.c_[rng.uniform([-5, 4, -1.7], [-4.4, 4.6, 0.0], (90, 3)), rng.random(90)]
    post = np.c_[rng.uniform([3, -6, -1.7], [3.2, -5.8, 0.6], (40, 3)), rng.random(40)]
    points = np.concatenate([car, person, post]).astype(np.float32)
    members = [np.arange(700), np.arange(700, 790), np.arange(790, 830)]
    views = segmenter.view_classes(points, members)
    assert views.shape == (3, canonical.NUM_VIEWS)
    inference = canonical.inference_views(canonical.fit_box_members(points, members))
    expected = segmenter.segment(points, members).proposal_class
    assert np.array_equal(views[np.arange(3), inference], expected)
    assert segmenter.view_classes(points, []).shape == (0, canonical.NUM_VIEWS)


def test_evaluate_view_agreement_needs_no_labels(tmp_path: Path) -> None:
    out = tmp_path / "agreement.json"
    assert evaluate.main(["--view-agreement", "--data", "synthetic:frames=2,seed=98", "--json", str(out),
                          "--no-progress"]) == 0
    summary = json.loads(out.read_text())
    assert summary["mode"] == "view_agreement" and summary["frames"] == 2
    car = summary["agreement"]["car"]
    assert car["proposals"] > 0 and 0.5 <= car["agreement"] <= 1.0  # the shipped weights on their own world
    assert set(summary["intensity"].values()) == {summary["intensity"]["synthetic:frames=2,seed=98"]}


def test_view_agreement_refuses_what_has_no_views() -> None:
    spec = "synthetic:frames=1,seed=98"
    assert evaluate.main(["--view-agreement", "--data", spec, "--classifier", "size_rules"]) == 2
    with pytest.raises(SystemExit) as stop:  # one mode per run
        evaluate.main(["--view-agreement", "--stage1-only", "--data", "synthetic:frames=1,seed=98"])
    assert stop.value.code == 2
