"""A stream's intensity full scale is decided once, held, and changed only on sustained evidence."""

from __future__ import annotations

import numpy as np

from pass3d_ros.ros.intensity_scale import FRAMES_TO_LOWER, FRAMES_TO_RAISE, StreamIntensityScale


def scan(high: float, n: int = 20000, seed: int = 0) -> np.ndarray:
    """Intensities spread up to `high`, the way a driver's values are."""
    return np.random.default_rng(seed).uniform(0.0, high, n).astype(np.float32)


def test_a_16_bit_stream_is_not_rescaled_frame_by_frame() -> None:
    scale = StreamIntensityScale()
    changes = [scale.update(scan(250.0 if k % 2 == 0 else 300.0, seed=k)) for k in range(40)]
    assert str(changes[0]).startswith("full scale none -> 255")
    assert sum(change is not None for change in changes) == 1, "alternating 250 / 300 must not flip the scale"
    assert scale.divisor == 255.0


def test_sustained_evidence_raises_the_scale_once_and_it_stays() -> None:
    scale = StreamIntensityScale()
    scale.update(scan(250.0))
    changes = [scale.update(scan(3000.0, seed=k)) for k in range(10)]
    assert [k for k, change in enumerate(changes) if change is not None] == [FRAMES_TO_RAISE - 1]
    assert scale.divisor == 65535.0
    assert "255 -> 65535" in str(changes[FRAMES_TO_RAISE - 1])
    assert all(scale.update(scan(200.0, seed=k)) is None for k in range(FRAMES_TO_LOWER - 1))
    assert scale.divisor == 65535.0, "a few dark scans do not lower it"


def test_one_absurd_return_does_not_scale_the_scan() -> None:
    scale = StreamIntensityScale()
    values = scan(255.0)
    values[123] = 1e6
    scale.update(values)
    assert scale.divisor == 255.0


def test_a_unit_stream_keeps_divisor_one_and_empty_scans_change_nothing() -> None:
    scale = StreamIntensityScale()
    assert scale.update(np.array([np.nan, np.inf], np.float32)) is None and scale.divisor is None
    scale.update(scan(1.0))
    assert scale.divisor == 1.0
    assert all(scale.update(scan(1.0, seed=k)) is None for k in range(5))
