"""Stage 2's proposal budget is never a silent cap: the offline tools count what it cuts, as the segmentation node does
(pass3d_ros.core.stage2.segmentation.proposals_cut), and print and write it; and `--param` takes the node's names."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS, proposals_cut
from pass3d_ros.tools import evaluate, segment

SPEC = "synthetic:frames=2,seed=0"


def test_proposals_cut_counts_what_the_budget_leaves() -> None:
    assert proposals_cut(10, 64) == 0 and proposals_cut(64, 64) == 0 and proposals_cut(70, 64) == 6
    assert DEFAULT_MAX_PROPOSALS == 128  # a 360-degree scan has twice a front view's proposals


def test_full_evaluation_reports_the_cut(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "full.json"
    assert evaluate.main(["--data", SPEC, "--classifier", "size_rules", "--max-proposals", "3", "--no-progress",
                          "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    rows = summary["per_frame"]
    cuts = [max(0, row["proposals"] - 3) for row in rows]
    assert [row["proposals_cut"] for row in rows] == cuts and sum(cuts) > 0
    assert summary["budget"] == {"max_proposals": 3, "proposals_cut": sum(cuts), "frames_cut": sum(c > 0 for c in cuts)}
    printed = capsys.readouterr().out
    assert (f"proposals cut by the budget (max_proposals 3, nearest first): {sum(cuts)} in "
            f"{sum(c > 0 for c in cuts)} frame(s)") in printed


def test_stage1_evaluation_says_what_the_budget_would_cut(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s1.json"
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--no-progress", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["budget"] == {"max_proposals": DEFAULT_MAX_PROPOSALS, "proposals_cut": 0, "frames_cut": 0}
    said = capsys.readouterr().out
    assert f"would cut (max_proposals {DEFAULT_MAX_PROPOSALS}, nearest first): 0 in 0 frame(s)" in said
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--no-progress", "--max-proposals", "1",
                          "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["budget"]["proposals_cut"] == sum(row["proposals"] - 1 for row in summary["per_frame"])


@pytest.mark.parametrize(("args", "says"), [
    (["--max-proposals", "0"], "--max-proposals must be >= 1"),
    (["--live", "--max-proposals", "5"], "--max-proposals does not apply with --live"),
])
def test_bad_budget_is_one_line(args: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert evaluate.main(["--data", SPEC, "--classifier", "size_rules", "--no-progress", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_segment_reports_the_cut(tmp_path: Path) -> None:
    said: list[str] = []
    assert segment.main(["--data", SPEC, "--out", str(tmp_path / "out"), "--classifier", "size_rules",
                         "--max-proposals", "2", "--no-progress", "--no-png"], log=said.append) == 0
    budget = json.loads((tmp_path / "out" / "summary.json").read_text())["budget"]
    assert budget["max_proposals"] == 2 and budget["proposals_cut"] > 0
    assert any("proposals cut by the budget (max_proposals 2" in line and f"{budget['proposals_cut']} in" in line
               for line in said), said


@pytest.mark.parametrize("item", ["stage1.sensor=pandar64", "sensor=pandar64", "sensor='pandar64'"])
def test_evaluate_takes_the_node_name_and_unquoted_strings(item: str, tmp_path: Path) -> None:
    out = tmp_path / "s1.json"
    assert evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0,sensor=pandar64", "--no-progress",
                          "--param", item, "--param", "stage1.enlarge=0.1,0.1,0.5", "--json", str(out)]) == 0
    config = json.loads(out.read_text())["config"]
    assert config["sensor"] == "pandar64" and config["enlarge"] == [0.1, 0.1, 0.5]


def test_segment_takes_the_node_name(tmp_path: Path) -> None:
    assert segment.main(["--data", "synthetic:frames=1,seed=0", "--out", str(tmp_path / "out"), "--classifier",
                         "size_rules", "--no-progress", "--no-png", "--param", "stage1.th_dist=0.25",
                         "--param", "ground_thread=false"], log=lambda _: None) == 0
