"""`pass3d_benchmark codec` / `layout`'s timer: what it times."""

from __future__ import annotations

import time

from pass3d_ros.bench.codec import time_ms


def test_time_ms_leaves_the_first_call_untimed() -> None:
    """The first call of a codec function compiles or loads numba kernels (decode_xyzi: about 0.6 s against 0.7 ms);
    the median of a few repeats used to be that compile time. Now one untimed call comes first, then `repeat` timed."""
    calls = []

    def slow_first() -> int:
        calls.append(1)
        if len(calls) == 1:
            time.sleep(0.3)
        return len(calls)

    median, low = time_ms(slow_first, 2)
    assert len(calls) == 3 and median < 100.0 and low <= median
