"""Pseudo-labels for self-training on unlabelled scans (pass3d_ros.training.pseudo_labels, pass3d_pseudo_label)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pass3d_ros.classes import BACKGROUND
from pass3d_ros.core.stage2.pointnet2 import PointNet2Seg, make_config
from pass3d_ros.core.stage2.segmentation import Segmenter, make_checkpoint
from pass3d_ros.data.semantickitti import read_semantickitti
from pass3d_ros.tools import pseudo_label
from pass3d_ros.training.pseudo_labels import pseudo_label_scan


@pytest.fixture(scope="module")
def segmenter() -> Segmenter:
    torch.manual_seed(11)
    return Segmenter(make_checkpoint(PointNet2Seg(make_config("lite")), data={}, epoch=0))


def scene() -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(2)
    car = np.c_[rng.uniform([6, -1, -1.7], [10, 1, -0.3], (600, 3)), rng.random(600)]
    person = np.c_[rng.uniform([-5, 4, -1.7], [-4.4, 4.6, 0.0], (80, 3)), rng.random(80)]
    rest = np.c_[rng.uniform([-30, -30, -1.8], [30, 30, -1.6], (500, 3)), rng.random(500)]
    points = np.concatenate([car, person, rest]).astype(np.float32)
    return points, [np.arange(600), np.arange(600, 680)]


def test_only_unanimous_confident_proposals_keep_their_points(segmenter: Segmenter) -> None:
    points, members = scene()
    views = segmenter.view_classes(points, members)
    labels, keep, kept = pseudo_label_scan(points, members, segmenter, min_confidence=0.0)
    unanimous = (views == views[:, :1]).all(axis=1)
    assert len(kept) == unanimous.sum() and np.array_equal(kept, views[unanimous, 0])
    for p, member in enumerate(members):
        assert keep[member].all() == unanimous[p]  # a split proposal's points are left out
    assert keep[680:].all() and np.all(labels[680:] == BACKGROUND)  # outside every proposal: background
    labels, keep, kept = pseudo_label_scan(points, members, segmenter, min_confidence=1.0)
    assert len(kept) == 0 and not keep[:680].any() and keep[680:].all()


def test_tool_writes_a_trainable_sequence(tmp_path: Path) -> None:
    out = tmp_path / "pseudo"
    args = ["--data", "synthetic:frames=2,seed=98", "--out", str(out), "--no-progress"]
    assert pseudo_label.main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 2 and sum(summary["kept"].values()) > 0
    frames = list(read_semantickitti(out))
    assert [f.name for f in frames] == ["000000", "000001"]
    assert all(f.labels is not None and len(f.labels) == len(f.points) for f in frames)
    assert any(np.any(f.labels != BACKGROUND) for f in frames)
    assert pseudo_label.main(args) == 2  # exists: needs --force
    with pytest.raises(SystemExit) as refused:  # argparse's usage line, exit 2
        pseudo_label.main([*args, "--min-confidence", "1.5", "--force"])
    assert refused.value.code == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial folder left behind
