"""A driver's ring field put in stage 1's ring order (ring 0 = the highest laser), measured from the points.

Drivers number their lasers in different orders: `velodyne_pointcloud` and Hesai's driver count ring 0 as the lowest
laser, Ouster as the top beam, and some drivers in firing order. Scan-line-run clustering links each ring to its
neighbour below, so a field read in the wrong direction links every ring to the one above it: on real KITTI frames
it halved car IoU without a warning. So the order is measured once per stream: the median elevation (tan, z over
horizontal range) of each ring value's points, ring 0 the highest. A field already numbered top-down is used as it
is; bottom-up is mirrored; any other order is ranked by elevation. A field whose points do not sit on one elevation
per value (a random or broken field) does not fit the scan and is ignored: the rings are recovered from the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from pass3d_ros.core.stage1.scanline import nearer_of_two
from pass3d_ros.msgs.errors import Pass3dError

RING_CONVENTIONS: tuple[str, ...] = ("top_down", "bottom_up", "driver_order", "unfit")
MIN_RANGE_M = 2.0  # nearer returns (the vehicle, the mount) are left out of a ring's elevation
MIN_RING_POINTS = 3  # a ring value needs this many returns beyond MIN_RANGE_M, else all of its points are read
MIN_FIT_SHARE = 0.5  # share of returns whose elevation is nearest to their own ring's or a neighbour's for the field
# to fit: >= 0.9 on real HDL-64E, Ouster and Hesai scans; a random field scores about 5 / rings
ONE_LASER_DEG = 2.0  # a field of one measured value fits the returns within this of its median elevation (one laser,
# off the origin by a few centimetres); a driver that fills the field with one value for every laser fits none
NEIGHBOURS = 2  # rings either side of a return's own that still count as fitting it (KITTI's lasers sit off the
# origin, so a near return's elevation can read a ring or two away)


@dataclass(frozen=True)
class RingFieldOrder:
    """How one stream's ring field maps to stage 1's rings (ring 0 = highest laser), held across its scans.

    `table[value]` is the stage-1 ring of a field value (-1: not measured yet); None with `top_down` (the field as
    it is) and with `unfit` (the field is ignored). `n_values`: field values at or above it were not measured."""

    convention: str
    table: np.ndarray | None
    n_values: int
    fit_share: float

    @property
    def fits(self) -> bool:
        """Whether the field is used (else the rings are recovered from the points)."""
        return self.convention != "unfit"

    def rings(self, ring: np.ndarray) -> np.ndarray | None:
        """The stage-1 rings (uint16) of a scan's field values; None when the field is ignored (`unfit`).
        Raises `UnmeasuredRingError` for a value this order has not measured (the caller measures this scan)."""
        if not self.fits:
            return None
        if len(ring) == 0:
            return ring.astype(np.uint16, copy=False)
        if int(ring.max()) >= self.n_values or (np.issubdtype(ring.dtype, np.signedinteger) and int(ring.min()) < 0):
            raise UnmeasuredRingError
        if self.table is None:
            return ring.astype(np.uint16, copy=False)
        mapped = self.table[ring]
        if int(mapped.min()) < 0:
            raise UnmeasuredRingError
        return mapped.astype(np.uint16)


class UnmeasuredRingError(Pass3dError):
    """A ring field value the held order never saw: the order is measured again."""


def field_rings(points: np.ndarray, ring: np.ndarray, held: RingFieldOrder | None = None
                ) -> tuple[np.ndarray | None, RingFieldOrder]:
    """A scan's ring field in stage 1's order (None: the field does not fit and is ignored), and the order used:
    `held` (a stream's earlier scan's) while it covers the field's values, else one measured on this scan."""
    if held is not None:
        try:
            return held.rings(ring), held
        except UnmeasuredRingError:
            pass
    order = measure_ring_order(points, ring)
    return order.rings(ring), order


def _ring_elevations(r: np.ndarray, tan: np.ndarray, ring: np.ndarray, n_values: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Median tan(elevation) of every ring value's returns beyond MIN_RANGE_M (horizontal range `r`), and whether it
    had MIN_RING_POINTS there (else the median of all its returns off the origin; NaN for a value with none).
    `ring` holds values 0 .. n_values - 1."""
    off_origin = r.dtype.type(0.1)  # compared in r's own precision, as numpy compares an array with a float
    return _elevations_kernel(r, tan, ring, n_values, float(MIN_RANGE_M), off_origin, MIN_RING_POINTS)


@nb.njit(cache=True, nogil=True)
def _elevations_kernel(r: np.ndarray, tan: np.ndarray, ring: np.ndarray, n_values: int, min_range: float,
                       off_origin: float, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    """`_ring_elevations` in one pass: the returns grouped by ring value (a counting sort), each group's median
    selected (numpy's: the middle value, or the mean of the two middle values in tan's own precision). Per-value
    numpy medians took 1.5 ms of a 28k-point HDL-32E scan."""
    n = ring.shape[0]
    start = np.zeros(n_values + 1, dtype=np.int64)
    for i in range(n):
        start[ring[i] + 1] += 1
    for v in range(n_values):
        start[v + 1] += start[v]
    fill = start[:n_values].copy()
    members = np.empty(n, dtype=np.int64)
    for i in range(n):
        members[fill[ring[i]]] = i
        fill[ring[i]] += 1
    medians = np.full(n_values, np.nan)
    well = np.zeros(n_values, dtype=np.bool_)
    buf = np.empty(n, dtype=tan.dtype)
    for v in range(n_values):
        m = _beyond(members[start[v]:start[v + 1]], r, tan, min_range, buf)
        well[v] = m >= min_points
        if not well[v]:
            m = _beyond(members[start[v]:start[v + 1]], r, tan, off_origin, buf)
        if m > 0:
            half = m // 2
            if m % 2:
                medians[v] = np.partition(buf[:m], half)[half]
            else:
                part = np.partition(buf[:m], (half - 1, half))
                medians[v] = (part[half - 1] + part[half]) / 2
    return medians, well


@nb.njit(cache=True, nogil=True)
def _beyond(members: np.ndarray, r: np.ndarray, tan: np.ndarray, reach: float, buf: np.ndarray) -> int:
    """Copy the `tan` of the `members` farther than `reach` into `buf`, in order; how many."""
    m = 0
    for i in members:
        if r[i] > reach:
            buf[m] = tan[i]
            m += 1
    return m


def _fit_share(r: np.ndarray, tan: np.ndarray, ring: np.ndarray, medians: np.ndarray, measured: np.ndarray
               ) -> float:
    """Share of the returns beyond MIN_RANGE_M (of `measured` ring values) whose elevation is nearest to the median
    of their own ring value or of one within NEIGHBOURS rings of it in elevation order; with one measured value, of
    those within ONE_LASER_DEG of its median (a field of one value on a scan of many lasers does not fit)."""
    if len(measured) == 0:
        return 1.0
    if len(measured) == 1:
        far = (r > MIN_RANGE_M) & (ring == measured[0])
        if not far.any():
            return 1.0
        off = np.abs(np.arctan(tan[far]) - np.arctan(medians[measured[0]]))
        return float(np.mean(off <= np.deg2rad(ONE_LASER_DEG)))
    by_elevation = measured[np.argsort(medians[measured])]
    levels = medians[by_elevation]
    rank = np.zeros(len(medians), dtype=np.int64)
    rank[by_elevation] = np.arange(len(by_elevation))
    is_measured = np.zeros(len(medians), dtype=bool)
    is_measured[measured] = True
    fitting, far = _fit_counts(r, tan, ring, is_measured, levels, rank, float(MIN_RANGE_M), NEIGHBOURS)
    return 1.0 if far == 0 else fitting / far


@nb.njit(cache=True, nogil=True)
def _fit_counts(r: np.ndarray, tan: np.ndarray, ring: np.ndarray, is_measured: np.ndarray, levels: np.ndarray,
                rank: np.ndarray, min_range: float, neighbours: int) -> tuple[int, int]:
    """`_fit_share`'s counts in one pass (numpy's masks, searchsorted and comparisons took 0.8 ms of a 28k-point
    scan): the returns beyond `min_range` of measured values whose nearest level (`levels` ascending; the lower one
    on a tie) is within `neighbours` ranks of their own, and all of those returns."""
    fitting = 0
    far = 0
    for i in range(ring.shape[0]):
        if not (r[i] > min_range and is_measured[ring[i]]):
            continue
        far += 1
        nearest = nearer_of_two(levels, np.float64(tan[i]))
        if abs(nearest - rank[ring[i]]) <= neighbours:
            fitting += 1
    return fitting, far


def measure_ring_order(points: np.ndarray, ring: np.ndarray) -> RingFieldOrder:
    """The `RingFieldOrder` of a scan's ring field, measured from its points (N x >=3, finite coordinates)."""
    ring = np.asarray(ring).astype(np.int64, copy=False)
    if len(ring) == 0:
        return RingFieldOrder("top_down", None, 0, 1.0)
    if int(ring.min()) < 0:
        return RingFieldOrder("unfit", None, 0, 0.0)
    n_values = int(ring.max()) + 1
    r = np.hypot(points[:, 0], points[:, 1])
    tan = points[:, 2] / np.maximum(r, 1e-3)
    medians, well = _ring_elevations(r, tan, ring, n_values)
    measured = np.flatnonzero(well)  # the order is decided on these; near-only rings follow their near median
    share = _fit_share(r, tan, ring, medians, measured)
    if share < MIN_FIT_SHARE:
        return RingFieldOrder("unfit", None, n_values, share)
    by_elevation = measured[np.argsort(-medians[measured], kind="stable")]  # highest first
    if np.array_equal(by_elevation, measured):
        return RingFieldOrder("top_down", None, n_values, share)
    table = np.full(n_values, -1, dtype=np.int64)
    if np.array_equal(by_elevation, measured[::-1]):
        table[:] = n_values - 1 - np.arange(n_values)
        return RingFieldOrder("bottom_up", table, n_values, share)
    located = np.flatnonzero(np.isfinite(medians))
    by_elevation = located[np.argsort(-medians[located], kind="stable")]
    table[by_elevation] = np.arange(len(by_elevation))
    present = np.unique(ring)
    unmeasured = present[table[present] < 0]  # only returns at the origin: placed after the measured rings
    table[unmeasured] = len(by_elevation) + np.arange(len(unmeasured))
    return RingFieldOrder("driver_order", table, n_values, share)
