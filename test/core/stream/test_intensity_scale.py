"""A stream's intensity full scale is decided on several scans, held, changed only on sustained evidence, and
never by a corrupt scan."""

from __future__ import annotations

import numpy as np

from pass3d_ros.core.stream.intensity_scale import FRAMES_TO_LOWER, FRAMES_TO_RAISE, StreamIntensityScale


def scan(high: float, n: int = 20000, seed: int = 0) -> np.ndarray:
    """Intensities spread up to `high`, the way a driver's values are."""
    return np.random.default_rng(seed).uniform(0.0, high, n).astype(np.float32)


def corrupt(n: int = 20000, seed: int = 0) -> np.ndarray:
    """A corrupt cloud's intensities: random float32 bit patterns (huge, tiny, NaN, inf)."""
    return np.random.default_rng(seed).integers(0, 2**32, n, dtype=np.uint32).view(np.float32)


def test_a_16_bit_stream_is_not_rescaled_frame_by_frame() -> None:
    scale = StreamIntensityScale()
    readings = [scale.read(scan(250.0 if k % 2 == 0 else 300.0, seed=k)) for k in range(40)]
    changes = [r.change for r in readings if r.change is not None]
    assert len(changes) == 1, "alternating 250 / 300 must not flip the scale"
    assert str(changes[0]).startswith("full scale none -> 255")
    assert scale.divisor == 255.0
    assert [r.divisor for r in readings[:2]] == [255.0, 65535.0], "before the scale settles a scan is its own"
    assert {r.divisor for r in readings[FRAMES_TO_RAISE + 1:]} == {255.0}


def test_the_first_scans_of_a_stream_are_divided_by_their_own_scale_until_it_settles() -> None:
    scale = StreamIntensityScale()
    readings = [scale.read(scan(255.0, seed=k)) for k in range(FRAMES_TO_RAISE + 1)]
    assert [r.divisor for r in readings] == [255.0] * (FRAMES_TO_RAISE + 1)
    assert [r.provisional for r in readings] == [True] * (FRAMES_TO_RAISE - 1) + [False, False]
    assert [r.change is not None for r in readings] == [False] * (FRAMES_TO_RAISE - 1) + [True, False]
    assert scale.divisor == 255.0


def test_sustained_evidence_raises_the_scale_once_and_it_stays() -> None:
    scale = StreamIntensityScale()
    for k in range(FRAMES_TO_RAISE):
        scale.read(scan(250.0, seed=k))
    readings = [scale.read(scan(3000.0, seed=k)) for k in range(10)]
    assert [k for k, r in enumerate(readings) if r.change is not None] == [FRAMES_TO_RAISE - 1]
    assert scale.divisor == 65535.0
    assert "255 -> 65535" in str(readings[FRAMES_TO_RAISE - 1].change)
    assert all(scale.read(scan(200.0, seed=k)).change is None for k in range(FRAMES_TO_LOWER - 1))
    assert scale.divisor == 65535.0, "a few dark scans do not lower it"


def test_one_absurd_return_does_not_scale_the_scan() -> None:
    scale = StreamIntensityScale()
    values = scan(255.0)
    values[123] = 1e6
    assert scale.read(values).divisor == 255.0


def test_a_unit_stream_keeps_divisor_one_and_empty_scans_change_nothing() -> None:
    scale = StreamIntensityScale()
    reading = scale.read(np.array([np.nan, np.inf], np.float32))
    assert reading.implausible and reading.divisor == 1.0 and scale.divisor is None
    for k in range(FRAMES_TO_RAISE + 5):
        assert scale.read(scan(1.0, seed=k), in_unit_range=True).divisor == 1.0
    assert scale.divisor == 1.0


def test_one_corrupt_cloud_changes_no_later_scan() -> None:
    """The hostile case: a 0..1 stream, one cloud of garbage bytes, then 70 good scans: every good scan after it is
    divided by 1, as before it (it was 49 of 70 read as all 0 when the garbage set the scale at once)."""
    scale = StreamIntensityScale()
    for k in range(5):
        scale.read(scan(1.0, seed=k), in_unit_range=True)
    bad = scale.read(corrupt())
    assert bad.implausible and bad.divisor == 1.0 and bad.change is None
    assert all(scale.read(scan(1.0, seed=k), in_unit_range=True).divisor == 1.0 for k in range(70))
    assert scale.divisor == 1.0


def test_a_finite_but_absurd_scan_is_no_evidence_even_at_the_start() -> None:
    scale = StreamIntensityScale()
    bright = scan(3.9e37)
    reading = scale.read(bright)
    assert "beyond any sensor's range" in reading.implausible and reading.divisor == 1.0
    assert scale.read(scan(255.0)).divisor == 255.0, "the next plausible scan is read on its own"
    assert scale.divisor is None


def test_a_corrupt_scan_does_not_break_a_rise_in_progress() -> None:
    scale = StreamIntensityScale()
    for k in range(FRAMES_TO_RAISE):
        scale.read(scan(1.0, seed=k), in_unit_range=True)
    scale.read(scan(255.0, seed=1))
    scale.read(corrupt())
    readings = [scale.read(scan(255.0, seed=k)) for k in range(FRAMES_TO_RAISE - 1)]
    assert readings[-1].change is not None and scale.divisor == 255.0
