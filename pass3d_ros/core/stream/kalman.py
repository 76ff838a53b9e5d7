"""The tracker's filter: a constant-velocity Kalman filter on a box centre in the ground plane (x, y, vx, vy; AB3DMOT's
model reduced to the plane stage 1 levels the scan into), for many tracks at once. Compiled loops: a scan's 60 tracks
cost microseconds, where numpy's batched 4 x 4 products cost a few hundred (their overhead, not their arithmetic)."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def predict_rows(rows: np.ndarray, states: np.ndarray, covs: np.ndarray, stamps: np.ndarray, stamp_s: float,
                 max_dt: float, accel: float) -> None:
    """Carry the `rows` of `states` (x, y, vx, vy) and `covs` (4 x 4) to `stamp_s` from their `stamps` (at most
    `max_dt` ahead, never back), in place, their stamps set to it; white acceleration of spread `accel` (m/s^2) is the
    process noise."""
    for r in rows:
        _predict(states[r], covs[r], min(max(stamp_s - stamps[r], 0.0), max_dt), accel * accel)
        stamps[r] = stamp_s


@nb.njit(cache=True, nogil=True)
def _predict(state: np.ndarray, p: np.ndarray, h: float, a2: float) -> None:
    """One state (4,) and covariance (4, 4) `h` seconds ahead (`predict_rows`)."""
    state[0] += h * state[2]
    state[1] += h * state[3]
    for i in range(4):  # P F^T: column 0 += h * column 2, column 1 += h * column 3
        p[i, 0] += h * p[i, 2]
        p[i, 1] += h * p[i, 3]
    for j in range(4):  # F (P F^T): row 0 += h * row 2, row 1 += h * row 3
        p[0, j] += h * p[2, j]
        p[1, j] += h * p[3, j]
    q4, q3, q2 = a2 * h ** 4 / 4, a2 * h ** 3 / 2, a2 * h * h
    for axis in range(2):
        p[axis, axis] += q4
        p[axis, axis + 2] += q3
        p[axis + 2, axis] += q3
        p[axis + 2, axis + 2] += q2


@nb.njit(cache=True, nogil=True)
def correct_rows(rows: np.ndarray, states: np.ndarray, covs: np.ndarray, measured: np.ndarray, noise: float,
                 view: np.ndarray) -> None:
    """Correct the `rows` of `states` and `covs` by their measured centres (`measured`, one per row, in order) of
    variance `noise`, in place. Where `view` (one per row) is above 0 the centre is a new view of the object: the
    position's link to the velocity is cut first and the position made uncertain by `view` more (where the old view's
    centre was says little of where this one's is), so the centre corrects the position and not the velocity."""
    for t in range(len(rows)):
        _correct(states[rows[t]], covs[rows[t]], measured[t, 0], measured[t, 1], noise, view[t])


@nb.njit(cache=True, nogil=True)
def correct_moved_rows(rows: np.ndarray, states: np.ndarray, covs: np.ndarray, moved: np.ndarray,
                       measured: np.ndarray, noise: float, view: np.ndarray) -> None:
    """`correct_rows` for new views whose object's move was read apart from its box centre (`moved`: where the
    object's points say it is, one per row): that corrects position and velocity first, then the new view's centre
    (`measured`, `view`) the position alone. A parked car's velocity learns it stands still although each view moves
    its box centre."""
    for t in range(len(rows)):
        _correct(states[rows[t]], covs[rows[t]], moved[t, 0], moved[t, 1], noise, 0.0)
        _correct(states[rows[t]], covs[rows[t]], measured[t, 0], measured[t, 1], noise, view[t])


@nb.njit(cache=True, nogil=True)
def _correct(state: np.ndarray, p: np.ndarray, x: float, y: float, noise: float, view: float) -> None:
    """One state (4,) and covariance (4, 4) corrected by the centre (x, y) (`correct_rows`)."""
    gain = np.empty((4, 2))
    top = np.empty((2, 4))
    if view > 0.0:
        for i in range(2):
            p[i, i] += view
            for j in range(2, 4):
                p[i, j] = 0.0
                p[j, i] = 0.0
    s00, s01, s10, s11 = p[0, 0] + noise, p[0, 1], p[1, 0], p[1, 1] + noise
    det = s00 * s11 - s01 * s10
    i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
    for i in range(4):
        gain[i, 0] = p[i, 0] * i00 + p[i, 1] * i10
        gain[i, 1] = p[i, 0] * i01 + p[i, 1] * i11
    r0, r1 = x - state[0], y - state[1]
    for i in range(4):
        state[i] += gain[i, 0] * r0 + gain[i, 1] * r1
    top[:, :] = p[:2, :]
    for i in range(4):
        for j in range(4):
            p[i, j] -= gain[i, 0] * top[0, j] + gain[i, 1] * top[1, j]
