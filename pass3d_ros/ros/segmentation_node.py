"""Stage-2 node: proposals cloud in, labeled cloud (label, confidence, rgb) and objects (markers, detections) out.

Detections (vision_msgs) go out where vision_msgs imports; see pass3d_ros.ros.detections. The labeled cloud in the
input's own layout (`output_layout: as_input`) and the background cloud (`publish_background`) are built from the
frame's source, the input as it came; see pass3d_ros.ros.input_layout.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, NamedTuple

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN, packed_rgb
from pass3d_ros.core import scan_checks, tracked_scan
from pass3d_ros.core.objects import FrameObjects, LabelledObject, frame_objects
from pass3d_ros.core.objects import warm_up as warm_up_objects
from pass3d_ros.core.pipeline import ProposalSegmenter
from pass3d_ros.core.stage1 import proposal_members
from pass3d_ros.core.stage1.proposals import level_points
from pass3d_ros.core.stage2 import Classifier, open_classifier
from pass3d_ros.core.stage2.classifier_process import (
    ClassifierProcessDownError,
    ClassifierProcessHungError,
    ProcessClassifier,
)
from pass3d_ros.core.stage2.config import Stage2Config, parameter_table
from pass3d_ros.core.stage2.segmentation import SegmentResult, proposals_cut
from pass3d_ros.core.stream import shapes
from pass3d_ros.core.threads import limit_threads
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, encode, header_stamp_ns
from pass3d_ros.msgs.pointcloud2 import warm_up as warm_up_codec
from pass3d_ros.ros import params
from pass3d_ros.ros.detections import DetectionOutputs
from pass3d_ros.ros.diagnostics import StepClock
from pass3d_ros.ros.input_layout import (
    AS_INPUT,
    LABEL_COLUMNS,
    OUTPUT_LAYOUT_HELP,
    background_cloud,
    check_layout,
    compact_background,
    labeled_as_input,
)
from pass3d_ros.ros.latest_frame import DROPPED, FrameCounters, LatestFrameWorker, Outcome
from pass3d_ros.ros.markers import boxes_to_markers
from pass3d_ros.ros.node_base import LOG_PERIOD_S, PointCloudNode
from pass3d_ros.ros.odometry import NO_MOUNT, OdometryPoses, sensor_in_base
from pass3d_ros.ros.proposals import ProposalFrame, dense_ids, nearest_proposals, proposal_frame, source_ids
from pass3d_ros.ros.qos import INPUT_QOS_HELP, QOS_NAMES, qos_profile
from pass3d_ros.ros.run import run_nodes

HUNG_ERROR_S = 10.0  # a stage-2 process killed for hanging stays an ERROR on /diagnostics this long (seen at 1 Hz)

NODE_PARAMETERS: dict[str, tuple[Any, str, tuple[float, float] | None]] = {
    "input_topic": ("pass3d/proposals", "proposals cloud from cluster_proposal_node", None),
    "labeled_topic": ("pass3d/labeled", "output: labeled cloud (label, confidence, rgb)", None),
    "output_layout": ("compact", f"{OUTPUT_LAYOUT_HELP}; as_input needs cluster_proposal_node's output_layout as_input "
                      "too (pass3d_pipeline: always there)", None),
    "publish_background": (False, "publish background_topic: the input without the points labeled car, pedestrian or "
                           "cyclist, every input field as it came, input order, height 1 (for odometry / SLAM; while "
                           "something subscribes)", None),
    "background_topic": ("pass3d/background", "output: the background cloud (publish_background)", None),
    "objects_topic": ("pass3d/objects", "output: MarkerArray, one box and text per labeled object", None),
    "detections_topic": ("pass3d/detections", "output: vision_msgs/Detection3DArray, one detection per labeled "
                         "object (where vision_msgs is installed)", None),
    "label_info_topic": ("pass3d/label_info", "output: vision_msgs/LabelInfo, the class map (transient local, "
                         "where vision_msgs is installed)", None),
    "odometry_topic": ("", "input: the robot's nav_msgs/Odometry (empty: none); with tracking on, tracks are kept in "
                       "its world frame, so the robot's own motion is no object's", None),
    "sensor_in_base": (NO_MOUNT, "the sensor in the odometry's child frame: x y z roll pitch yaw (m, rad), as a URDF "
                       "joint's origin states it", None),
    "odometry_max_gap": (0.2, "a scan takes a pose only from odometry this close to its stamp (s)", (0.0, 10.0)),
    "input_qos": ("auto", INPUT_QOS_HELP, None),
    "output_qos": ("reliable", f"QoS of the outputs: {' or '.join(QOS_NAMES)}", None),
    **parameter_table(),  # stage 2's settings: Stage2Config (pass3d_ros.core.stage2.config)
    "overlap": (False, "pass3d_pipeline only: segment on this node's own thread, so stage 1 of the next scan "
                "overlaps stage 2 (more frames per second with a spare core; far fewer when the CPU is shared)", None),
}
PARAMETERS = params.NodeParameters("segmentation_node", NODE_PARAMETERS)


def thresholded(result: SegmentResult, min_confidence: float) -> np.ndarray:
    """Stage 2's labels (uint8) with the points below `min_confidence` background."""
    labels = result.labels.astype(np.uint8)
    if min_confidence > 0.0:
        labels = np.where(result.confidence >= min_confidence, labels, BACKGROUND).astype(np.uint8)
    return labels


def published(frame: ProposalFrame, proposals: Budgeted, result: SegmentResult, min_confidence: float
              ) -> FrameObjects:
    """The labels, cluster ids and objects the frame publishes: core.objects.frame_objects on the thresholded labels,
    each point owned by the proposal it is published with; boxes fitted in the level frame (they stand on the
    ground)."""
    return frame_objects(frame.levelled, proposals.owner, result.proposal_class,
                         thresholded(result, min_confidence), result.confidence, frame.cluster_id)


def labeled_cloud(frame: ProposalFrame, labels: np.ndarray, cluster_id: np.ndarray, confidence: np.ndarray,
                  track_id: np.ndarray | None = None) -> dict:
    """The columns of /pass3d/labeled: input geometry, and the published cluster ids, labels (`published`, with
    tracking on the vote applied) and stage 2's confidences, rgb, and with tracking on each point's `track_id`."""
    labels = np.asarray(labels, dtype=np.uint8)
    points = frame.points
    columns = {
        "x": points[:, 0],
        "y": points[:, 1],
        "z": points[:, 2],
        "intensity": points[:, 3],
    }
    if frame.ring is not None:
        columns["ring"] = frame.ring.astype(np.uint16, copy=False)
    columns["cluster_id"] = np.asarray(cluster_id, dtype=np.int32)
    columns["label"] = labels
    columns["confidence"] = np.asarray(confidence, dtype=np.float32)
    columns["rgb"] = packed_rgb(labels)
    if track_id is not None:
        columns["track_id"] = np.asarray(track_id, dtype=np.int32)
    return columns


def marker_text(obj: LabelledObject) -> str:
    """A tracked object's marker text: its class and its track id ("car 12"), the class alone while tentative."""
    return obj.class_id if obj.track_id < 0 else f"{obj.class_id} {obj.track_id}"


class Budgeted(NamedTuple):
    """The proposals of a frame stage 2 classifies: their member points, their cluster ids in the message, and per
    point the proposal it is published with (its primary; -1: none, or cut by the budget)."""

    members: list[np.ndarray]
    ids: np.ndarray
    owner: np.ndarray


class Labeled(NamedTuple):
    """A segmented frame on its way to being published."""

    frame: ProposalFrame
    proposals: Budgeted
    result: SegmentResult
    clock: StepClock


class SegmentationNode(PointCloudNode):
    """Runs the stage-2 classifier on every proposal of a frame in one batched pass.

    `in_memory=True` (both nodes in one process): no subscription; frames come from the cluster node through
    `submit_proposals`.
    """

    publisher: LatestFrameWorker[Labeled] | None = None  # the publishing thread (overlap and process); a class
    # default, because diagnostics may ask for the counters before __init__ has decided
    detections: DetectionOutputs | None = None  # the vision_msgs publishers; None without vision_msgs
    odometry: OdometryPoses | None = None  # the robot's poses (odometry_topic, with tracking on)

    def __init__(self, in_memory: bool = False, **kwargs: Any) -> None:
        super().__init__(PARAMETERS, **kwargs)
        self.settings = params.read_config(self, Stage2Config)  # stage 2's settings, read at start-up
        self.output_layout = check_layout(self.get_parameter("output_layout").value)
        self.points_dropped = 0  # input points with implausible coordinates, left out
        self.proposals_cut = 0  # input proposals beyond max_proposals, labeled background
        self.frames_down = 0  # frames dropped because the stage-2 process was down (or killed for hanging)
        self.frames_hung = 0  # frames whose stage-2 process answered nothing for stage2_timeout (killed)
        self.frames_late = 0  # frames whose result came after stage2_timeout, dropped instead of published late
        self._hung: tuple[float, str] | None = None  # when stage 2 was last killed for hanging, and why
        # max_proposals and stage2_timeout as the next frame takes them; one set while a frame is in stage 2 waits for
        # its end (`_frame_settings`), so the budget, the classifier and the late check of a frame read the same values
        self._settings_lock = threading.Lock()
        self._in_stage2 = False
        self._pending: dict[str, Any] = {}
        self._stage2_timeout = self.settings.stage2_timeout
        scan_checks.warm_up()
        shapes.warm_up()
        warm_up_objects()
        warm_up_codec()  # the proposals cloud is decoded here too, maybe in a process of its own
        tracked_scan.warm_up()
        self.classifier = self._load_classifier()
        # stage 2's share of the one door: the stream's intensity map onto the training scale, then the classifier
        # and, with tracking on, the stream's tracker (objects over time: pass3d_ros.core.tracked_scan)
        self.stage2 = ProposalSegmenter(self.classifier, self.settings.intensity_match,
                                        tracking=self.settings.tracking,
                                        tracker_config=self.settings.tracker_config(),
                                        people_in_groups=self.settings.people_in_groups)
        self.odometry = self._subscribe_odometry()
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.labeled_pub = self.output_publisher(PointCloud2, "labeled_topic")
        self.objects_pub = self.output_publisher(MarkerArray, "objects_topic")
        self.background_pub = self.output_publisher(PointCloud2, "background_topic") \
            if self.get_parameter("publish_background").value else None
        self.detections = DetectionOutputs.open(self, self.get_parameter("detections_topic").value,
                                                self.get_parameter("label_info_topic").value,
                                                qos_profile(self.get_parameter("output_qos").value))
        if self.detections is not None:
            self.detections.publish_label_info(self.get_parameter("min_confidence").value)
        self.overlap = in_memory and bool(self.get_parameter("overlap").value)
        self.start_worker(self._process, "stage2", subscribe=not in_memory)
        # With overlap and the classifier in a child process, a third thread encodes and publishes, so the stage-2
        # thread hands the next scan to the child at once (20 Hz, four back-to-back pairs: +1 to +11 % frames). With
        # stage 2 on a thread of this process it only added a third thread taking turns for the GIL.
        if self.overlap and isinstance(self.classifier, ProcessClassifier):
            self.publisher = LatestFrameWorker(self._publish, self._on_error, "publish")

    def _subscribe_odometry(self) -> OdometryPoses | None:
        """The odometry poses the tracker reads (None without `odometry_topic`, or with tracking off: then unused)."""
        topic = self.get_parameter("odometry_topic").value
        if not topic:
            return None
        if not self.settings.tracking:
            self.get_logger().warning(f"odometry_topic {topic} is read only with tracking on: not subscribed")
            return None
        poses = OdometryPoses(sensor_in_base(self.get_parameter("sensor_in_base").value),
                              float(self.get_parameter("odometry_max_gap").value))
        self.create_subscription(Odometry, topic, self._on_odometry, qos_profile("reliable"))
        return poses

    def _on_odometry(self, msg: Odometry) -> None:
        """Hold the message's pose; one with a non-finite or implausible position or a zero quaternion is skipped,
        counted and warned about (throttled), and so is a change of the messages' frames (OdometryPoses.add_message)."""
        if self.odometry is None:
            return
        before, changes = self.odometry.frames, self.odometry.frame_changes
        if not self.odometry.add_message(msg):
            self.get_logger().warning(
                f"skipping odometry message: non-finite or implausible position, or zero quaternion "
                f"({self.odometry.rejected} so far)",
                throttle_duration_sec=LOG_PERIOD_S)
        if self.odometry.frame_changes > changes:
            self.get_logger().warning(
                f"odometry frames changed from {before[0]!r} -> {before[1]!r} to {self.odometry.frames[0]!r} -> "
                f"{self.odometry.frames[1]!r}: poses held before dropped; tracks move as the frames differ",
                throttle_duration_sec=LOG_PERIOD_S)

    def submit_proposals(self, frame: ProposalFrame) -> None:
        """The in-memory input: stage 1's result for one frame, segmented at once on the caller's thread, or with
        `overlap` handed to this node's worker thread (its slot keeps the newest frames and counts drops).

        In line, a frame's latency is its compute and the cluster node's slot drops stale scans. On its own thread
        stage 2 overlaps the next scan's stage 1, but the two contend for the GIL at every torch op: measured
        (docs/performance.md) +15-19 % frames at 20 Hz with a core to spare, and 8.0 instead of 9.9 Hz beside a CPU hog.
        """
        if self.overlap:
            self.submit(frame, header_stamp_ns(frame))
            return
        self.stats.input(header_stamp_ns(frame))
        self.worker.run_inline(frame)

    def _load_classifier(self) -> Classifier:
        """Load and warm up the classifier; missing or incompatible weights end start-up with the reason."""
        config = self.settings
        threads = config.threads
        if threads > 0:
            self.get_logger().info(limit_threads(threads).describe())
        started = time.perf_counter()
        weights, kind = config.weights, config.classifier
        device, max_proposals = config.device, config.max_proposals
        if config.process:
            classifier: Classifier = ProcessClassifier(weights, kind, device=device, max_proposals=max_proposals,
                                                       threads=threads, report=self._on_stage2_report,
                                                       timeout_s=config.stage2_timeout)
            where = f" in process {classifier.pid}"
        else:
            classifier = open_classifier(weights, kind, device=device, max_proposals=max_proposals)
            classifier.warm_up()
            where = ""
        took = 1e3 * (time.perf_counter() - started)
        self.get_logger().info(f"stage 2 ready{where}: {classifier.kind} {classifier.weights or ''} "
                               f"(load + warm-up {took:.0f} ms)")
        return classifier

    def _on_stage2_report(self, level: str, message: str) -> None:
        """The stage-2 process's supervisor: each death and failed restart is an error, a restart is news."""
        if level == "error":
            self.get_logger().error(message)
        else:
            self.get_logger().info(message)

    def counters(self) -> FrameCounters:
        """The stage-2 worker's counters; with a publishing thread, a frame counts as processed once published, and
        a result that thread dropped for a newer one counts as dropped. A frame that found the stage-2 process down
        or hung, or whose result came late, counts as dropped."""
        stage2 = self.worker.counters
        if self.publisher is None:
            return FrameCounters(**vars(stage2))
        publish = self.publisher.counters
        return FrameCounters(received=stage2.received, processed=publish.processed,
                             dropped=stage2.dropped + publish.dropped, failed=stage2.failed + publish.failed,
                             skipped=stage2.skipped)

    def publish_diagnostics(self) -> None:
        """The base status, once the classifier exists (diagnostics may fire during start-up)."""
        if hasattr(self, "classifier"):
            super().publish_diagnostics()

    def diagnostic_extras(self) -> tuple[dict[str, float | int], list[str]]:
        """What the input checks, the intensity map and the stage-2 process did; a warning while that process is
        down."""
        values: dict[str, float | int] = {"points_dropped": self.points_dropped, "proposals_cut": self.proposals_cut,
                                          "frames_late": self.frames_late}
        held = self.stage2.match.map
        if held is not None:
            values["intensity_median"] = held.median
            values["intensity_matched"] = int(held.kind == "matched")
        tracker = self.stage2.tracker
        if tracker is not None:
            values.update({"tracks_alive": tracker.alive, "tracks_born": tracker.born, "tracks_lost": tracker.lost})
        if self.odometry is not None:
            values.update({"scans_without_pose": self.odometry.missing, "odometry_rejected": self.odometry.rejected,
                           "odometry_frame_changes": self.odometry.frame_changes})
        warnings = []
        if isinstance(self.classifier, ProcessClassifier):
            values["stage2_restarts"] = self.classifier.restarts
            values["stage2_hangs"] = self.classifier.hangs
            down = self.classifier.down_for()
            if down is not None:
                warnings.append(f"stage-2 process down for {down:.0f} s, restarting; frames are dropped")
        return values, warnings

    def diagnostic_errors(self) -> list[str]:
        """A stage-2 process killed for hanging, for HUNG_ERROR_S after the kill."""
        hung = self._hung
        if hung is None or time.monotonic() - hung[0] > HUNG_ERROR_S:
            return []
        return [hung[1]]

    def idle(self) -> bool:
        """True when neither the stage-2 thread nor the publishing thread has a frame."""
        return self.worker.idle() and (self.publisher is None or self.publisher.idle())

    def stop_worker(self) -> None:
        """Stop the stage-2 thread, then the publishing thread (each finishes the frame in hand; a pending one is
        dropped)."""
        super().stop_worker()
        if self.publisher is not None:
            self.publisher.stop()

    def destroy_node(self) -> None:
        """Stop the workers, then the classifier's process if it has one."""
        super().destroy_node()
        if isinstance(self.classifier, ProcessClassifier):
            self.classifier.close()

    def _on_set_parameters(self, changed: list[Parameter]) -> Any:
        """Only max_proposals, min_confidence, stage2_timeout and use_sim_time (rclpy's clock takes it) change at run
        time; the rest need a restart."""
        live = {"max_proposals", "min_confidence", "stage2_timeout", "use_sim_time"}
        fixed = [p.name for p in changed if p.name not in live]
        if fixed:
            return params.result(False, f"{', '.join(fixed)} can only be set at start-up")
        with self._settings_lock:
            self._pending.update({p.name: p.value for p in changed if p.name in ("max_proposals", "stage2_timeout")})
            if not self._in_stage2:
                self._take_changes()
        for p in changed:
            if p.name == "min_confidence" and self.detections is not None:
                self.detections.publish_label_info(p.value)  # LabelInfo's threshold follows it
        return params.result(True)

    def _take_changes(self) -> None:
        """Hand the max_proposals and stage2_timeout set since the last frame to the classifier (under
        `_settings_lock`, while no frame is in stage 2)."""
        pending, self._pending = self._pending, {}
        if "max_proposals" in pending:
            self.classifier.max_proposals = int(pending["max_proposals"])
        if "stage2_timeout" in pending:
            self._stage2_timeout = float(pending["stage2_timeout"])
            if isinstance(self.classifier, ProcessClassifier):
                self.classifier.timeout_s = self._stage2_timeout

    @contextmanager
    def _frame_settings(self) -> Iterator[tuple[int, float]]:
        """The max_proposals and stage2_timeout of the frame in stage 2: a change set meanwhile waits for the frame's
        end, so one frame never mixes two values (budgeted with one limit, classified with another)."""
        with self._settings_lock:
            self._in_stage2 = True
            settings = int(self.classifier.max_proposals), self._stage2_timeout
        try:
            yield settings
        finally:
            with self._settings_lock:
                self._in_stage2 = False
                self._take_changes()

    def _process(self, item: PointCloud2 | ProposalFrame) -> Outcome | None:
        """One frame: decode (a message: implausible points left out), segment up to max_proposals proposals,
        publish; malformed input is logged and skipped, a frame that finds the stage-2 process down or hung, or
        whose result comes after stage2_timeout, is dropped (a late result is never published)."""
        clock = self.step_clock()
        try:
            frame = item if isinstance(item, ProposalFrame) else self._plausible(proposal_frame(item))
        except PointCloud2Error as exc:
            self.get_logger().warning(f"skipping malformed proposals cloud: {exc}", throttle_duration_sec=LOG_PERIOD_S)
            return self.skipped("malformed")
        points = frame.points
        if len(points) == 0:
            self.get_logger().warning("skipping empty proposals cloud", throttle_duration_sec=LOG_PERIOD_S)
            return self.skipped("empty")
        with self._frame_settings() as (limit, timeout):
            proposals = self._budget(frame, limit)
            members = proposals.members
            stage2_points = level_points(self._on_training_scale(points), frame.level)
            clock.mark("decode")
            try:
                result = self.stage2.segment(stage2_points, members, frame.people_only)
            except ClassifierProcessHungError as exc:  # killed by the supervisor, which logged it; restarted
                self.frames_down += 1
                self.frames_hung += 1
                self._hung = (time.monotonic(), str(exc))
                return DROPPED
            except ClassifierProcessDownError:  # its death was logged once by the supervisor; this frame is dropped
                self.frames_down += 1
                return DROPPED
        clock.mark("compute")
        if clock.steps_ms["compute"] > 1e3 * timeout:
            self.frames_late += 1
            self.get_logger().warning(
                f"stage 2 took {clock.steps_ms['compute'] / 1e3:.1f} s, over stage2_timeout {timeout:g} s: the frame "
                "is dropped, not published late", throttle_duration_sec=LOG_PERIOD_S)
            return DROPPED
        labeled = Labeled(frame, proposals, result, clock)
        if self.publisher is None:
            self._publish(labeled)
        else:
            self.publisher.submit(labeled)

    def _on_training_scale(self, points: np.ndarray) -> np.ndarray:
        """The points with their intensities mapped onto the network's training scale (`intensity_match`); the
        published cloud keeps the sensor's own. The map is reported once, when it is held."""
        points, held = self.stage2.on_training_scale(points)
        if held is not None:
            self.get_logger().info(f"intensity: {held}")
        return points

    def _plausible(self, frame: ProposalFrame) -> ProposalFrame:
        """The frame without points whose coordinates no LiDAR returns (as the cluster node drops them), warned
        about (throttled) and counted; a non-finite intensity reads 0, as the cluster node reads it (warned about,
        throttled), so that it does not blank its proposal."""
        summary = scan_checks.scan_summary(frame.points)
        if summary.nonfinite_intensity:
            points = frame.points.copy()
            points[:, 3] = np.nan_to_num(points[:, 3], nan=0.0, posinf=0.0, neginf=0.0)
            frame = dataclasses.replace(frame, points=points)
            self.get_logger().warning(f"intensity: {summary.intensity_problem()}, read as 0",
                                      throttle_duration_sec=LOG_PERIOD_S)
        if summary.plausible:
            return frame
        keep = scan_checks.plausible_points(frame.points)
        dropped = int(np.count_nonzero(~keep))
        self.points_dropped += dropped
        self.get_logger().warning(scan_checks.dropped_points_warning(dropped), throttle_duration_sec=LOG_PERIOD_S)
        source = frame.source
        if source is not None:
            positions = np.arange(len(frame.points)) if source.positions is None else source.positions
            source = dataclasses.replace(source, positions=positions[keep])
        return ProposalFrame(frame.header, frame.points[keep], None if frame.ring is None else frame.ring[keep],
                             frame.cluster_id[keep], frame.cluster_id2[keep], source, frame.level,
                             None if frame.ground is None else frame.ground[keep],
                             None if frame.people_only is None else frame.people_only[keep])

    def _budget(self, frame: ProposalFrame, limit: int) -> Budgeted:
        """Member points and cluster ids of the frame's proposals, at most `limit` (max_proposals) of them (the
        nearest): the cut ones are not classified, so their points are background; a cut is counted and warned about
        (throttled)."""
        first, second, count = dense_ids(frame.cluster_id, frame.cluster_id2)
        cut = proposals_cut(count, limit)
        if cut:
            first, second, _ = nearest_proposals(frame.points, first, second, count, limit)
            self.proposals_cut += cut
            self.get_logger().warning(
                f"{count} proposals in one frame, max_proposals {limit}: the nearest {limit} are classified, the "
                f"points of the other {count - limit} labeled background", throttle_duration_sec=LOG_PERIOD_S)
            count = limit
        ids = source_ids((frame.cluster_id, frame.cluster_id2), (first, second), count)
        return Budgeted(proposal_members(first, second, n_proposals=count), ids, first)

    def _publish(self, labeled: Labeled) -> None:
        """Encode and publish one segmented frame (and its objects, as markers and detections, to whoever listens)."""
        frame, proposals, result, clock = labeled
        if self.publisher is not None:
            clock.mark("handoff")  # the wait in the publishing thread's slot
        out = published(frame, proposals, result, self.get_parameter("min_confidence").value)
        pose = None if self.odometry is None else self.odometry.pose_at(header_stamp_ns(frame))
        if self.odometry is not None and pose is None:
            self.get_logger().warning("no odometry within odometry_max_gap of the scan: tracked in the sensor's frame",
                                      throttle_duration_sec=LOG_PERIOD_S)
        if self.follow_frame(frame.header.frame_id, None if self.stage2.tracker is None else "the tracks start over"):
            self.stage2.reset_tracks()  # nothing to forget with tracking off
        tracked = self.stage2.track(out, header_stamp_ns(frame) * 1e-9, pose=pose, level=frame.level,
                                    points=frame.levelled, ground=frame.ground)
        out = out if tracked is None else tracked.voted
        clock.mark("compute")  # the objects, the labels and ids they settle, and with tracking on the vote
        columns = labeled_cloud(frame, out.labels, out.cluster_id, result.confidence,
                                None if tracked is None else tracked.track_id)
        source = frame.source
        if self.output_layout == AS_INPUT and source is None:
            self.warn_once("as_input", "output_layout as_input, but the proposals carry only the points stage 1 read: "
                            "publishing compact; set output_layout as_input on cluster_proposal_node too")
        if self.output_layout == AS_INPUT and source is not None:
            replaced = source.replaced(LABEL_COLUMNS + (("track_id",) if tracked is not None else ()))
            if replaced:
                self.warn_once("replaced", f"output_layout as_input: the input's field(s) {', '.join(replaced)} are "
                                "replaced by this node's")
            cloud = encode(labeled_as_input(source, columns), header=frame.header, height=source.height,
                           is_dense=source.is_dense)
        else:
            cloud = encode(columns, header=frame.header, is_dense=True)  # NaN points never reach stage 2
        clock.mark("encode")
        self.labeled_pub.publish(cloud)
        clock.mark("publish")
        labels = columns["label"]
        self._publish_background(frame, columns, clock)
        self._publish_objects(frame, out.objects, tracked is not None, clock)
        self.stats.frame(clock.steps_ms)
        # counted class by class: np.bincount of 120k uint8 labels took 1.3-3 ms
        counts = [int(np.count_nonzero(labels == k)) for k in (CAR, PEDESTRIAN, CYCLIST)]
        self.get_logger().info(
            f"{len(frame.points)} points, {len(proposals.members)} proposals, labeled car/ped/cyc points {counts}, "
            f"stage2 {sum(clock.steps_ms.values()):.1f} ms, dropped {self.counters().dropped}{self.missed_note()}",
            throttle_duration_sec=LOG_PERIOD_S,
        )

    def _publish_background(self, frame: ProposalFrame, columns: dict, clock: StepClock) -> None:
        """The input without its object points, while something subscribes; from the compact columns (warned once)
        when the frame has no source."""
        if self.background_pub is None or self.background_pub.get_subscription_count() == 0:
            return
        if frame.source is None:
            self.warn_once("background", "publish_background: the proposals carry only the points stage 1 read, so "
                            "the background cloud has only x, y, z, intensity, ring; the input's other fields need "
                            "output_layout as_input or publish_background true on cluster_proposal_node")
            cloud = encode(compact_background(columns), header=frame.header, is_dense=True)
        else:
            cloud = encode(background_cloud(frame.source, columns["label"]), header=frame.header)
        clock.mark("encode")
        self.background_pub.publish(cloud)
        clock.mark("publish")

    def _publish_objects(self, frame: ProposalFrame, objects: list[LabelledObject], tracking: bool,
                         clock: StepClock) -> None:
        """The frame's objects (`published`, or with `tracking` voted and carrying track ids) as markers and as
        detections, each only while something subscribes; with tracking the markers' texts and the detections' ids
        are the track ids."""
        markers = self.objects_pub.get_subscription_count() > 0
        detections = self.detections is not None and self.detections.wanted()
        if not (markers or detections):
            return
        if markers:
            boxes = [obj.box() for obj in objects]
            texts = [marker_text(obj) for obj in objects] if tracking else None
            array = boxes_to_markers(boxes, frame.header, "objects", [obj.label for obj in objects], with_text=True,
                                     level=frame.level, texts=texts)
            clock.mark("encode")
            self.objects_pub.publish(array)
            clock.mark("publish")
        if detections:
            message = self.detections.message(objects, frame.header, frame.level, tracking)
            clock.mark("encode")
            self.detections.publish(message)
            clock.mark("publish")

def main(argv: list[str] | None = None) -> int:
    """`ros2 run pass3d_ros segmentation_node [--ros-args ...]`."""
    return run_nodes("segmentation_node", [SegmentationNode], argv)


if __name__ == "__main__":
    sys.exit(main())
