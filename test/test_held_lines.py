"""Laser lines held across a stream (pass3d_ros.core.stage1.held_lines.LineHolder), as the cluster node and every
offline tool hold them: one search per stream, a new one for a new stream or when the held lines stop fitting, and a
failed search repeated only after LINE_SEARCH_RETRY_S (offline: counted in scans, not wall time)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from pass3d_ros.core.stage1 import Stage1Config, held_lines, propose, ring, synthetic_scan
from pass3d_ros.core.stage1.held_lines import LineHolder
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.offline import evaluate_stage1


def shuffled(points: np.ndarray, seed: int) -> np.ndarray:
    return np.ascontiguousarray(points[np.random.default_rng(seed).permutation(len(points))])


def no_laser_lines_scan(points: int = 20000, seed: int = 0) -> np.ndarray:
    """Points at random elevations in random order: no ring field, no firing order, no laser lines to find."""
    rng = np.random.default_rng(seed)
    r, az, z = rng.uniform(5, 50, points), rng.uniform(-np.pi, np.pi, points), rng.uniform(-2, 3, points)
    return np.stack([r * np.cos(az), r * np.sin(az), z, rng.uniform(0, 1, points)], 1).astype(np.float32)


@pytest.fixture
def searches(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Records the point count of every laser-line search."""
    calls: list[int] = []
    search: Callable[..., ring.Rings | None] = ring.rings_from_lines

    def counted(points: np.ndarray, sensor: str = "auto") -> ring.Rings | None:
        calls.append(len(points))
        return search(points, sensor)

    monkeypatch.setattr(ring, "rings_from_lines", counted)
    return calls


SCAN64 = synthetic_scan(points_per_ring=900)


def test_a_stream_searches_once_and_reads_the_next_scans_off_the_held_lines(searches: list[int]) -> None:
    expected = propose(shuffled(SCAN64, 0))
    searches.clear()
    holder = LineHolder()
    for k in range(3):
        order = np.random.default_rng(k).permutation(len(SCAN64))
        result = holder.propose(np.ascontiguousarray(SCAN64[order]))
        assert result.ring_source == "elevation_lines" and result.n_proposals == expected.n_proposals
        assert holder.held is not None and len(holder.held.a) == 64
    assert len(searches) == 1


def test_a_new_stream_forgets_the_lines_and_the_same_stream_keeps_them(searches: list[int]) -> None:
    holder = LineHolder()
    for key, seed in (("a", 0), ("a", 1), ("b", 2), ("b", 3), ("a", 4)):
        holder.follow(key)
        holder.propose(shuffled(SCAN64, seed))
    assert len(searches) == 3  # a, then b, then a again
    holder.reset()
    assert holder.held is None and holder.lines() is None


def test_held_lines_that_stop_fitting_are_searched_again() -> None:
    """Lines of a 64-laser scan do not fit a 32-laser one: that scan searches and its own 32 lines are held."""
    holder = LineHolder()
    holder.propose(shuffled(SCAN64, 0))
    assert len(holder.held.a) == 64
    scan32 = synthetic_scan(n_rings=32, points_per_ring=900)
    result = holder.propose(shuffled(scan32, 1))
    assert result.ring_source == "elevation_lines" and result.sensor.n_rings == 32
    assert len(holder.held.a) == 32


def test_a_scan_with_a_ring_field_keeps_what_was_held() -> None:
    holder = LineHolder()
    holder.propose(shuffled(SCAN64, 0))
    lines = holder.held
    result = holder.propose(SCAN64, np.repeat(np.arange(64, dtype=np.uint16), 900))  # no lines read or found
    assert result.ring_source == "field" and holder.held is lines


def test_offline_a_failed_search_is_repeated_after_the_retry_time_in_scans(searches: list[int],
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """No clock: each scan counts SCAN_PERIOD_S, so a run's searches do not depend on how fast it runs."""
    monkeypatch.setattr(held_lines, "LINE_SEARCH_RETRY_S", 3 * held_lines.SCAN_PERIOD_S)
    holder = LineHolder()
    pts = no_laser_lines_scan()
    for _ in range(7):
        assert holder.propose(pts).ring_source == "elevation_bins"
    assert len(searches) == 3  # scans 0, 3 and 6


def test_a_clock_times_the_retry() -> None:
    now = [100.0]
    holder = LineHolder(clock=lambda: now[0])
    holder.hold(None, ring.NO_LINES)
    assert holder.lines() is ring.NO_LINES
    now[0] += held_lines.LINE_SEARCH_RETRY_S
    assert holder.lines() is None


def test_evaluate_stage1_holds_lines_per_spec(searches: list[int]) -> None:
    """The evaluator gives each spec's frames the lines held after the frames before, and starts over on a new spec;
    the rows are those of scans searched one by one."""
    scans = [shuffled(SCAN64, seed) for seed in range(5)]
    expected = [propose(s).n_proposals for s in scans]
    frames = [(spec, Frame(f"{k}", scans[k])) for k, spec in enumerate(("a", "a", "a", "b", "b"))]
    summary = evaluate_stage1(iter(frames), Stage1Config())
    assert len([n for n in searches if n == len(SCAN64)]) == 5 + 2  # `expected`, then one per spec (warm-up: tiny)
    assert [row["ring_source"] for row in summary["per_frame"]] == ["elevation_lines"] * 5
    assert [row["proposals"] for row in summary["per_frame"]] == expected


def test_training_samples_hold_the_lines_across_frames(searches: list[int]) -> None:
    """train's sample cache runs stage 1 as a stream too: one search for three shuffled scans."""
    from pass3d_ros.training.samples import build_samples

    frames = [Frame(f"{k}", shuffled(SCAN64, k), labels=np.zeros(len(SCAN64), np.uint8)) for k in range(3)]
    samples = build_samples(frames, progress=False)
    assert len(searches) == 1 and len(samples) > 0
