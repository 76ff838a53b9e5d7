"""Stage-1 parameters that follow the sensor: the paper's point-count gate is an HDL-64E fact.

An object at range r shows about (height / (r * dv)) * (width / (r * dh)) points, dv and dh the sensor's vertical and
horizontal angular resolution. PASS3D's th_num (about 30 points near the sensor) was chosen for KITTI's HDL-64E at
10 Hz; a 32-laser sensor spinning at 20 Hz sees an object with about a sixth of those points and would keep none of
them. So each frame runs with an *effective config* (`effective_config`), computed from the config and the rings that
ring recovery found:

* dv: the median elevation gap between neighbouring rings (elevation of a ring: the median over its points of a
  sample), dh: the median azimuth step between neighbouring points of a ring, both read from the scan itself.
  Rings binned by elevation are not lasers (64 bins span any sensor), so there dv is the median gap between the
  peaks of a fine elevation histogram (`laser_spacing`), when the peaks hold the scan; else the bins' guess.
* density = (REFERENCE_DV / dv) * (REFERENCE_DH / dh), each factor snapped to exactly 1 when within SNAP of it, so
  the HDL-64E keeps the paper's values bit for bit, and at most 1: a denser scan keeps them too (two merged
  VLP-32C binned by elevation read as 3x denser than they are, and a higher th_num would only lose objects).
* th_num_near scales by density; th_num_floor too, never below MIN_FLOOR (a cluster needs two points for a
  box) unless configured lower.
* With `Stage1Config.range_scaling` and lasers (not elevation bins) the vertical part of th_num_near's factor is
  read per range, and for a tilted sensor per azimuth, too (`RangeGate`): the lasers that cross a person-tall object
  (OBJECT_HEIGHT_M) standing on the ground there, from the sensor's height above the fitted ground, over the same
  count for KITTI's HDL-64E at 1.73 m, where that is under half of the median-gap factor. A sensor mounted high sees
  a near person with its lower lasers, which on most sensors are the sparse ones (a VLP-32C at 3.5 m: 3 lasers on a
  person 15 m away, the HDL-64E at 1.73 m 20), and a tilted one with its sparse upper lasers on one side; the median
  gap (0.33 degrees, denser than the HDL-64E) cannot say so.

Left as configured, measured on a real HDL-32E frame (nuScenes, true rings, th_num scaled): th_prop widened to the
ring spacing (2 or 3 m instead of 1 m) merged objects with their neighbours (foreground recall 0.73 -> 0.68),
as did a wider th_ring (0.5 -> 1.0 m: 0.73 -> 0.66); sensor_height only bounds the ground seeds from below and
gives the fallback plane, and the ground fit follows the road wherever it is (Argoverse's road at z = -0.3 m).
With `Stage1Config.sensor_scaling` off, the config is used as it is.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import NamedTuple

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.config import MOUNT_HEIGHT_RANGE_M, Stage1Config
from pass3d_ros.core.stage1.lasers import LASER_TABLES
from pass3d_ros.core.stage1.scanline import group_starts, nearer_of_two

REFERENCE_DV_DEG = 0.42  # KITTI's HDL-64E: median elevation gap between neighbouring rings (this module's estimate)
REFERENCE_DH_DEG = 0.17  # KITTI's HDL-64E at 10 Hz: median azimuth step between neighbouring points of a ring
SNAP = 0.25  # a resolution ratio within this of 1 counts as 1 (the paper's values, exactly)
MIN_FLOOR = 2  # th_num_floor never falls below this
OBJECT_HEIGHT_M = 1.76  # `RangeGate`: the object whose lasers are counted, KITTI's mean pedestrian height
REFERENCE_HEIGHT_M = 1.73  # KITTI's HDL-64E above the road
RANGE_STEP_M = 0.5  # `RangeGate`: the factor's range bins
RANGE_TABLE_M = 150.0  # `RangeGate`: the last bin (farther clusters read it)
MIN_RING_SAMPLES = 8  # `ring_elevations`: a ring needs this many sampled points at PEAK_MIN_RANGE or farther
AZIMUTH_SECTORS = 16  # `range_gate` of a tilted sensor: level-frame azimuth sectors read apart
TILT_AZIMUTHS = 360  # `level_elevations`: directions a laser's cone is read at
RANGE_REPLACES_BELOW = 0.5  # `range_gate`: a range's laser count replaces the median-gap factor only under this share
# of it: counts of one to a few lasers move with the lasers' exact angles (rule G: a level HDL-32E's per-range factor
# 0.27-0.38 against its median gap's 0.32, the gate up and down by chance)
_SAMPLE_STRIDE = 16  # the estimates read every 16th point (and its successor)
_MIN_RANGE = 2.0  # nearer points are left out of the estimates (m)
PEAK_BIN_DEG = 0.05  # `laser_spacing`: the elevation histogram's bin
PEAK_MIN_RANGE = 5.0  # `laser_spacing` reads points this far or farther: nearer elevations are bent by the lasers'
# offsets from the sensor's origin (m)
MIN_PEAKS = 8  # fewer peaks than this say nothing about the lasers
MIN_PEAK_SHARE = 0.8  # share of the points within a quarter gap of a peak for the peaks to be lasers: 0.94-0.99 on
# HDL-32E, Pandar64 and Ouster scans, 0.14-0.16 on two merged VLP-32C (no common origin), 0.42-0.62 on KITTI's HDL-64E
# (its two laser blocks); 0.5 on uniform elevations


@dataclass(frozen=True)
class SensorScale:
    """What a frame's scan says about its sensor and the stage-1 values it runs with."""

    n_rings: int
    vertical_deg: float  # median elevation gap between neighbouring rings (nan when unknown)
    horizontal_deg: float  # median azimuth step between neighbouring points of a ring (nan when unknown)
    density: float  # points per object relative to KITTI's HDL-64E (1.0: the paper's values)
    th_num_near: float
    th_num_floor: int
    th_prop: float
    spacing_deg: float | None = field(default=None, compare=False)  # `laser_spacing` of binned rings (nan: no lasers
    # found; None: not read): a stream's holder passes it to its next scans' `effective_config` (`spacing`). Not
    # compared: it says how vertical_deg was read, not what the frame runs with
    resolution: tuple[float, float] | None = field(default=None, compare=False)  # what `resolutions` read (or was
    # given): a stream's holder may pass it on as `effective_config`'s `resolution`. Not compared, as spacing_deg
    elevations_deg: np.ndarray | None = field(default=None, compare=False, repr=False)  # with range_scaling, the
    # lasers' elevations (`ring_elevations`) that `range_gate` counts; None: th_num_near holds the vertical factor
    vertical_factor: float = field(default=1.0, compare=False)  # with elevations_deg, the vertical part of density
    # (density over its horizontal factor): what `range_gate` compares the per-range laser counts with
    read_here: bool = field(default=True, compare=False)  # False: resolution and elevations_deg were an earlier
    # scan's, given (`effective_config`'s `resolution`); a holder counts the scans since they were read

    def describe(self) -> str:
        """One line for logs: resolutions, density and the effective values."""
        per_range = "" if self.elevations_deg is None else " (less where few lasers cross a person)"
        return (f"{self.n_rings} rings, vertical {self.vertical_deg:.2f} deg, "
                f"horizontal {self.horizontal_deg:.3f} deg, density {self.density:.3f} x HDL-64E: "
                f"th_num_near {self.th_num_near:.3g}{per_range}, "
                f"th_num_floor {self.th_num_floor}, th_prop {self.th_prop:.3g}")


class RangeGate(NamedTuple):
    """The few-points gate's factor per azimuth sector and range (`range_gate`; on th_num_near as `effective_config`
    scaled it, 1 where the median gap holds): `factor[k, i]` for clusters
    centred in the level frame's azimuth sector k (of `len(factor)` equal sectors from -180 degrees; one for a level
    sensor) and [i * RANGE_STEP_M, (i + 1) * RANGE_STEP_M) away, the last bin for any farther."""

    factor: np.ndarray

    def at(self, rng: np.ndarray, xy: np.ndarray | None = None) -> np.ndarray:
        """The factor at horizontal ranges `rng` (m), for clusters centred in the directions `xy` (level frame, any
        positive multiple of the centres; needed with sectors)."""
        factor = np.atleast_2d(self.factor)
        index = np.clip((np.asarray(rng) / RANGE_STEP_M).astype(np.int64), 0, factor.shape[1] - 1)
        if len(factor) == 1:
            return factor[0, index]
        return factor[azimuth_sector(xy[:, 0], xy[:, 1], len(factor)), index]


def azimuth_sector(x: np.ndarray, y: np.ndarray, sectors: int) -> np.ndarray:
    """Which of `sectors` equal azimuth sectors from -180 degrees each direction (x, y) lies in."""
    return np.floor((np.arctan2(y, x) + np.pi) / (2.0 * np.pi) * sectors).astype(np.int64) % sectors


_RANGES_M = (np.arange(int(RANGE_TABLE_M / RANGE_STEP_M) + 1) + 0.5) * RANGE_STEP_M


def lasers_across(elevations_deg: np.ndarray, height_m: float) -> np.ndarray:
    """Per `RangeGate` bin, how many of the lasers (elevations in degrees from the sensor's horizontal plane) cross
    an OBJECT_HEIGHT_M tall object standing on the ground `height_m` below the sensor at the bin's range; with rows
    of elevations (one set of lasers per row), a row of counts each."""
    elevations = np.sort(np.atleast_2d(np.asarray(elevations_deg, dtype=np.float64)), axis=1)
    low = np.degrees(np.arctan2(-height_m, _RANGES_M))
    high = np.degrees(np.arctan2(OBJECT_HEIGHT_M - height_m, _RANGES_M))
    counts = np.stack([np.searchsorted(row, high, "right") - np.searchsorted(row, low, "left") for row in elevations])
    return counts if np.ndim(elevations_deg) > 1 else counts[0]


_REFERENCE_ACROSS = lasers_across(np.asarray(LASER_TABLES["hdl64e"]), REFERENCE_HEIGHT_M)


def level_elevations(elevations_deg: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Each laser's elevation (degrees) in the level frame of a tilted sensor (`level`: the rotation from the sensor's
    frame to the level one), per AZIMUTH_SECTORS sector of the level frame (S x L; a sector no direction reaches
    keeps the laser's own elevation): a laser's cone, tilted, runs higher on one side than the other."""
    e = np.radians(np.asarray(elevations_deg, dtype=np.float64))
    a = np.linspace(-np.pi, np.pi, TILT_AZIMUTHS, endpoint=False)
    r = np.asarray(level, dtype=np.float64)
    cos_e, sin_e = np.cos(e)[:, None], np.sin(e)[:, None]
    cos_a, sin_a = np.cos(a)[None, :], np.sin(a)[None, :]
    turned = [cos_e * (r[k, 0] * cos_a + r[k, 1] * sin_a) + r[k, 2] * sin_e for k in range(3)]  # x, y, z: (L, A) each
    elevation = np.degrees(np.arcsin(np.clip(turned[2], -1.0, 1.0)))
    sector = azimuth_sector(turned[0], turned[1], AZIMUTH_SECTORS)
    cell = (sector * len(e) + np.arange(len(e))[:, None]).ravel()  # (sector, laser), sector-major
    sums = np.bincount(cell, weights=elevation.ravel(), minlength=AZIMUTH_SECTORS * len(e)).reshape(AZIMUTH_SECTORS, -1)
    counts = np.bincount(cell, minlength=AZIMUTH_SECTORS * len(e)).reshape(AZIMUTH_SECTORS, -1)
    own = np.broadcast_to(np.degrees(e), sums.shape)
    return np.where(counts > 0, sums / np.maximum(counts, 1.0), own)


def ring_elevations(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """The elevation (degrees) of each ring with MIN_RING_SAMPLES or more sampled points at PEAK_MIN_RANGE or
    farther: the median over its points of every _SAMPLE_STRIDE-th point (points in the sensor's frame)."""
    pts = np.asarray(points)[::_SAMPLE_STRIDE]
    rings = np.asarray(ring)[::_SAMPLE_STRIDE]
    horizontal = np.hypot(pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64))
    far = horizontal >= PEAK_MIN_RANGE
    elevation = np.degrees(np.arctan2(pts[far, 2].astype(np.float64), horizontal[far]))
    rings = rings[far].astype(np.int64)
    if not len(rings):
        return np.zeros(0)
    return _lower_medians(elevation, rings, int(rings.max()) + 1, MIN_RING_SAMPLES)


@nb.njit(cache=True, nogil=True)
def _lower_medians(values: np.ndarray, group: np.ndarray, n_groups: int, least: int) -> np.ndarray:
    """The lower median of the `values` of each group (0 .. n_groups - 1) holding `least` or more, in group order:
    a counting sort and a selection per group (a lexsort of the whole sample took twice as long)."""
    start = group_starts(group, n_groups)
    grouped = np.empty(len(values), dtype=np.float64)
    fill = start[:n_groups].copy()
    for s in range(len(values)):
        grouped[fill[group[s]]] = values[s]
        fill[group[s]] += 1
    out = np.empty(n_groups, dtype=np.float64)
    n = 0
    for k in range(n_groups):
        count = start[k + 1] - start[k]
        if count >= least:
            middle = (count - 1) // 2
            out[n] = np.partition(grouped[start[k]:start[k + 1]], middle)[middle]
            n += 1
    return out[:n]


def range_gate(scale: SensorScale | None, planes: np.ndarray, segment_edges: np.ndarray,
               level: np.ndarray | None = None) -> RangeGate | None:
    """The frame's `RangeGate` from its lasers (`scale.elevations_deg`) and the sensor's height above the fitted
    ground plane under it (clipped to the mount heights the config accepts); None without lasers. At each range the
    lasers across the object over the HDL-64E's (half a laser added to both: far bins hold none) replace the
    median-gap factor (`scale.vertical_factor`) where they are under RANGE_REPLACES_BELOW of it; elsewhere the
    median-gap factor stays (a factor of 1 on th_num_near, which holds it). So the gate never rises, and the HDL-64E,
    read at its own height, keeps the paper's.
    `level` (a tilted sensor's levelling rotation): the lasers are counted per azimuth sector at their elevations in
    the level frame (`level_elevations`)."""
    if scale is None or scale.elevations_deg is None or len(planes) == 0:
        return None
    segment = int(np.clip(np.searchsorted(segment_edges, 0.0) - 1, 0, len(planes) - 1))
    c, d = planes[segment, 2:]
    height = float(np.clip(d / c, *MOUNT_HEIGHT_RANGE_M)) if c > 0 else REFERENCE_HEIGHT_M
    per_sector = scale.elevations_deg if level is None else level_elevations(scale.elevations_deg, level)
    counts = np.atleast_2d(lasers_across(per_sector, height))
    across = (counts + 0.5) / (_REFERENCE_ACROSS + 0.5)  # not capped: vertical_factor may exceed 1 (a dense sensor
    # spinning slowly keeps the paper's gate by its lasers, density = min(1, vertical x horizontal))
    median_gap = scale.vertical_factor
    return RangeGate(np.where(across < RANGE_REPLACES_BELOW * median_gap, across / median_gap, 1.0))


def resolutions(points: np.ndarray, ring: np.ndarray) -> tuple[float, float]:
    """(vertical, horizontal) angular resolution in degrees of a scan in scan order (each ring's points together,
    in azimuth order): the median elevation gap between neighbouring non-empty rings and the median azimuth step
    between neighbouring points of one ring, from every _SAMPLE_STRIDE-th point; nan where the scan cannot tell."""
    if len(points) < 2:
        return float("nan"), float("nan")
    pts = np.ascontiguousarray(points, dtype=np.float32)
    rings = np.ascontiguousarray(ring, dtype=np.uint16)
    vertical, horizontal = _resolutions_kernel(pts, rings, int(rings.max()) + 1, _SAMPLE_STRIDE, _MIN_RANGE)
    return float(vertical), float(horizontal)


def laser_spacing(points: np.ndarray) -> float:
    """The median elevation gap (degrees) between the lasers of a scan in any point order: the peaks of an elevation
    histogram (PEAK_BIN_DEG bins, lightly smoothed; a peak counts once the histogram falls to half of the lower of it
    and the previous one between them). nan unless MIN_PEAKS or more peaks hold MIN_PEAK_SHARE of the points within
    a quarter of that gap: lines seen from the sensor's own origin, not merged sensors or a shifted frame. It reads
    every point: a stride would alias with a driver's interleaved lasers (every 4th point of a 32-laser firing order
    holds 8 of its lasers), and the answer must not depend on the points' order."""
    pts = np.asarray(points)
    horizontal = np.hypot(pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64))
    far = horizontal >= PEAK_MIN_RANGE
    if np.count_nonzero(far) < 10 * MIN_PEAKS:
        return float("nan")
    elevation = np.degrees(np.arctan2(pts[far, 2].astype(np.float64), horizontal[far]))
    lo, hi = np.percentile(elevation, [0.2, 99.8])
    edges = np.arange(lo, hi + PEAK_BIN_DEG, PEAK_BIN_DEG)
    counts = _histogram(elevation, edges) if len(edges) >= 2 else np.zeros(0, dtype=np.int64)
    if len(counts) < 3:
        return float("nan")
    smooth = np.convolve(counts, [0.25, 0.5, 0.25], mode="same")
    tops = np.flatnonzero((smooth[1:-1] > smooth[:-2]) & (smooth[1:-1] >= smooth[2:])) + 1
    peaks: list[int] = []
    for top in tops:
        if peaks and smooth[peaks[-1]:top + 1].min() > 0.5 * min(smooth[peaks[-1]], smooth[top]):
            if smooth[top] > smooth[peaks[-1]]:  # no valley between them: one laser, at the higher top
                peaks[-1] = int(top)
            continue
        peaks.append(int(top))
    if len(peaks) < MIN_PEAKS:
        return float("nan")
    centres = edges[np.asarray(peaks)] + 0.5 * PEAK_BIN_DEG
    gap = float(np.median(np.diff(centres)))
    if _near_peaks(elevation, centres, 0.25 * gap) / len(elevation) < MIN_PEAK_SHARE:
        return float("nan")
    return gap


@nb.njit(cache=True, nogil=True)
def _histogram(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """np.histogram(values, bins=edges)'s counts (edges ascending, nearly evenly spaced; the last bin closed): each
    value's bin guessed from the spacing and settled by comparisons with the edges, as numpy's binary search settles
    it (numpy sorts the values first: 4.4 of laser_spacing's 12.7 ms on a 120k-point scan)."""
    n_bins = edges.shape[0] - 1
    counts = np.zeros(n_bins, dtype=np.int64)
    first = edges[0]
    last = edges[n_bins]
    step = (last - first) / n_bins
    for i in range(values.shape[0]):
        v = values[i]
        if not (v >= first and v <= last):
            continue
        k = min(max(int((v - first) / step), 0), n_bins - 1)
        while k > 0 and edges[k] > v:
            k -= 1
        while k < n_bins - 1 and edges[k + 1] <= v:
            k += 1
        counts[k] += 1
    return counts


@nb.njit(cache=True, nogil=True)
def _near_peaks(elevation: np.ndarray, centres: np.ndarray, tolerance: float) -> int:
    """How many elevations lie within `tolerance` of the nearest of `centres` (ascending, at least 2): the nearer of
    the two centres around numpy's searchsorted position, as `laser_spacing` read it with numpy."""
    near = 0
    for i in range(elevation.shape[0]):
        e = elevation[i]
        if abs(e - centres[nearer_of_two(centres, e)]) <= tolerance:
            near += 1
    return near


@nb.njit(cache=True, nogil=True)
def _resolutions_kernel(pts: np.ndarray, ring: np.ndarray, n_rings: int, stride: int,
                        min_range: float) -> tuple[float, float]:
    """`resolutions` in one pass over the sample: the azimuth steps to each sampled point's successor in its ring,
    and the sampled elevations grouped by ring (a counting sort), each ring's median (the upper one of an even
    count) selected from its group. Medians are taken over z / r and over a key of each step, which order as the
    angles do, and only the medians are turned into angles (the arc tangents were most of the time)."""
    n_sample = (pts.shape[0] - 2) // stride + 1
    steps = np.empty(n_sample, dtype=np.float64)
    elev = np.empty(n_sample, dtype=np.float64)
    elev_ring = np.empty(n_sample, dtype=np.int64)
    n_steps = 0
    n_elev = 0
    for s in range(n_sample):
        i = s * stride
        x = np.float64(pts[i, 0])
        y = np.float64(pts[i, 1])
        r = np.hypot(x, y)
        if r < min_range:
            continue
        elev[n_elev] = np.float64(pts[i, 2]) / r
        elev_ring[n_elev] = ring[i]
        n_elev += 1
        if ring[i + 1] == ring[i]:
            x1 = np.float64(pts[i + 1, 0])
            y1 = np.float64(pts[i + 1, 1])
            cross = abs(x * y1 - y * x1)
            dot = x * x1 + y * y1
            if cross > 0.0 or dot < 0.0:
                steps[n_steps] = _step_key(cross, dot)
                n_steps += 1
    horizontal = np.nan
    if n_steps > 0:
        middle = n_steps // 2
        keys = np.partition(steps[:n_steps], (max(middle - 1, 0), middle))
        upper = _step_angle(keys[middle])
        horizontal = np.degrees(upper if n_steps % 2 else 0.5 * (_step_angle(keys[middle - 1]) + upper))
    start = group_starts(elev_ring[:n_elev], n_rings)
    grouped = np.empty(n_elev, dtype=np.float64)
    fill = start[:n_rings].copy()
    for s in range(n_elev):
        k = elev_ring[s]
        grouped[fill[k]] = elev[s]
        fill[k] += 1
    gaps = np.empty(n_rings, dtype=np.float64)
    n_gaps = 0
    last_ring = -1
    last_median = 0.0
    for k in range(n_rings):
        count = start[k + 1] - start[k]
        if count == 0:
            continue
        group = np.partition(grouped[start[k]:start[k + 1]], count // 2)
        median = np.degrees(np.arctan(group[count // 2]))
        if last_ring >= 0:
            gaps[n_gaps] = abs(median - last_median) / (k - last_ring)
            n_gaps += 1
        last_ring = k
        last_median = median
    if n_gaps == 0:
        return np.nan, horizontal
    return np.median(gaps[:n_gaps]), horizontal


@nb.njit(cache=True, nogil=True, inline="always")
def _step_key(cross: float, dot: float) -> float:
    """A key in [0, 2] that orders azimuth steps (|cross|, dot: the sines and cosines of their angles, scaled) as the
    angles do: cross / (cross + dot) below 90 degrees, 1 + -dot / (cross - dot) from there to 180."""
    if dot > 0.0:
        return cross / (cross + dot)
    return 1.0 - dot / (cross - dot)


@nb.njit(cache=True, nogil=True, inline="always")
def _step_angle(key: float) -> float:
    """The step angle (radians) of a `_step_key`."""
    if key < 1.0:
        return np.arctan2(key, 1.0 - key)
    return 0.5 * np.pi + np.arctan2(key - 1.0, 2.0 - key)


def _ratio(reference: float, measured: float) -> float:
    """reference / measured, snapped to 1 within SNAP; 1 when the scan could not tell."""
    if not np.isfinite(measured) or measured <= 0.0:
        return 1.0
    ratio = reference / measured
    return 1.0 if abs(ratio - 1.0) <= SNAP else ratio


def effective_config(config: Stage1Config, points: np.ndarray, ring: np.ndarray,
                     n_rings: int, binned: bool = False, spacing: float | None = None,
                     resolution: tuple[float, float] | None = None,
                     elevations: np.ndarray | None = None) -> tuple[Stage1Config, SensorScale]:
    """The config a frame runs with (module docstring) and what it was derived from. `points` and `ring` in scan
    order; `binned`: the rings are elevation bins, not lasers (the vertical resolution is then `laser_spacing`'s
    where it reads one). `spacing`: `laser_spacing` of binned rings read before, on an earlier scan of the same
    sensor (its `SensorScale.spacing_deg`, nan included): used as it is instead of reading this scan's (6 ms on a
    120k-point scan; the lasers' spacing is the sensor's, not the frame's). `resolution`: `resolutions`' (vertical,
    horizontal) read before (an earlier scan's `SensorScale.resolution`), used instead of reading this scan's (0.2-0.4
    ms on a KITTI scan): the frame then runs with the earlier scan's values, the same wherever both snap to the
    paper's. `elevations`: `ring_elevations` read before (an earlier scan's `SensorScale.elevations_deg`), used
    instead of reading this scan's (0.3 ms). The config itself is returned (not a copy) when nothing changes."""
    read_here = resolution is None
    if read_here:
        resolution = resolutions(points, ring)
    vertical, horizontal = (float(v) for v in resolution)
    if binned:
        spacing = laser_spacing(points) if spacing is None else float(spacing)
        vertical = spacing if np.isfinite(spacing) else vertical
    else:
        spacing = None
    density, vertical_factor, lasers = 1.0, 1.0, None
    if config.sensor_scaling:
        density = min(1.0, _ratio(REFERENCE_DV_DEG, vertical) * _ratio(REFERENCE_DH_DEG, horizontal))
        if config.range_scaling and not binned:
            lasers = ring_elevations(points, ring) if elevations is None else elevations
            if len(lasers) >= MIN_PEAKS:  # `range_gate` may read the vertical factor per range
                vertical_factor = density / min(1.0, _ratio(REFERENCE_DH_DEG, horizontal))
            else:
                lasers = None
    cfg = config
    if density != 1.0:  # both values stay in their ranges (density <= 1), so the copy is not validated again
        cfg = copy.copy(config)
        cfg.th_num_near = max(1.0, config.th_num_near * density)
        cfg.th_num_floor = max(min(MIN_FLOOR, config.th_num_floor), round(config.th_num_floor * density))
    scale = SensorScale(n_rings, vertical, horizontal, density, cfg.th_num_near, cfg.th_num_floor, cfg.th_prop, spacing,
                        resolution, lasers, vertical_factor, read_here)
    return cfg, scale
