"""The full scale of a stream's intensities, decided per stream rather than per frame.

A driver's intensity range (0..1, 0..255, 16-bit reflectivity) is a property of the sensor, not of one scan: a
16-bit scan whose brightest return happens to read 250 must not be divided by 255 while the next one, reading 300,
is divided by 65535, and one absurd return must not darken a whole scan. So the scale is read from a high quantile
of each scan, held, and changed only when several scans in a row say so, up as well as down; the caller logs each
change. A scan no sensor could have sent (intensities not finite, or far beyond any sensor's range: a corrupt cloud)
is no evidence at all: it is divided by the held scale and changes nothing, so one bad cloud cannot darken the scans
after it. Until the stream's scale is settled (its first scans), each plausible scan is divided by its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pass3d_ros.core.scan_checks import intensity_divisor

HIGH_QUANTILE = 99.9  # a scan's "brightest" return: a handful of outliers above it do not count
SAMPLE_STRIDE = 4  # the quantile reads every 4th point: 30k of a 120k-point scan, a fraction of a millisecond
FRAMES_TO_RAISE = 3  # scans in a row whose returns exceed the held scale before it is raised; the first scale
# held is the median of the first this many plausible scans' (each of them divided by its own until then)
FRAMES_TO_LOWER = 50  # scans in a row that fit a smaller scale before it is lowered (5 s at 10 Hz: dark scenes)
MAX_PLAUSIBLE_INTENSITY = 1e6  # 15x a 16-bit full scale: a brighter scan is a corrupt cloud, not a sensor
MAX_NONFINITE_SHARE = 0.01  # a scan with more non-finite intensities than this is a corrupt cloud


@dataclass(frozen=True)
class ScaleChange:
    """The held divisor changed: from what, to what, and on how many scans' evidence."""

    old: float | None
    new: float
    frames: int

    def __str__(self) -> str:
        before = "none" if self.old is None else f"{self.old:g}"
        return f"full scale {before} -> {self.new:g}, from the {HIGH_QUANTILE:g}th percentile of {self.frames} scan(s)"


@dataclass(frozen=True)
class ScaleReading:
    """What one scan's intensities are divided by, whether the held scale changed on it, why the scan was no
    evidence of the stream's scale ("" when it was), and whether the divisor is the scan's own (no scale held yet)."""

    divisor: float
    change: ScaleChange | None = None
    implausible: str = ""
    provisional: bool = False


class StreamIntensityScale:
    """Holds the divisor that maps one stream's intensities to 0..1."""

    def __init__(self) -> None:
        self.divisor: float | None = None  # the held scale; None until FRAMES_TO_RAISE scans agreed on one
        self._candidate: float | None = None
        self._streak = 0
        self._first: list[float] = []  # the scales of the first plausible scans, while none is held

    def _evidence(self, intensity: np.ndarray, in_unit_range: bool) -> float | str:
        """The full scale this scan says, or why it says nothing."""
        if in_unit_range:
            return 1.0
        sample = intensity[::SAMPLE_STRIDE]
        finite = sample[np.isfinite(sample)]
        if len(finite) == 0 or len(finite) < (1.0 - MAX_NONFINITE_SHARE) * len(sample):
            return f"{len(sample) - len(finite)} of {len(sample)} sampled values not finite"
        high = float(np.percentile(finite, HIGH_QUANTILE))
        if not high <= MAX_PLAUSIBLE_INTENSITY:
            return f"{HIGH_QUANTILE:g}th percentile {high:.3g}, beyond any sensor's range ({MAX_PLAUSIBLE_INTENSITY:g})"
        return intensity_divisor(high)

    def read(self, intensity: np.ndarray, in_unit_range: bool = False) -> ScaleReading:
        """Read one scan's (already `intensity_scale`d) intensities: what to divide it by, and any change of the
        held divisor. `in_unit_range`: the caller knows every value is finite and within 0..1 (no quantile needed)."""
        evidence = self._evidence(intensity, in_unit_range)
        if isinstance(evidence, str):
            return ScaleReading(self.divisor or 1.0, None, evidence)
        held = self.divisor
        if held is None:  # settling: the median of the first FRAMES_TO_RAISE plausible scans' scales
            self._first.append(evidence)
            if len(self._first) < FRAMES_TO_RAISE:
                return ScaleReading(evidence, provisional=True)
            self.divisor = float(np.median(self._first))
            return ScaleReading(self.divisor, ScaleChange(None, self.divisor, len(self._first)))
        if evidence == held:
            self._candidate, self._streak = None, 0
            return ScaleReading(evidence)
        if evidence == self._candidate:
            self._streak += 1
        else:
            self._candidate, self._streak = evidence, 1
        needed = FRAMES_TO_RAISE if evidence > held else FRAMES_TO_LOWER
        if self._streak < needed:
            return ScaleReading(held)
        change = ScaleChange(held, evidence, self._streak)
        self.divisor, self._candidate, self._streak = evidence, None, 0
        return ScaleReading(evidence, change)
