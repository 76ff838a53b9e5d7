"""Per-node live counters for `/diagnostics`: frames received / processed / dropped, input gaps from header
stamps, latency percentiles and where each frame's time went (queue wait, decode, compute, encode, publish,
and the in-memory next stage).

`NodeStats` knows no rclpy (it is fed plain numbers); `to_status` builds the `diagnostic_msgs` message.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Mapping

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTICS_PERIOD_S = 1.0
GAP_FACTOR = 1.5  # a stamp interval above this x the sensor's period means frames were lost before the node
HISTORY = 200  # frames kept for the percentiles
CADENCE_WINDOW = 30  # recent stamp intervals the sensor's period is estimated from (gaps included: it re-learns)
CADENCE_QUANTILE = 10.0  # a first guess of the period: this low percentile of them, so that loss leaves it alone
MIN_INTERVALS = 3  # intervals seen before gaps are counted
MIN_PERIOD_NS = 2_000_000  # no scanning LiDAR turns faster than 500 Hz: a shorter interval is a repeated stamp
MAX_GAP_NS = 10_000_000_000  # a longer silence is a pause of the stream (stopped, bag restarted), not lost frames
STEPS = ("wait", "decode", "compute", "handoff", "encode", "publish", "sink")  # sink: the in-memory next stage;
# handoff: the wait in segmentation_node's publishing thread (overlap)


class NodeStats:
    """Thread-safe counters of one node: fed by the subscription callback (`input`) and the worker (`frame`)."""

    def __init__(self, history: int = HISTORY, count_gaps: bool = True) -> None:
        self._lock = threading.Lock()
        self.count_gaps = count_gaps  # False where the input is another node's output, whose drops are its own
        self._intervals: deque[int] = deque(maxlen=CADENCE_WINDOW)
        self._last_stamp: int | None = None
        self.input_gaps = 0  # stamp intervals longer than GAP_FACTOR x the sensor's period
        self.frames_missed = 0  # frames those gaps stand for (interval / period - 1, rounded)
        self.stream_pauses = 0  # silences longer than MAX_GAP_NS
        self.stamps_out_of_order = 0  # stamps not after the previous one, or repeated within MIN_PERIOD_NS
        self.latency_ms: deque[float] = deque(maxlen=history)
        self.steps_ms: dict[str, deque[float]] = {name: deque(maxlen=history) for name in STEPS}

    def input(self, stamp_ns: int) -> None:
        """A frame arrived with this header stamp: count the frames missing since the previous one."""
        if not self.count_gaps:
            return
        with self._lock:
            last, self._last_stamp = self._last_stamp, stamp_ns
            if last is None:
                return
            interval = stamp_ns - last
            if interval < MIN_PERIOD_NS:
                self.stamps_out_of_order += 1
                return
            if interval > MAX_GAP_NS:
                self.stream_pauses += 1
                return
            if len(self._intervals) >= MIN_INTERVALS:
                period = self._period()
                missing = round(interval / period) - 1
                if interval > GAP_FACTOR * period and missing >= 1:
                    self.input_gaps += 1
                    self.frames_missed += missing
            self._intervals.append(interval)

    def _period(self) -> float:
        """The sensor's period (call with the lock held): each recent interval divided by the whole number of
        periods it spans by a first guess (a low percentile), then their median, which averages out jitter."""
        intervals = np.asarray(self._intervals, dtype=np.float64)
        guess = float(np.percentile(intervals, CADENCE_QUANTILE))
        return float(np.median(intervals / np.maximum(1.0, np.round(intervals / guess))))

    def frame(self, steps_ms: Mapping[str, float]) -> None:
        """One processed frame: its step times (ms); their sum is the node's latency for it."""
        with self._lock:
            for name, value in steps_ms.items():
                if name in self.steps_ms:
                    self.steps_ms[name].append(value)
            self.latency_ms.append(float(sum(steps_ms.values())))

    def snapshot(self) -> dict[str, float | int | None]:
        """The gap counters, latency p50 / p95 / max and the median of every step, as plain numbers."""
        with self._lock:
            latency = np.array(self.latency_ms)
            out: dict[str, float | int | None] = {}
            if self.count_gaps:
                out.update({
                    "input_gaps": self.input_gaps,
                    "frames_missed_upstream": self.frames_missed,
                    "stream_pauses": self.stream_pauses,
                    "stamps_out_of_order": self.stamps_out_of_order,
                    "input_period_ms": self._period() / 1e6 if self._intervals else None,
                })
            out.update({
                "latency_p50_ms": float(np.percentile(latency, 50)) if len(latency) else None,
                "latency_p95_ms": float(np.percentile(latency, 95)) if len(latency) else None,
                "latency_max_ms": float(latency.max()) if len(latency) else None,
            })
            for name, values in self.steps_ms.items():
                out[f"{name}_p50_ms"] = float(np.median(values)) if values else None
        return out


class StepClock:
    """Times a frame's steps: `mark(name)` closes the step that ran since the previous mark."""

    def __init__(self, wait_s: float = 0.0) -> None:
        self.steps_ms: dict[str, float] = {"wait": 1e3 * wait_s}
        self._last = time.perf_counter()

    def mark(self, name: str) -> None:
        """The time since the last mark (or start) goes to step `name` (added when it repeats)."""
        now = time.perf_counter()
        self.steps_ms[name] = self.steps_ms.get(name, 0.0) + 1e3 * (now - self._last)
        self._last = now


def to_status(name: str, counters: Mapping[str, int], stats: NodeStats, message: str = "",
              warning: str = "") -> DiagnosticStatus:
    """One DiagnosticStatus: OK, or WARN when frames were dropped, failed or lost before the node, or when a
    `warning` (what is wrong now, e.g. with the input) is given; the warning is then the message."""
    values: dict[str, float | int | None] = dict(counters)
    values.update(stats.snapshot())
    trouble = bool(warning) or any(values.get(k) for k in ("dropped", "failed", "input_gaps"))
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if trouble else DiagnosticStatus.OK,
        name=name,
        message=warning or message or ("frames dropped or lost" if trouble else "ok"),
        hardware_id="pass3d",
        values=[KeyValue(key=k, value="" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v)))
                for k, v in values.items()],
    )


def status_values(status: DiagnosticStatus) -> dict[str, float | None]:
    """A DiagnosticStatus's values back as numbers (None where empty): what a monitor or test reads."""
    return {kv.key: (float(kv.value) if kv.value else None) for kv in status.values}
