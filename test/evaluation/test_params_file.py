"""`pass3d_evaluate --params-file`: a folder pass3d_adapt wrote is scored with the settings the nodes would run with."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from pass3d_ros.core.stage2 import DEFAULT_WEIGHTS
from pass3d_ros.data.params_file import read_params_file
from pass3d_ros.tools import evaluate

SPEC = "synthetic:frames=1,seed=3"
SHIPPED = Path(__file__).resolve().parents[2] / "launch_configs" / "pass3d_params.yaml"


def _adapted(tmp_path: Path) -> tuple[Path, Path]:
    """A parameter file as pass3d_adapt writes it, and the weights it names (a copy of the shipped ones)."""
    weights = tmp_path / "mine" / "weights.pt"
    weights.parent.mkdir()
    shutil.copy(DEFAULT_WEIGHTS, weights)
    params = tmp_path / "mine" / "pass3d_params.yaml"
    params.write_text("# Written by pass3d_adapt\n/**/cluster_proposal_node:\n  ros__parameters:\n"
                      "    input_topic: /ouster/points\n    stage1:\n      sensor: vlp16\n      min_range: 2.5\n"
                      "      enlarge: [0.2, 0.2, 0.4]\n      split_merged: false\n"
                      f"/**/segmentation_node:\n  ros__parameters:\n    weights: {weights}\n")
    return params, weights


def test_the_nodes_settings_are_read_and_the_command_line_wins(tmp_path: Path) -> None:
    params, weights = _adapted(tmp_path)
    node = read_params_file(params)
    assert node.stage1 == ["stage1.sensor=vlp16", "stage1.min_range=2.5", "stage1.enlarge=0.2,0.2,0.4",
                           "stage1.split_merged=false"] and node.weights == str(weights)
    out = tmp_path / "run.json"
    assert evaluate.main(["--data", SPEC, "--params-file", str(params), "--param", "sensor=auto", "--json", str(out),
                          "--no-progress"]) == 0
    summary = json.loads(out.read_text())
    assert summary["config"]["min_range"] == 2.5 and summary["config"]["enlarge"] == [0.2, 0.2, 0.4]
    assert summary["config"]["split_merged"] is False and summary["config"]["sensor"] == "auto"
    assert Path(summary["classifier"]["weights"]) == weights
    shipped = read_params_file(SHIPPED)  # the shipped file holds every stage-1 default and no weights
    assert shipped.weights is None and "stage1.min_range=0.0" in shipped.stage1


@pytest.mark.parametrize(("text", "problem"), [
    ("a: [", "cannot be read"),
    ("just text", "no cluster_proposal_node or segmentation_node"),
    ("/**/cluster_proposal_node:\n  stage1: {}\n", "has no ros__parameters"),
    ("/**/cluster_proposal_node:\n  ros__parameters:\n    stage1:\n      th_dits: 0.2\n", "th_dits"),
    ("/**/segmentation_node:\n  ros__parameters:\n    weights: [1, 2]\n", "weights is not a path"),
])
def test_a_file_that_is_no_parameter_file_names_itself(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                        text: str, problem: str) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    assert evaluate.main(["--data", SPEC, "--params-file", str(bad), "--no-progress", "--stage1-only"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and problem in err and "Traceback" not in err
