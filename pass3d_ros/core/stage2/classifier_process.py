"""A stage-2 classifier in a child process, behind the same `segment` call as one in this process.

Torch releases the GIL inside its kernels but not between them, and the PointNet++ forward pass is hundreds of small
ops: stage 2 on a thread beside stage 1 still takes turns with it for the GIL. In a child process it does not; the
parent only waits on a pipe (which releases the GIL) while the frame's arrays travel there and back (about 2 MB for
a 120k-point scan). The child is started with `spawn`, so nothing of the parent (ROS contexts, DDS threads) is copied
into it; like every `spawn` user, a script that starts one needs the `if __name__ == "__main__":` guard (the package's
commands have it).

A child that dies (the OOM killer's SIGKILL, a crash in a native library) is noticed at once by a supervisor
thread, reported once, and started again after a back-off (1, 2, 4 ... s, at most 30 s; reset by a frame served);
meanwhile `segment` raises `ClassifierProcessDownError` at once, so the caller drops the frame instead of waiting. A
child that answers nothing for `timeout_s` (hung, or stopped by SIGSTOP) is killed by the supervisor, which SIGKILL
does even to a stopped process: that frame raises `ClassifierProcessHungError` and the child is restarted like a dead
one. The child ignores SIGINT: Ctrl-C in a terminal reaches the whole process group, and the parent shuts the child
down.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any, NamedTuple

import numpy as np

from pass3d_ros.core.stage2 import DEFAULT_CLASSIFIER, ClassifierError, open_classifier
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS, SegmentResult
from pass3d_ros.core.threads import limit_threads

START_TIMEOUT_S = 120.0  # loading torch and the weights, and the warm-up, in a fresh interpreter
STOP_TIMEOUT_S = 5.0
POLL_S = 0.2  # how often a start that waits for the child looks whether it should give up
WATCH_S = 0.1  # how often the supervisor looks whether the frame in the child has outlived `timeout_s`
RESTART_FIRST_S = 1.0  # back-off before the first restart after a death; doubled per further failure
RESTART_MAX_S = 30.0

Report = Callable[[str, str], None]  # (level "info" or "error", message): what the supervisor has to say


class ClassifierProcessError(ClassifierError):
    """The child process could not start, failed a frame, or is gone; the message says which and why."""


class ClassifierProcessDownError(ClassifierProcessError):
    """No child serves now (it died and is being restarted, or the classifier is closed): the frame is not segmented."""


class ClassifierProcessHungError(ClassifierProcessDownError):
    """The child answered nothing for `timeout_s` during this frame: it was killed (and is being restarted)."""


def restart_delay(failures: int) -> float:
    """Seconds to wait before a restart that follows `failures` earlier deaths or failed starts with no frame served
    in between: 1, 2, 4 ... capped at RESTART_MAX_S."""
    return min(RESTART_FIRST_S * 2.0 ** min(failures, 16), RESTART_MAX_S)


def describe_exit(exitcode: int | None) -> str:
    """How a process ended, from its multiprocessing exit code (negative: the signal that killed it)."""
    if exitcode is None:
        return "exit status unknown"
    if exitcode >= 0:
        return f"exit code {exitcode}"
    try:
        name = signal.Signals(-exitcode).name
    except ValueError:
        name = f"signal {-exitcode}"
    return f"killed by {name}" + (", as the out-of-memory killer does" if -exitcode == signal.SIGKILL else "")


@contextlib.contextmanager
def _sigint_blocked() -> Iterator[None]:
    """SIGINT blocked in this thread, so that a child started here inherits it blocked (until `_serve` ignores it)
    and a Ctrl-C while it imports torch prints no traceback."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _serve(conn: Connection, weights: str | None, classifier: str | None, device: str, max_proposals: int,
           threads: int) -> None:
    """The child: open and warm up the classifier, say "ready" (or why not), then segment each frame it is sent
    until told to stop or the parent goes. SIGINT is ignored: the parent decides when the child ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        if threads > 0:
            limit_threads(threads)
        model = open_classifier(weights, classifier, device=device, max_proposals=max_proposals)
        model.warm_up()
    except Exception as exc:  # every failure goes back to the parent as text, which raises it there
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", (os.getpid(), model.kind, model.weights)))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        if request[0] == "stop":
            return
        _, points, members, limit = request
        model.max_proposals = limit
        try:
            reply: tuple[str, Any] = ("ok", tuple(model.segment(points, members)))
        except Exception:  # a frame's failure is the parent's to log; the child keeps serving
            reply = ("error", traceback.format_exc(limit=4))
        conn.send(reply)


class _Child(NamedTuple):
    """A started child that said it is ready."""

    process: BaseProcess
    conn: Connection
    pid: int
    kind: str
    weights: str | None


def _start(args: tuple, give_up: threading.Event) -> _Child:
    """Start a child with `_serve`'s arguments and wait until it is ready; ClassifierProcessError when it cannot
    load, ends, takes longer than START_TIMEOUT_S, or `give_up` is set meanwhile."""
    context = mp.get_context("spawn")
    conn, child_conn = context.Pipe()
    process = context.Process(target=_serve, args=(child_conn, *args), name="pass3d-stage2", daemon=True)
    with _sigint_blocked():
        process.start()
    child_conn.close()
    deadline = time.monotonic() + START_TIMEOUT_S
    try:
        while not conn.poll(POLL_S):  # the child's end of the pipe closing (it died) also ends the wait
            if give_up.is_set():
                raise ClassifierProcessError("stage-2 process start abandoned: the classifier is closing")
            if time.monotonic() > deadline:
                raise ClassifierProcessError(f"stage-2 process did not start within {START_TIMEOUT_S:.0f} s")
        try:
            status, detail = conn.recv()
        except (EOFError, OSError):
            process.join(STOP_TIMEOUT_S)
            raise ClassifierProcessError(f"stage-2 process ended while starting ({describe_exit(process.exitcode)})"
                                         ) from None
        if status != "ready":
            raise ClassifierProcessError(f"stage-2 process could not load the classifier: {detail}")
    except BaseException:  # a child that is not serving cannot hear "stop"
        process.terminate()
        process.join(STOP_TIMEOUT_S)
        conn.close()
        raise
    return _Child(process, conn, *detail)


def _stop(process: BaseProcess, conn: Connection) -> None:
    """Stop a child (politely, then by SIGTERM, then by SIGKILL, which also ends a stopped one) and close its pipe."""
    if process.is_alive():
        with contextlib.suppress(OSError, ValueError):  # a pipe already broken: the child is going anyway
            conn.send(("stop",))
        process.join(STOP_TIMEOUT_S)
        if process.is_alive():
            process.terminate()
            process.join(STOP_TIMEOUT_S)
        if process.is_alive():  # stopped (SIGSTOP): SIGTERM waits for a SIGCONT, and exit would wait for the child
            process.kill()
            process.join(STOP_TIMEOUT_S)
    conn.close()


class ProcessClassifier:
    """A classifier (`pass3d_ros.core.stage2.open_classifier` arguments) opened and running in a child process.

    One frame at a time (the caller's thread waits for its result); `close` ends the child, as does the parent's
    exit. `pid` is the serving child's process id; `kind` and `weights` are what it opened. A child that dies, or
    answers a frame nothing for `timeout_s` seconds (None: waits forever), is restarted (see the module's
    description); `report(level, message)` hears of each death, kill and restart, `restarts` counts the restarts,
    `hangs` the children killed for hanging, `down_for()` says how long no child has served.
    """

    def __init__(self, weights: str | None, classifier: str | None = DEFAULT_CLASSIFIER, device: str = "cpu",
                 max_proposals: int = DEFAULT_MAX_PROPOSALS, threads: int = 1, report: Report | None = None,
                 timeout_s: float | None = None) -> None:
        self.max_proposals = max_proposals
        self.timeout_s = timeout_s
        self.restarts = 0
        self.hangs = 0
        self._asked: float | None = None  # when the frame in hand was handed to the child (None: no frame)
        self._killed_pid: int | None = None  # the child the supervisor killed for hanging
        self._args = (weights, classifier, device, max_proposals, threads)
        self._report: Report = report or (lambda level, message: None)
        self._closing = threading.Event()
        self._lock = threading.Lock()  # held for a frame; the supervisor swaps children under it
        self._failures = 0  # deaths and failed starts since a frame was last served
        self._down_since: float | None = None
        self._child: _Child | None = _start(self._args, self._closing)
        self.pid, self.kind, self.weights = self._child.pid, self._child.kind, self._child.weights
        self._supervisor = threading.Thread(target=self._supervise, name="pass3d-stage2-supervisor", daemon=True)
        self._supervisor.start()

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        """The child's `segment` of these points and proposals; ClassifierProcessDownError at once while no child
        serves, or when the child dies during this frame."""
        with self._lock:
            child = self._child
            if child is None:
                raise ClassifierProcessDownError(self._down_reason())
            self._asked = time.monotonic()  # the supervisor's watch covers the send too: a stopped child's full pipe
            try:
                child.conn.send(("segment", points, members, int(self.max_proposals)))
                status, detail = child.conn.recv()
            except (EOFError, OSError, ValueError, TypeError) as exc:
                if isinstance(exc, TypeError) and not child.conn.closed:
                    raise  # not the pipe closed under the send by `close` (its handle gone): a frame not sendable
                if self._killed_pid == child.pid:
                    raise ClassifierProcessHungError(
                        f"stage-2 process {child.pid} answered nothing for {self.timeout_s:g} s (stage2_timeout): "
                        "killed, restarting; this frame is dropped") from None
                raise ClassifierProcessDownError(f"stage-2 process {child.pid} ended during this frame") from None
            finally:
                self._asked = None
        if status != "ok":
            raise ClassifierProcessError(f"stage-2 process failed this frame:\n{detail}")
        self._failures = 0
        return SegmentResult(*detail)

    def down_for(self) -> float | None:
        """Seconds since the child died while no new one serves yet; None while one serves."""
        since = self._down_since
        return None if since is None else time.monotonic() - since

    def _down_reason(self) -> str:
        if self._closing.is_set():
            return "stage-2 process ended: the classifier is closed"
        return f"stage-2 process down for {self.down_for() or 0.0:.1f} s, restarting"

    def warm_up(self) -> None:
        """Nothing: the child warmed up before it said it was ready."""

    def _supervise(self) -> None:
        """Wait for the serving child to end, killing it when a frame outlives `timeout_s`; unless closing, report
        it and start another with back-off."""
        child = self._child
        while child is not None:
            while not wait([child.process.sentinel], WATCH_S):
                asked, timeout = self._asked, self.timeout_s
                if timeout is not None and asked is not None and time.monotonic() - asked > timeout:
                    self._killed_pid = child.pid
                    child.process.kill()  # SIGKILL: also ends a stopped (SIGSTOP) process
            if self._closing.is_set():
                return
            child.process.join(STOP_TIMEOUT_S)
            with self._lock:
                self._down_since = time.monotonic()
                self._child = None
            child.conn.close()
            if self._killed_pid == child.pid:
                self.hangs += 1
                how = f"answered nothing for {self.timeout_s:g} s (hung or stopped): killed"
            else:
                how = f"died ({describe_exit(child.process.exitcode)})"
            self._report("error", f"stage 2 process {child.pid} {how}; frames are dropped until it is restarted, "
                                  f"in {restart_delay(self._failures):g} s")
            child = self._restart()

    def _restart(self) -> _Child | None:
        """Start children, with back-off, until one serves (returned) or the classifier closes (None)."""
        while True:
            delay = restart_delay(self._failures)
            self._failures += 1
            if self._closing.wait(delay):
                return None
            started = time.perf_counter()
            try:
                child = _start(self._args, self._closing)
            except ClassifierProcessError as exc:
                if self._closing.is_set():
                    return None
                self._report("error", f"stage 2 restart failed: {exc}; next try in "
                                      f"{restart_delay(self._failures):g} s")
                continue
            with self._lock:
                if self._closing.is_set():
                    _stop(child.process, child.conn)
                    return None
                down = self.down_for() or 0.0
                # reported before the child serves, so that the log line comes before its first frame
                self._report("info", f"stage 2 restarted in process {child.pid} (restart {self.restarts + 1}, down "
                                     f"{down:.1f} s, load + warm-up {1e3 * (time.perf_counter() - started):.0f} ms)")
                self._child, self._down_since = child, None
                self.pid, self.restarts = child.pid, self.restarts + 1
            return child

    def close(self) -> None:
        """Stop the child (politely, then by force) and the supervisor; later calls fail with the reason."""
        self._closing.set()
        locked = self._lock.acquire(timeout=STOP_TIMEOUT_S)  # a frame in hand finishes first, unless it hangs
        child, self._child = self._child, None
        if locked:
            self._lock.release()
        elif child is not None:  # a frame still in hand: the child may be stopped on a full pipe, where "stop"
            child.process.kill()  # would block this send as it blocks the frame's
        if child is not None:
            _stop(child.process, child.conn)
        if self._supervisor is not threading.current_thread():
            self._supervisor.join(STOP_TIMEOUT_S + POLL_S)
