"""Arguments a tool cannot use, and starts and stops it must survive: nan / inf / out-of-range numbers refused with one
line naming the option (exit 2), a CUDA device on a CPU-only torch refused likewise, a diverging training stopped
before it writes NaN checkpoints, Ctrl-C while pass3d_train imports torch, and data-parallel workers whose launcher is
killed while they still import torch."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from pass3d_ros.core.stage1.config import ConfigError
from pass3d_ros.evaluation.live import LiveOptions
from pass3d_ros.tools.cli import number, torch_device

SPEC = "synthetic:frames=1,seed=7"
TRAIN = [sys.executable, "-m", "pass3d_ros.tools.train"]
LAUNCH_VARIABLES = ("WORLD_SIZE", "RANK", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT",
                    "PASS3D_LAUNCHER_PID")


def plain_env() -> dict[str, str]:
    """This environment without any launcher's variables, one thread per process."""
    env = {k: v for k, v in os.environ.items() if k not in LAUNCH_VARIABLES}
    return {**env, "OMP_NUM_THREADS": "1"}


def refused(capsys: pytest.CaptureFixture[str], main: Callable[[], object], flag: str) -> str:
    """Run a tool's `main` that must stop at its arguments: exit 2, one line (besides argparse's usage lines) naming
    `flag`, no traceback; that line."""
    with pytest.raises(SystemExit) as stopped:
        main()
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert stopped.value.code == 2 and len(lines) == 1 and f"argument {flag}: " in lines[0], err
    assert "Traceback" not in err, err
    return lines[0]


# ----------------------------------------------------------------------------------------------- the types


@pytest.mark.parametrize("text", ["nan", "NaN", "inf", "-inf", "Infinity", "1e999"])
def test_number_refuses_what_is_not_finite(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="not a finite number"):
        number(float, 0.0)(text)


def test_number_checks_kind_and_bounds() -> None:
    assert number(float, 0.0)("0") == 0.0 and number(float, 0.0, 1.0)("1") == 1.0 and number(float)("-3.5") == -3.5
    assert number(int, 1)("3") == 3 and isinstance(number(int, 1)("3"), int)
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be > 0"):
        number(float, 0.0, low_open=True)("0")
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be >= 0 and <= 1"):
        number(float, 0.0, 1.0)("1.5")
    with pytest.raises(argparse.ArgumentTypeError, match="not an integer"):
        number(int, 1)("2.5")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this torch has CUDA")
def test_torch_device_refuses_cuda_without_it() -> None:
    assert torch_device("cpu") == "cpu"
    with pytest.raises(argparse.ArgumentTypeError, match="no such CUDA device here"):
        torch_device("cuda")
    with pytest.raises(argparse.ArgumentTypeError, match="not a torch device"):
        torch_device("gpu0")
    for other in ("mps", "meta"):  # the nodes' check: a device type this torch cannot run on is one line too
        with pytest.raises(argparse.ArgumentTypeError, match="cannot run on it here"):
            torch_device(other)


# ----------------------------------------------------------------------------------------------- the tools


@pytest.mark.parametrize(("flag", "value"), [("--lr", "inf"), ("--lr", "nan"), ("--weight-decay", "inf"),
                                             ("--focal-gamma", "inf"), ("--consistency-weight", "nan")])
def test_train_refuses_numbers_that_are_not_finite(flag: str, value: str, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import train

    out = tmp_path / "run"
    line = refused(capsys, lambda: train.main(["--data", SPEC, "--out", str(out), flag, value]), flag)
    assert "finite" in line and not out.exists()


@pytest.mark.parametrize("tool", ["train", "demo"])
def test_a_negative_seed_is_refused_before_any_work(tool: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """numpy takes no negative seed: refused by the parser (was a traceback once stage 1 had run, and for the demo a
    one-line error only after the classifier loaded and --out was made)."""
    from pass3d_ros.tools import demo, train

    out = tmp_path / "run"
    argv = ["--out", str(out), "--seed", "-1"]
    main = {"train": lambda: train.main(["--data", SPEC, *argv]), "demo": lambda: demo.main(argv)}[tool]
    refused(capsys, main, "--seed")
    assert not out.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this torch has CUDA")
def test_train_refuses_cuda_on_a_cpu_torch(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.bench import benchmark
    from pass3d_ros.tools import train

    out = tmp_path / "run"
    line = refused(capsys, lambda: train.main(["--data", SPEC, "--out", str(out), "--device", "cuda"]), "--device")
    assert "no such CUDA device" in line and not out.exists()
    refused(capsys, lambda: benchmark.main(["stage2", "--device", "cuda"]), "--device")


@pytest.mark.parametrize("argv", [
    ["--record", "/points", "--out", "x", "--duration", "nan"],
    ["--record", "/points", "--out", "x", "--duration", "inf"],
    ["--record", "/points", "--out", "x", "--duration", "0"],
    ["some.bag", "--rate", "nan"],
    ["some.bag", "--rate", "inf"],
    ["some.bag", "--wait-timeout", "nan"],
    ["--record", "/points", "--out", "x", "--discovery-timeout", "inf"],
])
def test_replay_refuses_numbers_that_are_not_finite(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import replay

    flag = next(a for a in argv if a.startswith("--") and a not in ("--record", "--out"))
    refused(capsys, lambda: replay.build_parser().parse_args(argv), flag)


@pytest.mark.parametrize(("flag", "value"), [("--rate", "nan"), ("--rate", "inf"), ("--timeout", "nan"),
                                             ("--timeout", "inf"), ("--timeout", "0")])
def test_evaluate_live_refuses_numbers_that_are_not_finite(flag: str, value: str,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import evaluate

    refused(capsys, lambda: evaluate.main(["--data", SPEC, "--live", flag, value]), flag)


@pytest.mark.parametrize(("flag", "value"), [("--rate", "nan"), ("--rate", "inf"), ("--hz", "inf"),
                                             ("--seconds", "nan"), ("--warmup", "inf")])
def test_benchmark_live_refuses_numbers_that_are_not_finite(flag: str, value: str,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.bench import benchmark

    refused(capsys, lambda: benchmark.main(["live", flag, value]), flag)


@pytest.mark.parametrize(("suite", "flag", "value"), [
    ("codec", "--points", "-1"), ("codec", "--repeat", "0"), ("layout", "--width", "0"), ("layout", "--repeat", "0"),
    ("stage2", "--repeats", "0"), ("stage2", "--proposals", "0"), ("stage2", "--max-points", "0"),
    ("stage2", "--seed", "-1"), ("fuzz", "--seed", "-1"), ("tracks", "--seed", "-1"), ("simulate", "--seed", "-1"),
    ("stage2", "--threads", "0"), ("stage2", "--threads", "-2"), ("live", "--seed", "-1"),
])
def test_benchmark_suites_refuse_counts_they_cannot_run(suite: str, flag: str, value: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Zero repetitions, an empty cloud, no thread or a negative seed: one line naming the option (was a traceback: a
    median of nothing, an empty grid, numpy refusing the seed, limit_threads refusing 0; live's seed was refused only
    once the classifier was loaded, naming the synthetic spec it builds rather than --seed)."""
    from pass3d_ros.bench import benchmark

    refused(capsys, lambda: benchmark.main([suite, flag, value]), flag)


def test_live_options_name_the_option_not_the_field() -> None:
    """The in-process API refuses the same values, naming the command-line option, never the field `timeout_s`."""
    cases = ((LiveOptions(rate=float("nan")), "--rate"), (LiveOptions(timeout_s=float("inf")), "--timeout"),
             (LiveOptions(timeout_s=0.0), "--timeout"))
    for options, flag in cases:
        with pytest.raises(ConfigError) as error:
            options.check()
        assert flag in str(error.value) and "timeout_s" not in str(error.value)


# --------------------------------------------------------------------------------------------- training


def test_diverging_training_stops_before_writing_nan_checkpoints(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A learning rate far too high: exit 2 with one line naming the epoch and step and suggesting a smaller --lr,
    and no checkpoint; likewise when the loss is still finite but a step left the weights NaN."""
    from pass3d_ros.tools import train

    out = tmp_path / "run"
    common = ["--data", SPEC, "--out", str(out), "--epochs", "1", "--batch-size", "4", "--quiet", "--threads", "1"]
    threads = torch.get_num_threads()
    try:
        assert train.main([*common, "--max-steps", "3", "--lr", "1e30"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert err.startswith("pass3d_train: error: training diverged") and "epoch 1, step" in err, err
        assert "smaller --lr" in err and not (out / "last.pt").exists() and not (out / "best.pt").exists()

        step = torch.optim.Adam.step

        def poisoning_step(self: torch.optim.Adam, *args: object, **kwargs: object) -> object:
            result = step(self, *args, **kwargs)
            with torch.no_grad():
                self.param_groups[0]["params"][0].fill_(float("nan"))
            return result

        monkeypatch.setattr(torch.optim.Adam, "step", poisoning_step)
        assert train.main([*common, "--max-steps", "1"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "weights are no longer finite after epoch 1" in err, err
        assert not (out / "last.pt").exists() and not (out / "best.pt").exists()
    finally:
        torch.set_num_threads(threads)


# ----------------------------------------------------------------------------------- starting up, subprocesses


def importing_torch(pid: int) -> bool:
    """Whether process `pid` has loaded torch's library, that is, is in (or past) `import torch`."""
    try:
        return "libtorch" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def wait_for(condition: Callable[[], bool], seconds: float, what: str) -> None:
    """Poll `condition` until it holds; fail the test naming `what` after `seconds`."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.02)


def _sigint_as_a_shell_leaves_it() -> None:
    """In the child before exec: SIGINT unblocked and at its default, as a terminal's Ctrl-C finds a command, whatever
    the test process inherited or set (a worker thread's mask is inherited through fork and exec)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def sigint_state(pid: int) -> str:
    """Whether process `pid` blocks or ignores SIGINT, from /proc (for a failure's message)."""
    try:
        fields = dict(line.split(":\t", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                      if ":\t" in line)
    except OSError:
        return "process gone"
    bit = 1 << (signal.SIGINT - 1)
    return ", ".join(f"{name} {'yes' if int(fields.get(key, '0'), 16) & bit else 'no'}"
                     for name, key in (("blocked", "SigBlk"), ("ignored", "SigIgn"), ("caught", "SigCgt")))


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc")
def test_ctrl_c_while_train_imports_torch_is_one_line(tmp_path: Path) -> None:
    """SIGINT while pass3d_train still imports torch: status 130 and one line, no traceback, no output folder."""
    out = tmp_path / "run"
    for _attempt in range(5):  # a starved test process can see the short run end before it sees torch load
        proc = subprocess.Popen([*TRAIN, "--data", SPEC, "--out", str(out), "--quiet"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=plain_env(),
                                preexec_fn=_sigint_as_a_shell_leaves_it)
        try:
            wait_for(lambda p=proc: importing_torch(p.pid) or p.poll() is not None, 60, "torch never loaded")
            interrupted = proc.poll() is None
            state = sigint_state(proc.pid)
            if interrupted:
                proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
        if interrupted:
            break
        shutil.rmtree(out, ignore_errors=True)
    assert interrupted, "the run always ended before the test saw torch load"
    assert proc.returncode == 130, f"status {proc.returncode}, SIGINT in the child when sent: {state}; {err}"
    assert err.count("\n") == 1 and err.startswith("pass3d_train: interrupted") and "Traceback" not in err, err
    assert not out.exists()


def children(pid: int) -> list[int]:
    """The pids of the live processes whose parent is `pid`."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie, exited but not reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs /proc and the parent-death signal")
@pytest.mark.parametrize("how", ["torchrun", "nproc"])
def test_workers_killed_launcher_in_its_first_seconds_takes_them_along(how: str, tmp_path: Path) -> None:
    """SIGKILL on torchrun / pass3d_train --nproc 2 while both workers still import torch (a second or two after the
    start): both are gone at once (before, torchrun's stayed with parent PID 1 and their watchdog watched PID 1;
    --nproc's lived on until their imports ended)."""
    argv = ["--data", SPEC, "--epochs", "100000", "--batch-size", "4", "--quiet", "--out", str(tmp_path / "run")]
    command = ([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--standalone", *TRAIN[1:]]
               if how == "torchrun" else [*TRAIN, "--nproc", "2"])
    launcher = subprocess.Popen([*command, *argv], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                env=plain_env(), start_new_session=True)
    workers: list[int] = []
    try:
        wait_for(lambda: len(children(launcher.pid)) == 2 or launcher.poll() is not None, 60, "no workers started")
        workers = children(launcher.pid)
        assert len(workers) == 2
        wait_for(lambda: all(importing_torch(pid) or not alive(pid) for pid in workers), 60, "torch never loaded")
        launcher.kill()
        launcher.wait()
        wait_for(lambda: not any(alive(pid) for pid in workers), 2.0, "workers outlived their launcher")
    finally:
        launcher.kill()
        launcher.wait()
        for pid in filter(alive, workers):
            os.kill(pid, signal.SIGKILL)
