"""The full scale of a stream's intensities, decided per stream rather than per frame.

A driver's intensity range (0..1, 0..255, 16-bit reflectivity) is a property of the sensor, not of one scan: a
16-bit scan whose brightest return happens to read 250 must not be divided by 255 while the next one, reading 300,
is divided by 65535, and one absurd return must not darken a whole scan. So the scale is read from a high quantile
of each scan, held, and changed only when several scans in a row say so; the caller logs each change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pass3d_ros.ros.scan_checks import intensity_divisor

HIGH_QUANTILE = 99.9  # a scan's "brightest" return: a handful of outliers above it do not count
SAMPLE_STRIDE = 4  # the quantile reads every 4th point: 30k of a 120k-point scan, a fraction of a millisecond
FRAMES_TO_RAISE = 3  # scans in a row whose returns exceed the held scale before it is raised
FRAMES_TO_LOWER = 50  # scans in a row that fit a smaller scale before it is lowered (5 s at 10 Hz: dark scenes)


@dataclass(frozen=True)
class ScaleChange:
    """The held divisor changed: from what, to what, and on how many scans' evidence."""

    old: float | None
    new: float
    frames: int

    def __str__(self) -> str:
        before = "none" if self.old is None else f"{self.old:g}"
        return f"full scale {before} -> {self.new:g}, from the {HIGH_QUANTILE:g}th percentile of {self.frames} scan(s)"


class StreamIntensityScale:
    """Holds the divisor that maps one stream's intensities to 0..1."""

    def __init__(self) -> None:
        self.divisor: float | None = None
        self._candidate: float | None = None
        self._streak = 0

    def update(self, intensity: np.ndarray) -> ScaleChange | None:
        """Read one scan's (already `intensity_scale`d) intensities; returns the change when the held divisor
        changed, else None. `divisor` is then the one to divide this scan by."""
        finite = intensity[::SAMPLE_STRIDE]
        finite = finite[np.isfinite(finite)]
        if len(finite) == 0:
            return None
        candidate = intensity_divisor(float(np.percentile(finite, HIGH_QUANTILE)))
        if self.divisor is None:
            self.divisor = candidate
            return ScaleChange(None, candidate, 1)
        if candidate == self.divisor:
            self._candidate, self._streak = None, 0
            return None
        if candidate == self._candidate:
            self._streak += 1
        else:
            self._candidate, self._streak = candidate, 1
        needed = FRAMES_TO_RAISE if candidate > self.divisor else FRAMES_TO_LOWER
        if self._streak < needed:
            return None
        change = ScaleChange(self.divisor, candidate, self._streak)
        self.divisor, self._candidate, self._streak = candidate, None, 0
        return change
