"""Laser lines held across a stream (pass3d_ros.core.stream.lines.LineHolder), as the cluster node and every
offline tool hold them: one search per stream, a new one for a new stream or when the held lines stop fitting, and a
failed search repeated after 1, 2, 4, 8 ... scan periods, at most LINE_SEARCH_RETRY_S apart (offline: counted in
scans, not wall time), the count starting over when a search finds lines."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from pass3d_ros.core.stage1 import Stage1Config, propose, ring, synthetic_scan
from pass3d_ros.core.stream import lines as held_lines
from pass3d_ros.core.stream.lines import LineHolder
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

    def counted(points: np.ndarray, sensor: str = "auto", tilted: bool = False) -> ring.Rings | None:
        calls.append(len(points))
        return search(points, sensor, tilted)

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


def searched_scans(holder: LineHolder, scans: list[np.ndarray], searches: list[int]) -> tuple[list[int], list[str]]:
    """Run `scans` through `holder`: the indices of the scans that searched for laser lines, and every ring source."""
    searched, sources = [], []
    for k, points in enumerate(scans):
        before = len(searches)
        sources.append(holder.propose(points).ring_source)
        if len(searches) > before:
            searched.append(k)
    return searched, sources


def test_offline_a_failed_search_is_repeated_after_the_retry_time_in_scans(searches: list[int],
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """No clock: each scan counts SCAN_PERIOD_S, so a run's searches do not depend on how fast it runs; the waits of
    1, 2, 4 ... scans stop growing at LINE_SEARCH_RETRY_S (here 3 scans)."""
    monkeypatch.setattr(held_lines, "LINE_SEARCH_RETRY_S", 3 * held_lines.SCAN_PERIOD_S)
    searched, sources = searched_scans(LineHolder(), [no_laser_lines_scan()] * 10, searches)
    assert searched == [0, 1, 3, 6, 9] and set(sources) == {"elevation_bins"}


def test_failed_searches_back_off_and_one_that_finds_lines_starts_over(monkeypatch: pytest.MonkeyPatch) -> None:
    """A stream whose first three searches find no lines searches on scans 0, 1, 3 and 7 (1, 2 and 4 scans apart),
    bins by elevation in between, and from the search that finds its lines on reads every scan off them."""
    calls: list[int] = []
    search: Callable[..., ring.Rings | None] = ring.rings_from_lines

    def failing_three_times(points: np.ndarray, sensor: str = "auto", tilted: bool = False) -> ring.Rings | None:
        calls.append(len(points))
        return None if len(calls) <= 3 else search(points, sensor, tilted)

    monkeypatch.setattr(ring, "rings_from_lines", failing_three_times)
    holder = LineHolder()
    searched, sources = searched_scans(holder, [shuffled(SCAN64, seed) for seed in range(12)], calls)
    assert searched == [0, 1, 3, 7]
    assert sources == ["elevation_bins"] * 7 + ["elevation_lines"] * 5
    assert holder.failures == 0 and len(holder.held.a) == 64


def test_the_waits_double_from_one_scan_up_to_the_retry_time() -> None:
    """Offline, a stream whose every search fails searches on scans 0, 1, 3, 7 ... 127 (each wait twice the last),
    then every LINE_SEARCH_RETRY_S (100 scans)."""
    holder = LineHolder()
    searched = []
    for k in range(400):
        given = holder.lines()
        if given is None:
            searched.append(k)
        holder.hold(given, ring.NO_LINES)  # a search that found none (given None), else a scan binned without one
    assert searched == [0, 1, 3, 7, 15, 31, 63, 127, 227, 327]
    waits = [held_lines.retry_wait(n) for n in (1, 2, 3, 4, 7, 8, 9, 10**6)]
    assert waits == pytest.approx([0.1, 0.2, 0.4, 0.8, 6.4, 10.0, 10.0, 10.0])


def test_a_clock_times_the_retries_and_found_lines_or_a_new_stream_start_over() -> None:
    now = [100.0]
    holder = LineHolder(clock=lambda: now[0])
    lines = ring.LaserLines(np.array([0.02, -0.02]), np.zeros(2))
    holder.hold(None, ring.NO_LINES)  # the first search finds none
    for wait in (0.1, 0.2, 0.4, 0.8, 1.6):
        now[0] += wait - 0.01
        assert holder.lines() is ring.NO_LINES  # too early: binned by elevation, no search
        holder.hold(ring.NO_LINES, ring.NO_LINES)  # a scan binned without a search changes nothing
        now[0] += 0.01
        assert holder.lines() is None  # time to search again ...
        holder.hold(None, ring.NO_LINES)  # ... and that search finds none either
    assert holder.failures == 6
    holder.hold(None, lines)
    assert holder.failures == 0 and holder.lines() is lines
    holder.hold(lines, ring.NO_LINES)  # the held lines stopped fitting and a new search found none: wait 1 again
    now[0] += 0.09
    assert holder.lines() is ring.NO_LINES
    now[0] += 0.01
    assert holder.lines() is None
    for _ in range(20):
        holder.hold(None, ring.NO_LINES)
    now[0] += held_lines.LINE_SEARCH_RETRY_S - 0.01
    assert holder.lines() is ring.NO_LINES  # the waits stop growing at LINE_SEARCH_RETRY_S
    now[0] += 0.01
    assert holder.lines() is None
    holder.follow("another stream")
    assert holder.failures == 0 and holder.held is None


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


def test_a_binned_stream_reads_its_laser_spacing_once_until_it_searches_again(
        monkeypatch: pytest.MonkeyPatch, searches: list[int]) -> None:
    """Rings that fall back to elevation bins take the laser spacing read on the stream's first binned scan; a new
    line search (after the retry wait) reads it afresh, and every scan's result reports the spacing it ran with."""
    from pass3d_ros.core.stage1 import sensor_params

    reads: list[float] = []
    spacing = sensor_params.laser_spacing

    def counted(points: np.ndarray) -> float:
        reads.append(spacing(points))
        return reads[-1]

    monkeypatch.setattr(sensor_params, "laser_spacing", counted)
    holder = LineHolder()
    scans = [no_laser_lines_scan(seed=k) for k in range(4)]
    results = [holder.propose(scan) for scan in scans]
    assert all(r.ring_source == "elevation_bins" for r in results)
    assert len(searches) == 3 and len(reads) == 3  # scans 0, 1 and 3 search (retry waits of 1 and 2 scans)
    assert results[2].sensor.spacing_deg is results[1].sensor.spacing_deg or (
        np.isnan(results[2].sensor.spacing_deg) and np.isnan(results[1].sensor.spacing_deg))
    holder.reset()
    holder.propose(scans[0])
    assert len(reads) == 4, "a new stream reads its own"


def test_a_stream_reads_its_sensors_resolution_every_tenth_scan_and_when_the_rings_change(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The sensor's angular resolution and laser elevations are read on a stream's first scan and given to the next
    ones (the results run with the values read), read again after SCALE_REREAD_SCANS scans, when a scan's rings differ
    in number, and on a new stream."""
    from pass3d_ros.core.stage1 import sensor_params

    reads: list[int] = []
    resolutions = sensor_params.resolutions

    def counted(points: np.ndarray, ring_field: np.ndarray) -> tuple[float, float]:
        reads.append(len(points))
        return resolutions(points, ring_field)

    monkeypatch.setattr(sensor_params, "resolutions", counted)
    holder, scan = LineHolder(), synthetic_scan()
    results = [holder.propose(scan) for _ in range(held_lines.SCALE_REREAD_SCANS + 1)]
    assert len(reads) == 2, "scans 0 and SCALE_REREAD_SCANS read, the others are given scan 0's"
    assert [r.sensor.read_here for r in results] == [True] + [False] * (held_lines.SCALE_REREAD_SCANS - 1) + [True]
    assert all(r.sensor.resolution is results[0].sensor.resolution for r in results[1:-1])
    assert all(r.sensor == results[0].sensor for r in results)  # the same scan runs with the same values
    fewer = synthetic_scan(n_rings=32)
    assert holder.propose(fewer).sensor.read_here, "other rings: the scan reads its own"
    holder.follow("another stream")
    assert holder.propose(scan).sensor.read_here
    assert len(reads) == 4
