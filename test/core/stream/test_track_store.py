"""The tracks' rows (pass3d_ros.core.stream.track_store): the vote over a sliding window as a plain list votes, rows
reused fresh, rows kept as the arrays grow."""

from __future__ import annotations

from collections import deque

import numpy as np

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.stream.track_store import FIRST_ROWS, MIN_WEIGHT, Track, TrackStore


def _plain_vote(sightings: list[tuple[int, float]], window: int) -> tuple[int, float]:
    """The vote as the module docstring words it, over a plain window (weights kept as it slides, as the store does:
    the same sums in the same order)."""
    votes: deque = deque(maxlen=window)
    weight = [0.0] * NUM_CLASSES
    for label, confidence in sightings:
        if len(votes) == window:
            gone, old = votes[0]
            weight[gone] -= max(old, MIN_WEIGHT)
        votes.append((label, confidence))
        weight[label] += max(confidence, MIN_WEIGHT)
    oldest = votes[0][0]
    best = max(range(NUM_CLASSES), key=weight.__getitem__)
    label = oldest if weight[oldest] >= weight[best] else best
    total = sum(weight)
    return label, weight[label] / total if total else 0.0


def _new(store: TrackStore, track_id: int, label: int, confidence: float) -> int:
    return store.new(track_id, np.array([1.0, 2.0, 0.0, 0.0]), np.eye(4), 0.5, np.array([4.0, 1.7, 1.5]), label,
                     confidence, 0.0)


def test_the_vote_is_the_plain_windows_vote_sighting_by_sighting() -> None:
    rng = np.random.default_rng(7)
    store = TrackStore(window=5)
    for track in range(20):
        sightings = [(int(rng.integers(0, NUM_CLASSES)), float(rng.choice([0.0, 0.3, 0.5, 0.9, 1.0])))
                     for _ in range(int(rng.integers(1, 15)))]
        slot = _new(store, track, *sightings[0])
        for k in range(1, len(sightings) + 1):
            if k > 1:
                label, confidence = sightings[k - 1]
                store.see(np.array([slot]), np.zeros((1, 3)), np.ones((1, 3)), np.array([label]),
                          np.array([confidence]), 0.1 * k, 2)
            got_label, got_score = store.voted(np.array([slot]))
            assert (int(got_label[0]), float(got_score[0])) == _plain_vote(sightings[:k], 5)


def test_a_reused_row_starts_fresh_and_rows_survive_the_arrays_growing() -> None:
    store = TrackStore(window=3)
    slots = [_new(store, k, 1, 0.8) for k in range(FIRST_ROWS + 5)]  # more rows than made at first
    assert len(set(slots)) == FIRST_ROWS + 5
    store.see(np.array(slots[:3]), np.zeros((3, 3)), np.ones((3, 3)), np.array([2, 2, 2]), np.array([0.9] * 3), 0.1, 2)
    store.offsets[slots[0], :4] = 1.0
    store.points[slots[0]] = 4
    first = Track(0, slots[0], store)
    assert first.hits == 2 and first.offsets is not None and first.offsets.shape == (4, 2)
    assert Track(FIRST_ROWS + 4, slots[-1], store).state.tolist() == [1.0, 2.0, 0.0, 0.0]
    store.release([slots[0]])
    again = Track(99, _new(store, 99, 3, 0.6), store)
    assert again.slot == slots[0], "a released row is used again"
    assert again.hits == 1 and again.misses == 0 and again.offsets is None
    assert again.label() == 3 and again.score() == 1.0 and again.confidence() == 0.6
    assert int(store.track_id[again.slot]) == 99
