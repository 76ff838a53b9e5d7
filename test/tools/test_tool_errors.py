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

from pass3d_ros.core.stage2.segmentation import CheckpointError, load_model
from pass3d_ros.tools import cli, evaluate, kitti2bag, params_yaml, simulate, train

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


@pytest.mark.slow
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


# ------------------------------------------------------------------------------------------- bugs are not user errors


def test_a_bug_keeps_its_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A plain ValueError or TypeError from inside the work is a bug: it is raised (exit 1 with a traceback from the
    interpreter), not printed as one line with exit 2 the way the project's own errors are."""
    from pass3d_ros.core import stage1
    from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
    from pass3d_ros.tools import segment

    def numpy_slip(*_args, **_kwargs):
        raise ValueError("operands could not be broadcast together with shapes (3,) (4,)")

    with monkeypatch.context() as patch:
        patch.setattr(stage1, "propose", numpy_slip)
        with pytest.raises(ValueError, match="broadcast"):
            evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--no-progress"])
    monkeypatch.setattr(SizeRuleClassifier, "segment", lambda *_: None + 1)
    with pytest.raises(TypeError):
        segment.main(["--data", "synthetic:frames=1,seed=0", "--out", str(tmp_path / "out"), "--classifier",
                      "size_rules", "--no-progress", "--no-png"], log=lambda _: None)
    for bug in (ValueError("bad shape"), TypeError("None + 1"), OSError(5, "Input/output error"), KeyError("k")):
        with pytest.raises(type(bug)):
            cli.run_tool("prog", lambda bug=bug: (_ for _ in ()).throw(bug))
    assert "error:" not in capsys.readouterr().err

    # what the user can fix still ends in one line and exit 2: the project's errors and a path the user named
    assert evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--param", "th_ring"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", "--param 'th_ring'", "KEY=VALUE")
    assert evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=0", "--param", "th_ring=9"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", "th_ring=9 outside")
    assert cli.run_tool("prog", lambda: len((tmp_path / "nowhere.txt").read_text())) == 2
    one_error_line(capsys.readouterr().err, "prog", tmp_path / "nowhere.txt")


# -------------------------------------------------------------------------------- issue 26: attacks that must fail well


def dead_pid() -> int:
    """The id of a process that has ended (a finished child's)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


@pytest.mark.parametrize("device", ["cuda:99", "bogus"])
def test_bad_device_is_one_line(device: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import segment

    assert evaluate.main(["--data", SPEC, "--device", device, "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", repr(device))
    assert segment.main(["--data", SPEC, "--out", str(tmp_path / "out"), "--device", device, "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_segment", repr(device))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("item", ["th_dist='abc'", "th_dist=[1]", "th_dist=None", "enlarge=0.1", "n_seg=3.5",
                                  "max_top=0.5", "th_dist=abc"])
def test_bad_param_is_one_line(item: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--param", item, "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", item.partition("=")[0])


def test_check_writable_tries_instead_of_trusting_access(tmp_path: Path) -> None:
    """/proc takes no new files, even from root (for whom os.access says yes to everything)."""
    with pytest.raises(cli.OutputError, match="cannot create --json file in /proc"):
        cli.check_writable("/proc/nowrite/x", folder=False, what="--json file")
    existing = tmp_path / "old.json"
    existing.write_text("kept")
    cli.check_writable(existing, folder=False)
    assert existing.read_text() == "kept" and sorted(tmp_path.iterdir()) == [existing]


def test_evaluate_json_under_proc_fails_before_evaluating(monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(evaluate, "run", lambda _args: pytest.fail("evaluated although the result cannot be saved"))
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--json", "/proc/nowrite/x", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", "/proc/nowrite/x")


def test_evaluate_record_out_under_proc_fails_before_evaluating(monkeypatch: pytest.MonkeyPatch,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(evaluate, "run", lambda _args: pytest.fail("ran live although the recording cannot be saved"))
    assert evaluate.main(["--live", "--data", SPEC, "--record-out", "/proc/nowrite/x", "--no-progress"]) == 2
    line = one_error_line(capsys.readouterr().err, "pass3d_evaluate", "/proc/nowrite/x", "--record-out")
    assert ".partial" not in line


def test_params_yaml_out_under_proc_names_it(capsys: pytest.CaptureFixture[str]) -> None:
    """The error names --out as given, not the hidden file it would have been written through."""
    assert params_yaml.main(["--out", "/proc/nowrite/x.yaml"]) == 2
    assert ".partial" not in one_error_line(capsys.readouterr().err, "pass3d_params_yaml", "/proc/nowrite/x.yaml")


@pytest.mark.parametrize(("argv", "work"), [
    (["stage1", "--repeat", "1", "--limit", "1", "--no-patchwork"], "pass3d_ros.bench.stage1.load_frames"),
    (["sensors", "--frames", "1", "--stage1-only"], "pass3d_ros.bench.sensors._names"),
    (["live", "--frames", "1"], "pass3d_ros.core.stage2.open_classifier"),
])
def test_benchmark_json_under_proc_fails_before_timing(argv: list[str], work: str, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.bench import benchmark

    monkeypatch.setattr(work, lambda *_a, **_k: pytest.fail("timed although the numbers cannot be saved"))
    assert benchmark.main([*argv, "--json", "/proc/nowrite/x.json"]) == 2
    line = one_error_line(capsys.readouterr().err, "pass3d_benchmark", "/proc/nowrite/x.json", "--json")
    assert ".partial" not in line


@pytest.mark.parametrize("out", ["existing", "/proc/nowrite/bag"])
def test_replay_record_checks_out_before_waiting_for_topics(out: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """An --out that exists (no --force) or cannot be created fails before the topics are waited for, naming it."""
    from pass3d_ros.tools import replay

    if out == "existing":
        out = str(tmp_path / "bag")
        Path(out).mkdir()
    monkeypatch.setattr(replay, "discover_types", lambda *_a: pytest.fail("waited for topics with an unusable --out"))
    assert replay.main(["--record", "/x", "--out", out, "--duration", "1"]) == 2
    err = "\n".join(line for line in capsys.readouterr().err.splitlines() if "Fast DDS" not in line)
    assert ".partial" not in one_error_line(err, "pass3d_replay", out)


def test_bag_with_broken_metadata_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """rosbags' YAML error spans several lines (a caret under the column): the tool still prints one."""
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: [\n")
    assert evaluate.main(["--stage1-only", "--data", f"bag:{bag}", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", bag, "metadata.yaml", "cannot open as a rosbag2 bag")


# ------------------------------------------------------------------------------------------------------ pass3d_view


def test_view_spawn_without_the_viewer_binary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import view

    pytest.importorskip("rerun")
    monkeypatch.setenv("PATH", str(tmp_path))
    assert view.main(["--data", "synthetic:frames=1,seed=1", "--spawn"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_view", "rerun viewer", "--out")


def test_view_keeps_an_existing_recording_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import view

    pytest.importorskip("rerun")
    out = tmp_path / "x.rrd"
    out.write_text("not a recording")
    assert view.main(["--data", "synthetic:frames=1,seed=1", "--out", str(out), "--force"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_view", out, "not a rerun recording")
    out.write_bytes(view.RRD_MAGIC + b"2 an earlier recording")
    assert view.main(["--data", "synthetic:frames=1,seed=1", "--out", str(out)]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_view", out, "--force")
    assert out.read_bytes() == view.RRD_MAGIC + b"2 an earlier recording"
    assert view.main(["--data", "synthetic:frames=1,seed=1", "--out", str(out), "--force"]) == 0
    assert out.stat().st_size > 1_000 and sorted(p.name for p in tmp_path.iterdir()) == ["x.rrd"]


def test_view_removes_partials_of_killed_runs_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import view

    pytest.importorskip("rerun")
    killed = tmp_path / f".x.rrd.partial-{dead_pid()}"
    killed.write_bytes(b"half a recording")
    running = tmp_path / f".x.rrd.partial-{os.getppid()}"
    running.write_bytes(b"another run, still writing")
    assert view.main(["--data", "synthetic:frames=1,seed=1", "--out", str(tmp_path / "x.rrd")]) == 0
    assert not killed.exists() and running.exists()
    assert killed.name in capsys.readouterr().err


# --------------------------------------------------------------------------------------------------- pass3d_segment


def test_segment_failure_leaves_no_half_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A run that fails or is interrupted after some frames leaves --out as it was; the rerun needs no --force."""
    from pass3d_ros.evaluation import segmenting
    from pass3d_ros.tools import segment

    out = tmp_path / "out"
    write_png = segmenting.write_png
    for error, status, says in ((PermissionError(13, "Permission denied", "bev/000002.png"), 2,
                                 "bev/000002.png: permission denied"),
                                (cli.Interrupted(130), 130, f"interrupted; {out} left as it was")):
        calls: list[Path] = []

        def failing(path: Path, image: np.ndarray, error: BaseException = error, calls: list[Path] = calls) -> None:
            calls.append(path)
            if len(calls) == 3:
                raise error
            write_png(path, image)

        monkeypatch.setattr(segmenting, "write_png", failing)
        assert segment.main(["--data", SPEC, "--out", str(out), "--classifier", "size_rules", "--no-progress"],
                            log=lambda _: None) == status
        one_error_line(capsys.readouterr().err, "pass3d_segment", says)
        assert list(tmp_path.iterdir()) == [], "nothing half-written, no hidden build folder"
    monkeypatch.setattr(segmenting, "write_png", write_png)
    assert segment.main(["--data", SPEC, "--out", str(out), "--classifier", "size_rules", "--no-progress"],
                        log=lambda _: None) == 0
    assert len(list((out / "labels").iterdir())) == 5 and (out / "summary.json").is_file()


def test_segment_force_failure_keeps_the_old_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.evaluation import segmenting
    from pass3d_ros.tools import segment

    out = tmp_path / "out"
    args = ["--data", "synthetic:frames=2,seed=1", "--out", str(out), "--classifier", "size_rules", "--no-progress"]
    assert segment.main(args, log=lambda _: None) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    monkeypatch.setattr(segmenting, "write_png", lambda *_: (_ for _ in ()).throw(PermissionError(13, "denied")))
    assert segment.main([*args, "--force"], log=lambda _: None) == 2
    capsys.readouterr()
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_segment_removes_the_build_folder_of_a_killed_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import segment

    stale = tmp_path / f".out.partial-{dead_pid()}"
    (stale / "labels").mkdir(parents=True)
    (stale / "labels" / "000000.label").write_bytes(b"\0" * 8)
    assert segment.main(["--data", "synthetic:frames=1,seed=1", "--out", str(tmp_path / "out"), "--classifier",
                         "size_rules", "--no-progress", "--no-png"], log=lambda _: None) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["out"] and stale.name in capsys.readouterr().err


def test_segment_param_reaches_stage1(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.core import stage1
    from pass3d_ros.tools import segment

    seen = []
    propose = stage1.propose
    monkeypatch.setattr(stage1, "propose", lambda pts, ring, config, **held: seen.append(config)
                        or propose(pts, ring, config, **held))
    base = ["--data", "synthetic:frames=1,seed=1", "--classifier", "size_rules", "--no-progress", "--no-png"]
    assert segment.main([*base, "--out", str(tmp_path / "a"), "--param", "th_dist=0.25", "--param", "n_seg=4"],
                        log=lambda _: None) == 0
    assert [(c.th_dist, c.n_seg) for c in seen] == [(0.25, 4)]
    for item in ("n_seg=3.5", "max_top=0.5", "th_dsit=0.2"):
        assert segment.main([*base, "--out", str(tmp_path / "b"), "--param", item]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_segment", item.partition("=")[0])
    assert not (tmp_path / "b").exists()


def test_a_recording_given_twice_is_scored_once_or_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`pass3d_evaluate` given one recording twice (the same spec, or its folder through a symlink) would score its
    frames twice (and with --tracking run them as one stream with stamps going back): one line, exit 2."""
    assert evaluate.main(["--stage1-only", "--data", SPEC, "--data", SPEC, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "the same recording" in err and "Traceback" not in err
    folder = tmp_path / "seq"
    assert simulate.main(["--frames", "1", "--out", str(folder)]) == 0
    (tmp_path / "link").symlink_to(folder)
    capsys.readouterr()
    assert evaluate.main(["--stage1-only", "--data", f"semantickitti:{folder}", "--data",
                          f"semantickitti:{tmp_path / 'link'}", "--no-progress"]) == 2
    assert "the same recording" in capsys.readouterr().err
