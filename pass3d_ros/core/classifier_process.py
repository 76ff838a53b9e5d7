"""A stage-2 classifier in a child process, behind the same `segment` call as one in this process.

Torch releases the GIL inside its kernels but not between them, and the PointNet++ forward pass is hundreds of small
ops: stage 2 on a thread beside stage 1 still takes turns with it for the GIL. In a child process it does not; the
parent only waits on a pipe (which releases the GIL) while the frame's arrays travel there and back (about 2 MB for
a 120k-point scan). The child is started with `spawn`, so nothing of the parent (ROS contexts, DDS threads) is copied
into it; like every `spawn` user, a script that starts one needs the `if __name__ == "__main__":` guard (the package's
commands have it).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import traceback
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from pass3d_ros.core.segmentation import DEFAULT_MAX_PROPOSALS, SegmentResult
from pass3d_ros.core.stage2 import ClassifierError, load_classifier
from pass3d_ros.core.threads import limit_threads

START_TIMEOUT_S = 120.0  # loading torch and the weights, and the warm-up, in a fresh interpreter
STOP_TIMEOUT_S = 5.0


class ClassifierProcessError(ClassifierError):
    """The child process could not start, failed a frame, or is gone; the message says which and why."""


def _serve(conn: Connection, kind: str, weights: str | None, device: str, max_proposals: int, threads: int) -> None:
    """The child: load and warm up the classifier, say "ready" (or why not), then segment each frame it is sent
    until told to stop or the parent goes."""
    try:
        if threads > 0:
            limit_threads(threads)
        classifier = load_classifier(kind, weights, device=device, max_proposals=max_proposals)
        classifier.warm_up()
    except Exception as exc:  # every failure goes back to the parent as text, which raises it there
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", os.getpid()))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        if request[0] == "stop":
            return
        _, points, members, limit = request
        classifier.max_proposals = limit
        try:
            reply: tuple[str, Any] = ("ok", tuple(classifier.segment(points, members)))
        except Exception:  # a frame's failure is the parent's to log; the child keeps serving
            reply = ("error", traceback.format_exc(limit=4))
        conn.send(reply)


class ProcessClassifier:
    """A classifier (`pass3d_ros.core.stage2.load_classifier` arguments) running in a child process.

    One frame at a time (the caller's thread waits for its result); `close` ends the child, as does the parent's
    exit. `pid` is the child's process id.
    """

    def __init__(self, kind: str, weights: str | None, device: str = "cpu",
                 max_proposals: int = DEFAULT_MAX_PROPOSALS, threads: int = 1) -> None:
        self.max_proposals = max_proposals
        context = mp.get_context("spawn")
        self._conn, child_conn = context.Pipe()
        self._process = context.Process(target=_serve, args=(child_conn, kind, weights, device, max_proposals,
                                                             threads), name="pass3d-stage2", daemon=True)
        self._process.start()
        child_conn.close()
        if not self._conn.poll(START_TIMEOUT_S):
            self.close()
            raise ClassifierProcessError(f"stage-2 process did not start within {START_TIMEOUT_S:.0f} s")
        status, detail = self._receive()
        if status != "ready":
            self.close()
            raise ClassifierProcessError(f"stage-2 process could not load the classifier: {detail}")
        self.pid: int = detail

    def _receive(self) -> tuple[str, Any]:
        try:
            return self._conn.recv()
        except (EOFError, OSError):
            raise ClassifierProcessError(
                f"stage-2 process ended (exit code {self._process.exitcode})") from None

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        """The child's `segment` of these points and proposals."""
        try:
            self._conn.send(("segment", points, members, int(self.max_proposals)))
        except (OSError, ValueError):
            raise ClassifierProcessError(
                f"stage-2 process ended (exit code {self._process.exitcode})") from None
        status, detail = self._receive()
        if status != "ok":
            raise ClassifierProcessError(f"stage-2 process failed this frame:\n{detail}")
        return SegmentResult(*detail)

    def warm_up(self) -> None:
        """Nothing: the child warmed up before it said it was ready."""

    def close(self) -> None:
        """Stop the child (politely, then by force) and release the pipe; later calls fail with the reason."""
        if self._process.is_alive():
            with contextlib.suppress(OSError, ValueError):  # a pipe already broken: the child is going anyway
                self._conn.send(("stop",))
            self._process.join(STOP_TIMEOUT_S)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(STOP_TIMEOUT_S)
        self._conn.close()
