"""`pass3d_benchmark live`'s memory summary (no live run: the samples are made up)."""

from __future__ import annotations

import pytest

from pass3d_ros.bench.live import MEMORY_SPAN_S, memory_report


def test_memory_growth_of_a_short_run_compares_disjoint_spans() -> None:
    """Seven seconds after the warm-up, memory rising 10 MiB/s: the "after warm-up" and "at the end" medians used to be
    taken over 10 s each, so both were the median of every sample and the growth read +0.00 % beside a fitted slope of
    +600 MiB/min. Each span is now at most half the window: the first half against the second."""
    samples = [(float(t), 100.0 + 10.0 * t) for t in range(8)]
    report = memory_report(samples, warmup_s=0.0)
    assert report["growth_pct"] == pytest.approx(100.0 * 40.0 / 115.0)
    assert report["after_warmup_mib"] == pytest.approx(115.0) and report["end_mib"] == pytest.approx(155.0)
    assert report["span_s"] == pytest.approx(3.5)
    assert report["slope_mib_per_min"] == pytest.approx(600.0)


def test_memory_growth_of_a_long_run_keeps_its_ten_second_spans() -> None:
    samples = [(float(t), 100.0 + (1.0 if t > 50 else 0.0)) for t in range(61)]
    report = memory_report(samples, warmup_s=0.0)
    assert report["span_s"] == MEMORY_SPAN_S == 10.0
    assert report["after_warmup_mib"] == 100.0 and report["end_mib"] == 101.0 and report["growth_pct"] == 1.0
