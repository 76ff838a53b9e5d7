"""One door per scan: the input checks, stage 1, the proposals' member points and stage 2, in that order, with what
the stream holds (pass3d_ros.core.stream). Both nodes, every offline tool, training's samples, the demo, pass3d_adapt
and the realism scorecard run a scan through a `ScanPipeline`, so a scan is treated the same wherever it comes from.

`propose` is stage 1's half (the cluster node's share, and all a stage-1 evaluation needs); `segment` is stage 2's
(the segmentation node's share, through a `ProposalSegmenter`, which holds the intensity map and, with tracking on,
the stream's tracker); `run` is both.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pass3d_ros.core.objects import FrameObjects, frame_objects
from pass3d_ros.core.stage1 import STEPS, Stage1Config, Stage1Result, proposal_members
from pass3d_ros.core.stage1.proposals import level_points
from pass3d_ros.core.stage2 import Classifier, groups, segmentation
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.core.stage2.segmentation import SegmentResult
from pass3d_ros.core.stream import PreparedScan, ScanStream
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stream.intensity_match import IntensityMap, StreamIntensityMatch
from pass3d_ros.core.stream.tracks import Tracker, TrackerConfig
from pass3d_ros.core.tracked_scan import TrackedScan, track_scan

NOMINAL_SCAN_PERIOD_S = 0.1  # a scan without a stamp comes this long after the last (a 10 Hz LiDAR's revolution)


def matches_intensity(wanted: bool, classifier: Classifier | None) -> bool:
    """Whether stage 2 reads intensities mapped onto the network's training scale: when `wanted` and the classifier is
    the network (size rules read no intensity, so there is nothing to map)."""
    return wanted and (classifier is None or classifier.kind != "size_rules")


@dataclass
class ProposedScan:
    """A scan after the input checks and stage 1. `members[k]`: proposal k's point indices into `scan.points` (an
    empty array for a proposal without points); `points`: `scan.points` as stage 2 reads them: in the level frame
    stage 1 ran in (`result.level`: a proposal's canonical frame stands on the ground) and with intensities on its
    training scale (the same array when neither changes anything). A scan the checks left empty has an empty result:
    stage 1 did not run."""

    scan: PreparedScan
    result: Stage1Result
    training: np.ndarray  # scan.points with intensities on stage 2's training scale (the stream's map, folded eagerly)
    stage1_ms: float = 0.0

    @cached_property
    def points(self) -> np.ndarray:
        """The points stage 2 reads: `training` in the level frame (made on first use: the cluster node never needs
        them)."""
        return level_points(self.training, self.result.level)

    @cached_property
    def members(self) -> list[np.ndarray]:
        """Each proposal's point indices into `scan.points` (made on first use: the cluster node never needs them)."""
        return proposal_members(self.result.cluster_id, self.result.cluster_id2, self.result.n_proposals)

    @property
    def empty(self) -> bool:
        """No point left after the input checks: nothing was proposed."""
        return len(self.scan.points) == 0

    @property
    def people_only(self) -> np.ndarray | None:
        """Per point of `scan.points`, whether stage 2 may call it pedestrian or background only
        (Stage1Result.people_only); None when no point is."""
        return self.result.people_only()

    def nonempty_members(self) -> list[np.ndarray]:
        """The members of the proposals that have points, in proposal order."""
        return [m for m in self.members if len(m)]

    def kept_values(self, values: np.ndarray | None) -> np.ndarray | None:
        """Per-point `values` of the input (labels, a ground mask) at the points the checks kept; None stays None."""
        kept = self.scan.kept
        return values if values is None or kept is None else values[kept]

    def in_input(self, values: np.ndarray, size: int, fill: int | float | bool) -> np.ndarray:
        """Per-point `values` of the checked points at their positions in the input of `size` points; the points
        the checks left out take `fill`."""
        kept = self.scan.kept
        if kept is None:
            return values
        out = np.full(size, fill, dtype=values.dtype)
        out[kept] = values
        return out

    def input_members(self) -> list[np.ndarray]:
        """`members` as indices into the input (they differ only when the checks left points out)."""
        kept = self.scan.kept
        return self.members if kept is None else [kept[m] for m in self.members]


@dataclass
class LabelledScan:
    """A proposed scan and stage 2's labels of its checked points."""

    proposed: ProposedScan
    segmented: SegmentResult
    stage2_ms: float = 0.0
    all_proposals: bool = True  # segmented with every proposal of `proposed`, in order (see `published`)
    tracked: TrackedScan | None = None  # with tracking on: `published` through the stream's tracker, the vote applied

    def labels_in_input(self, size: int) -> np.ndarray:
        """Stage 2's labels at the input's positions; points the checks left out are background (0). What the nodes
        publish is `published`."""
        return self.proposed.in_input(self.segmented.labels.astype(np.uint8), size, 0)

    @cached_property
    def published(self) -> FrameObjects:
        """The scan-by-scan labels, cluster ids and objects (core.objects.frame_objects: each point owned by its primary
        proposal; boxes in the level frame): what the nodes publish with tracking off; with it on they publish `output`.
        Only for a scan segmented with all its proposals."""
        if not self.all_proposals:
            raise ValueError("published: the scan was segmented with a chosen subset of its proposals")
        segmented = self.segmented
        return frame_objects(self.proposed.points, self.proposed.result.cluster_id, segmented.proposal_class,
                             segmented.labels, segmented.confidence)

    @property
    def output(self) -> FrameObjects:
        """What the nodes publish: with tracking on the objects and labels with the track's vote applied (`tracked`),
        else `published`."""
        return self.published if self.tracked is None else self.tracked.voted

    def published_in_input(self, size: int) -> tuple[np.ndarray, np.ndarray]:
        """The published labels (`output`) and cluster ids at the input's positions; points the checks left out are
        background in no proposal (0, -1)."""
        out = self.output
        return self.proposed.in_input(out.labels, size, 0), self.proposed.in_input(out.cluster_id, size, -1)


def _nothing_proposed() -> Stage1Result:
    """Stage 1's result for a scan without points, made without running it (the stream learns nothing from it)."""
    return Stage1Result(ring=np.zeros(0, np.uint16), ground=np.zeros(0, bool), cluster_id=np.zeros(0, np.int32),
                        cluster_id2=np.zeros(0, np.int32), boxes=[], timings_ms=dict.fromkeys(STEPS, 0.0),
                        ring_source="none")


class ProposalSegmenter:
    """Stage 2 on one stream's proposals: intensities onto the training scale through the map the stream holds (fitted
    on its first scans), then the classifier; with `tracking`, the published objects through the stream's tracker
    (`track`). The segmentation node holds one; a `ScanPipeline` holds one."""

    def __init__(self, classifier: Classifier, intensity_match: bool = INTENSITY_MATCH,
                 match: StreamIntensityMatch | None = None, tracking: bool = False,
                 tracker_config: TrackerConfig | None = None, people_in_groups: bool = PEOPLE_IN_GROUPS) -> None:
        self.classifier = classifier
        self.people_in_groups = people_in_groups
        self.group_parts_read = 0  # parts the last segmented scan's groups gave the classifier (core.stage2.groups)
        self.intensity_match = matches_intensity(intensity_match, classifier)
        self.match = match if match is not None else StreamIntensityMatch()
        self.tracker = Tracker(tracker_config) if tracking else None
        self._last_stamp_s: float | None = None

    def track(self, objects: FrameObjects, stamp_s: float | None = None, pose: np.ndarray | None = None,
              level: np.ndarray | None = None, points: np.ndarray | None = None,
              ground: np.ndarray | None = None) -> TrackedScan | None:
        """One scan's published objects through the stream's tracker (None with tracking off): `stamp_s` seconds
        (None: NOMINAL_SCAN_PERIOD_S after the last scan), the sensor's pose (world from sensor) when known, `level`
        the scan's levelling rotation, `points` the scan in the level frame and `ground` stage 1's ground mask
        (footprints and held objects: core.tracked_scan.track_scan)."""
        if self.tracker is None:
            return None
        if stamp_s is None:
            stamp_s = 0.0 if self._last_stamp_s is None else self._last_stamp_s + NOMINAL_SCAN_PERIOD_S
        self._last_stamp_s = stamp_s
        return track_scan(self.tracker, objects, stamp_s, pose, level, points, ground)

    def reset_tracks(self) -> None:
        """Forget the tracks (a new stream)."""
        if self.tracker is not None:
            self.tracker.reset()
        self._last_stamp_s = None

    def on_training_scale(self, points: np.ndarray) -> tuple[np.ndarray, IntensityMap | None]:
        """`points` with intensities on the training scale (the same array when matching is off or changes nothing),
        and the map when this scan's made it held (for a caller to report once)."""
        return self.match.fold(points) if self.intensity_match else (points, None)

    def segment(self, points: np.ndarray, members: list[np.ndarray], people_only: np.ndarray | None = None
                ) -> SegmentResult:
        """The classifier on points already on the training scale (`on_training_scale`); the points flagged in
        `people_only` (stage 1's `rerun_dropped` parts: ProposedScan.people_only) are pedestrian or background; with
        `people_in_groups`, proposals holding a group of people are read again person by person
        (pass3d_ros.core.stage2.groups)."""
        result = segmentation.people_only(self.classifier.segment(points, members), members, people_only)
        self.group_parts_read = 0
        if self.people_in_groups:
            result, self.group_parts_read = groups.people_in_groups(points, members, result, self.classifier)
        return result


class ScanPipeline:
    """One sensor stream's scans through the checks, stage 1 and (with a classifier) stage 2. `clock`: seconds for
    what the stream learns over time (`time.monotonic` live; None offline, each scan one revolution);
    `intensity_match`: map intensities onto stage 2's training scale (never for size rules); `tracking`: the published
    objects through the stream's tracker (Stage2Config.tracking), each segmented scan's `tracked` and `output`, with
    `tracker_config` (None: TrackerConfig's defaults); `people_in_groups`: Stage2Config.people_in_groups."""

    def __init__(self, config: Stage1Config | None = None, classifier: Classifier | None = None, *,
                 clock: Callable[[], float] | None = None, intensity_match: bool = INTENSITY_MATCH,
                 tracking: bool = False, tracker_config: TrackerConfig | None = None,
                 people_in_groups: bool = PEOPLE_IN_GROUPS) -> None:
        self.config = config or Stage1Config()  # a node replaces it when its parameters change
        self.stream = ScanStream(clock, intensity_match=matches_intensity(intensity_match, classifier))
        self.segmenter = None if classifier is None else ProposalSegmenter(classifier, intensity_match,
                                                                           self.stream.match, tracking,
                                                                           tracker_config, people_in_groups)
        self._followed: Hashable | None = None

    @property
    def classifier(self) -> Classifier | None:
        return None if self.segmenter is None else self.segmenter.classifier

    def follow(self, key: Hashable) -> None:
        """The next scan belongs to stream `key` (a dataset spec): a new key starts over (its tracks too)."""
        if key != self._followed and self.segmenter is not None:
            self.segmenter.reset_tracks()
        self._followed = key
        self.stream.follow(key)

    def prepare(self, points: np.ndarray, ring: np.ndarray | None = None, *, intensity_scale: float = 1.0,
                use_ring: bool = True) -> PreparedScan:
        """The input checks (pass3d_ros.core.stream.ScanStream.prepare) on one N x 4 float32 scan."""
        return self.stream.prepare(points, ring, self.config, intensity_scale=intensity_scale, use_ring=use_ring)

    def stage1(self, scan: PreparedScan) -> ProposedScan:
        """Stage 1 on a checked scan with the stream's held state, the proposals' members, and the points as stage 2
        will read them."""
        if len(scan.points) == 0:
            return ProposedScan(scan, _nothing_proposed(), scan.points)
        started = time.perf_counter()
        result = self.stream.propose(scan, self.config)
        stage1_ms = 1e3 * (time.perf_counter() - started)
        return ProposedScan(scan, result, self.stream.on_training_scale(scan.points), stage1_ms)

    def propose(self, points: np.ndarray, ring: np.ndarray | None = None, **checks: float | bool) -> ProposedScan:
        """`prepare` then `stage1`; `checks`: intensity_scale, use_ring."""
        return self.stage1(self.prepare(points, ring, **checks))

    def segment(self, proposed: ProposedScan, members: list[np.ndarray] | None = None, *,
                stamp_s: float | None = None, pose: np.ndarray | None = None) -> LabelledScan:
        """Stage 2 on a proposed scan's proposals (`members`: a chosen subset or order; default all of them); with
        tracking on (all proposals only: a subset is no scan of the stream), its published objects through the
        stream's tracker at `stamp_s` seconds (None: the nominal period after the last) and the sensor's `pose`
        (world from sensor) when known."""
        if self.segmenter is None:
            raise ValueError("this pipeline has no classifier: stage 1 only")
        started = time.perf_counter()
        chosen = proposed.members if members is None else members
        segmented = self.segmenter.segment(proposed.points, chosen, proposed.people_only)
        labelled = LabelledScan(proposed, segmented, 1e3 * (time.perf_counter() - started), members is None)
        if members is None:
            labelled.tracked = self.segmenter.track(labelled.published, stamp_s, pose, proposed.result.level,
                                                    proposed.points, proposed.result.ground)
        return labelled

    def run(self, points: np.ndarray, ring: np.ndarray | None = None, *, stamp_s: float | None = None,
            pose: np.ndarray | None = None, **checks: float | bool) -> LabelledScan:
        """Both stages on one scan (`propose`, then `segment`, tracked at `stamp_s` and `pose` with tracking on); a
        scan the checks empty is all background (and its tracks go unseen)."""
        proposed = self.propose(points, ring, **checks)
        if proposed.empty:
            n = len(proposed.scan.points)
            empty = SegmentResult(np.zeros(n, np.uint8), np.zeros(n, np.float32), np.zeros(0, np.int16))
            labelled = LabelledScan(proposed, empty)
            if self.segmenter is not None:
                labelled.tracked = self.segmenter.track(labelled.published, stamp_s, pose, None)
            return labelled
        return self.segment(proposed, stamp_s=stamp_s, pose=pose)
