"""pass3d_train's own data-parallel launcher on stand-in workers (a tiny module, no torch): which worker's report is
shown, and the exit status, when one rank fails alone, when all fail alike, and when a worker dies of a signal."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from pass3d_ros.training import launcher

WORKER = '''
import os, sys, time
rank = int(os.environ["RANK"])
assert os.environ["WORLD_SIZE"] == "2" and os.environ["MASTER_PORT"] and os.environ["{env}"] == str(os.getppid())
plan = dict(item.split("=") for item in sys.argv[1:])
action = plan.get(str(rank), "ok")
if action == "error":
    print(f"pass3d_train: error: bad frame in rank {{rank}}", file=sys.stderr)
    sys.exit(2)
if action == "hang":
    time.sleep(60)
if action == "peer":
    sys.exit({peer})
if action == "kill":
    os.kill(os.getpid(), 9)
'''


@pytest.fixture
def worker_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """The name of a stand-in worker module: argv `RANK=ACTION` (ok, error, hang, peer, kill) says what each does."""
    (tmp_path / "stand_in_worker.py").write_text(
        WORKER.format(env=launcher.LAUNCHER_ENV, peer=launcher.EXIT_PEER_LOST))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), *sys.path]))
    monkeypatch.setattr(launcher, "PEER_GRACE_SECONDS", 1.0)
    return "stand_in_worker"


def test_all_workers_succeed(worker_module: str, capfd: pytest.CaptureFixture[str]) -> None:
    assert launcher.launch(worker_module, [], 2, "pass3d_train") == 0
    assert capfd.readouterr().err == ""


def test_a_rank_failing_alone_is_shown_once(worker_module: str, capfd: pytest.CaptureFixture[str]) -> None:
    """Rank 1 fails alone while rank 0 hangs: rank 0 is stopped after the grace period, rank 1's line is shown
    once, and its status is the launcher's."""
    assert launcher.launch(worker_module, ["0=hang", "1=error"], 2, "pass3d_train") == 2
    assert capfd.readouterr().err == "pass3d_train: error: bad frame in rank 1\n"


def test_a_peer_loss_is_not_a_report(worker_module: str, capfd: pytest.CaptureFixture[str]) -> None:
    """Rank 0 only lost its peer (silent, EXIT_PEER_LOST): rank 1's line and status are the report."""
    assert launcher.launch(worker_module, ["0=peer", "1=error"], 2, "pass3d_train") == 2
    assert capfd.readouterr().err == "pass3d_train: error: bad frame in rank 1\n"


def test_the_same_error_everywhere_is_rank_0s_line(worker_module: str, capfd: pytest.CaptureFixture[str]) -> None:
    assert launcher.launch(worker_module, ["0=error", "1=error"], 2, "pass3d_train") == 2
    assert capfd.readouterr().err == "pass3d_train: error: bad frame in rank 0\n"


def test_a_worker_killed_by_a_signal(worker_module: str, capfd: pytest.CaptureFixture[str]) -> None:
    """A worker that dies of SIGKILL (the OOM killer, say): 137 and one line saying so."""
    assert launcher.launch(worker_module, ["1=kill"], 2, "pass3d_train") == 137
    assert capfd.readouterr().err == "pass3d_train: worker 1 died of signal 9\n"
