"""pass3d_segment --nproc: the frames shared by several processes give the files one process gives, byte for byte,
one summary over all of them; a failing process fails the run with one line and leaves --out as it was."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.data.spec import resolve_datasets
from pass3d_ros.evaluation import segmenting
from pass3d_ros.evaluation.segmenting import blocks
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.tools import segment
from pass3d_ros.training import worker

SPEC = "synthetic:frames=4,seed=4"
BASE = ["--classifier=size_rules", "--no-progress", "--no-png"]


def files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("pass3d_segment: ") and "Traceback" not in err, err
    return lines[0]


def test_blocks_are_contiguous_and_even() -> None:
    assert blocks(5, 2) == [(0, 2), (2, 5)]
    assert blocks(4, 4) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    assert blocks(1, 3) == [(0, 0), (0, 0), (0, 1)], "more processes than frames: some get none"


def test_two_processes_write_what_one_writes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    one, two = tmp_path / "one", tmp_path / "two"
    assert segment.main([f"--data={SPEC}", f"--out={one}", *BASE], log=lambda _: None) == 0
    assert segment.main([f"--data={SPEC}", f"--out={two}", *BASE, "--nproc=2"]) == 0, capsys.readouterr().err
    first, second = files(one), files(two)
    assert sorted(first) == sorted(second)
    outputs = [name for name in first if name.startswith(("labels/", "objects/"))]
    assert len(outputs) == 8
    assert all(first[name] == second[name] for name in outputs), "rank 1 warmed its stream: identical labels"
    solo, shared = json.loads(first["summary.json"]), json.loads(second["summary.json"])
    assert shared["frames"] == 4 and shared["labeled_frames"] == 4 and shared["points"] == solo["points"]
    assert [(r["rank"], r["first_frame"], r["frames"]) for r in shared["ranks"]] == [(0, 0, 2), (1, 2, 2)]
    assert shared["ranks"][1]["warm_frames"] == 2 and shared["ranks"][0]["warm_frames"] == 0
    assert shared["per_class"] == solo["per_class"] and shared["mean_iou"] == solo["mean_iou"], \
        "metrics from the summed confusion, not averaged percentages"
    assert shared["budget"] == solo["budget"] and shared["intensity"] == solo["intensity"]
    assert not list(tmp_path.glob(".*partial*")), "no build folder left"


def test_a_failing_process_fails_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Rank 1's block is a sequence whose first scan is corrupt, while rank 0 labels its synthetic frames: one line
    naming the scan, exit 2, no --out and no build folder left."""
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "velodyne" / "000000.bin").write_bytes(b"x" * 10)
    for k in (1, 2):
        generate_frame(4, 0).points.tofile(seq / "velodyne" / f"{k:06d}.bin")
    out = tmp_path / "out"
    code = segment.main(["--data=synthetic:frames=3,seed=4", f"--data=semantickitti:{seq}", f"--out={out}", *BASE,
                         "--nproc=2"])
    assert code == 2
    assert "000000.bin" in one_line(capsys.readouterr().err)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_the_launcher_removes_the_build_folder_of_a_killed_rank_0(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A rank 0 killed after a peer failed leaves its build folder; --nproc's launcher removes it, DIR untouched."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    out = tmp_path / "out"
    left = tmp_path / f".out.partial-{gone.pid}"

    def failed_run(*_args: object) -> int:
        left.mkdir()
        (left / "labels").mkdir()
        return 2

    monkeypatch.setattr(segment.launcher, "launch", failed_run)
    assert segment.main([f"--data={SPEC}", f"--out={out}", *BASE, "--nproc=2"]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["0", "-1", "two", "1.5"])
def test_bad_nproc_is_one_line(value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        segment.main([f"--data={SPEC}", f"--out={tmp_path / 'out'}", *BASE, f"--nproc={value}"])
    assert exit_.value.code == 2
    assert "--nproc" in one_line(capsys.readouterr().err) and not (tmp_path / "out").exists()


def test_nproc_under_torchrun_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(worker, "die_with_parent", lambda: None)
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    monkeypatch.delenv(worker.LAUNCHER_ENV, raising=False)
    with pytest.raises(SystemExit) as exit_:
        segment.main([f"--data={SPEC}", f"--out={tmp_path / 'out'}", *BASE, "--nproc=2"])
    assert exit_.value.code == 2 and "torchrun" in one_line(capsys.readouterr().err)


@pytest.mark.parametrize("warm", [True, False])
def test_rank_1_labels_its_block_after_warming_its_stream(warm: bool, tmp_path: Path) -> None:
    """In-process, as rank 1 of 2: only its block is written; with the warm-up it replayed the frames before it."""
    datasets = resolve_datasets([SPEC])
    build = tmp_path / "build"
    segmenting._make_folders(build, 1, png=False)
    stats = segmenting._segment_all(datasets, tmp_path / "out", build, SizeRuleClassifier(), None, False, False,
                                    True, segmenting.Ranks(rank=1, world=2), warm)
    assert sorted(p.name for p in (build / "labels").iterdir()) == ["000002.label", "000003.label"]
    assert stats.frames == 2 and stats.ranks[0]["first_frame"] == 2
    assert stats.ranks[0]["warm_frames"] == (2 if warm else 0)
