"""`stage1.min_range: auto` on a stream: the vehicle's own returns (pass3d_ros.core.self_returns) read from the
stream's scans while it moves, then the radius held. The holder offers the reader a scan every SAMPLE_EVERY_S, reads
once it holds WINDOW of them, starts over without the older half while the vehicle stands still, then holds."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pass3d_ros.core.self_returns import STILL_SHARE, SelfReturnReader, SelfReturns

SAMPLE_EVERY_S = 0.5  # a stream offers the reader a scan at most this often...
WINDOW = 10  # ...and reads once it holds this many (5 s of a stream)
OFFLINE_SCAN_S = 0.1  # a stream without a clock counts each scan as one revolution at 10 Hz


class BodyHolder:
    """`stage1.min_range: auto` on one stream: the vehicle's own returns read from its scans, then held. `clock`:
    seconds (live), or None (offline: each scan OFFLINE_SCAN_S later). Until a reading is held the radius is 0."""

    def __init__(self, clock: Callable[[], float] | None = None) -> None:
        self.clock = clock
        self.reset()

    def reset(self) -> None:
        """Forget the scans and any held reading (another stream)."""
        self._reader = SelfReturnReader()
        self._offered: float | None = None
        self._ticks = 0
        self.held: SelfReturns | None = None

    @property
    def radius_m(self) -> float:
        """The held body radius (0.0 until held, and when the held reading found no body)."""
        return 0.0 if self.held is None else self.held.radius_m

    def observe(self, points: np.ndarray, ground: np.ndarray) -> SelfReturns | None:
        """Offer a scan (points in the sensor frame, stage 1's ground mask); the reading when this scan decided it,
        else None. A vehicle standing still decides nothing: the older half of the window is dropped and reading
        goes on."""
        if self.held is not None:
            return None
        now = self.clock() if self.clock is not None else self._ticks * OFFLINE_SCAN_S
        self._ticks += 1
        if self._offered is not None and now - self._offered < SAMPLE_EVERY_S:
            return None
        self._offered = now
        self._reader.add(points, ground)
        if self._reader.scans < WINDOW:
            return None
        reading = self._reader.read()
        if reading.scene_persistent is not None and reading.scene_persistent >= STILL_SHARE:
            self._reader.drop_oldest(WINDOW // 2)
            return None
        self.held = reading
        return reading
