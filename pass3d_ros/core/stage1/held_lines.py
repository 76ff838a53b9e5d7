"""Laser lines and the ring field's order held across the scans of one stream: the one place that decides which
lines a scan is given.

A scan in no firing order and without a ring field (a column-major driver, a shuffled or filtered cloud) has its rings
read off the laser lines of its sensor (pass3d_ros.core.stage1.ring). Searching for them costs 20-40 ms a scan; the
lines are a property of the sensor, so a stream searches once and gives the lines it found to the following scans
(`propose(..., lines=...)`), which check that they still fit and search again when they do not. A search that found none
(`NO_LINES`) is not repeated on every scan either: the stream bins by elevation until `LINE_SEARCH_RETRY_S` has passed,
then searches again. The cluster node and every offline tool (evaluation, segmentation, the stage-1 benchmark,
training's samples) hold their lines through a `LineHolder`, so a stream costs the same everywhere.

A driver's ring field is read in the order of its rings' measured elevations (pass3d_ros.core.stage1.ring_field);
the order is measured on a stream's first scan with a field and held with the lines, so the stream pays for it once.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import numpy as np

from pass3d_ros.core import stage1 as _stage1
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.ring import LaserLines
from pass3d_ros.core.stage1.ring_field import RingFieldOrder

LINE_SEARCH_RETRY_S = 10.0  # a stream whose laser-line search found none searches again after this long
SCAN_PERIOD_S = 0.1  # offline (no clock), each scan counts as this long: a 10 Hz sensor's revolution


class LineHolder:
    """The laser lines of one stream, and when a search last found none.

    `clock`: seconds (`time.monotonic` on a live stream); None counts scans, each `SCAN_PERIOD_S` long, so an
    offline run does not depend on how fast it runs. `follow(key)` starts over when the stream changes (another
    dataset, another sensor); a changed stage-1 config calls `reset()`."""

    def __init__(self, clock: Callable[[], float] | None = None) -> None:
        self._clock = clock
        self._scans = 0
        self._lines: LaserLines | None = None
        self._ring_order: RingFieldOrder | None = None
        self._searched_at = 0.0  # when a line search last found none (clock time)
        self._key: Hashable = None

    def _now(self) -> float:
        return self._clock() if self._clock is not None else self._scans * SCAN_PERIOD_S

    @property
    def held(self) -> LaserLines | None:
        """The lines held now (None: none yet; `NO_LINES`: a search found none)."""
        return self._lines

    @property
    def ring_order(self) -> RingFieldOrder | None:
        """How the stream's ring field is read (None: no field seen yet)."""
        return self._ring_order

    def reset(self) -> None:
        """Forget the lines and the ring field's order: the next scan without a firing order searches."""
        self._lines = None
        self._ring_order = None
        self._searched_at = 0.0

    def follow(self, key: Hashable) -> None:
        """The next scan belongs to stream `key` (a dataset spec): a new key forgets the lines."""
        if key != self._key:
            self._key = key
            self.reset()

    def lines(self) -> LaserLines | None:
        """The laser lines to give the next scan: those held, but none (a new search) once a failed search
        (`NO_LINES`) is LINE_SEARCH_RETRY_S old."""
        failed = self._lines is not None and self._lines.empty
        if failed and self._now() - self._searched_at >= LINE_SEARCH_RETRY_S - 1e-9:  # 1e-9: scan counts in floats
            return None
        return self._lines

    def hold(self, given: LaserLines | None, found: LaserLines | None) -> None:
        """Keep what a scan's ring recovery found (`Stage1Result.lines`; a firing-order scan finds nothing and keeps
        what was held), and when a search that ran found no lines. `given`: what `lines()` gave that scan."""
        if found is not None and found.empty and not (given is not None and given.empty):
            self._searched_at = self._now()
        self._lines = found or self._lines
        self._scans += 1

    def propose(self, points: np.ndarray, ring: np.ndarray | None = None,
                config: Stage1Config | None = None) -> _stage1.Stage1Result:
        """`pass3d_ros.core.stage1.propose` on the stream's next scan, given the held lines, holding what it found."""
        given = self.lines()
        result = _stage1.propose(points, ring, config, lines=given, ring_order=self._ring_order)
        self.hold(given, result.lines)
        self._ring_order = result.ring_order or self._ring_order
        return result
