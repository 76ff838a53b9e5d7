"""Per-node live counters for `/diagnostics`: frames received / processed / skipped / dropped, input gaps from
header stamps, latency percentiles and where each frame's time went (queue wait, decode, compute, encode, publish,
and the in-memory next stage).

`NodeStats` and `OutputWatch` know no rclpy (they are fed plain numbers); `to_status` builds the
`diagnostic_msgs` message.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Mapping

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from pass3d_ros.ros.input_watch import MIN_PERIOD_NS, Cadence

DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTICS_PERIOD_S = 1.0
HISTORY = 200  # frames kept for the percentiles
NO_OUTPUT_WARN_S = 3.0  # frames came in and were skipped, dropped or failed, but none went out for this long: WARN
MAX_GAP_NS = 10_000_000_000  # a longer silence is a pause of the stream (stopped, bag restarted), not lost frames
TROUBLE_WINDOW_S = 10.0  # WARN for frames dropped, failed or lost only while their count grew this recently
TROUBLE_COUNTERS = ("dropped", "failed", "input_gaps")
STEPS = ("wait", "decode", "compute", "handoff", "encode", "publish", "sink")  # sink: the in-memory next stage;
# handoff: the wait in segmentation_node's publishing thread (overlap)


class NodeStats:
    """Thread-safe counters of one node: fed by the subscription callback (`input`) and the worker (`frame`)."""

    def __init__(self, history: int = HISTORY, count_gaps: bool = True) -> None:
        self._lock = threading.Lock()
        self.count_gaps = count_gaps  # False: no gap counting (each node's input counts its own)
        self._cadence = Cadence()  # the sensor's period, learnt (a rate change is no loss); input_gaps and
        # frames_missed are its confirmed losses
        self._last_stamp: int | None = None
        self.stream_pauses = 0  # silences longer than MAX_GAP_NS
        self.stamps_out_of_order = 0  # stamps not after the previous one, or repeated within MIN_PERIOD_NS
        self.latency_ms: deque[float] = deque(maxlen=history)
        self.steps_ms: dict[str, deque[float]] = {name: deque(maxlen=history) for name in STEPS}

    @property
    def input_gaps(self) -> int:
        """Stamp intervals confirmed as frames lost before the node."""
        return self._cadence.gaps

    @property
    def frames_missed(self) -> int:
        """Frames those gaps stand for (interval / learned period - 1, rounded)."""
        return self._cadence.missed

    @property
    def frames_pending(self) -> int:
        """Frames that stamp gaps not yet confirmed as loss stand for (loss, or the first intervals of a slower
        rate)."""
        return self._cadence.pending()

    def input(self, stamp_ns: int) -> None:
        """A frame arrived with this header stamp: count the frames missing since the previous one (once the
        stream confirms them: a rate change is learnt, not counted)."""
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
            self._cadence.add(interval)

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
                    "frames_missed_pending": self.frames_pending,
                    "stream_pauses": self.stream_pauses,
                    "stamps_out_of_order": self.stamps_out_of_order,
                    "input_rate_changes": self._cadence.rate_changes,
                    "input_period_ms": self._cadence.period_ns / 1e6 if self._cadence.period_ns else None,
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


class OutputWatch:
    """Says when frames come in but none goes out: over the last `after_s` the input grew and the output did not
    (the totals alone read fine while a stream of malformed clouds produces nothing); names where they went."""

    def __init__(self, after_s: float = NO_OUTPUT_WARN_S) -> None:
        self.after_s = after_s
        self._samples: deque[tuple[float, dict[str, int]]] = deque()  # (time, counters) at each check
        self._last_output: float | None = None  # when the output count last grew (or watching began)

    def check(self, now: float, counters: Mapping[str, int], skip_reasons: Mapping[str, int]) -> str:
        """The warning ("" when none) from the node's counters (received, processed = output, skipped, dropped,
        failed) and its skips by reason, totals since start; called about once a second."""
        current = {key: int(counters.get(key, 0)) for key in ("received", "processed", "skipped", "dropped",
                                                              "failed")}
        current.update({f"skip:{reason}": int(count) for reason, count in skip_reasons.items()})
        if self._last_output is None or (self._samples and current["processed"] != self._samples[-1][1]["processed"]):
            self._last_output = now
        self._samples.append((now, current))
        while len(self._samples) > 1 and now - self._samples[1][0] >= self.after_s:
            self._samples.popleft()
        then, base = self._samples[0]
        if now - then < self.after_s:
            return ""
        new = {key: value - base.get(key, 0) for key, value in current.items()}
        if not new["received"] or new["processed"]:
            return ""
        reasons = ", ".join(f"{key[5:]} {count}" for key, count in new.items() if key.startswith("skip:") and count)
        why = [f"{new['skipped']} skipped" + (f" ({reasons})" if reasons else "")] if new["skipped"] else []
        why += [f"{new[key]} {key}" for key in ("dropped", "failed") if new[key]]
        return (f"no output for {now - self._last_output:.0f} s while {new['received']} frames came in: "
                + (", ".join(why) or "none finished"))


class RecentTrouble:
    """Whether frames were dropped, failed or lost (TROUBLE_COUNTERS summed) within the last `window_s`: a node's
    status describes the present, so one drop an hour ago leaves it OK (the counts stay in its values). Fed one sample
    per status (plain numbers, no rclpy)."""

    def __init__(self, window_s: float = TROUBLE_WINDOW_S) -> None:
        self.window_s = window_s
        self._last_growth_s = -np.inf
        self._total = 0

    def update(self, now_s: float, values: Mapping[str, float | int | None]) -> bool:
        """Record this status's counts at `now_s` (monotonic seconds); True when their sum grew within the window
        (from 0 at the start: a first status after loss warns)."""
        total = int(sum(values.get(k) or 0 for k in TROUBLE_COUNTERS))
        if total != self._total:
            self._last_growth_s = now_s
        self._total = total
        return now_s - self._last_growth_s <= self.window_s


def to_status(name: str, counters: Mapping[str, int], stats: NodeStats, recent: RecentTrouble, message: str = "",
              warning: str = "", error: str = "", now_s: float | None = None) -> DiagnosticStatus:
    """One DiagnosticStatus: OK; WARN when frames were dropped, failed or lost before the node within `recent`'s
    window (up to `now_s`, default now), or when a `warning` (what is wrong now, e.g. with the input) is given; ERROR
    when an `error` is (a stage that had to be killed). The error, else the warning, is then the message."""
    values: dict[str, float | int | None] = dict(counters)
    values.update(stats.snapshot())
    lost = recent.update(time.monotonic() if now_s is None else now_s, values)
    trouble = bool(warning) or lost
    level = DiagnosticStatus.ERROR if error else DiagnosticStatus.WARN if trouble else DiagnosticStatus.OK
    return DiagnosticStatus(
        level=level,
        name=name,
        message="; ".join(m for m in (error, warning) if m) or message or (
            f"frames dropped or lost in the last {recent.window_s:g} s" if trouble else "ok"),
        hardware_id="pass3d",
        values=[KeyValue(key=k, value="" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v)))
                for k, v in values.items()],
    )


def status_values(status: DiagnosticStatus) -> dict[str, float | str | None]:
    """A DiagnosticStatus's values back as numbers (None where empty, text where not a number): what a monitor or
    test reads."""
    return {kv.key: _number(kv.value) for kv in status.values}


def _number(text: str) -> float | str | None:
    try:
        return float(text) if text else None
    except ValueError:
        return text
