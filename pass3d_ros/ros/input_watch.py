"""Says when a node's input goes wrong between processes: publishers exist but no scan arrives, or scans arrive
with stamps missing in between; names the likely cause (message size vs the transport, a QoS mismatch) and the
fix. Plain numbers in, one line out: the node logs it (throttled) and puts it on /diagnostics."""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Sequence

import numpy as np

from pass3d_ros.ros.qos import RELIABILITY_WORDS

SILENT_AFTER_S = 5.0  # publishers but no scan for this long: say so
WINDOW_S = 10.0  # missing scans are counted among the stamps that arrived this recently
MISSING_FRACTION = 0.2  # ... and reported when at least this share of the expected scans (and 3) is missing
PERIOD_PERCENTILE = 10  # the sensor period: a low percentile of the stamp steps (losses only lengthen steps)


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
        self._recent: deque[tuple[float, int]] = deque()  # (arrival, header stamp) of one unbroken stretch

    def received(self, now: float, stamp_ns: int) -> None:
        """A message with header stamp `stamp_ns` arrived at monotonic time `now`; a pause, a stamp going back or
        jumping ahead starts a new stretch (a restarted or looped bag is no loss)."""
        if self._recent:
            last_now, last_stamp = self._recent[-1]
            if (now - last_now >= self.silent_after_s or stamp_ns <= last_stamp
                    or stamp_ns - last_stamp >= self.silent_after_s * 1e9):
                self._recent.clear()
        self._recent.append((now, stamp_ns))

    def restart(self, now: float) -> None:
        """The subscription was recreated: give the publishers the grace period again."""
        self._since = now

    def missing(self, now: float) -> tuple[int, int, float]:
        """(missing, expected, period s) among the stamps of the last WINDOW_S s."""
        while self._recent and now - self._recent[0][0] > WINDOW_S:
            self._recent.popleft()
        if len(self._recent) < 3:
            return 0, len(self._recent), 0.0
        stamps = np.array([stamp for _, stamp in self._recent], dtype=np.int64)
        period = float(np.percentile(np.diff(stamps), PERIOD_PERCENTILE))
        expected = round(float(stamps[-1] - stamps[0]) / period) + 1
        return max(0, expected - len(stamps)), expected, period / 1e9

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
