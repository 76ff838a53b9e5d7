"""The per-stream intensity map onto the training scale (pass3d_ros.core.stream.intensity_match)."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.stream import ScanStream
from pass3d_ros.core.stream import intensity_match as im
from pass3d_ros.core.stream.intensity_match import REFERENCE_QUANTILES, StreamIntensityMatch, fit_map
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.synthetic.sensor import SENSOR_NAMES


def training_like(rng: np.random.Generator, n: int) -> np.ndarray:
    """Draws from the reference distribution (piecewise uniform between its quantiles), 10 % zeros."""
    u = rng.uniform(0.0, 100.0, n)
    values = np.interp(u, im.QUANTILES, REFERENCE_QUANTILES).astype(np.float32)
    values[rng.random(n) < 0.1] = 0.0
    return values


def test_reference_is_the_generators_distribution() -> None:
    """The stored quantiles are those of today's synthetic scans (every sensor): a change to the generator's
    intensity model that moves them must update the table (and says the shipped weights saw another scale)."""
    pooled = []
    for sensor in SENSOR_NAMES:  # as the table was made: 2 scans of seed 0 each, 60,000 returns a sensor
        scans = [generate_frame(0, index, sensor=sensor).points[:, 3] for index in range(2)]
        positive = np.concatenate([s[s > 0] for s in scans])
        pooled.append(np.random.default_rng(0).choice(positive, 60000))
    measured = np.percentile(np.concatenate(pooled), im.QUANTILES)
    assert np.abs(measured[1:-1] - REFERENCE_QUANTILES[1:-1]).max() <= 0.03, np.round(measured, 3).tolist()


@pytest.mark.parametrize("gain, gamma", [(0.15, 1.0), (0.6, 2.0), (2.5, 0.7)])
def test_a_darker_or_brighter_sensor_is_mapped_back(gain: float, gamma: float) -> None:
    rng = np.random.default_rng(1)
    original = training_like(rng, 200_000)
    sensor = np.clip(gain * original.astype(np.float64) ** gamma, 0.0, 1.0).astype(np.float32)
    stream = StreamIntensityMatch()
    for _ in range(im.FIT_SCANS):
        stream.update(sensor)
    assert stream.held and stream.map is not None and stream.map.kind == "matched"
    mapped = stream.apply(sensor)
    assert mapped.dtype == np.float32
    assert np.all(mapped[original == 0.0] == 0.0)  # no echo strength stays none
    unclipped = sensor < 1.0
    assert np.abs(mapped - original)[unclipped].mean() < 0.02
    order = np.argsort(sensor, kind="stable")
    assert np.all(np.diff(mapped[order]) >= 0)  # the order of returns never changes


def test_a_sensor_on_the_training_scale_is_left_alone() -> None:
    values = training_like(np.random.default_rng(2), 50_000) * 0.9  # KITTI's HDL-64E: median 0.30 vs 0.31
    fitted = fit_map(values[values > 0], 5)
    assert fitted.kind == "unchanged" and fitted.apply(values) is values
    constant = np.ones(10_000, dtype=np.float32)  # a driver without intensity
    fitted = fit_map(constant, 5)
    assert fitted.kind == "constant" and fitted.apply(constant) is constant
    assert "constant" in str(fitted)


def test_the_map_is_held_after_the_first_scans() -> None:
    rng = np.random.default_rng(3)
    stream = StreamIntensityMatch()
    dark = training_like(rng, 40_000) * 0.1
    reports = [stream.update(dark) for _ in range(im.FIT_SCANS)]
    assert reports[:-1] == [None] * (im.FIT_SCANS - 1) and reports[-1] is not None  # told once, when held
    held = stream.map
    assert stream.update(training_like(rng, 40_000)) is None and stream.map is held  # a bright scene: same map
    assert stream.on_training_scale(np.zeros((4, 4), np.float32)).shape == (4, 4)
    stream.reset()
    assert stream.map is None and not stream.held


def test_first_scan_is_mapped_before_the_map_is_held() -> None:
    stream = StreamIntensityMatch()
    dark = training_like(np.random.default_rng(4), 40_000) * 0.1
    assert stream.update(dark) is None and not stream.held
    assert stream.map is not None and stream.map.kind == "matched"
    points = np.zeros((len(dark), 4), np.float32)
    points[:, 3] = dark
    mapped = stream.on_training_scale(points)
    assert mapped is not points and np.median(mapped[dark > 0, 3]) == pytest.approx(REFERENCE_QUANTILES[10], abs=0.02)
    assert np.array_equal(points[:, 3], dark)  # the caller's points are untouched


def test_offline_streams_follow_the_spec_and_match_only_when_asked() -> None:
    rng = np.random.default_rng(5)
    points = np.zeros((40_000, 4), np.float32)
    points[:, 3] = training_like(rng, 40_000) * 0.1
    stream = ScanStream()
    stream.follow("a")
    assert stream.on_training_scale(points) is not points
    assert stream.match.map.kind == "matched"
    bright = points.copy()
    bright[:, 3] *= 10
    stream.follow("b")
    assert stream.on_training_scale(bright) is bright and "already on the training scale" in str(stream.match.map)
    off = ScanStream(intensity_match=False)
    assert off.on_training_scale(points) is points
