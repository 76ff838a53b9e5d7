"""What the cluster node checks in every input scan before stage 1: coordinates a LiDAR could return, and
intensities the core can read as 0..1. The segmentation node applies the same coordinate limits to its input.

A normal scan passes every check, so the node reads one `ScanSummary` (a single pass over the points, about a
tenth of the separate NumPy reductions it replaces) and only a scan that fails one looks further.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

MAX_COORDINATE_M = 1e4  # no LiDAR return is farther: a larger |x|, |y| or |z| is a broken driver or message
INTENSITY_TOLERANCE = 1e-3  # rounding slack on the 0..1 range, relative to the full scale


@dataclass(frozen=True)
class ScanSummary:
    """One pass over an N x 4 (x, y, z, intensity) scan: what the node's checks need."""

    points: int
    plausible: bool  # every x, y, z finite and within MAX_COORDINATE_M
    nonfinite_intensity: int  # intensities that are NaN or infinite
    intensity_low: float  # smallest and largest finite intensity (inf, -inf when there is none)
    intensity_high: float
    no_returns: int = 0  # points at (0, 0, 0) or nearer than the scan's min_range: a driver's "no return"

    def scaled(self, scale: float) -> ScanSummary:
        """The summary after the intensities were multiplied by `scale` >= 0 (float32 rounding is monotone)."""
        low, high = self.intensity_low, self.intensity_high
        if self.points > self.nonfinite_intensity:
            low, high = float(np.float32(low) * np.float32(scale)), float(np.float32(high) * np.float32(scale))
        return ScanSummary(self.points, self.plausible, self.nonfinite_intensity, low, high, self.no_returns)

    def intensity_problem(self) -> str:
        """Why the intensities cannot be the 0..1 the core expects; "" when they can."""
        if self.nonfinite_intensity:
            return f"{self.nonfinite_intensity} values are not finite"
        low, high = self.intensity_low, self.intensity_high
        if self.points and (low < -INTENSITY_TOLERANCE or high > 1.0 + INTENSITY_TOLERANCE):
            return f"values {low:.4g}..{high:.4g}"
        return ""

    def constant_intensity(self) -> bool:
        """Whether every point of a (non-trivial) scan reads the same finite intensity."""
        return self.points > 1 and not self.nonfinite_intensity and self.intensity_low == self.intensity_high


@numba.njit(cache=True, nogil=True)
def _summary_kernel(points: np.ndarray, limit: float, near2: float) -> tuple:
    plausible = True
    nonfinite = 0
    no_returns = 0
    low, high = np.inf, -np.inf
    for k in range(points.shape[0]):
        r2 = 0.0
        for axis in range(3):
            value = points[k, axis]
            if not (-limit <= value <= limit):  # NaN fails both comparisons
                plausible = False
            r2 += float(value) * float(value)
        if r2 < near2 or r2 == 0.0:
            no_returns += 1
        value = points[k, 3]
        if np.isfinite(value):
            low = min(low, float(value))
            high = max(high, float(value))
        else:
            nonfinite += 1
    return plausible, nonfinite, low, high, no_returns


def scan_summary(points: np.ndarray, min_range: float = 0.0) -> ScanSummary:
    """The `ScanSummary` of N x 4 float32 points; `no_returns` counts those at the origin or nearer than
    `min_range` (m)."""
    plausible, nonfinite, low, high, no_returns = _summary_kernel(points, MAX_COORDINATE_M, min_range * min_range)
    return ScanSummary(len(points), bool(plausible), int(nonfinite), float(low), float(high), int(no_returns))


def returns(points: np.ndarray, min_range: float = 0.0) -> np.ndarray:
    """True for the points a LiDAR returned: not at (0, 0, 0), where drivers put a no-return, nor nearer than
    `min_range` (m: the vehicle, the mount); coordinates assumed plausible."""
    r2 = np.einsum("ij,ij->i", points[:, :3].astype(np.float64), points[:, :3].astype(np.float64))
    return (r2 >= min_range * min_range) & (r2 > 0.0)


def plausible_points(points: np.ndarray) -> np.ndarray:
    """True for points whose x, y, z are finite and within MAX_COORDINATE_M."""
    with np.errstate(invalid="ignore"):
        return (np.abs(points[:, :3]) <= MAX_COORDINATE_M).all(axis=1)


def dropped_points_warning(dropped: int) -> str:
    """The warning for a scan whose `dropped` implausible points (see `plausible_points`) were left out."""
    return (f"x/y/z: dropping {dropped} points with non-finite or absurd coordinates (expected finite, |value| <= "
            f"{MAX_COORDINATE_M:g} m)")


def intensity_divisor(high: float) -> float:
    """What a driver's intensity range is divided by to give 0..1, from its largest value: 1 for 0..1, 255 for an
    8-bit driver (Velodyne), 65535 for 16-bit reflectivity (Ouster), else the largest value itself."""
    for full_scale in (1.0, 255.0, 65535.0):
        if high <= full_scale + INTENSITY_TOLERANCE * full_scale:
            return full_scale
    return high


def unit_intensity(intensity: np.ndarray, divisor: float) -> np.ndarray:
    """0..1 intensities from a driver's: non-finite values read 0, the rest are divided by `divisor` (the
    `intensity_divisor` of the scan's largest finite value) and clipped."""
    values = np.nan_to_num(intensity, nan=0.0, posinf=0.0, neginf=0.0)
    if divisor != 1.0:
        values = values / divisor
    return np.clip(values, 0.0, 1.0).astype(np.float32)


def warm_up() -> None:
    """Compile the summary kernel (numba's disk cache after the first time)."""
    scan_summary(np.zeros((2, 4), np.float32))
