"""The tracker's filter (pass3d_ros.core.stream.kalman): the compiled loops over rows give the textbook matrix
formulas."""

from __future__ import annotations

import numpy as np

from pass3d_ros.core.stream import kalman


def _random(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    half = rng.normal(size=(count, 4, 4))
    return rng.normal(size=(count, 4)), half @ half.transpose(0, 2, 1) + np.eye(4)


def test_predict_is_f_p_f_transposed_plus_q() -> None:
    rng = np.random.default_rng(0)
    states, covs = _random(rng, 5)
    dt = rng.uniform(0.0, 1.0, 5)
    want_states, want_covs = [], []
    for x, p, h in zip(states, covs, dt, strict=True):
        f = np.eye(4)
        f[0, 2] = f[1, 3] = h
        q = np.zeros((4, 4))
        for axis in range(2):
            q[axis, axis], q[axis + 2, axis + 2] = 9.0 * h ** 4 / 4, 9.0 * h ** 2
            q[axis, axis + 2] = q[axis + 2, axis] = 9.0 * h ** 3 / 2
        want_states.append(f @ x)
        want_covs.append(f @ p @ f.T + q)
    stamps = -dt  # carried to 0.0: dt ahead
    rows = np.array([0, 1, 2, 4])  # row 3 stays where it is
    before = states[3].copy()
    kalman.predict_rows(rows, states, covs, stamps, 0.0, 10.0, 3.0)
    assert np.allclose(states[rows], np.array(want_states)[rows]) and np.allclose(covs[rows], np.array(want_covs)[rows])
    assert np.array_equal(states[3], before) and np.all(stamps[rows] == 0.0)


def test_correct_is_the_kalman_update_and_a_new_view_leaves_the_velocity() -> None:
    rng = np.random.default_rng(1)
    states, covs = _random(rng, 4)
    measured = rng.normal(size=(4, 2))
    h = np.zeros((2, 4))
    h[0, 0] = h[1, 1] = 1.0
    want_states, want_covs = [], []
    for x, p, z in zip(states, covs, measured, strict=True):
        gain = p @ h.T @ np.linalg.inv(h @ p @ h.T + 0.09 * np.eye(2))
        want_states.append(x + gain @ (z - h @ x))
        want_covs.append((np.eye(4) - gain @ h) @ p)
    velocity = states[:, 2:].copy()
    view = np.array([0.0, 0.0, 0.0, 4.0])
    kalman.correct_rows(np.arange(4), states, covs, measured, 0.09, view)
    assert np.allclose(states[:3], want_states[:3]) and np.allclose(covs[:3], want_covs[:3])
    assert np.allclose(states[3, 2:], velocity[3]), "a new view corrects the position only"
    assert np.linalg.norm(states[3, :2] - measured[3]) < np.linalg.norm(want_states[3][:2] - measured[3])
