"""`pass3d_train --nproc N`: start N data-parallel workers on this machine, stop them together, exit cleanly.

Each worker runs `python -m MODULE ARGS` with RANK, LOCAL_RANK, WORLD_SIZE, LOCAL_WORLD_SIZE, MASTER_ADDR and
MASTER_PORT set as torchrun sets them, in a session of its own (so a terminal's Ctrl-C reaches the launcher alone,
which forwards it once), and with pass3d_ros.training.worker.LAUNCHER_ENV naming the launcher, so a worker dies with
it. Rank 0 writes to the launcher's stdout and stderr; the other ranks' stderr goes to a temporary file, shown only
when one of them fails first. Exit status: 0 when every worker succeeded; after SIGINT / SIGTERM (forwarded to the
workers as SIGTERM) 130 / 143; else the status of the first worker that failed, once the others stopped (killed when
they have not stopped by themselves `PEER_GRACE_SECONDS` later); a worker that stopped only because another one did
exits `EXIT_PEER_LOST` and says nothing.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from types import FrameType
from typing import IO

from pass3d_ros.training.worker import LAUNCHER_ENV

EXIT_SIGINT, EXIT_SIGTERM = 130, 143
POLL_SECONDS = 0.05
PEER_GRACE_SECONDS = 5.0  # after one worker failed: time for the others to stop on their own before SIGKILL
STOP_SECONDS = 30.0  # after SIGINT / SIGTERM: time for the workers to stop before SIGKILL
EXIT_PEER_LOST = 3  # a worker's status when it stopped only because another one did (it prints nothing)


def free_port() -> int:
    """A TCP port on the loopback interface that is free now (for the workers' rendezvous)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def worker_env(rank: int, world: int, port: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of worker `rank` of `world`: torchrun's variables, one CPU thread per worker unless
    OMP_NUM_THREADS is set, and this launcher's pid."""
    env = dict(os.environ if base is None else base)
    env.setdefault("OMP_NUM_THREADS", "1")
    env.update(RANK=str(rank), LOCAL_RANK=str(rank), WORLD_SIZE=str(world), LOCAL_WORLD_SIZE=str(world),
               GROUP_RANK="0", MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    env[LAUNCHER_ENV] = str(os.getpid())
    return env


@dataclass
class _Worker:
    """One started worker: its rank, process and captured stderr (ranks > 0)."""

    rank: int
    process: subprocess.Popen
    stderr: IO[bytes] | None


@dataclass
class _State:
    """What the launcher has seen: the signal status (130 / 143), the failed workers in the order they failed (a
    worker that only lost a peer, and one the launcher killed, do not count) and the deadlines."""

    signalled: int | None = None
    failures: list[_Worker] = field(default_factory=list)
    killed: bool = False
    stop_deadline: float | None = None
    workers: list[_Worker] = field(default_factory=list)

    def note_failures(self) -> None:
        """Add the workers that failed by themselves since the last look."""
        for worker in self.workers:
            code = worker.process.poll()
            if code not in (None, 0, EXIT_PEER_LOST) and not self.killed and worker not in self.failures:
                self.failures.append(worker)


def launch(module: str, args: list[str], nproc: int, prog: str) -> int:
    """Run `python -m module args` in `nproc` workers as described above; the exit status."""
    state = _State()
    port = free_port()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        if state.signalled is None:
            state.signalled = EXIT_SIGTERM if signum == signal.SIGTERM else EXIT_SIGINT
            state.stop_deadline = time.monotonic() + STOP_SECONDS
            _send(state.workers, signal.SIGTERM)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    with contextlib.ExitStack() as files:
        try:
            for rank in range(nproc):
                stderr = None if rank == 0 else files.enter_context(tempfile.TemporaryFile())
                process = subprocess.Popen([sys.executable, "-m", module, *args], env=worker_env(rank, nproc, port),
                                           stderr=stderr, start_new_session=True)
                state.workers.append(_Worker(rank, process, stderr))
                if state.signalled is not None:
                    _send(state.workers, signal.SIGTERM)
            _wait(state)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            _send(state.workers, signal.SIGKILL)
        return _report(state, prog)


def _send(workers: list[_Worker], signum: int) -> None:
    """Send `signum` to every worker still running."""
    for worker in workers:
        if worker.process.poll() is None:
            try:
                worker.process.send_signal(signum)
            except ProcessLookupError:
                continue


def _wait(state: _State) -> None:
    """Until every worker exited: note the failures; after the first, give the others a grace period to stop by
    themselves, then kill them (likewise after a signal)."""
    peer_deadline: float | None = None
    while any(w.process.poll() is None for w in state.workers):
        time.sleep(POLL_SECONDS)
        now = time.monotonic()
        state.note_failures()
        if state.failures and peer_deadline is None:
            peer_deadline = now + PEER_GRACE_SECONDS
        deadline = state.stop_deadline if state.signalled is not None else peer_deadline
        if deadline is not None and now > deadline:
            state.note_failures()
            state.killed = True
            _send(state.workers, signal.SIGKILL)
    state.note_failures()


def _report(state: _State, prog: str) -> int:
    """The launcher's exit status; prints what no worker printed: when rank 0 failed by itself it reported, else
    the first failed rank's own output, or one line when rank 0 died of the signal before it could say so."""
    rank0 = state.workers[0].process if state.workers else None
    if state.signalled is not None:
        if rank0 is None or rank0.returncode is None or rank0.returncode < 0:
            print(f"{prog}: interrupted", file=sys.stderr)
        return state.signalled
    if not state.failures:
        if all(w.process.returncode == 0 for w in state.workers):
            return 0
        print(f"{prog}: a worker stopped without saying why", file=sys.stderr)
        return 1
    reported = [w for w in state.failures if w.rank == 0 and w.process.returncode > 0]
    failure = reported[0] if reported else state.failures[0]
    if failure.stderr is not None:
        failure.stderr.seek(0)
        sys.stderr.write(failure.stderr.read().decode(errors="replace"))
        sys.stderr.flush()
    code = failure.process.returncode
    if code < 0:
        print(f"{prog}: worker {failure.rank} died of signal {-code}", file=sys.stderr)
    return code if code > 0 else 128 - code
