"""A small mailbox with a worker thread: a slow stage drops stale frames and counts them, never queues without bound
(`backlog` frames wait at most; 1: only the newest)."""

from __future__ import annotations

import enum
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


class Outcome(enum.Enum):
    """What `process` returns for a frame that produced no output (anything else: it did)."""

    SKIPPED = "skipped"  # malformed or empty input: nothing to process
    DROPPED = "dropped"  # a good frame given up (its stage hung or was down, its result came too late)


SKIPPED, DROPPED = Outcome.SKIPPED, Outcome.DROPPED


@dataclass
class FrameCounters:
    """A node's frame totals: processed counts frames that produced output, skipped the malformed or empty ones."""

    received: int = 0
    processed: int = 0
    dropped: int = 0
    failed: int = 0
    skipped: int = 0


class LatestFrameWorker(Generic[T]):
    """Runs `process` on the oldest waiting item in a background thread, in order.

    `submit` never blocks: at most `backlog` items wait; when a newer one arrives the oldest waiting one is dropped
    and counted, so memory stays bounded however slow `process` is. A backlog of 2 lets a stage that keeps up on
    average ride out one slow frame (a stream's first scans, a busy CPU's hiccup) without losing the next.
    Exceptions from `process` go to `on_error`; a frame for which it returns SKIPPED or DROPPED is counted so, not as
    processed.
    """

    def __init__(self, process: Callable[[T], object], on_error: Callable[[BaseException], None], name: str,
                 backlog: int = 1) -> None:
        if backlog < 1:
            raise ValueError(f"backlog must be >= 1, got {backlog}")
        self._process = process
        self._on_error = on_error
        self._pending: deque[tuple[T, float]] = deque()  # (item, when submitted), oldest first
        self._backlog = backlog
        self._cond = threading.Condition()
        self._stopping = False
        self._busy = False
        self.last_wait_s = 0.0  # how long the item in hand waited in the slot (read by `process`)
        self.counters = FrameCounters()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, item: T) -> None:
        """Hand over the newest item; the oldest pending one is dropped when `backlog` already wait."""
        with self._cond:
            self.counters.received += 1
            if len(self._pending) >= self._backlog:
                self._pending.popleft()
                self.counters.dropped += 1
            self._pending.append((item, time.perf_counter()))
            self._cond.notify()

    def run_inline(self, item: T) -> None:
        """Process `item` now, on the caller's thread, counted like a submitted one (no slot, no drop): for a
        stage fed in memory by the stage before it, so the two never contend for the GIL."""
        with self._cond:
            self.counters.received += 1
        self.last_wait_s = 0.0
        self._call(item)

    def idle(self) -> bool:
        """True when nothing is pending or being processed."""
        with self._cond:
            return not self._pending and not self._busy

    def stop(self, timeout: float = 5.0) -> None:
        """Finish the item in hand, drop what is pending, and join the thread (unless called from it)."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                item, submitted = self._pending.popleft()
                self.last_wait_s = time.perf_counter() - submitted
                self._busy = True
            try:
                self._call(item)  # type: ignore[arg-type]
            finally:
                with self._cond:
                    self._busy = False

    def _call(self, item: T) -> None:
        try:
            outcome = self._process(item)
        except Exception as exc:  # a bad frame must never kill the worker
            self.counters.failed += 1
            self._on_error(exc)
            return
        if outcome is SKIPPED:
            self.counters.skipped += 1
        elif outcome is DROPPED:
            self.counters.dropped += 1
        else:
            self.counters.processed += 1
