"""Intensity on the training scale: a per-stream quantile map from a sensor's returns to the network's.

Stage 2 learned intensity from the synthetic scans' distribution (positive returns: median 0.31). Sensors differ
far beyond the training's gain augmentation: the KITTI HDL-64E matches it (median 0.30), a nuScenes HDL-32E
reads 0.047 and a Pandar64 ~0.04, six to eight times darker. So each stream's positive returns are mapped through
the monotone function that takes its quantiles onto the training quantiles (`REFERENCE_QUANTILES`). The map is
fitted on the stream's first `FIT_SCANS` scans and then held: a scene's brightness must not re-scale a sensor
from scan to scan. Zero returns stay zero (no echo strength: dark paint, glass); a stream whose median lies
within `IDENTITY_BAND` of the training median is left as it is, and so is a constant-intensity stream (nothing
to match). The map is monotone, so the order of returns within a scan never changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_ENABLED = True  # the nodes' `intensity_match` and the tools' --intensity-match default

QUANTILES = np.linspace(0.0, 100.0, 21)
# Quantiles 0, 5, ..., 100 % of the positive returns of synthetic scans of the seven simulated sensors (2 scans
# each, seed 0, 60,000 returns a sensor): the distribution the shipped weights were trained on. `test_intensity_
# match` recomputes them from the generator and fails when the two part.
REFERENCE_QUANTILES = np.array([
    0.01, 0.08, 0.14, 0.17, 0.2, 0.22, 0.24, 0.26, 0.27, 0.29, 0.31,
    0.33, 0.34, 0.36, 0.38, 0.4, 0.43, 0.46, 0.5, 0.55, 0.99,
])
FIT_SCANS = 5  # scans pooled before the map is held (half a second of a 10 Hz sensor)
MIN_RETURNS = 2000  # positive returns a fit needs; sparser scans are pooled until there are enough
SAMPLE_STRIDE = 4  # every 4th return is pooled: 30k of a 120k-point scan
IDENTITY_BAND = 0.25  # a stream median within +-25 % of the training median is already on its scale
CONSTANT_SPREAD = 1e-3  # 5th-95th percentile spread below which a stream's intensity is constant


@dataclass(frozen=True)
class IntensityMap:
    """The held map of one stream: `kind` "matched", "unchanged" (already on the training scale) or "constant";
    `source` the stream's quantiles at `QUANTILES` (matched only), `median` the stream's median positive return."""

    kind: str
    median: float
    scans: int
    source: np.ndarray | None = None

    def apply(self, intensity: np.ndarray) -> np.ndarray:
        """Intensities (N,) on the training scale (a new array when matched, else the input)."""
        if self.kind != "matched" or self.source is None:
            return intensity
        out = np.interp(intensity, self.source, REFERENCE_QUANTILES).astype(intensity.dtype, copy=False)
        return np.where(intensity > 0.0, out, intensity)

    def __str__(self) -> str:
        if self.kind == "matched":
            return (f"matched to the training scale from {self.scans} scan(s): median {self.median:.3g} -> "
                    f"{REFERENCE_QUANTILES[10]:g}")
        if self.kind == "constant":
            return f"constant intensity {self.median:g}, left as it is (stage 2 gets no intensity information)"
        return f"median {self.median:.3g} already on the training scale ({REFERENCE_QUANTILES[10]:g}), left as it is"


def fit_map(positive: np.ndarray, scans: int) -> IntensityMap:
    """The map of a stream whose pooled positive returns are `positive`."""
    source = np.percentile(positive, QUANTILES)
    median = float(source[10])
    if source[19] - source[1] < CONSTANT_SPREAD:
        return IntensityMap("constant", median, scans)
    if abs(median / REFERENCE_QUANTILES[10] - 1.0) <= IDENTITY_BAND:
        return IntensityMap("unchanged", median, scans)
    # Quantised drivers repeat values (8-bit: 1/255 steps); interpolation needs strictly rising support points.
    source = np.maximum.accumulate(source) + np.arange(len(source)) * 1e-7
    return IntensityMap("matched", median, scans, source)


class StreamIntensityMatch:
    """Fits one stream's map on its first scans, then holds it; `apply` maps each scan.

    Until the map is held, each scan is mapped with the fit of the scans so far (the first scan's own map on the
    first scan), so the first frames are not judged on a foreign scale.
    """

    def __init__(self) -> None:
        self.map: IntensityMap | None = None
        self._pool: list[np.ndarray] = []
        self._scans = 0

    @property
    def held(self) -> bool:
        """Whether the map is final for this stream."""
        return self.map is not None and self._scans >= FIT_SCANS

    def update(self, intensity: np.ndarray) -> IntensityMap | None:
        """Fold one scan's intensities (0..1) into the fit while it is open; returns the map on the scan that
        makes it held (the caller reports it once), else None."""
        if self.held:
            return None
        sample = intensity[::SAMPLE_STRIDE]
        positive = sample[np.isfinite(sample) & (sample > 0.0)]
        self._pool.append(positive.astype(np.float32, copy=False))
        self._scans += 1
        pooled = np.concatenate(self._pool)
        if len(pooled) < MIN_RETURNS // SAMPLE_STRIDE and self._scans < FIT_SCANS:
            return None
        if len(pooled) == 0:
            self.map = IntensityMap("constant", 0.0, self._scans)
        else:
            self.map = fit_map(pooled, self._scans)
        if self._scans < FIT_SCANS:
            return None
        self._pool = []
        return self.map

    def apply(self, intensity: np.ndarray) -> np.ndarray:
        """This scan's intensities on the training scale (unchanged before the first fit)."""
        return intensity if self.map is None else self.map.apply(intensity)

    def fold(self, points: np.ndarray) -> tuple[np.ndarray, IntensityMap | None]:
        """One scan of the stream: its intensities folded into the fit (`update`), and the points on the training
        scale (`on_training_scale`); the map when this scan made it held."""
        held = self.update(points[:, 3])
        return self.on_training_scale(points), held

    def on_training_scale(self, points: np.ndarray) -> np.ndarray:
        """Points (N, 4) with column 3 mapped: a copy when the map changes anything, else `points` itself."""
        if self.map is None or self.map.kind != "matched":
            return points
        mapped = points.copy()
        mapped[:, 3] = self.map.apply(points[:, 3])
        return mapped

    def reset(self) -> None:
        """Start over (another stream)."""
        self.map, self._pool, self._scans = None, [], 0
