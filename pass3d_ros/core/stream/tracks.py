"""Objects over time: the tracks of one stream, so an object keeps one id for as long as it is seen and a class voted
over its sightings instead of one scan's.

A track holds a constant-velocity Kalman filter on its box centre in the ground plane (x, y, vx, vy; AB3DMOT's model
reduced to the plane stage 1 levels the scan into), its box's height and extent, and its recent sightings' classes and
confidences. Each scan: every track is predicted to the scan's stamp; detections and tracks are matched by the
distance of each detection's centre from each track's predicted centre, gated per class (`TrackerConfig.gate_m`; a
detection of another class than the track's costs `class_penalty_m` more), with the assignment that minimises the
summed distance (scipy's `linear_sum_assignment`: the Hungarian method, a well-kept C implementation, not ours);
matched tracks are corrected, unmatched detections start tentative tracks, confirmed after `min_hits` sightings, and
tracks unseen for `max_misses` scans end. A track's class is the confidence-weighted vote of its last `vote_window`
sightings: a new track takes its first sighting's class; a change needs the new class to lead the window's vote.

With a pose per scan (world from sensor, 4 x 4: odometry), tracks live in the world frame and the ego's own motion is
no object's; without one, in the sensor's frame, where the filter's velocity absorbs the ego's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.optimize import linear_sum_assignment

from pass3d_ros.classes import CAR, CYCLIST, NUM_CLASSES, PEDESTRIAN

NO_MATCH = 1e6  # the cost of a pair outside the gate


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's settings (one default each; metres, scans, seconds)."""

    gate_m: tuple[tuple[int, float], ...] = ((CAR, 3.0), (PEDESTRIAN, 1.5), (CYCLIST, 2.5))  # centre distance a
    # detection of this class may lie from a track's prediction
    class_penalty_m: float = 1.0  # extra cost of matching a detection of another class than the track's
    min_hits: int = 2  # sightings before a track is confirmed (its id published)
    max_misses: int = 3  # scans a track may go unseen before it ends
    vote_window: int = 10  # recent sightings a track's class is voted over
    process_accel: float = 3.0  # m/s^2: how fast a road user may change its velocity (the filter's process noise)
    measurement_m: float = 0.3  # a detection centre's error (the filter's measurement noise)
    max_dt_s: float = 1.0  # a gap longer than this predicts no further (a stalled stream)

    def gate(self, label: int) -> float:
        """The gate of a detection of class `label` (the widest for a class without one)."""
        return float(self.gates[label])

    @cached_property
    def gates(self) -> np.ndarray:
        """The gate of each class id, as `gate` says (one array: a scan looks up every detection's at once)."""
        widest = max(g for _, g in self.gate_m)
        return np.array([dict(self.gate_m).get(label, widest) for label in range(NUM_CLASSES)])


@dataclass
class Track:
    """One object over time: its filter state in the tracking frame and its sightings."""

    track_id: int
    state: np.ndarray  # (4,) x, y, vx, vy
    cov: np.ndarray  # (4, 4)
    z: float  # the box centre's height
    size: tuple[float, float, float]
    votes: deque = field(default_factory=deque)  # (label, confidence) of the recent sightings
    hits: int = 1
    misses: int = 0
    stamp_s: float = 0.0
    _label: int = -1  # the vote's result and its share, made again when a sighting is added
    _score: float = 0.0

    def sighting(self, label: int, confidence: float) -> None:
        """Add a sighting to the vote."""
        self.votes.append((label, confidence))
        self._label = -1

    def label(self) -> int:
        """The confidence-weighted vote of the recent sightings (the first sighting's class wins a tie)."""
        if self._label < 0:
            self._vote()
        return self._label

    def score(self) -> float:
        """The voted class's share of the vote weight."""
        if self._label < 0:
            self._vote()
        return self._score

    def _vote(self) -> None:
        weight = [0.0] * NUM_CLASSES
        for label, confidence in self.votes:
            weight[label] += max(confidence, 1e-3)
        first = self.votes[0][0]
        best = max(range(NUM_CLASSES), key=weight.__getitem__)
        self._label = first if weight[first] >= weight[best] else best
        total = sum(weight)
        self._score = weight[self._label] / total if total else 0.0


@dataclass(frozen=True)
class Tracked:
    """What the tracker says of one detection of the scan: its track, the track's voted class and score, and whether
    the track is confirmed (a tentative track's id is not yet worth publishing)."""

    track_id: int
    label: int
    score: float
    confirmed: bool


class Tracker:
    """The tracks of one stream (module docstring). `update` takes a scan's detections (centre, size, class,
    confidence) and its stamp, and says each detection's track; `alive`, `born`, `lost` count for diagnostics."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self.reset()

    def reset(self) -> None:
        """Forget every track (a new stream); ids start over."""
        self.tracks: list[Track] = []
        self._next_id = 0
        self.born = 0
        self.lost = 0

    @property
    def alive(self) -> int:
        """Confirmed tracks now."""
        return sum(1 for t in self.tracks if t.hits >= self.config.min_hits)

    def update(self, centers: np.ndarray, sizes: np.ndarray, labels: Sequence[int], scores: Sequence[float],
               stamp_s: float, pose: np.ndarray | None = None) -> list[Tracked]:
        """One scan: `centers` (K, 3) and `sizes` (K, 3) of its detections in the sensor frame, their classes and
        confidences, its stamp (s) and, when known, the sensor's pose (world from sensor, 4 x 4)."""
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        if pose is not None:
            pose = np.asarray(pose, dtype=np.float64)
            centers = centers @ pose[:3, :3].T + pose[:3, 3]
        self._predict_all(stamp_s)
        pairs = self._associate(centers, labels)
        matched = {d: t for t, d in pairs}
        self._correct_all([self.tracks[t] for t, _ in pairs], centers[[d for _, d in pairs]])
        out: list[Tracked] = []
        seen: set[int] = set()
        for d in range(len(centers)):
            if d in matched:
                track = self.tracks[matched[d]]
                self._sighted(track, centers[d], tuple(sizes[d]), int(labels[d]), float(scores[d]), stamp_s)
            else:
                track = self._birth(centers[d], tuple(sizes[d]), int(labels[d]), float(scores[d]), stamp_s)
            seen.add(track.track_id)
            out.append(Tracked(track.track_id, track.label(), track.score(), track.hits >= self.config.min_hits))
        for track in self.tracks:
            if track.track_id not in seen:
                track.misses += 1
        ended = [t for t in self.tracks if t.misses > self.config.max_misses]
        self.lost += sum(1 for t in ended if t.hits >= self.config.min_hits)
        self.tracks = [t for t in self.tracks if t.misses <= self.config.max_misses]
        return out

    def _associate(self, centers: np.ndarray, labels: Sequence[int]) -> list[tuple[int, int]]:
        """(track index, detection index) pairs: the least summed distance within each detection's gate."""
        if not self.tracks or len(centers) == 0:
            return []
        predicted = np.array([t.state[:2] for t in self.tracks])
        cost = np.linalg.norm(predicted[:, None, :] - centers[None, :, :2], axis=2)
        track_labels = np.array([t.label() for t in self.tracks])
        det_labels = np.asarray(labels)
        cost = cost + self.config.class_penalty_m * (track_labels[:, None] != det_labels[None, :])
        gates = self.config.gates[det_labels]
        cost = np.where(cost <= gates[None, :], cost, NO_MATCH)
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < NO_MATCH]

    def _birth(self, center: np.ndarray, size: tuple, label: int, score: float, stamp_s: float) -> Track:
        r = self.config.measurement_m ** 2
        cov = np.diag([r, r, 25.0, 25.0])  # velocity unknown: up to 5 m/s either way
        track = Track(self._next_id, np.array([center[0], center[1], 0.0, 0.0]), cov, float(center[2]), size,
                      deque([(label, score)], maxlen=self.config.vote_window), stamp_s=stamp_s)
        self._next_id += 1
        self.tracks.append(track)
        if self.config.min_hits <= 1:
            self.born += 1
        return track

    def _predict_all(self, stamp_s: float) -> None:
        """Every track's state and covariance carried to `stamp_s` (constant velocity; at most max_dt_s ahead)."""
        if not self.tracks:
            return
        dt = np.clip(stamp_s - np.array([t.stamp_s for t in self.tracks]), 0.0, self.config.max_dt_s)
        f = np.broadcast_to(np.eye(4), (len(dt), 4, 4)).copy()
        f[:, 0, 2] = f[:, 1, 3] = dt
        a2 = self.config.process_accel ** 2
        q = np.zeros((len(dt), 4, 4))
        q[:, 0, 0] = q[:, 1, 1] = a2 * dt ** 4 / 4
        q[:, 0, 2] = q[:, 2, 0] = q[:, 1, 3] = q[:, 3, 1] = a2 * dt ** 3 / 2
        q[:, 2, 2] = q[:, 3, 3] = a2 * dt ** 2
        states = np.einsum("tij,tj->ti", f, np.array([t.state for t in self.tracks]))
        covs = f @ np.array([t.cov for t in self.tracks]) @ f.transpose(0, 2, 1) + q
        for track, state, cov in zip(self.tracks, states, covs, strict=True):
            track.state, track.cov, track.stamp_s = state, cov, stamp_s

    def _correct_all(self, tracks: list[Track], centers: np.ndarray) -> None:
        """The Kalman correction of each matched track by its detection's centre (x, y measured), all at once."""
        if not tracks:
            return
        states = np.array([t.state for t in tracks])
        covs = np.array([t.cov for t in tracks])
        s = covs[:, :2, :2] + np.eye(2) * self.config.measurement_m ** 2
        det = s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0]
        inv = np.stack([np.stack([s[:, 1, 1], -s[:, 0, 1]], -1), np.stack([-s[:, 1, 0], s[:, 0, 0]], -1)], 1)
        gain = covs[:, :, :2] @ (inv / det[:, None, None])  # (T, 4, 2)
        states = states + np.einsum("tij,tj->ti", gain, centers[:, :2] - states[:, :2])
        covs = covs - gain @ covs[:, :2, :]
        for track, state, cov in zip(tracks, states, covs, strict=True):
            track.state, track.cov = state, cov

    def _sighted(self, track: Track, center: np.ndarray, size: tuple, label: int, score: float,
                 stamp_s: float) -> None:
        """A corrected track's sighting: its height, extent, vote and counts."""
        track.z, track.size, track.stamp_s = float(center[2]), size, stamp_s
        track.sighting(label, score)
        track.hits += 1
        track.misses = 0
        if track.hits == self.config.min_hits:
            self.born += 1
