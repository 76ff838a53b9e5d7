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
GAP_FACTOR = 1.5  # a stamp gap above this x the median period means frames were lost before the node
HISTORY = 200  # frames kept for the percentiles and the median period
STEPS = ("wait", "decode", "compute", "handoff", "encode", "publish", "sink")  # sink: the in-memory next stage;
# handoff: the wait in segmentation_node's publishing thread (overlap)


class NodeStats:
    """Thread-safe counters of one node: fed by the subscription callback (`input`) and the worker (`frame`)."""

    def __init__(self, history: int = HISTORY) -> None:
        self._lock = threading.Lock()
        self._periods: deque[int] = deque(maxlen=history)
        self._last_stamp: int | None = None
        self.input_gaps = 0  # stamp gaps longer than GAP_FACTOR x the median period
        self.frames_missed = 0  # frames those gaps stand for (gap / median period - 1, rounded)
        self.stamps_out_of_order = 0
        self.latency_ms: deque[float] = deque(maxlen=history)
        self.steps_ms: dict[str, deque[float]] = {name: deque(maxlen=history) for name in STEPS}

    def input(self, stamp_ns: int) -> None:
        """A frame arrived with this header stamp: count a gap when it is far after the previous one."""
        with self._lock:
            last, self._last_stamp = self._last_stamp, stamp_ns
            if last is None:
                return
            period = stamp_ns - last
            if period <= 0:
                self.stamps_out_of_order += 1
                return
            if len(self._periods) >= 3:
                median = float(np.median(self._periods))
                if period > GAP_FACTOR * median:
                    self.input_gaps += 1
                    self.frames_missed += max(1, round(period / median) - 1)
                    return  # a gap is not a period: the median stays the sensor's
            self._periods.append(period)

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
            out: dict[str, float | int | None] = {
                "input_gaps": self.input_gaps,
                "frames_missed_upstream": self.frames_missed,
                "stamps_out_of_order": self.stamps_out_of_order,
                "input_period_ms": float(np.median(self._periods)) / 1e6 if self._periods else None,
                "latency_p50_ms": float(np.percentile(latency, 50)) if len(latency) else None,
                "latency_p95_ms": float(np.percentile(latency, 95)) if len(latency) else None,
                "latency_max_ms": float(latency.max()) if len(latency) else None,
            }
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


def to_status(name: str, counters: Mapping[str, int], stats: NodeStats, message: str = "") -> DiagnosticStatus:
    """One DiagnosticStatus: OK, or WARN when frames were dropped, failed or lost before the node."""
    values: dict[str, float | int | None] = dict(counters)
    values.update(stats.snapshot())
    trouble = any(values.get(k) for k in ("dropped", "failed", "input_gaps"))
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if trouble else DiagnosticStatus.OK,
        name=name,
        message=message or ("frames dropped or lost" if trouble else "ok"),
        hardware_id="pass3d",
        values=[KeyValue(key=k, value="" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v)))
                for k, v in values.items()],
    )


def status_values(status: DiagnosticStatus) -> dict[str, float | None]:
    """A DiagnosticStatus's values back as numbers (None where empty): what a monitor or test reads."""
    return {kv.key: (float(kv.value) if kv.value else None) for kv in status.values}
