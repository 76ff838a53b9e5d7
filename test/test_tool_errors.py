"""The command-line tools' failure paths: unwritable outputs, signals (also inside numba), stale partial bags,
unreadable weights. Each ends with one line naming the problem, the documented exit status and no traceback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.core.segmentation import CheckpointError, load_model
from pass3d_ros.tools import cli, evaluate, kitti2bag, simulate, train

SPEC = "synthetic:frames=5,seed=1"


def one_error_line(err: str, prog: str, *names: object) -> str:
    """The single stderr line of a failed tool; it names every one of `names` and carries no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: ") and "Traceback" not in err, err
    for name in names:
        assert str(name) in lines[0], err
    return lines[0]


@pytest.fixture
def blocker(tmp_path: Path) -> Path:
    """A regular file: no folder can be created under it."""
    path = tmp_path / "blocker"
    path.write_text("not a folder\n")
    return path


# ------------------------------------------------------------------------------------------- unwritable outputs


def test_evaluate_json_unwritable_fails_before_evaluating(
    blocker: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def no_evaluation(_args):
        raise AssertionError("evaluated although the result could not be saved")

    monkeypatch.setattr(evaluate, "run", no_evaluation)
    target = blocker / "sub" / "eval.json"
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--json", str(target), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", target, blocker)
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--json", str(blocker.parent), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", blocker.parent)


def test_train_out_unwritable(blocker: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = blocker / "run"
    assert train.main(["--data", SPEC, "--out", str(out), "--quiet"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_train", out)
    assert not out.exists()


def test_simulate_out_unwritable(blocker: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for out in (blocker / "seq", blocker):
        assert simulate.main(["--frames", "1", "--out", str(out)]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_simulate", out)


def test_kitti2bag_out_unwritable(blocker: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = blocker / "bag"
    assert kitti2bag.main(["--data", SPEC, "--out", str(out), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", out)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_outputs_in_a_read_only_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        assert simulate.main(["--frames", "1", "--out", str(locked / "seq")]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_simulate", locked / "seq")
        assert evaluate.main(["--stage1-only", "--data", SPEC, "--json", str(locked / "e.json")]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_evaluate", locked / "e.json")
    finally:
        locked.chmod(0o755)


def test_check_writable_accepts_what_can_be_written(tmp_path: Path) -> None:
    cli.check_writable(tmp_path / "a" / "b", folder=True)
    cli.check_writable(tmp_path / "a" / "b.json", folder=False)
    cli.check_writable(tmp_path, folder=True)
    with pytest.raises(cli.OutputError, match="exists and is not a file"):
        cli.check_writable(tmp_path, folder=False)
    assert list(tmp_path.iterdir()) == [], "checking must not create anything"


# ------------------------------------------------------------------------------------------------------ signals


def test_run_tool_maps_a_wrapped_interrupt(capsys: pytest.CaptureFixture[str]) -> None:
    """numba turns a KeyboardInterrupt raised inside a compiled call into a SystemError with it as context."""

    def numba_like(status: int):
        def work() -> int:
            try:
                raise cli.Interrupted(status)
            except KeyboardInterrupt as exc:
                raise SystemError("CPUDispatcher(<function cast_rays>) returned a result with an exception set") \
                    from exc
        return work

    cleaned = []
    assert cli.run_tool("prog", numba_like(130), cleanup=lambda: cleaned.append(1)) == 130
    assert cli.run_tool("prog", numba_like(143), interrupted=lambda: "stopped here") == 143
    err = capsys.readouterr().err
    assert err.splitlines() == ["prog: interrupted", "prog: stopped here"] and cleaned == [1]
    with pytest.raises(SystemError):
        cli.run_tool("prog", lambda: (_ for _ in ()).throw(SystemError("a real bug")))


def _start_kitti2bag(out: Path) -> subprocess.Popen:
    code = "import sys; from pass3d_ros.tools.kitti2bag import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen([sys.executable, "-c", code, "--data", SPEC, "--out", str(out), "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_partial(folder: Path, proc: subprocess.Popen, delay: float = 1.0, timeout: float = 60.0) -> None:
    """Until the conversion has started writing (its hidden build folder exists), plus `delay` seconds."""
    deadline = time.monotonic() + timeout
    while not any(p.name.startswith(".bag.partial-") for p in folder.iterdir()):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "kitti2bag never started writing"
        time.sleep(0.02)
    time.sleep(delay)


@pytest.mark.parametrize(("signum", "status", "delay"),
                         [(signal.SIGINT, 130, 0.4), (signal.SIGINT, 130, 0.9), (signal.SIGTERM, 143, 0.6)])
def test_kitti2bag_signal_exits_cleanly(tmp_path: Path, signum: int, status: int, delay: float) -> None:
    """Sent while numba compiles and runs the ray caster (where a bare handler gave SystemError, exit 1)."""
    out = tmp_path / "bag"
    proc = _start_kitti2bag(out)
    _wait_for_partial(tmp_path, proc, delay)
    proc.send_signal(signum)
    _stdout, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the conversion finished before the signal came")
    assert proc.returncode == status, err
    assert "Traceback" not in err and "SystemError" not in err, err
    assert f"pass3d_kitti2bag: interrupted, {out} not written" in err
    assert list(tmp_path.iterdir()) == [], "an interrupted conversion must leave nothing"


def test_kitti2bag_removes_partials_left_by_sigkill(tmp_path: Path) -> None:
    out = tmp_path / "bag"
    proc = _start_kitti2bag(out)
    _wait_for_partial(tmp_path, proc)
    proc.kill()
    proc.communicate(timeout=60)
    stale = [p.name for p in tmp_path.iterdir()]
    assert len(stale) == 1 and stale[0].startswith(".bag.partial-")
    proc = _start_kitti2bag(out)
    _stdout, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    notes = [line for line in err.splitlines() if stale[0] in line]
    assert len(notes) == 1 and "removed" in notes[0], err
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]


def test_a_live_writers_partial_is_kept(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Another process still writing the same bag keeps its build folder."""
    live = tmp_path / ".bag.partial-live"
    live.mkdir()
    (live / ".owner").write_text(f"{os.getppid()}\n")
    assert kitti2bag.main(["--data", "synthetic:frames=1,seed=1", "--out", str(tmp_path / "bag"),
                           "--no-progress"]) == 0
    assert live.is_dir() and "removed" not in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------------ weights


def test_random_bytes_are_not_a_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(CheckpointError) as info:
        load_model(garbage)
    assert str(info.value) == f"not a pass3d checkpoint: {garbage}"
    assert evaluate.main(["--data", "synthetic:frames=1,seed=0", "--weights", str(garbage), "--no-progress"]) == 2
    line = one_error_line(capsys.readouterr().err, "pass3d_evaluate", garbage)
    assert "weights_only" not in line and "pickle" not in line.lower()
