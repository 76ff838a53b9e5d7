"""A launched worker's place and lifeline, from the environment alone: its rank and world size as the launcher set
them, whether it reports, and its tie to the launcher that dies with it. Standard library only, so a worker reads
them, and ties itself to its launcher, before the seconds of importing torch (pass3d_ros.training.distributed
builds the process group on top)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

LAUNCHER_ENV = "PASS3D_LAUNCHER_PID"  # set by pass3d_train --nproc in its workers: the launcher's pid
PR_SET_PDEATHSIG = 1  # linux/prctl.h
WATCH_SECONDS = 0.5  # how often the watchdog looks for a new parent
GRACE_SECONDS = 10.0  # after the parent died: time to stop cleanly on SIGTERM before a hard exit
EXIT_ORPHANED = 143  # a worker whose launcher died exits as if terminated

_watched: list[int] = []  # the parent pid the watchdog compares with, once it runs


def world_size() -> int:
    """The WORLD_SIZE a launcher set (torchrun, or pass3d_train --nproc); 1 without one."""
    try:
        return max(1, int(os.environ.get("WORLD_SIZE", "1")))
    except ValueError:
        return 1


def env_rank() -> int:
    """The RANK a launcher set; 0 without one."""
    try:
        return int(os.environ.get("RANK", "0"))
    except ValueError:
        return 0


def reports() -> bool:
    """Whether this process prints errors and interruptions: rank 0, or any rank under pass3d_train's own launcher
    (which keeps the other ranks' output and shows it only when rank 0 has nothing to say)."""
    return env_rank() == 0 or LAUNCHER_ENV in os.environ


def launcher_pid() -> int:
    """The pid this worker's launcher is: the one pass3d_train --nproc names in LAUNCHER_ENV (right even when the
    launcher died before this process got here), else the parent's now (torchrun)."""
    with contextlib.suppress(KeyError, ValueError):
        return int(os.environ[LAUNCHER_ENV])
    return os.getppid()


def die_with_parent() -> None:
    """In a launched worker (WORLD_SIZE > 1): SIGTERM when the launcher dies (Linux parent-death signal), and a
    watchdog thread that sends it when the parent pid is not the launcher's (at once if the launcher is already
    gone) and exits hard if the worker has not stopped `GRACE_SECONDS` later. Call it first thing, before the heavy
    imports; idempotent; a no-op in a plain run."""
    if world_size() <= 1 or _watched:
        return
    parent = launcher_pid()
    _watched.append(parent)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):  # without it, the watchdog still covers it
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    threading.Thread(target=_watch_parent, args=(parent,), name="pass3d-parent-watchdog", daemon=True).start()


@contextlib.contextmanager
def starting(prog: str) -> Iterator[None]:
    """A tool's first step, around the seconds of its heavy imports: tie a launched worker to its launcher first (so
    a launcher killed meanwhile takes it along), and make Ctrl-C meanwhile the one line (`prog: interrupted`, from a
    rank that reports) and status 130 it is later, not a traceback."""
    die_with_parent()
    try:
        yield
    except KeyboardInterrupt:
        if reports():
            print(f"{prog}: interrupted", file=sys.stderr)
        sys.exit(130)  # cli.EXIT_SIGINT, whose module may be what the interrupted import was loading


def _watch_parent(parent: int) -> None:
    """Wait until `parent` is no longer this process's parent; then SIGTERM this process, and exit hard later."""
    while os.getppid() == parent:
        time.sleep(WATCH_SECONDS)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(GRACE_SECONDS)
    os._exit(EXIT_ORPHANED)
