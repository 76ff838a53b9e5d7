"""Objects over time: the tracks of one stream, so an object keeps one id for as long as it is seen and a class voted
over its sightings instead of one scan's.

A track holds a constant-velocity Kalman filter on its box centre in the ground plane (x, y, vx, vy; AB3DMOT's model
reduced to the plane stage 1 levels the scan into), its box's height and extent, its last points' footprint (cells of
the ground plane, `footprints`) and its recent sightings' classes and confidences. Each scan:
1. Every track is predicted to the scan's stamp, its footprint moved with it.
2. Detections and tracks are matched (scipy's `linear_sum_assignment`: the Hungarian method, a well-kept C
   implementation, not ours) for the most summed margin: a pair's cost is the distance of the detection's centre from
   the track's predicted centre, plus `class_penalty_m` for another class and up to `youth_penalty_m` for a young
   track (of two tracks on one object, the older wins it), times 1 - the share of footprint cells they share; its
   margin is the detection's class gate (`gate_m`) less that, or 0.05 m for a pair beyond the gate whose footprints
   share `match_overlap` of the smaller one's cells (a partly seen car's box centre jumps by metres while its points
   stay put). Leaving both unmatched is worth 0, so two poor pairs never beat one good one.
3. An unmatched detection lying mostly (`part_overlap` of its cells) on the footprint of a confirmed track that
   another detection matched, or that with that track's points fits one object of its class (`_ends`: another end of
   a parked car coming into view), is a part of that object: it takes that track, and starts none. A matched
   detection that also covers `merge_cover` of another confirmed track's predicted cells joined two objects: its
   points are shared out between the tracks by their footprints (`ScanTracks.merged`).
4. Matched tracks are corrected (a car's new view, its box edges changed by `reshape_m`, corrects the position and not
   the velocity); an unmatched car detection that with a confirmed car track no detection took fits one car (as
   `_ends` reads one) is that track's sighting (`waiting_views`: its box centre jumped past the gate); other
   unmatched detections find again a track that ended less than `reid_misses` scans ago, or start tentative tracks,
   confirmed after `min_hits` sightings; a detection whose box is implausible for its class starts none
   (`implausible_births`).
5. A confirmed track that no detection matched (waiting) may be held by the scan's points that stage 2 called
   background on its predicted footprint (`_hold`): stage 2 missed the object this scan, the track did not. A
   person's or rider's track only on a stream of 5 Hz or more (`hold_people_period_s`).
6. Tracks unseen (neither matched nor held) for `max_misses` scans end.
A track's class is the confidence-weighted vote of its last `vote_window` sightings: a new track takes its first
sighting's class; a change needs the new class to lead the window's vote. Parts and held points do not vote.

With a pose per scan (world from sensor, 4 x 4: odometry), tracks live in the world frame and the ego's own motion is
no object's; without one, in the sensor's frame, where the filter's velocity absorbs the ego's.

A track's numbers live in a row of the stream's `TrackStore` (`track_store`), so each step above is one compiled call
or numpy operation over all tracks (`kalman`, `association`, `footprints`), not a Python call per track.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from pass3d_ros.classes import CAR, CYCLIST, MEAN_SIZE, NUM_CLASSES, PEDESTRIAN
from pass3d_ros.core.stream import kalman
from pass3d_ros.core.stream.association import covering, margins
from pass3d_ros.core.stream.footprints import (
    CELL_M,
    Footprints,
    cell_sets,
    cells,
    edge_shifts,
    evenly_spaced,
    extent,
    keep_rows,
    matching,
    nearest_owner,
    pieces,
    point_cells,
    rows_cells,
    shared_cells,
)
from pass3d_ros.core.stream.shapes import ShapeMemory
from pass3d_ros.core.stream.track_store import FOOTPRINT_POINTS, Track, TrackStore, new_views

LONG_M = 3.0  # a class this long on average (a car) moves its box centre by metres when seen from another side; a
# person's or a rider's moves less than a centre's error
LONG_CLASS = np.array([MEAN_SIZE.get(label, (0.0,))[0] >= LONG_M for label in range(NUM_CLASSES)])  # per class id
COS_HEADING = float(np.cos(np.radians(30.0)))  # "along the heading": within 30 degrees of it
MIN_MARGIN_M = 0.05  # the margin of a pair matched beyond its gate by its footprint (`Tracker._associate`)
NO_TRACK = -1  # the track id of a detection in no track (an implausible box that starts none)


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's settings (one default each; metres, scans, seconds)."""

    gate_m: tuple[tuple[int, float], ...] = ((CAR, 3.0), (PEDESTRIAN, 1.5), (CYCLIST, 2.5))  # centre distance a
    # detection of this class may lie from a track's prediction
    never_match: tuple[tuple[int, int], ...] = ((CAR, PEDESTRIAN),)  # class pairs a track and a detection never
    # match across: a car is never a person (a person's track taking a car's detection is stage 2 or stage 1 wrong)
    class_penalty_m: float = 1.0  # extra cost of matching a detection of another class than the track's
    min_hits: int = 2  # sightings before a track is confirmed (its id published)
    max_misses: int = 3  # scans a track may go unseen before it ends
    reid_misses: int = 10  # scans after its last sighting an ended confirmed track may still be found again by a
    # detection that matched no live track (its id kept: an object behind another for a second is the same object)
    vote_window: int = 10  # recent sightings a track's class is voted over
    process_accel: float = 3.0  # m/s^2: how fast a road user may change its velocity (the filter's process noise)
    measurement_m: float = 0.3  # a detection centre's error (the filter's measurement noise)
    reshape_m: float | None = 0.5  # a detection of a long class (a car: LONG_M) whose box edges changed by more than
    # this (summed) from its track's corrects the track's position, not its velocity (`_correct_all`); None: both
    birth_speed: float = 5.0  # m/s: a new track's velocity is unknown up to this either way (its prior's spread)
    max_dt_s: float = 1.0  # a gap longer than this predicts no further (a stalled stream)
    match_overlap: float = 0.3  # a detection sharing this share of the smaller footprint's cells with a track may
    # match it beyond the centre gate
    part_overlap: float = 0.5  # an unmatched detection with this share of its cells on a matched track's footprint is
    # a part of that object (no track of its own)
    hold_cover: float = 0.3  # a waiting track holds the background points on its footprint when they cover this
    # share of its cells (and are at least hold_points)
    hold_points: int = 10  # the least background points that hold a track (MIN_OBJECT_POINTS alike)
    hold_margin_m: float = 0.5  # the held points' extent may pass the track's remembered size by this much
    max_held: int = 10  # scans in a row a confirmed track may be held without a detection of its own (and never
    # more than its sightings: a track seen twice is held twice at most)
    part_extent: float | None = 1.3  # a detection is another end of a tracked object of its class when both fit
    # in this times the class's mean size (KITTI's: 5.0 x 2.1 m for a car); None: footprint overlap only
    part_gap_m: float = 2.0  # ... its points come this close to the object's (a neighbour's fragment lies apart)
    heading_speed: float = 2.0  # m/s: ... and for a track this fast, the two lie along its heading (a moving car's
    # other end is ahead of it or behind it, never beside it)
    merge_cover: float | None = 0.4  # a detection holding this share of another confirmed track's predicted cells
    # (besides its own track's) covers that track's object too: its points are shared out (None: never)
    waiting_views: bool = True  # a detection left unmatched may be another view of a confirmed car track no
    # detection matched this scan (its points with the track's remembered ones fit one car, as `_ends` reads one):
    # it is that track's sighting, not a new track's (a parked car's box centre jumps by metres past the gate)
    youth_penalty_m: float = 0.5  # extra cost of matching a new track, falling to 0 at mature_hits sightings: of two
    # tracks on one object (a duplicate born of a split), the older one wins the object
    mature_hits: int = 10
    hold_min_confidence: float = 0.8  # the mean confidence of its voted class's sightings a held track needs (a
    # track born of a few unsure sightings of clutter is not held on that clutter)
    hold_people_period_s: float = 0.2  # a pedestrian's or cyclist's waiting track is held only when the scan came at
    # most this long after the one before (5 Hz or more): at 2 Hz a person walks more than their width between scans,
    # off the footprint that would hold them (docs/experiments/tracks.md, rule M2)
    implausible_births: bool = False  # a detection whose box cannot be one object of its class (core.objects'
    # plausible flag: a car 1.2 x 0.2 x 0.01 m, a sliver of a car's roof) may start a track; False: it starts none
    # (it may still match a track, be a part of one or find an ended one again) and has no track this scan
    first_score: float = 0.0  # detections at least this confident are matched to the tracks first, the rest to the
    # tracks left (ByteTrack's two rounds, Zhang et al. 2022): a faint fragment beside a person never takes the
    # person's track from the person's own detection; 0: one round. One round by rule W of docs/experiments/tracks.md
    # (36 fresh drives: id switches 51 -> 51 with 0.6)
    edge_shift: bool = False  # a car's move read from its box edge that moved least (`footprints.edge_shifts`): a
    # detection whose centre moved more than reshape_m apart from that is a new view, and that move corrects the
    # velocity (a parked car seen by another side keeps one end where it was). Off: rule V of
    # docs/experiments/tracks.md (36 fresh drives: id switches 33 -> 37, all on one drive; nothing else moved)
    edge_min_hits: int = 5  # sightings a track needs before the move its edges read corrects its velocity in a new
    # view (a younger track's velocity is its prior's guess, which one sparse view's edges would set; its new views
    # correct the position alone)
    fill_shapes: bool = False  # a confirmed car track's remembered shape (`shapes`: the voxels its objects' points
    # filled over its last shape_sightings sightings) takes the scan's points stage 2 left background, in no proposal
    # and off the ground, that fall in it (core.tracked_scan). Off: rule N of docs/experiments/tracks.md (flicker
    # -12 % on synthetic drives, but 1.24 ms against 0.88 at 60 objects, over issue 54's 1 ms; parking lot car -1.0)
    shape_sightings: int = 10  # sightings a car track's shape remembers
    fill_min_confidence: float = 0.8  # the mean confidence of its voted class's sightings a track filling needs

    def extent_limit(self, label: int) -> tuple[float, float] | None:
        """The longer and shorter horizontal edge one object of class `label` fits in (`part_extent` times its
        mean size; None without a mean size)."""
        if self.part_extent is None or label not in MEAN_SIZE:
            return None
        length, width, _ = MEAN_SIZE[label]
        return length * self.part_extent, width * self.part_extent

    def gate(self, label: int) -> float:
        """The gate of a detection of class `label` (the widest for a class without one)."""
        return float(self.gates[label])

    @cached_property
    def never(self) -> np.ndarray:
        """(NUM_CLASSES, NUM_CLASSES): whether a track and a detection of these classes never match (`never_match`,
        either way round)."""
        table = np.zeros((NUM_CLASSES, NUM_CLASSES), bool)
        for a, b in self.never_match:
            table[a, b] = table[b, a] = True
        return table

    @cached_property
    def gates(self) -> np.ndarray:
        """The gate of each class id, as `gate` says (one array: a scan looks up every detection's at once)."""
        widest = max(g for _, g in self.gate_m)
        return np.array([dict(self.gate_m).get(label, widest) for label in range(NUM_CLASSES)])


def _best_pairs(margin: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The allowed (row, column) pairs of the most summed margin (scipy's Hungarian method)."""
    if not margin.size:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rows, cols = linear_sum_assignment(margin, maximize=True)
    keep = allowed[rows, cols]
    return rows[keep], cols[keep]


class Tracked(NamedTuple):
    """What the tracker says of one detection of the scan: its track, the track's voted class and score, and whether
    the track is confirmed (a tentative track's id is not yet worth publishing)."""

    track_id: int
    label: int
    score: float
    confirmed: bool


class ScanTracks(NamedTuple):
    """What the tracker says of a scan: per detection its track; per held track, the background points that hold
    it (indices into the `background` the scan was given); per merged detection (one that covers another confirmed
    track's object too), the other tracks and every track's predicted footprint points (x, y, z; sensor frame), its
    own track's first: the detection's points go to the track whose footprint is nearest (`split_merged`)."""

    detections: list[Tracked]
    held: list[tuple[Tracked, np.ndarray]]
    merged: dict[int, list[tuple[Tracked, np.ndarray]]] | None = None


class _Shared(NamedTuple):
    """A scan's footprint cells shared by each track (predicted) and each detection, counted once for the matching,
    the parts and the merged objects: `cells` (T, K), each track's and each detection's cell count."""

    cells: np.ndarray
    tracks: np.ndarray
    detections: np.ndarray


class TrackingFrame:
    """Sensor frame -> tracking frame: the pose (world from sensor) when known, else none."""

    def __init__(self, pose: np.ndarray | None) -> None:
        self.pose = None if pose is None else np.asarray(pose, dtype=np.float64)

    def points(self, xyz: np.ndarray) -> np.ndarray:
        return xyz if self.pose is None else xyz @ self.pose[:3, :3].T + self.pose[:3, 3]

    def to_sensor(self, xyz: np.ndarray) -> np.ndarray:
        return xyz if self.pose is None else (xyz - self.pose[:3, 3]) @ self.pose[:3, :3]

    def xy(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)  # contiguous either way: one kernel signature
        return np.ascontiguousarray(xy) if self.pose is None else xy @ self.pose[:2, :2].T + self.pose[:2, 3]

    def after(self, rotation: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(rotation, shift) taking points rotated first by `rotation` (3 x 3; None: none) into the tracking frame,
        as x @ rotation.T + shift: one matrix product for points given in another frame than the sensor's."""
        first = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        if self.pose is None:
            return first, np.zeros(3)
        return self.pose[:3, :3] @ first, self.pose[:3, 3].copy()


class Tracker:
    """The tracks of one stream (module docstring). `update` takes a scan's detections (centre, size, class,
    confidence) and its stamp, and says each detection's track; `alive`, `born`, `lost` count for diagnostics."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self.reset()

    def reset(self) -> None:
        """Forget every track (a new stream); ids start over."""
        self.store = TrackStore(self.config.vote_window)
        self.tracks: list[Track] = []
        self._rows, self._rows_of = np.zeros(0, np.int64), self.tracks  # `_live`
        self.ended: list[Track] = []  # confirmed tracks ended less than reid_misses scans ago (`_revive`)
        self._next_id = 0
        self._last_stamp_s: float | None = None  # the last scan's (`_hold` reads the scan period)
        # car tracks' remembered shapes, only with `fill_shapes` (a stream's few hundred kB of arrays otherwise)
        self.shapes = ShapeMemory(self.config.shape_sightings) if self.config.fill_shapes else None
        self.born = 0
        self.lost = 0

    def filling(self) -> list[Track]:
        """The tracks whose remembered shape fills the scan (`fill_shapes`): confirmed car tracks, alive, of mean
        confidence fill_min_confidence or more, with a shape."""
        if self.shapes is None or not len(self.shapes):
            return []
        slots = self._live()
        label, _ = self.store.voted(slots)
        chosen = np.flatnonzero((label == CAR) & (self.store.hits[slots] >= self.config.min_hits))
        chosen = chosen[self.store.confidences_of(slots[chosen]) >= self.config.fill_min_confidence]
        return [self.tracks[k] for k in chosen.tolist() if self.tracks[k].track_id in self.shapes]

    @property
    def alive(self) -> int:
        """Confirmed tracks now."""
        return int((self.store.hits[self._live()] >= self.config.min_hits).sum())

    def update(self, centers: np.ndarray, sizes: np.ndarray, labels: Sequence[int], scores: Sequence[float],
               stamp_s: float, pose: np.ndarray | None = None,
               footprints: Footprints | None = None) -> list[Tracked]:
        """One scan: `centers` (K, 3) and `sizes` (K, 3) of its detections in the sensor frame, their classes and
        confidences, its stamp (s), when known the sensor's pose (world from sensor, 4 x 4), and each detection's
        footprint points (x, y in the sensor frame, `Footprints`). Says each detection's track (`scan` for more)."""
        return self.scan(centers, sizes, labels, scores, stamp_s, pose, footprints).detections

    def scan(self, centers: np.ndarray, sizes: np.ndarray, labels: Sequence[int], scores: Sequence[float],
             stamp_s: float, pose: np.ndarray | None = None, footprints: Footprints | None = None,
             background: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
             plausible: Sequence[bool] | None = None) -> ScanTracks:
        """`update`, and with `background` each confirmed track no detection matched may be held by the scan's
        points stage 2 called background on its predicted footprint (module docstring): `background(centers, reach)`
        gives those points (B, 3; sensor frame) within `reach` (T,) metres in x and y of the waiting tracks'
        `centers` (T, 3; sensor frame), and is called only when a track waits. `plausible`: whether each detection's
        box can be one object of its class (without `implausible_births` one that cannot starts no track). A
        detection whose centre, size or score is not finite is in no track (NO_TRACK): it would make a track's filter,
        box or vote NaN for good."""
        to_world = TrackingFrame(pose)
        centers = to_world.points(np.asarray(centers, dtype=np.float64).reshape(-1, 3))
        sizes = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
        usable = (np.isfinite(centers).all(axis=1) & np.isfinite(sizes).all(axis=1)
                  & np.isfinite(np.asarray(scores, dtype=np.float64)))
        world = detections = shared = None
        if footprints is not None:
            world = Footprints(to_world.xy(footprints.xy), footprints.counts)
            detections = cell_sets(world.xy, world.counts)
        self._predict_all(stamp_s)
        tracks = self._footprints()
        if tracks is not None and detections is not None:
            shared = _Shared(shared_cells(tracks, detections), np.diff(tracks[1]), np.diff(detections[1]))
        rows, cols = self._associate(centers, labels, shared, usable, np.asarray(scores, dtype=np.float64))
        matched = dict(zip(cols.tolist(), rows.tolist(), strict=True))
        split = world.split() if world is not None else None  # each detection's footprint points, once a scan
        self._correct_all(self._live()[rows], centers[cols], sizes[cols],
                          [split[c] for c in cols.tolist()] if split is not None and self.config.edge_shift else None)
        confirmed = self.store.hits[self._live()] >= self.config.min_hits
        parts = self._parts(matched, shared, confirmed)
        if self.config.part_extent is not None:
            parts.update(self._ends(matched, parts, labels, split))
        covered = self._covered(matched, parts, labels, shared, confirmed)
        births = None if plausible is None or self.config.implausible_births else plausible
        rows, early = self._sightings(centers, sizes, labels, scores, stamp_s, matched, parts, detections,
                                      split if self.config.waiting_views else None, births, usable)
        out = self._said_all(rows, early, labels, scores)
        seen = {self.tracks[u].track_id for others in covered.values() for u in others}
        seen.update(self.store.track_id[self._live()[[r for r in rows if r >= 0]]].tolist())
        merged = self._merged_footprints(matched, covered, to_world)
        if footprints is not None:
            self._keep_footprints(rows, world, merged)
        held_out = self._hold(background, seen, stamp_s, to_world) if background is not None else []
        self._age(seen)
        self._last_stamp_s = stamp_s
        return ScanTracks(out, held_out, merged)

    def _sightings(self, centers: np.ndarray, sizes: np.ndarray, labels: Sequence[int], scores: Sequence[float],
                   stamp_s: float, matched: dict[int, int], parts: dict[int, int],
                   detections: tuple[np.ndarray, np.ndarray] | None,
                   points: list[np.ndarray] | None = None,
                   births: Sequence[bool] | None = None,
                   usable: np.ndarray | None = None) -> tuple[list[int], dict[int, Tracked]]:
        """Each detection's track (its row in `tracks`): a matched track sighted (all at once), a part its object's
        track, any other (with `points`, each detection's footprint) another view of a waiting car track
        (`_waiting_view`), a track found again (`_revive`) or born, in detection order; with `births`, a detection
        it marks False starts no track (row -1); one `usable` marks False (not finite) is in none but a part. Also
        what the tracker says of the parts that come before their object's own detection (said before that
        detection's sighting)."""
        own = {t: d for d, t in matched.items()}
        early = {d: self._said(self.tracks[t]) for d, t in parts.items() if own[t] > d}
        ds = sorted(matched)
        self._sighted(self._live()[[matched[d] for d in ds]], centers[ds], sizes[ds],
                      np.asarray(labels, dtype=np.int64)[ds], np.asarray(scores, dtype=np.float64)[ds], stamp_s)
        rows = []
        taken = set(matched.values()) | set(parts.values())
        for d in range(len(centers)):
            if d in parts:
                rows.append(parts[d])
                continue
            if d in matched:
                rows.append(matched[d])
                continue
            if usable is not None and not usable[d]:
                rows.append(-1)
                continue
            row = None if points is None or not len(points[d]) else self._waiting_view(points[d], int(labels[d]), taken)
            if row is not None:  # another view of a waiting car: corrected as a matched track is
                taken.add(row)
                track = self.tracks[row]
                self._correct_all(np.array([track.slot]), centers[d:d + 1], sizes[d:d + 1], [points[d]])
            else:
                track = self._revive(centers[d], sizes[d], int(labels[d]), stamp_s, None if detections is None
                                     else detections[0][detections[1][d]:detections[1][d + 1]])
            if track is None and births is not None and not births[d]:
                rows.append(-1)
                continue
            if track is None:
                self._birth(centers[d], sizes[d], int(labels[d]), float(scores[d]), stamp_s)
            else:
                self._sighted(np.array([track.slot]), centers[d:d + 1], sizes[d:d + 1], np.array([int(labels[d])]),
                              np.array([float(scores[d])]), stamp_s)
            rows.append(row if row is not None else len(self.tracks) - 1)
        return rows, early

    def _said_all(self, rows: list[int], early: dict[int, Tracked], labels: Sequence[int],
                  scores: Sequence[float]) -> list[Tracked]:
        """What the tracker says of each detection's track (`rows`), all voted at once; `early` as `_sightings`; a
        detection in no track (row -1) keeps its own class and score, NO_TRACK, unconfirmed."""
        tracked = [d for d, row in enumerate(rows) if row >= 0]
        slots = self._live()[[rows[d] for d in tracked]]
        label, score = self.store.voted(slots)
        ids, confirmed = self.store.track_id[slots].tolist(), (self.store.hits[slots] >= self.config.min_hits).tolist()
        out = [Tracked(NO_TRACK, int(labels[d]), float(scores[d]), False) for d in range(len(rows))]
        for k, said in enumerate(map(Tracked, ids, label.tolist(), score.tolist(), confirmed)):
            out[tracked[k]] = said
        for d, said in early.items():
            out[d] = said
        return out

    def _age(self, seen: set[int]) -> None:
        """A miss for each track not seen this scan and each ended one; tracks unseen max_misses scans end (the
        confirmed ones may be found again for reid_misses scans), ended ones unseen reid_misses are forgotten."""
        store, live = self.store, self._live()
        unseen = [s for s, i in zip(live.tolist(), store.track_id[live].tolist(), strict=True) if i not in seen]
        store.misses[unseen + [t.slot for t in self.ended]] += 1
        gone = store.misses[live] > self.config.max_misses
        if not self.ended and not gone.any():
            return  # nothing ends, nothing is forgotten (the list of tracks stays as it is)
        ended = [t for t, g in zip(self.tracks, gone.tolist(), strict=True) if g]
        self.lost += sum(1 for t in ended if t.hits >= self.config.min_hits)
        self.tracks = [t for t, g in zip(self.tracks, gone.tolist(), strict=True) if not g]
        kept = [t for t in self.ended if t.misses <= self.config.reid_misses]
        found = [t for t in ended if t.hits >= self.config.min_hits and self.config.reid_misses > t.misses]
        store.release([t.slot for t in self.ended if t.misses > self.config.reid_misses]
                      + [t.slot for t in ended if not (t.hits >= self.config.min_hits
                                                      and self.config.reid_misses > t.misses)])
        self.ended = kept + found
        if self.shapes is not None:  # a forgotten track's shape goes with it
            self.shapes.keep_only({t.track_id for t in self.tracks} | {t.track_id for t in self.ended})

    @staticmethod
    def _slots(tracks: Sequence[Track]) -> np.ndarray:
        """The store rows of `tracks`."""
        return np.array([t.slot for t in tracks], dtype=np.int64)

    def _live(self) -> np.ndarray:
        """The store rows of `tracks`, made again only when the list changed (a track born, found again or ended)."""
        if self._rows_of is not self.tracks or len(self._rows) != len(self.tracks):
            self._rows, self._rows_of = self._slots(self.tracks), self.tracks
        return self._rows

    def _said(self, track: Track) -> Tracked:
        """What the tracker says of a track this scan: its id, voted class and score, whether it is confirmed."""
        return Tracked(track.track_id, track.label(), track.score(), track.hits >= self.config.min_hits)

    def _covered(self, matched: dict[int, int], parts: dict[int, int], labels: Sequence[int],
                 shared: _Shared | None, confirmed: np.ndarray) -> dict[int, list[int]]:
        """Matched detections that cover another confirmed track's object too (stage 1 joined two cars parked side
        by side): merge_cover of that track's predicted footprint cells inside the detection's, the track of the
        detection's class, matched to no other detection that holds more of its cells. detection -> track indices.
        `confirmed`: whether each track is."""
        if self.config.merge_cover is None or shared is None or not matched:
            return {}
        det_track = np.full(len(shared.detections), -1, np.int64)
        det_track[list(matched)] = list(matched.values())
        out: dict[int, list[int]] = {}
        taken = set(parts.values())
        for u, d, most, mine in zip(*(a.tolist() for a in covering(
                shared.cells, shared.tracks, confirmed, det_track, self.config.merge_cover)), strict=True):
            if self.tracks[u].label() != int(labels[d]) or self.tracks[matched[d]].label() != int(labels[d]):
                continue
            if mine >= most or u in taken:
                continue  # its own detection holds as much of it, or it took a part: not covered here
            out.setdefault(d, []).append(u)
        return out

    def _merged_footprints(self, matched: dict[int, int], covered: dict[int, list[int]],
                           to_world: TrackingFrame) -> dict[int, list[tuple[Tracked, np.ndarray]]]:
        """Per merged detection, its track and the tracks it covers, each with its predicted footprint points in
        the sensor frame (x, y, the track's height)."""
        out: dict[int, list[tuple[Tracked, np.ndarray]]] = {}
        for d, others in covered.items():
            entries = []
            for u in [matched[d], *others]:
                track = self.tracks[u]
                if track.offsets is None:
                    continue
                xy = track.state[:2] + track.offsets
                xyz = np.column_stack([xy, np.full(len(xy), track.z)])
                entries.append((self._said(track), to_world.to_sensor(xyz)))
            if len(entries) > 1:
                out[d] = entries
        return out

    def _revive(self, center: np.ndarray, size: np.ndarray, label: int, stamp_s: float,
                footprint: np.ndarray | None) -> Track | None:
        """An ended confirmed track of class `label` that a detection otherwise new finds again (within reid_misses
        scans of its last sighting): its predicted centre within the class's gate of the detection's, or its last
        footprint sharing match_overlap of the cells. Such a track lives again, corrected by the detection; else
        None. Ended tracks take part in no other matching: a neighbour's fragment never takes a lost track's id."""
        if not self.ended:
            return None
        store, slots = self.store, self._slots(self.ended)
        mine = np.flatnonzero(store.voted(slots)[0] == label)
        if not len(mine):
            return None
        slots = slots[mine]
        dt = np.maximum(np.minimum(stamp_s - store.stamp[slots], self.config.max_dt_s), 0.0)
        predicted = store.state[slots, :2] + store.state[slots, 2:] * dt[:, None]
        distance = np.hypot(predicted[:, 0] - center[0], predicted[:, 1] - center[1])
        gate = self.config.gate(label)
        near = distance <= gate
        far = np.flatnonzero(~near & (store.points[slots] > 0)) if footprint is not None else []
        if len(far):  # beyond the gate: its last footprint, moved with it, sharing match_overlap of the cells
            moved = np.zeros((len(store.state), 2))
            moved[slots[far]] = predicted[far]
            keys, starts = rows_cells(store.offsets, store.points, slots[far], moved)
            shared = shared_cells((keys, starts), (footprint, np.array([0, len(footprint)])))[:, 0]
            near[far] = shared / np.maximum(np.minimum(np.diff(starts), len(footprint)), 1) >= self.config.match_overlap
            distance[far] = np.minimum(distance[far], gate)
        found = np.flatnonzero(near)
        if not len(found):
            return None
        best = self.ended[int(mine[found[np.argmin(distance[found])]])]
        self.ended.remove(best)
        self._predict_all(stamp_s, [best])
        self._correct_all(np.array([best.slot]), center[None, :], np.asarray(size, dtype=np.float64)[None, :])
        best.misses = 0
        best.hold_from = best.hits + self.config.min_hits  # this sighting the first of min_hits
        self.tracks.append(best)
        self.lost -= 1  # found again: not lost (so alive = born - lost, however often a track comes back)
        return best

    def _footprints(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Each track's footprint cells where its points are predicted now (its last points moved with its filter;
        `cell_sets`): an empty footprint for a track without points; None when no track has any."""
        slots = self._live()
        if not self.store.points[slots].any():
            return None
        return self._cells(slots)

    def _cells(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The footprint cells of the tracks of `slots` where their points are predicted now (`cell_sets`)."""
        return rows_cells(self.store.offsets, self.store.points, slots, self.store.state)

    def _associate(self, centers: np.ndarray, labels: Sequence[int], shared: _Shared | None = None,
                   usable: np.ndarray | None = None, scores: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The matched pairs' track indices and detection indices: a pair's cost is its centre distance (plus
        class_penalty_m for another class) times 1 - the share of footprint cells it shares; a pair may match within
        the detection's gate, or beyond it when its footprints share match_overlap of their cells. The pairs chosen
        have the most summed margin (gate less cost; MIN_MARGIN_M beyond the gate): a pair is worth its margin, leaving
        both unmatched nothing, so two poor pairs never beat one good one (a least summed cost would match as many as
        it can: a track taking a neighbour's fragment so that its own object's track can take the other). With
        `first_score` and the detections' `scores`, the detections that confident are matched first and the rest to
        the tracks left (ByteTrack's two rounds)."""
        if not self.tracks or len(centers) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        slots = self._live()
        none, empty = np.zeros((0, 0), np.int64), np.zeros(0, np.int64)
        config = self.config
        margin, allowed = margins(
            self.store.state[slots, :2], centers, self.store.voted(slots)[0], np.asarray(labels, dtype=np.int64),
            none if shared is None else shared.cells, empty if shared is None else shared.tracks,
            empty if shared is None else shared.detections, self.store.hits[slots].astype(np.float64), config.gates,
            config.never, config.class_penalty_m, config.match_overlap, config.youth_penalty_m,
            float(config.mature_hits), MIN_MARGIN_M)
        if usable is not None and not usable.all():  # a detection not finite matches nothing
            allowed[:, ~usable] = False
            margin[:, ~usable] = 0.0
        if scores is None or self.config.first_score <= 0.0:
            return _best_pairs(margin, allowed)
        sure = scores >= self.config.first_score
        rows, cols = _best_pairs(np.where(sure[None, :], margin, 0.0), allowed & sure[None, :])
        left = np.setdiff1d(np.arange(len(slots)), rows)
        more_rows, more_cols = _best_pairs(np.where(sure[None, :], 0.0, margin[left]), allowed[left] & ~sure[None, :])
        return np.concatenate([rows, left[more_rows]]), np.concatenate([cols, more_cols])

    def _parts(self, matched: dict[int, int], shared: _Shared | None, confirmed: np.ndarray) -> dict[int, int]:
        """Unmatched detections that are part of a confirmed track another detection matched this scan: most of
        their cells (part_overlap) on the track's footprint (a car stage 1 cut in two). detection -> track index.
        `confirmed`: whether each track is."""
        if shared is None:
            return {}
        free = [d for d in range(len(shared.detections)) if d not in matched]
        if not free:
            return {}
        taken = np.unique(np.fromiter(matched.values(), np.int64, len(matched)))
        confirmed = taken[confirmed[taken]].tolist()
        if not confirmed:
            return {}
        share = shared.cells[np.ix_(confirmed, free)] / np.maximum(shared.detections[free], 1)[None, :]
        best = np.argmax(share, axis=0)
        return {d: confirmed[int(best[k])] for k, d in enumerate(free)
                if share[best[k], k] >= self.config.part_overlap}

    def _ends(self, matched: dict[int, int], parts: dict[int, int], labels: Sequence[int],
              points: list[np.ndarray] | None) -> dict[int, int]:
        """Unmatched detections that are another end of a confirmed track's object: of the track's class, and the
        track's last points (moved with it) and its matched detection's points come within part_gap_m of theirs, all
        of them together still fit one object of that class (`extent_limit`: a parked car passed by is seen first by
        its rear, then cut in two as its side comes into view), and, for a track moving heading_speed or faster, the
        union's longer side lies along its heading. The smallest such union wins. detection -> track index."""
        if points is None:
            return {}
        free = [d for d in range(len(points)) if d not in matched and d not in parts and len(points[d])]
        if not free:
            return {}
        by_track: dict[int, list[int]] = {}  # confirmed tracks of a class with a size: their detections this scan
        track_label: dict[int, int] = {}
        for d, t in matched.items():
            track = self.tracks[t]
            if track.hits >= self.config.min_hits and self.config.extent_limit(track.label()) is not None:
                by_track.setdefault(t, []).append(d)
                track_label[t] = track.label()
        out: dict[int, int] = {}
        for d in free:
            best, best_length = -1, np.inf
            centre = points[d].mean(axis=0)
            for t, mine in by_track.items():
                if track_label[t] != int(labels[d]):
                    continue
                track = self.tracks[t]
                limit = self.config.extent_limit(track_label[t])
                near = np.linalg.norm(centre - track.state[:2]) <= limit[0]
                if not near:
                    continue
                remembered = [track.state[:2] + track.offsets] if track.offsets is not None else []
                length = self._one_object(track, np.concatenate([*remembered, *(points[k] for k in mine)]),
                                          points[d], limit)
                if length is not None and length < best_length:
                    best, best_length = t, length
            if best >= 0:
                out[d] = best
        return out

    def _waiting_view(self, points: np.ndarray, label: int, taken: set[int]) -> int | None:
        """The confirmed track of long class `label` that no detection took this scan (not in `taken`) of which a
        detection's footprint `points` (tracking frame) is another view, as `_ends` reads another end: within
        part_gap_m of the track's remembered points (moved with it), all of them together within `extent_limit`, along
        a moving track's heading; the smallest such union. Its index in `tracks`, or None."""
        limit = self.config.extent_limit(label)
        if limit is None or not LONG_CLASS[label]:
            return None
        best, best_length = None, np.inf
        centre = points.mean(axis=0)
        for u, track in enumerate(self.tracks):
            if u in taken or track.offsets is None or track.hits < self.config.min_hits or track.label() != label:
                continue
            if np.linalg.norm(centre - track.state[:2]) > limit[0]:
                continue
            length = self._one_object(track, track.state[:2] + track.offsets, points, limit)
            if length is not None and length < best_length:
                best, best_length = u, length
        return best

    def _one_object(self, track: Track, known: np.ndarray, points: np.ndarray,
                    limit: tuple[float, float]) -> float | None:
        """The longer side of `known` (a track's points, tracking frame) and `points` together where they are one
        object of the track's: within part_gap_m of each other, within `limit` (`extent_limit`), and for a track
        moving heading_speed or faster the longer side along its heading; else None."""
        gap = np.sqrt(((known[:, None, :] - points[None, :, :]) ** 2).sum(axis=2).min())
        if gap > self.config.part_gap_m:
            return None
        length, width, axis = extent(np.concatenate([known, points]))
        speed = float(np.hypot(*track.state[2:]))
        along = speed < self.config.heading_speed or abs(axis @ track.state[2:]) >= COS_HEADING * speed
        return length if along and length <= limit[0] and width <= limit[1] else None

    def _keep_footprints(self, rows: list[int], world: Footprints,
                         merged: dict[int, list[tuple[Tracked, np.ndarray]]] | None = None) -> None:
        """Each seen track's footprint: its detections' points (parts included; tracking frame), at most 2 x
        MAX_POINTS evenly spaced, as offsets from its centre; a merged detection's points go to the track whose
        predicted footprint is nearest (`nearest_owner`); `rows` each detection's track."""
        owner = np.repeat(np.array(rows, dtype=np.int64), world.counts)  # -1: a detection in no track
        if merged:
            index = {t.track_id: k for k, t in enumerate(self.tracks)}
            starts = np.concatenate([[0], np.cumsum(world.counts)])
            for d, entries in merged.items():
                ids = np.array([index[said.track_id] for said, _ in entries])
                xy = world.xy[starts[d]:starts[d + 1]]
                near = nearest_owner(xy, [self.tracks[k].state[:2] + self.tracks[k].offsets for k in ids])
                owner[starts[d]:starts[d + 1]] = ids[near]
        tracked = np.flatnonzero(owner >= 0)
        chosen, kept = evenly_spaced(tracked, owner[tracked], len(self.tracks), FOOTPRINT_POINTS)
        keep_rows(world.xy, chosen, kept, self._live(), self.store.state, self.store.offsets,
                  self.store.points)

    def _hold(self, background: Callable[[np.ndarray, np.ndarray], np.ndarray], seen: set[int], stamp_s: float,
              to_world: TrackingFrame) -> list[tuple[Tracked, np.ndarray]]:
        """The confirmed tracks no detection matched (waiting), oldest first: each is held
        by the background points in the cells of its predicted footprint when there are at least hold_points of them,
        they cover hold_cover of its cells and their extent is within hold_margin_m of its remembered size. A held
        track is corrected by their centre, keeps its class, counts no sighting and no miss, and keeps the footprint
        of its last detection (held points never grow it: a track beside a wall would creep along the wall); it may
        be held at most max_held scans in a row, and a track found again after it ended (`_revive`) only once it is
        seen min_hits times more. A person's or rider's track is held only on a stream of scans at most
        hold_people_period_s apart. A point holds one track at most."""
        ids = self.store.track_id[self._live()].tolist()
        unseen = [t for t, i in zip(self.tracks, ids, strict=True) if i not in seen]
        period = None if self._last_stamp_s is None else stamp_s - self._last_stamp_s
        people = period is None or period <= self.config.hold_people_period_s
        waiting = [t for t in unseen if t.offsets is not None and t.hits >= self.config.min_hits
                   and t.held < min(self.config.max_held, t.hits) and t.confidence() >= self.config.hold_min_confidence
                   and t.hits >= t.hold_from and (people or t.label() not in (PEDESTRIAN, CYCLIST))]
        if not waiting:
            return []
        reach = np.array([np.abs(t.offsets).max() + CELL_M for t in waiting])
        centers = to_world.to_sensor(np.array([[*t.state[:2], t.z] for t in waiting]))
        xyz = to_world.points(np.asarray(background(centers, reach), dtype=np.float64).reshape(-1, 3))
        out: list[tuple[Tracked, np.ndarray]] = []
        free = np.ones(len(xyz), bool)
        keys = point_cells(xyz[:, :2])
        order = np.argsort(keys, kind="stable")  # the points by cell, once: a track's points are then a few ranges of
        keys = keys[order]  # it (a pass over all of them per track took 6 ms a scan)
        keys_at = self._cells(self._slots(waiting))
        for track, footprint in zip(waiting, pieces(keys_at[0], np.diff(keys_at[1])), strict=True):
            inside = order[matching(keys, footprint)[0]]
            mine = np.sort(inside[free[inside]])  # in a footprint cell: within the track's reach too
            if len(mine) < self.config.hold_points:
                continue
            if len(np.intersect1d(cells(xyz[mine, :2]), footprint)) < self.config.hold_cover * len(footprint):
                continue
            spread = np.ptp(xyz[mine], axis=0)
            length = max(track.size[0], track.size[1]) + self.config.hold_margin_m
            if np.hypot(spread[0], spread[1]) > np.hypot(length, length) or spread[2] > track.size[2] + 0.5:
                continue
            free[mine] = False
            center = (xyz[mine].min(axis=0) + xyz[mine].max(axis=0)) / 2
            self._correct_all(np.array([track.slot]), center[None, :])
            track.held += 1
            track.misses = 0
            track.z, track.stamp_s = float(center[2]), stamp_s
            seen.add(track.track_id)
            out.append((self._said(track), mine))
        return out

    def _birth(self, center: np.ndarray, size: np.ndarray, label: int, score: float, stamp_s: float) -> Track:
        """A new tentative track of one sighting, at rest where the detection is, its velocity unknown."""
        r = self.config.measurement_m ** 2
        v = self.config.birth_speed ** 2
        slot = self.store.new(self._next_id, np.array([center[0], center[1], 0.0, 0.0]), np.diag([r, r, v, v]),
                              float(center[2]), size, label, score, stamp_s)
        track = Track(self._next_id, slot, self.store)
        self._next_id += 1
        self.tracks.append(track)
        if self.config.min_hits <= 1:
            self.born += 1
        return track

    def _predict_all(self, stamp_s: float, tracks: list[Track] | None = None) -> None:
        """Every track's (or `tracks`') state and covariance carried to `stamp_s` (constant velocity; at most max_dt_s
        ahead)."""
        slots, store = self._live() if tracks is None else self._slots(tracks), self.store
        kalman.predict_rows(slots, store.state, store.cov, store.stamp, stamp_s, self.config.max_dt_s,
                            self.config.process_accel)

    def _correct_all(self, slots: np.ndarray, centers: np.ndarray, sizes: np.ndarray | None = None,
                     points: list[np.ndarray] | None = None) -> None:
        """The Kalman correction of each matched track (its store row) by its detection's centre (x, y measured), all
        at once. With
        the detections' `sizes`, a box of a long object (LONG_M: a car) whose horizontal edges changed by more than
        `reshape_m` from the track's is a new view of the object: its centre corrects the position (uncertain by half
        the change) and not the velocity (a parked car seen by its rear, then whole, moves its box centre by metres
        while it stands still). With `edge_shift` and the detections' footprint `points` (tracking frame), a long
        object's move is also read from its box edge that moved least (`edge_shifts`): a footprint whose box centre
        moved more than `reshape_m` apart from that is a new view too, and on a track seen `edge_min_hits` times the
        move read corrects the velocity first."""
        if not len(slots):
            return
        store = self.store
        measured = np.ascontiguousarray(centers[:, :2], dtype=np.float64)
        view = np.zeros(len(slots))
        if self.config.reshape_m is None or (sizes is None and points is None):
            kalman.correct_rows(slots, store.state, store.cov, measured, self.config.measurement_m ** 2, view)
            return
        long = LONG_CLASS[store.voted(slots)[0]]
        if sizes is not None:
            view = new_views(slots, store.box, np.ascontiguousarray(sizes, dtype=np.float64), long,
                             self.config.reshape_m)
        if points is None or not self.config.edge_shift or not long.any():
            kalman.correct_rows(slots, store.state, store.cov, measured, self.config.measurement_m ** 2, view)
            return
        starts = np.concatenate([[0], np.cumsum([len(p) for p in points])]).astype(np.int64)
        xy = np.concatenate(points).reshape(-1, 2) if points else np.zeros((0, 2))
        shifts, centres, read = edge_shifts(slots, store.state, store.offsets, store.points,
                                            np.ascontiguousarray(xy, dtype=np.float64), starts)
        moved = store.state[slots, :2] + shifts
        apart = np.hypot(*(centres - shifts).T)
        by_edges = read & long & (apart > self.config.reshape_m)
        view = np.where(by_edges, np.maximum(view, (apart / 2) ** 2), view)
        # the move read corrects the velocity before the new view's centre, on a track seen often enough
        first = read & long & (view > 0) & (store.hits[slots] >= self.config.edge_min_hits)
        noise = self.config.measurement_m ** 2
        kalman.correct_moved_rows(slots[first], store.state, store.cov, moved[first], measured[first], noise,
                                  view[first])
        kalman.correct_rows(slots[~first], store.state, store.cov, measured[~first], noise, view[~first])

    def _sighted(self, slots: np.ndarray, centers: np.ndarray, sizes: np.ndarray, labels: np.ndarray,
                 scores: np.ndarray, stamp_s: float) -> None:
        """Corrected tracks' sightings (their store rows), all at once: their height, box, vote and counts."""
        self.born += self.store.see(slots, centers, sizes, labels, scores, stamp_s, self.config.min_hits)
