"""Objects over time, scored offline (`pass3d_evaluate --tracking`): the full pipeline with the stream's tracker on,
each scan's scan-by-scan labels (`LabelledScan.published`) beside the labels with the tracks' vote applied
(`LabelledScan.output`), from the same run.

- IoU per class of both, and the voted minus the scan-by-scan IoU with a paired frame-bootstrap interval (as
  `--paired-with` compares two runs: pass3d_ros.core.metrics.paired_iou_difference).
- Flicker of ground-truth objects (where instance ids persist over a sequence: synthetic drives, SemanticKITTI): per
  instance, in each scan where it has at least MIN_INSTANCE_POINTS labelled points, its class is the majority of its
  points' published labels (background included: a person called background in one sweep and pedestrian in the next
  is flicker); a change between consecutive such scans is one class change; flicker = class changes per object per
  10 s of its life (first to last such scan, plus one scan period), pooled over the objects.
- CLEAR-MOT id switches and fragmentations per 100 object-tracks (instances seen in 2+ scans; Bernardin and
  Stiefelhagen 2008). An instance and a published object correspond in a scan when the object holds more than half of
  the instance's points and the instance more than half of the object's (one to one, as CLEAR-MOT's correspondences
  are: a threshold on overlap, here over points); the instance is matched when that object's track is confirmed. A
  switch: a matched sighting whose track id differs from the instance's previous matched one. A fragmentation:
  matched, then unmatched in one or more scans where the instance is seen, then matched again. Also counted the way
  this module first did (`mot_most_points`): the sighting is the object holding most of the instance's points,
  however few, so that two people stage 1 joined for one scan both take its one track (a switch for one of them).
- Label-free flicker of the tracks themselves (any data): per track, class changes along its sightings of the
  scan-by-scan class against those of the voted class, per 10 s of the track's life, pooled over tracks seen 2+ times;
  a track is sighted once a scan, as its largest object there (the parts of one it took are not changes in time).

The scan period comes from the stamps (their median step within a spec) unless a rate is given (`scan_rate_hz`: the
nuScenes parking lot's key frames, read without stamps at 10 Hz, are 2 Hz); the tracker then sees stamps index /
rate. A frame's pose (world from sensor) is used when the data has one.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from itertools import pairwise

import numpy as np

from pass3d_ros.classes import BACKGROUND, CLASS_NAMES, FOREGROUND, NUM_CLASSES
from pass3d_ros.core.metrics import SegmentationMetrics, paired_iou_difference
from pass3d_ros.core.objects import warm_up as warm_up_objects
from pass3d_ros.core.pipeline import LabelledScan, ScanPipeline
from pass3d_ros.core.point_owners import object_points
from pass3d_ros.core.stage1 import Stage1Config, warm_up
from pass3d_ros.core.stage2 import Classifier
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stream.tracks import TrackerConfig
from pass3d_ros.core.tracked_scan import NO_TRACK
from pass3d_ros.core.tracked_scan import warm_up as warm_up_tracker
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError
from pass3d_ros.evaluation.offline import proposed_frame

MATCH_SHARE = 0.5  # an object and an instance correspond when each holds more than this share of the other's points
MIN_INSTANCE_POINTS = 10  # labelled points that make a ground-truth object seen in a scan (MIN_OBJECT_POINTS alike)
FLICKER_PERIOD_S = 10.0  # flicker is counted per this much of an object's life
PER_TRACKS = 100  # id switches and fragmentations are counted per this many object-tracks


@dataclass
class Flicker:
    """Class changes of objects over time, scan-by-scan against voted, and the objects' lives."""

    objects: int = 0  # objects seen in 2+ scans
    life_s: float = 0.0
    changes_scan: int = 0
    changes_voted: int = 0

    def add(self, scan: list[int], voted: list[int], life_s: float) -> None:
        """One object's classes over its sightings, in order, and its life."""
        if len(scan) < 2:
            return
        self.objects += 1
        self.life_s += life_s
        self.changes_scan += _changes(scan)
        self.changes_voted += _changes(voted)

    def summary(self) -> dict:
        per = FLICKER_PERIOD_S / self.life_s if self.life_s > 0 else None
        scan = None if per is None else self.changes_scan * per
        voted = None if per is None else self.changes_voted * per
        reduction = None if not scan else 1.0 - voted / scan
        return {"objects": self.objects, "life_s": self.life_s, "changes_scan": self.changes_scan,
                "changes_voted": self.changes_voted, "per_10s_scan": scan, "per_10s_voted": voted,
                "reduction": reduction}


def _changes(classes: list[int]) -> int:
    return sum(1 for a, b in pairwise(classes) if a != b)


@dataclass
class Sighting:
    """A ground-truth instance in one scan: its majority classes and the track its main object is matched to."""

    stamp_s: float
    scan_class: int
    voted_class: int
    track: int  # NO_TRACK: unmatched (no object, or a tentative track's)
    object_class_scan: int  # the main object's class, scan-by-scan and voted (BACKGROUND: no object)
    object_class_voted: int
    match: int = NO_TRACK  # the track of the object that corresponds to it (CLEAR-MOT, MATCH_SHARE), else NO_TRACK


@dataclass
class StreamHistory:
    """One spec's sightings: per ground-truth instance and per track."""

    period_s: float
    poses: int = 0  # frames with a pose (world from sensor): tracks in the world frame
    instances: dict[int, list[Sighting]] = field(default_factory=lambda: defaultdict(list))
    tracks: dict[int, list[tuple[float, int, int]]] = field(default_factory=lambda: defaultdict(list))


def instance_sightings(truth: np.ndarray, instance: np.ndarray, scan: np.ndarray, voted: np.ndarray,
                       cluster_id: np.ndarray, track_id: np.ndarray, stamp_s: float) -> dict[int, Sighting]:
    """Each ground-truth road user of a scan with at least MIN_INSTANCE_POINTS labelled points: its majority
    published class scan-by-scan and voted, and its sighting: the object published with tracking on (`voted` labels,
    `cluster_id` its ids: held objects too) holding most of its points; `match` that object's track where the two
    correspond (MATCH_SHARE of each other's points)."""
    mine = np.isin(truth, FOREGROUND) & (instance >= 0)
    on_road = voted != BACKGROUND
    object_ids, object_sizes = np.unique(cluster_id[on_road], return_counts=True)
    out: dict[int, Sighting] = {}
    ids, counts = np.unique(instance[mine], return_counts=True)
    if not len(ids):  # no road user with an instance id (np.split would still give one, empty, group)
        return out
    index = np.flatnonzero(mine)
    order = np.argsort(instance[index], kind="stable")
    groups = np.split(index[order], np.cumsum(counts)[:-1])
    for g, points in zip(ids, groups, strict=True):
        if len(points) < MIN_INSTANCE_POINTS:
            continue
        scan_class = int(np.bincount(scan[points], minlength=NUM_CLASSES).argmax())
        voted_class = int(np.bincount(voted[points], minlength=NUM_CLASSES).argmax())
        road = points[voted[points] != BACKGROUND]
        track, object_scan, object_voted, match = NO_TRACK, BACKGROUND, BACKGROUND, NO_TRACK
        if len(road):
            objects, held = np.unique(cluster_id[road], return_counts=True)
            most = int(np.argmax(held))
            main = road[cluster_id[road] == objects[most]]
            track = int(track_id[main[0]])
            object_scan, object_voted = int(scan[main[0]]), int(voted[main[0]])
            size = object_sizes[np.searchsorted(object_ids, objects[most])]
            if held[most] > MATCH_SHARE * len(points) and held[most] > MATCH_SHARE * size:
                match = track
        out[int(g)] = Sighting(stamp_s, scan_class, voted_class, track, object_scan, object_voted, match)
    return out


@dataclass
class Mot:
    """CLEAR-MOT counts over ground-truth instances (module docstring): by the one-to-one correspondences
    (`Sighting.match`), or with `most_points` by the object holding most of each instance's points (`Sighting.track`).
    """

    object_tracks: int = 0
    sightings: int = 0
    matched: int = 0
    id_switches: int = 0
    fragmentations: int = 0
    right_scan: int = 0  # sightings with an object whose class is the instance's (scan-by-scan, voted)
    right_voted: int = 0
    most_points: bool = False

    def add(self, sightings: list[Sighting], truth_class: int) -> None:
        """One instance's sightings in order."""
        if len(sightings) >= 2:
            self.object_tracks += 1
        last_track, gap = None, False
        for s in sightings:
            self.sightings += 1
            self.right_scan += s.object_class_scan == truth_class
            self.right_voted += s.object_class_voted == truth_class
            track = s.track if self.most_points else s.match
            if track == NO_TRACK:
                gap = last_track is not None
                continue
            self.matched += 1
            if last_track is not None and track != last_track:
                self.id_switches += 1
            if gap:
                self.fragmentations += 1
            last_track, gap = track, False

    def summary(self) -> dict:
        per = PER_TRACKS / self.object_tracks if self.object_tracks else None
        share = 1.0 / self.sightings if self.sightings else None
        return {"object_tracks": self.object_tracks, "sightings": self.sightings, "matched": self.matched,
                "id_switches": self.id_switches, "fragmentations": self.fragmentations,
                "id_switches_per_100": None if per is None else self.id_switches * per,
                "fragmentations_per_100": None if per is None else self.fragmentations * per,
                "right_class_scan": None if share is None else self.right_scan * share,
                "right_class_voted": None if share is None else self.right_voted * share}


def scan_period(stamps_ns: list[int]) -> float | None:
    """The median step of a spec's stamps in seconds; None when they do not step forward."""
    if len(stamps_ns) < 2:
        return None
    step = float(np.median(np.diff(np.asarray(stamps_ns, dtype=np.float64)))) * 1e-9
    return step if step > 0 else None


class TrackingEvaluation:
    """The accumulators of a `--tracking` run over one or more specs (each its own stream)."""

    def __init__(self, per_frame_instances: bool) -> None:
        self.per_frame_instances = per_frame_instances
        self.scan = SegmentationMetrics()
        self.voted = SegmentationMetrics()
        self.labelled: bool | None = None  # every frame labelled (True), none (False)
        self.instance_flicker = Flicker()
        self.track_flicker = Flicker()
        self.mot = Mot()
        self.mot_most_points = Mot(most_points=True)
        self.truth_class: dict[tuple[str, int], list[int]] = defaultdict(lambda: [0] * NUM_CLASSES)
        self.with_instances = False  # a labelled frame carried instance ids
        self.streams: dict[str, dict] = {}
        self.track_ms: list[float] = []

    def frame(self, spec: str, frame: Frame, labelled: LabelledScan, stamp_s: float, history: StreamHistory) -> None:
        """Fold one tracked scan in."""
        has_labels = frame.labels is not None
        if self.labelled is None:
            self.labelled = has_labels
        elif self.labelled != has_labels:
            raise DatasetError(f"{spec}: frame {frame.name} {'has' if has_labels else 'lacks'} point labels and "
                               "earlier frames do not: --tracking scores all frames labelled or none")
        tracked = labelled.tracked
        if tracked is None:
            raise ValueError("TrackingEvaluation.frame: a scan segmented without tracking")
        self.track_ms.append(tracked.ms)
        objects = labelled.published
        points = np.bincount(object_points(objects)[1], minlength=len(objects.objects))
        sighted: dict[int, tuple[int, int, int]] = {}  # per track: (points, scan-by-scan class, voted class)
        for obj, said, n in zip(objects.objects, tracked.tracked, points.tolist(), strict=True):
            # a detection in no track (an implausible box) is no object over time; a track with several objects in
            # the scan (parts of it) is sighted once, as its largest: parts' classes differ in space, not time
            if said.track_id != NO_TRACK and n > sighted.get(said.track_id, (-1,))[0]:
                sighted[said.track_id] = (n, obj.label, said.label)
        for track, (_, scan_class, voted_class) in sighted.items():
            history.tracks[track].append((stamp_s, scan_class, voted_class))
        if not has_labels:
            return
        size = len(frame.points)
        scan = labelled.proposed.in_input(labelled.published.labels, size, BACKGROUND)
        voted, cluster_id = labelled.published_in_input(size)
        name = f"{spec}#{frame.name}"
        self.scan.update(name, frame.labels, scan, vehicle_other=frame.vehicle_other)
        self.voted.update(name, frame.labels, voted, vehicle_other=frame.vehicle_other)
        if self.per_frame_instances or frame.instance is None:
            return
        self.with_instances = True
        track_id = labelled.proposed.in_input(tracked.track_id, size, NO_TRACK)
        seen = instance_sightings(frame.labels, frame.instance, scan, voted, cluster_id, track_id, stamp_s)
        for g, sighting in seen.items():
            history.instances[g].append(sighting)
            counts = self.truth_class[(spec, g)]
            counts[int(np.bincount(frame.labels[frame.instance == g]).argmax())] += 1

    def end_stream(self, spec: str, history: StreamHistory) -> None:
        """Score one spec's histories."""
        period = history.period_s
        for g, sightings in history.instances.items():
            life = sightings[-1].stamp_s - sightings[0].stamp_s + period
            self.instance_flicker.add([s.scan_class for s in sightings], [s.voted_class for s in sightings], life)
            truth = self.truth_class[(spec, g)]
            self.mot.add(sightings, int(np.argmax(truth)))
            self.mot_most_points.add(sightings, int(np.argmax(truth)))
        for sightings in history.tracks.values():
            life = sightings[-1][0] - sightings[0][0] + period
            self.track_flicker.add([s[1] for s in sightings], [s[2] for s in sightings], life)

    def summary(self) -> dict:
        """The run's summary (docs/evaluate_json.md, "tracking")."""
        frames = sum(row["frames"] for row in self.streams.values())
        out: dict = {"frames": frames, "labelled": bool(self.labelled),
                     "streams": self.streams, "track_flicker": self.track_flicker.summary(),
                     "track_ms": {"median": float(np.median(self.track_ms)) if self.track_ms else None,
                                  "max": max(self.track_ms, default=None)}}
        if not self.labelled:
            return out
        scan, voted = self.scan.summary(), self.voted.summary()
        differences = paired_iou_difference(self.scan.confusion.frames, self.voted.confusion.frames, FOREGROUND)
        out["iou"] = {CLASS_NAMES[c]: {"scan": scan["classes"][CLASS_NAMES[c]]["iou"],
                                       "voted": voted["classes"][CLASS_NAMES[c]]["iou"], **differences[c]}
                      for c in FOREGROUND}
        out["mean_iou"] = {"scan": scan["mean_iou"], "voted": voted["mean_iou"]}
        if self.per_frame_instances:
            out["instances"] = "per-frame: ground-truth flicker, id switches and fragmentations not defined"
        elif not self.with_instances:
            out["instances"] = "none: ground-truth flicker, id switches and fragmentations need instance ids"
        else:
            out["instances"] = "persistent"
            out["flicker"] = self.instance_flicker.summary()
            out["mot"] = self.mot.summary()
            out["mot_most_points"] = self.mot_most_points.summary()
        out["per_frame"] = [{"frame": a["frame"], "confusion_scan": a["confusion"], "confusion_voted": b["confusion"]}
                            for a, b in zip(self.scan.per_frame, self.voted.per_frame, strict=True)]
        return out


def evaluate_tracking(frames: Iterator[tuple[str, Frame]], config: Stage1Config, classifier: Classifier,
                      intensity_match: bool = INTENSITY_MATCH, scan_rate_hz: float | None = None,
                      per_frame_instances: bool = False, tracker_config: TrackerConfig | None = None,
                      people_in_groups: bool = PEOPLE_IN_GROUPS) -> dict:
    """Both stages with the stream's tracker on every frame, each spec a stream (module docstring): the summary
    `TrackingEvaluation.summary` gives, with the tracker's settings (`tracker_config`, None: its defaults).
    `scan_rate_hz`: the scans' rate when the stamps do not tell it; `per_frame_instances`: the data's instance ids
    name boxes within one frame only (no ground-truth tracks); `people_in_groups`: Stage2Config.people_in_groups."""
    warm_up()
    classifier.warm_up()
    warm_up_objects()
    warm_up_tracker()  # the tracker's time a scan (track_ms) then counts no kernel's compiling or loading
    tracker_config = tracker_config or TrackerConfig()
    pipeline = ScanPipeline(config, classifier, intensity_match=intensity_match, tracking=True,
                            tracker_config=tracker_config, people_in_groups=people_in_groups)
    run = TrackingEvaluation(per_frame_instances)
    current: str | None = None
    history = StreamHistory(0.0)
    stamps: list[int] = []
    index = 0
    for spec, frame in frames:
        if spec != current:
            if current is not None:
                _end(run, current, history, stamps, scan_rate_hz)
            current, history, stamps, index = spec, StreamHistory(0.0), [], 0
        stamps.append(frame.stamp_ns)
        stamp_s = index / scan_rate_hz if scan_rate_hz else frame.stamp_ns * 1e-9
        proposed = proposed_frame(pipeline, spec, frame)
        labelled = pipeline.segment(proposed, stamp_s=stamp_s, pose=frame.pose)
        history.poses += frame.pose is not None
        run.frame(spec, frame, labelled, stamp_s, history)
        index += 1
    if current is not None:
        _end(run, current, history, stamps, scan_rate_hz)
    return {**run.summary(), "tracker": asdict(tracker_config)}


def _end(run: TrackingEvaluation, spec: str, history: StreamHistory, stamps: list[int],
         scan_rate_hz: float | None) -> None:
    """Close one spec: its scan period (the given rate, else the stamps'), then its histories scored."""
    from_stamps = scan_period(stamps)
    if scan_rate_hz:
        period, source = 1.0 / scan_rate_hz, "--scan-rate"
    elif from_stamps is not None:
        period, source = from_stamps, "stamps"
    else:
        raise DatasetError(f"{spec}: its stamps do not step forward; give the scan rate (--scan-rate HZ)")
    history.period_s = period
    run.streams[spec] = {"frames": len(stamps), "scan_period_s": period, "period_from": source,
                         "frames_with_pose": history.poses}
    run.end_stream(spec, history)
