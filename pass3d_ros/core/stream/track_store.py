"""Every track's numbers in one stream's arrays, a row (slot) per track: its filter state, box, counts and the vote of
its recent sightings. A scan's predictions, corrections, sightings and votes are then one compiled call or one numpy
operation over the rows it touches, not one Python call per track (at 60 tracks those calls were half the tracker's
time). `Track` is one track's view of its row; a slot is reused once its track is forgotten.

The vote: a track's class is the confidence-weighted vote of its last `window` sightings (each weighs its confidence,
at least MIN_WEIGHT); the window's weight per class is kept as it slides (added as a sighting comes, taken off as it
leaves); the oldest sighting's class wins a tie; the score is the voted class's share of the weight.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.stream.footprints import MAX_POINTS

MIN_WEIGHT = 1e-3  # a sighting's least weight in the vote (a confidence of 0 still counts)
FIRST_ROWS = 64  # rows made at first; twice as many each time they are all used
FOOTPRINT_POINTS = 2 * MAX_POINTS  # a track's remembered footprint points at most


class TrackStore:
    """The rows of a stream's tracks (module docstring). Arrays per row: `state` (x, y, vx, vy), `cov` (4 x 4),
    `stamp` (s), `z`, `box` (length, width, height), `hits`, `misses`, `held`, `hold_from`, and the vote: the window's
    classes and confidences (`votes`, `confidences`; a ring from `first`, `count` long), `weight` per class, the
    voted `label` (-1: to vote again) and its `score`; its `track_id`; the footprint it carries: its last points' x, y
    less its centre (`offsets`, the first `points` of the row; none: no points yet)."""

    state: np.ndarray
    cov: np.ndarray
    stamp: np.ndarray
    z: np.ndarray
    box: np.ndarray
    hits: np.ndarray
    misses: np.ndarray
    held: np.ndarray
    hold_from: np.ndarray
    votes: np.ndarray
    confidences: np.ndarray
    first: np.ndarray
    count: np.ndarray
    weight: np.ndarray
    label: np.ndarray
    score: np.ndarray
    track_id: np.ndarray
    offsets: np.ndarray
    points: np.ndarray

    def __init__(self, window: int) -> None:
        self.window = window
        self.free: list[int] = []
        self.rows = 0
        self._grow(FIRST_ROWS)

    def _fields(self) -> list[tuple[str, tuple[int, ...], type, float]]:
        """Each array's name, shape of one row, type and the value of a row not yet used."""
        one = ()
        return [("state", (4,), np.float64, 0), ("cov", (4, 4), np.float64, 0), ("stamp", one, np.float64, 0),
                ("z", one, np.float64, 0), ("box", (3,), np.float64, 0), ("hits", one, np.int64, 0),
                ("misses", one, np.int64, 0), ("held", one, np.int64, 0), ("hold_from", one, np.int64, 0),
                ("votes", (self.window,), np.int64, 0), ("confidences", (self.window,), np.float64, 0),
                ("first", one, np.int64, 0), ("count", one, np.int64, 0), ("weight", (NUM_CLASSES,), np.float64, 0),
                ("label", one, np.int64, -1), ("score", one, np.float64, 0), ("track_id", one, np.int64, 0),
                ("offsets", (FOOTPRINT_POINTS, 2), np.float64, 0), ("points", one, np.int64, 0)]

    def _grow(self, rows: int) -> None:
        """Room for `rows` rows, the rows in use kept."""
        for name, shape, dtype, fill in self._fields():
            grown = np.full((rows, *shape), fill, dtype)
            old = getattr(self, name, None)
            if old is not None:
                grown[:len(old)] = old
            setattr(self, name, grown)

    def new(self, track_id: int, state: np.ndarray, cov: np.ndarray, z: float, box: np.ndarray, label: int,
            confidence: float, stamp_s: float) -> int:
        """A row for a new track seen once (its first sighting's class and confidence), its slot."""
        if self.free:
            slot = self.free.pop()
        else:
            if self.rows == len(self.state):
                self._grow(2 * len(self.state))
            slot = self.rows
            self.rows += 1
        self.state[slot], self.cov[slot], self.stamp[slot], self.z[slot], self.box[slot] = state, cov, stamp_s, z, box
        self.track_id[slot] = track_id
        self.hits[slot], self.misses[slot], self.held[slot], self.hold_from[slot], self.points[slot] = 1, 0, 0, 0, 0
        self.first[slot] = self.count[slot] = 0
        self.weight[slot] = 0.0
        slots = np.array([slot])
        sight(slots, np.array([label]), np.array([confidence]), self.votes, self.confidences, self.first, self.count,
              self.weight, self.label, MIN_WEIGHT)
        return slot

    def see(self, slots: np.ndarray, centers: np.ndarray, sizes: np.ndarray, labels: np.ndarray,
            confidences: np.ndarray, stamp_s: float, confirmed_at: int) -> int:
        """A sighting of each track of `slots` (its detection's centre, box, class and confidence): height, box and
        stamp set, the vote's window moved on, one more hit, no miss, not held. Says how many reached `confirmed_at`
        hits with it."""
        return _see(slots, np.ascontiguousarray(centers, dtype=np.float64), np.ascontiguousarray(sizes, np.float64),
                    labels, confidences, stamp_s, confirmed_at, self.z, self.box, self.stamp, self.hits, self.misses,
                    self.held, self.votes, self.confidences, self.first, self.count, self.weight, self.label)

    def release(self, slots: list[int]) -> None:
        """Forget the tracks of `slots`: their rows are free for new tracks."""
        self.free.extend(slots)

    def voted(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The voted class and score of the tracks of `slots`, each voted again where a sighting came since."""
        vote(slots, self.votes, self.first, self.weight, self.label, self.score)
        return self.label[slots], self.score[slots]

    def confidences_of(self, slots: np.ndarray) -> np.ndarray:
        """The mean confidence of each track's recent sightings of its voted class (0 with none), for `slots` at
        once."""
        self.voted(slots)
        return _mean_confidences(slots, self.votes, self.confidences, self.first, self.count, self.label)

    def confidence(self, slot: int) -> float:
        """The mean confidence of a track's recent sightings of its voted class (0 with none)."""
        return float(self.confidences_of(np.array([slot], np.int64))[0])


@nb.njit(cache=True, nogil=True)
def _mean_confidences(slots: np.ndarray, votes: np.ndarray, ring: np.ndarray, first: np.ndarray, count: np.ndarray,
                      label: np.ndarray) -> np.ndarray:
    """Per track of `slots`, the mean confidence of its window's sightings of its voted class (0 with none)."""
    out = np.zeros(len(slots))
    window = votes.shape[1]
    for i in range(len(slots)):
        s = slots[i]
        total, n = 0.0, 0
        for j in range(count[s]):
            at = (first[s] + j) % window
            if votes[s, at] == label[s]:
                total += ring[s, at]
                n += 1
        out[i] = total / n if n else 0.0
    return out


@nb.njit(cache=True, nogil=True)
def sight(slots: np.ndarray, labels: np.ndarray, confidences: np.ndarray, votes: np.ndarray, ring: np.ndarray,
          first: np.ndarray, count: np.ndarray, weight: np.ndarray, voted: np.ndarray, least: float) -> None:
    """Add a sighting (class, confidence) to each track of `slots`' vote window, the oldest leaving a full window, the
    window's weight per class kept as it slides; its vote is made again when next asked (`vote`)."""
    window = votes.shape[1]
    for i in range(len(slots)):
        s = slots[i]
        if count[s] == window:
            gone = first[s]
            weight[s, votes[s, gone]] -= max(ring[s, gone], least)
            first[s] = (gone + 1) % window
            count[s] -= 1
        at = (first[s] + count[s]) % window
        votes[s, at] = labels[i]
        ring[s, at] = confidences[i]
        count[s] += 1
        weight[s, labels[i]] += max(confidences[i], least)
        voted[s] = -1


@nb.njit(cache=True, nogil=True)
def _see(slots: np.ndarray, centers: np.ndarray, sizes: np.ndarray, labels: np.ndarray, confidences: np.ndarray,
         stamp_s: float, confirmed_at: int, z: np.ndarray, box: np.ndarray, stamp: np.ndarray, hits: np.ndarray,
         misses: np.ndarray, held: np.ndarray, votes: np.ndarray, ring: np.ndarray, first: np.ndarray,
         count: np.ndarray, weight: np.ndarray, voted: np.ndarray) -> int:
    """`TrackStore.see` on the store's arrays."""
    sight(slots, labels, confidences, votes, ring, first, count, weight, voted, MIN_WEIGHT)
    confirmed = 0
    for i in range(len(slots)):
        s = slots[i]
        z[s] = centers[i, 2]
        box[s, :] = sizes[i, :3]
        stamp[s] = stamp_s
        hits[s] += 1
        misses[s] = 0
        held[s] = 0
        confirmed += hits[s] == confirmed_at
    return confirmed


@nb.njit(cache=True, nogil=True)
def new_views(slots: np.ndarray, box: np.ndarray, sizes: np.ndarray, long: np.ndarray, limit: float) -> np.ndarray:
    """Per track of `slots`, the variance a new view of its object adds to its position before a correction: (change
    / 2)^2 where the track is of a long class (`long`) and its box's horizontal edges (shorter with shorter) changed
    by more than `limit` in sum from its row of `box` to `sizes`; else 0."""
    out = np.zeros(len(slots))
    for i in range(len(slots)):
        s = slots[i]
        before0, before1 = min(box[s, 0], box[s, 1]), max(box[s, 0], box[s, 1])
        after0, after1 = min(sizes[i, 0], sizes[i, 1]), max(sizes[i, 0], sizes[i, 1])
        change = abs(after0 - before0) + abs(after1 - before1)
        if change > limit and long[i]:
            half = change / 2
            out[i] = half * half
    return out


@nb.njit(cache=True, nogil=True)
def vote(slots: np.ndarray, votes: np.ndarray, first: np.ndarray, weight: np.ndarray, voted: np.ndarray,
         score: np.ndarray) -> None:
    """The vote of each track of `slots` whose window changed: the class of most weight, the oldest sighting's class
    on a tie; its score that class's share of the weight (0 when there is none)."""
    for s in slots:
        if voted[s] >= 0:
            continue
        oldest = votes[s, first[s]]
        best = 0
        for c in range(1, weight.shape[1]):
            if weight[s, c] > weight[s, best]:
                best = c
        label = oldest if weight[s, oldest] >= weight[s, best] else best
        total = 0.0
        for c in range(weight.shape[1]):
            total += weight[s, c]
        voted[s] = label
        score[s] = weight[s, label] / total if total != 0.0 else 0.0


class Track:
    """One track: its id and its row `slot` of the stream's `TrackStore` (read and written through the
    properties)."""

    __slots__ = ("slot", "store", "track_id")

    def __init__(self, track_id: int, slot: int, store: TrackStore) -> None:
        self.track_id, self.slot, self.store = track_id, slot, store

    @property
    def offsets(self) -> np.ndarray | None:
        """(M, 2) its last points' x, y less its centre: the footprint it carries (None before it has any)."""
        count = self.store.points[self.slot]
        return self.store.offsets[self.slot, :count] if count else None

    @property
    def state(self) -> np.ndarray:
        """x, y, vx, vy (a view of the row)."""
        return self.store.state[self.slot]

    @property
    def cov(self) -> np.ndarray:
        return self.store.cov[self.slot]

    @property
    def stamp_s(self) -> float:
        return float(self.store.stamp[self.slot])

    @stamp_s.setter
    def stamp_s(self, value: float) -> None:
        self.store.stamp[self.slot] = value

    @property
    def z(self) -> float:
        """The box centre's height."""
        return float(self.store.z[self.slot])

    @z.setter
    def z(self, value: float) -> None:
        self.store.z[self.slot] = value

    @property
    def size(self) -> tuple[float, float, float]:
        """The last sighting's box: length, width, height."""
        length, width, height = self.store.box[self.slot]
        return float(length), float(width), float(height)

    @property
    def hits(self) -> int:
        return int(self.store.hits[self.slot])

    @property
    def misses(self) -> int:
        return int(self.store.misses[self.slot])

    @misses.setter
    def misses(self, value: int) -> None:
        self.store.misses[self.slot] = value

    @property
    def held(self) -> int:
        """Scans in a row the track was held by background points (no detection of its own)."""
        return int(self.store.held[self.slot])

    @held.setter
    def held(self, value: int) -> None:
        self.store.held[self.slot] = value

    @property
    def hold_from(self) -> int:
        """The sightings it needs before it may be held (a track found again is confirmed anew)."""
        return int(self.store.hold_from[self.slot])

    @hold_from.setter
    def hold_from(self, value: int) -> None:
        self.store.hold_from[self.slot] = value

    def label(self) -> int:
        """The confidence-weighted vote of the recent sightings (module docstring)."""
        if self.store.label[self.slot] < 0:
            self.store.voted(np.array([self.slot]))
        return int(self.store.label[self.slot])

    def score(self) -> float:
        """The voted class's share of the vote weight."""
        if self.store.label[self.slot] < 0:
            self.store.voted(np.array([self.slot]))
        return float(self.store.score[self.slot])

    def confidence(self) -> float:
        """The mean confidence of the recent sightings of the voted class."""
        return self.store.confidence(self.slot)
