"""The margin of every (track, detection) pair of a scan for the tracker's matching (`Tracker._associate`), in one
compiled pass: at 60 x 60 pairs numpy's dozen whole-matrix steps cost a few hundred microseconds of call overhead,
the arithmetic a few."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def margins(predicted: np.ndarray, centers: np.ndarray, track_labels: np.ndarray, det_labels: np.ndarray,
            shared: np.ndarray, track_cells: np.ndarray, det_cells: np.ndarray, hits: np.ndarray, gates: np.ndarray,
            never: np.ndarray, penalty: float, match_overlap: float, youth: float, mature: float,
            least: float) -> tuple[np.ndarray, np.ndarray]:
    """Each pair's margin (T, K) and whether it may match: its cost is the centre distance of the track's prediction
    (`predicted`, T x 2) from the detection's (`centers`, K x 2+), plus `penalty` for another class, times 1 - the
    share of footprint cells it shares (`shared` counts over the smaller of `track_cells`, `det_cells`; an empty
    `shared`: no footprints), plus the track's youth (`youth` falling to 0 at `mature` hits). It may match within
    the detection's class gate or with `match_overlap` of shared cells, never across a `never` class pair; its
    margin is the gate less its cost, at least `least`, and 0 where it may not match."""
    tracks, detections = len(predicted), len(centers)
    footprints = shared.shape[0] == tracks and shared.shape[1] == detections and tracks * detections > 0
    margin = np.zeros((tracks, detections))
    allowed = np.zeros((tracks, detections), np.bool_)
    for t in range(tracks):
        young = youth * min(max(1.0 - hits[t] / mature, 0.0), 1.0)
        for d in range(detections):
            dx = predicted[t, 0] - centers[d, 0]
            dy = predicted[t, 1] - centers[d, 1]
            cost = np.sqrt(dx * dx + dy * dy)
            if track_labels[t] != det_labels[d]:
                cost = cost + penalty
            gate = gates[det_labels[d]]
            ok = cost <= gate
            if footprints:
                share = shared[t, d] / max(min(track_cells[t], det_cells[d]), 1)
                ok = ok or share >= match_overlap
                cost = cost * (1.0 - share)
            if never[track_labels[t], det_labels[d]]:
                ok = False
            cost = cost + young
            allowed[t, d] = ok
            margin[t, d] = max(gate - cost, least) if ok else 0.0
    return margin, allowed


@nb.njit(cache=True, nogil=True)
def covering(shared: np.ndarray, track_cells: np.ndarray, confirmed: np.ndarray, det_track: np.ndarray,
             least: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The confirmed tracks (with footprint cells) that the matched detection holding most of their predicted cells
    (the first of equals; `det_track` each detection's track, -1 unmatched) holds `least` of or more and is not their
    own: the tracks, those detections, the share it holds and the share their own detection holds (-1: none)."""
    tracks, detections = shared.shape
    found = np.empty(tracks, np.int64)
    where = np.empty(tracks, np.int64)
    share = np.empty(tracks)
    own = np.empty(tracks)
    n = 0
    for u in range(tracks):
        if not confirmed[u] or track_cells[u] == 0:
            continue
        best, most, mine = -1, -1.0, -1.0
        for d in range(detections):
            if det_track[d] < 0:
                continue
            cover = shared[u, d] / max(track_cells[u], 1)
            if cover > most:
                best, most = d, cover
            if det_track[d] == u:
                mine = cover
        if best >= 0 and most >= least and det_track[best] != u:
            found[n], where[n], share[n], own[n] = u, best, most, mine
            n += 1
    return found[:n], where[:n], share[:n], own[:n]
