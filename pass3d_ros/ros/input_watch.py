"""Says when a node's input goes wrong between processes: publishers exist but no scan arrives, or scans arrive
with stamps missing in between; names the likely cause (message size vs the transport, a QoS mismatch) and the
fix. Plain numbers in, one line out: the node logs it (throttled) and puts it on /diagnostics. `Cadence` learns
the sensor's period from the stamps (a rate change is re-learnt, not reported as loss)."""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pass3d_ros.ros.qos import RELIABILITY_WORDS

SILENT_AFTER_S = 5.0  # publishers but no scan for this long: say so
WINDOW_S = 10.0  # missing scans are counted among the stamps that arrived this recently
MISSING_FRACTION = 0.2  # ... and reported when at least this share of the expected scans (and 3) is missing
MIN_PERIOD_NS = 2_000_000  # no scanning LiDAR turns faster than 500 Hz: a shorter interval is a repeated stamp
FIRST_INTERVALS = 3  # intervals the first period is learnt from (their smallest whole fraction)
PERIOD_SAMPLES = 30  # the period is the median of this many recent on-period intervals (it follows a slow drift)
ON_PERIOD = 1.5  # an interval within this factor of the period (either way) is on period
MULTIPLE_TOLERANCE = 0.15  # an interval this close (in periods) to a whole multiple of a period is that multiple
RATE_CHANGE_INTERVALS = 8  # this many off-period intervals in a row that one new period explains: a rate change
REGULAR_SHARE = 0.75  # ... when at least this share of them is that period itself (loss leaves many lengths)
MAX_PENDING = 100  # off-period intervals held pending at most (10 s at 10 Hz): older ones are confirmed as loss


class Cadence:
    """The sensor's period learnt from header stamp intervals, and the frames missing between them.

    An interval near the period confirms it. A longer one is a gap: frames lost (whole periods missing) or the
    first interval of a slower rate, so its missing frames stay pending until the stream tells which. An on-period
    interval again, or later intervals no single new period explains (3, then 2 periods), confirm them as loss;
    RATE_CHANGE_INTERVALS off-period intervals in a row that one new period explains (20 -> 5 Hz: 4, 4, 4 ...;
    5 -> 10 Hz: 0.5, 0.5 ...) are a rate change: the period is re-learnt and nothing is counted lost. At most
    MAX_PENDING intervals stay pending (a stream that never comes back on period nor settles on a new one, such as a
    slower rate with irregular loss, would otherwise hold every interval for hours, each scan costing more): the
    oldest beyond it are confirmed as loss at the learned period.
    """

    def __init__(self) -> None:
        self.period_ns: float | None = None
        self.gaps = 0  # intervals confirmed as loss
        self.missed = 0  # frames those stand for
        self.rate_changes = 0
        self._samples: deque[float] = deque(maxlen=PERIOD_SAMPLES)
        self._first: list[int] = []  # intervals before a period is known
        self._run: list[int] = []  # off-period intervals since the last on-period one, their loss pending

    def add(self, interval_ns: int) -> int:
        """One stamp interval (at least MIN_PERIOD_NS, not a pause of the stream); returns the frames it
        confirms lost, in it or in earlier pending gaps."""
        if self.period_ns is not None:
            return self._classify(interval_ns)
        self._first.append(interval_ns)
        if len(self._first) < FIRST_INTERVALS:
            return 0
        first, self._first = self._first, []
        self.period_ns = _base_period(first)
        return sum(self._classify(interval) for interval in first)

    def pending(self) -> int:
        """Frames that the pending gaps stand for if they turn out to be loss."""
        return sum(self._missing(interval) for interval in self._run)

    def _classify(self, interval: int) -> int:
        period = self.period_ns or float(interval)
        if period / ON_PERIOD <= interval <= ON_PERIOD * period:
            self._samples.append(float(interval))
            self.period_ns = float(np.median(self._samples))
            return self._confirm(len(self._run))
        self._run.append(interval)
        lost = self._confirm(max(self._explained_from(), len(self._run) - MAX_PENDING))
        if len(self._run) >= RATE_CHANGE_INTERVALS and self._regular():
            self.period_ns = _base_period(self._run)
            self._samples.clear()
            self._samples.extend(interval / max(1, round(interval / self.period_ns)) for interval in self._run)
            self._run = []
            self.rate_changes += 1
        return lost

    def _explained_from(self) -> int:
        """Where the longest tail of the pending run starts that one period (its shortest interval) explains."""
        for start in range(len(self._run)):
            tail = np.asarray(self._run[start:], dtype=np.float64)
            multiples = tail / tail.min()
            if np.all(np.abs(multiples - np.round(multiples)) <= MULTIPLE_TOLERANCE):
                return start
        return len(self._run)

    def _regular(self) -> bool:
        """Whether most of the pending run is one interval, as a new rate gives (loss gives many lengths)."""
        run = np.asarray(self._run, dtype=np.float64)
        return np.count_nonzero(np.round(run / run.min()) == 1) >= REGULAR_SHARE * len(run)

    def _missing(self, interval: int) -> int:
        period = self.period_ns or float(interval)
        return max(0, round(interval / period) - 1) if interval > ON_PERIOD * period else 0

    def _confirm(self, count: int) -> int:
        """The first `count` pending intervals are loss at the learned period: count them."""
        lost = 0
        for interval in self._run[:count]:
            missing = self._missing(interval)
            if missing:
                self.gaps += 1
                lost += missing
        self.missed += lost
        del self._run[:count]
        return lost


def _base_period(intervals: Sequence[int]) -> float:
    """The period a few intervals are whole multiples of: each divided by its multiple of the shortest, median."""
    values = np.asarray(intervals, dtype=np.float64)
    return float(np.median(values / np.maximum(1.0, np.round(values / values.min()))))


@dataclass(frozen=True)
class Coverage:
    """How many messages of a stream arrived of how many its header stamps imply (first..last at the stream's
    period), and of how many its publisher said it sent (`published`, when known)."""

    got: int
    implied: int
    period_s: float
    published: int | None = None

    @property
    def expected(self) -> int:
        """What should have arrived: the larger of the stamps' implication and the publisher's count."""
        return max(self.implied, self.published or 0)

    @property
    def missing(self) -> int:
        return max(0, self.expected - self.got)


def coverage(stamps: Sequence[int], published: int | None = None) -> Coverage:
    """The `Coverage` of a stream from its received header stamps: the period is the median of the intervals within
    ON_PERIOD of the shortest (loss only lengthens intervals), the implied count (last - first) / period + 1."""
    unique = np.unique(np.asarray(stamps, dtype=np.int64))
    intervals = np.diff(unique)
    intervals = intervals[intervals >= MIN_PERIOD_NS]
    if len(intervals) == 0:
        return Coverage(len(unique), len(unique), 0.0, published)
    period = float(np.median(intervals[intervals <= ON_PERIOD * intervals.min()]))
    implied = round(float(unique[-1] - unique[0]) / period) + 1
    return Coverage(len(unique), max(implied, len(unique)), period / 1e9, published)


class InputWatch:
    """State of one input subscription, fed by `received` (each message) and `check` (a timer, about 1 Hz)."""

    def __init__(self, topic: str, profile: str | None, silent_after_s: float = SILENT_AFTER_S,
                 count_missing: bool = True) -> None:
        self.topic = topic
        self.profile = profile or "the shipped fastdds_large_clouds.xml"
        self.silent_after_s = silent_after_s
        self.count_missing = count_missing  # False where the input is another node's output (it counts its drops)
        self.problem = ""  # what is wrong now, "" when nothing
        self._publishers = 0
        self._since: float | None = None  # when the current publishers appeared (or the subscription changed)
        self._recent: deque[tuple[float, int, int]] = deque()  # (arrival, header stamp, scans it confirmed
        # missing) of one unbroken stretch
        self._cadence = Cadence()  # the stretch's period

    def received(self, now: float, stamp_ns: int) -> None:
        """A message with header stamp `stamp_ns` arrived at monotonic time `now`; a pause, a stamp going back or
        jumping ahead starts a new stretch (a restarted or looped bag is no loss), a repeated stamp is left out."""
        lost = 0
        if self._recent:
            last_now, last_stamp, _ = self._recent[-1]
            if (now - last_now >= self.silent_after_s or stamp_ns <= last_stamp
                    or stamp_ns - last_stamp >= self.silent_after_s * 1e9):
                self._recent.clear()
                self._cadence = Cadence()
            elif stamp_ns - last_stamp < MIN_PERIOD_NS:
                return
            else:
                lost = self._cadence.add(stamp_ns - last_stamp)
        self._recent.append((now, stamp_ns, lost))

    def restart(self, now: float) -> None:
        """The subscription was recreated: give the publishers the grace period again."""
        self._since = now

    def missing(self, now: float) -> tuple[int, int, float]:
        """(missing, expected, period s) among the stamps of the last WINDOW_S s: scans confirmed missing at the
        learned period (a rate change is no loss)."""
        while self._recent and now - self._recent[0][0] > WINDOW_S:
            self._recent.popleft()
        missing = sum(lost for _, _, lost in self._recent)
        return missing, len(self._recent) + missing, (self._cadence.period_ns or 0.0) / 1e9

    def check(self, now: float, offered: Sequence[str], subscribed: str) -> str:
        """Update `problem` from the publishers' QoS names (`offered`, one per publisher) and the subscription's
        QoS name; returns it."""
        if len(offered) > self._publishers or (offered and self._since is None):
            self._since = now
        if not offered:
            self._since = None
        self._publishers = len(offered)
        self.problem = ""
        if self._since is not None:
            last = max(self._since, self._recent[-1][0] if self._recent else self._since)
            cause = self._silence_cause(offered, subscribed)
            if now - last >= self.silent_after_s and cause:
                words = ", ".join(RELIABILITY_WORDS[q] for q in offered)
                self.problem = (f"{self.topic}: {len(offered)} publisher(s) ({words}) but no scan for "
                                f"{now - last:.0f} s: {cause}")
                return self.problem
        missing, expected, period = self.missing(now)
        if self.count_missing and missing >= max(3, MISSING_FRACTION * expected):
            self.problem = (f"{self.topic}: {missing} of the last {expected} scans missing (header stamps every "
                            f"{1e3 * period:.0f} ms): {self._gap_cause(subscribed)}")
        return self.problem

    def _transport_fix(self) -> str:
        return (f"start the publisher (the driver's shell too) with the large-cloud profile, export "
                f"FASTRTPS_DEFAULT_PROFILES_FILE={self.profile}, or make it publish reliable")

    def _silence_cause(self, offered: Sequence[str], subscribed: str) -> str:
        """Why a publisher may send and nothing arrive; "" when both ends are reliable (it sends nothing)."""
        if subscribed == "reliable" and "sensor" in offered:
            return ("QoS mismatch: subscribed reliable, a best-effort publisher never matches; set input_qos auto "
                    "or sensor")
        if subscribed == "sensor":
            reliable = offered and all(q == "reliable" for q in offered)
            return ("if it publishes, a ~2 MB cloud between processes over Fast DDS's default transports is mostly "
                    "lost under best effort; " + ("set input_qos auto or reliable (the publisher offers reliable), or "
                                                  if reliable else "") + self._transport_fix())
        return ""

    def _gap_cause(self, subscribed: str) -> str:
        if subscribed == "sensor":
            return ("lost on the way: a large cloud between processes under best effort needs more than Fast DDS's "
                    "default transports; " + self._transport_fix())
        return "the publisher skipped them (a driver or an upstream node dropping frames)"


class OverlapFilter:
    """While two subscriptions of one topic overlap (an auto QoS switch), drops the copy of a message that the other
    one already delivered: per stamp, a subscription's copy is new while it has delivered fewer copies of that stamp
    than the other (a publisher may send one stamp several times)."""

    def __init__(self) -> None:
        self.active = False
        self._counts: tuple[Counter[int], Counter[int]] = (Counter(), Counter())

    def start(self) -> None:
        """Both subscriptions deliver from now on."""
        self.active = True
        self._counts = (Counter(), Counter())

    def stop(self) -> None:
        """One subscription is left: every message is new."""
        self.active = False
        self._counts = (Counter(), Counter())

    def accept(self, source: int, stamp_ns: int) -> bool:
        """Whether the message with `stamp_ns` from subscription `source` (0 or 1) is new."""
        if not self.active:
            return True
        mine, other = self._counts[source], self._counts[1 - source]
        duplicate = mine[stamp_ns] < other[stamp_ns]
        mine[stamp_ns] += 1
        return not duplicate
