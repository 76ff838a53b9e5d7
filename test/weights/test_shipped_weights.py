"""The weights shipped in the package load, fit this code, and beat the geometric baseline on unseen scans."""

from __future__ import annotations

import pass3d_ros.synthetic  # noqa: F401  (registers the synthetic: format that UNSEEN names)
from pass3d_ros.classes import CLASS_NAMES
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.segmentation import Segmenter
from pass3d_ros.evaluation.offline import evaluate_full, iter_frames
from pass3d_ros.weights import DEFAULT_WEIGHTS

# Seeds 1, 2, 11 and 12 trained and validated the shipped weights; 99 is unseen.
UNSEEN = "synthetic:frames=3,seed=99"


def test_shipped_weights_are_the_lite_config_with_our_classes(shipped: Segmenter) -> None:
    assert shipped.config.name == "lite"
    assert tuple(shipped.classes) == CLASS_NAMES
    assert DEFAULT_WEIGHTS.stat().st_size < 5 * 1024 * 1024, "shipped weights must stay a small file"
    assert (DEFAULT_WEIGHTS.parent / "README.md").read_text().count("pass3d_train") >= 1


def test_shipped_weights_beat_size_rules_on_unseen_synthetic_scans(shipped: Segmenter) -> None:
    config = Stage1Config()
    network = evaluate_full(iter_frames([UNSEEN], None, False), config, shipped)
    rules = evaluate_full(iter_frames([UNSEEN], None, False), config, open_classifier(None, "size_rules"))
    assert network["classes"]["car"]["iou"] > 0.75
    assert network["mean_iou"] > rules["mean_iou"] + 0.1, (network["mean_iou"], rules["mean_iou"])
