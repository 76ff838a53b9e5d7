"""Laser lines and the ring field's order held across the scans of one stream: the one place that decides which
lines a scan is given.

A scan in no firing order and without a ring field (a column-major driver, a shuffled or filtered cloud) has its rings
read off the laser lines of its sensor (pass3d_ros.core.stage1.ring). Searching for them costs 20-40 ms a scan; the
lines are a property of the sensor, so a stream searches once and gives the lines it found to the following scans
(`propose(..., lines=...)`), which check that they still fit and search again when they do not. A search that found none
(`NO_LINES`) is not repeated on every scan either: the stream bins by elevation and searches again after one scan period
(`LINE_SEARCH_FIRST_RETRY_S`), after each further failure twice as long (1, 2, 4, 8 ... scan periods), but at least
every `LINE_SEARCH_RETRY_S`; a search that finds lines, or a new stream, starts the count over. A search that failed
for a passing reason (a few odd scans) is made good within scans, not 10 s later, and a stream with no lines to find
costs a search about every 10 s. The cluster node and every offline tool (evaluation, segmentation, the stage-1
benchmark, training's samples) hold their lines through a `LineHolder`, so a stream costs the same everywhere.

A driver's ring field is read in the order of its rings' measured elevations (pass3d_ros.core.stage1.ring_field);
the order is measured on a stream's first scan with a field and held with the lines, so the stream pays for it once.
So is the laser spacing of a stream whose rings fall back to elevation bins (pass3d_ros.core.stage1.sensor_params
.laser_spacing, 6 ms a 120k-point scan): read on its first binned scan, held until the next line search. And the
sensor's angular resolution and laser elevations (`SensorScale`, 0.6 ms a KITTI scan): read on a scan, given to the
next ones, read again every `SCALE_REREAD_SCANS` scans (so an odd first scan is not held for long) and whenever a scan's
rings differ in kind or number.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import numpy as np

from pass3d_ros.core import stage1 as _stage1
from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage1.ring import LaserLines
from pass3d_ros.core.stage1.ring_field import RingFieldOrder
from pass3d_ros.core.stage1.sensor_params import SensorScale

SCAN_PERIOD_S = 0.1  # offline (no clock), each scan counts as this long: a 10 Hz sensor's revolution
LINE_SEARCH_FIRST_RETRY_S = SCAN_PERIOD_S  # after a failed laser-line search, the next one comes this much later ...
LINE_SEARCH_RETRY_S = 10.0  # ... and after each further failure twice as long, but never longer than this
SCALE_REREAD_SCANS = 10  # the sensor's resolution and laser elevations are read again after this many scans


def retry_wait(failures: int) -> float:
    """How long (seconds) a stream waits to search for laser lines again after `failures` failed searches in a row
    (at least 1): LINE_SEARCH_FIRST_RETRY_S doubled with each failure after the first, at most LINE_SEARCH_RETRY_S."""
    return min(LINE_SEARCH_FIRST_RETRY_S * 2.0 ** min(max(failures, 1) - 1, 60), LINE_SEARCH_RETRY_S)


class LineHolder:
    """The laser lines of one stream, and when and how often in a row a search found none.

    `clock`: seconds (`time.monotonic` on a live stream); None counts scans, each `SCAN_PERIOD_S` long, so an
    offline run does not depend on how fast it runs: a stream whose searches keep failing searches on scans 0, 1, 3,
    7, 15 ... (1, 2, 4, 8 ... scans apart: `retry_wait`), then every LINE_SEARCH_RETRY_S / SCAN_PERIOD_S scans.
    `follow(key)` starts over when the stream changes (another dataset, another sensor); a changed stage-1 config
    calls `reset()`."""

    def __init__(self, clock: Callable[[], float] | None = None) -> None:
        self._clock = clock
        self._scans = 0
        self._lines: LaserLines | None = None
        self._ring_order: RingFieldOrder | None = None
        self._spacing: float | None = None  # the laser spacing read off elevation-bin rings (nan: none to read)
        self._scale: SensorScale | None = None  # the sensor's resolution and elevations, read `_scale_age` scans ago
        self._scale_age = 0
        self._searched_at = 0.0  # when a line search last found none (clock time)
        self._failures = 0  # line searches in a row that found none
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

    @property
    def failures(self) -> int:
        """Line searches in a row that found no lines (0 after one that found them, and on a new stream)."""
        return self._failures

    def reset(self) -> None:
        """Forget the lines, the failed searches and the ring field's order: the next scan without a firing order
        searches."""
        self._lines = None
        self._ring_order = None
        self._spacing = None
        self._scale = None
        self._searched_at = 0.0
        self._failures = 0

    def follow(self, key: Hashable) -> None:
        """The next scan belongs to stream `key` (a dataset spec): a new key forgets the lines."""
        if key != self._key:
            self._key = key
            self.reset()

    def lines(self) -> LaserLines | None:
        """The laser lines to give the next scan: those held, but none (a new search) once the last failed search
        (`NO_LINES`) is `retry_wait(failures)` old."""
        failed = self._lines is not None and self._lines.empty
        if failed and self._now() - self._searched_at >= retry_wait(self._failures) - 1e-9:  # 1e-9: scans in floats
            return None
        return self._lines

    def hold(self, given: LaserLines | None, found: LaserLines | None) -> None:
        """Keep what a scan's ring recovery found (`Stage1Result.lines`; a firing-order scan finds nothing and keeps
        what was held). A search that ran and found no lines is one more failure in a row, timed from now; lines
        found start the count over. `given`: what `lines()` gave that scan."""
        if found is not None and found.empty and not (given is not None and given.empty):
            self._searched_at = self._now()
            self._failures += 1
        elif found is not None and not found.empty:
            self._failures = 0
        self._lines = found or self._lines
        self._scans += 1

    def scale(self) -> SensorScale | None:
        """The sensor's resolution and laser elevations to give the next scan (`propose`'s `scale`): those held, until
        they are SCALE_REREAD_SCANS scans old (None: the scan reads its own)."""
        return self._scale if self._scale_age < SCALE_REREAD_SCANS else None

    def hold_scale(self, sensor: SensorScale | None) -> None:
        """Keep what a scan read of its sensor (`Stage1Result.sensor`), or count one scan more on what it was given."""
        if sensor is None:
            return
        if sensor.read_here:
            self._scale, self._scale_age = sensor, 1
        else:
            self._scale_age += 1

    def propose(self, points: np.ndarray, ring: np.ndarray | None = None, config: Stage1Config | None = None,
                level: np.ndarray | None = None) -> _stage1.Stage1Result:
        """`pass3d_ros.core.stage1.propose` on the stream's next scan, given the held lines, holding what it found;
        `level`: the rotation that levels the scan (None: it runs as it comes)."""
        given = self.lines()
        if given is None:  # a new search: the bins it may fall back to are read afresh too
            self._spacing = None
        result = _stage1.propose(points, ring, config, lines=given, ring_order=self._ring_order, level=level,
                                 spacing=self._spacing, scale=self.scale())
        if result.ring_source == "elevation_bins" and result.sensor is not None:
            self._spacing = result.sensor.spacing_deg
        self.hold_scale(result.sensor)
        self.hold(given, result.lines)
        self._ring_order = result.ring_order or self._ring_order
        return result
