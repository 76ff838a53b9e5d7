"""Stage-1 node: Velodyne PointCloud2 in, proposals cloud (ring, ground, cluster ids) and proposal boxes out."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, Any

from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from pass3d_ros.core import scan_checks
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config, Stage1Result, warm_up
from pass3d_ros.core.stage1.config import AUTO, STAGE1_PREFIX
from pass3d_ros.core.stage1.mounting import level_rotation
from pass3d_ros.core.stage1.mounting import problems as mounting_problems
from pass3d_ros.core.stage1.ring_field import RingFieldOrder
from pass3d_ros.core.stream import Note
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, decode, encode, to_xyzi
from pass3d_ros.msgs.pointcloud2 import warm_up as warm_up_codec
from pass3d_ros.ros import params
from pass3d_ros.ros.input_layout import (
    AS_INPUT,
    STAGE1_COLUMNS,
    WIRE_PREFIX,
    check_layout,
    full_proposals_cloud,
    input_source,
)
from pass3d_ros.ros.latest_frame import Outcome
from pass3d_ros.ros.markers import boxes_to_markers
from pass3d_ros.ros.node_base import LOG_PERIOD_S, PointCloudNode
from pass3d_ros.ros.proposals import ProposalFrame, ProposalSink, proposals_cloud
from pass3d_ros.ros.qos import INPUT_QOS_HELP, QOS_NAMES
from pass3d_ros.ros.run import run_nodes

if TYPE_CHECKING:
    from pass3d_ros.core.stream import ScanStream

NODE_PARAMETERS: dict[str, tuple[Any, str, tuple[float, float] | None]] = {
    "input_topic": ("/velodyne_points", "PointCloud2 topic of the LiDAR driver", None),
    "proposals_topic": ("pass3d/proposals", "output: all valid points with ring, ground, cluster_id(2)", None),
    "boxes_topic": ("pass3d/proposal_boxes", "output: MarkerArray of the proposal boxes", None),
    "input_qos": ("auto", INPUT_QOS_HELP, None),
    "output_qos": ("reliable", f"QoS of the outputs: {' or '.join(QOS_NAMES)}", None),
    "intensity_scale": (
        1.0, "multiplies the input intensity into [0,1] (1/255 for a 0..255 driver, 1/65535 for 16-bit "
        "reflectivity); a scan still outside 0..1 is divided by its detected full scale, with a warning", (0.0, 1.0),
    ),
    "use_ring_field": (True, "use the cloud's ring field when present, in any numbering (measured from the points' "
                       "elevations; a field that does not fit them is ignored), else recover rings from the points",
                       None),
    "publish_boxes": (True, "publish the proposal boxes MarkerArray", None),
    "output_layout": ("compact", "compact: /pass3d/proposals carries the points stage 1 read; as_input: every input "
                      "point and field in the input's layout, so segmentation_node can publish as_input (give both "
                      "nodes the same value)", None),
    "publish_background": (False, "true: /pass3d/proposals carries every input point and field, as for output_layout "
                           "as_input (so segmentation_node can publish the background cloud)", None),
}
PARAMETERS = params.NodeParameters("cluster_proposal_node", NODE_PARAMETERS, {STAGE1_PREFIX: Stage1Config})


class ClusterProposalNode(PointCloudNode):
    """Subscribes a scan, runs ground plane fitting, scan-line-run clustering and proposal refinement.

    With a `sink` (both nodes in one process) every frame's result goes to it in memory; the proposals cloud
    and the boxes are then encoded and published only while something subscribes to them.
    """

    def __init__(self, sink: ProposalSink | None = None, **kwargs: Any) -> None:
        super().__init__(PARAMETERS, **kwargs)
        self.sink = sink
        self._ring_order: RingFieldOrder | None = None  # the order last reported (pass3d_ros.core.stage1.ring_field)
        self._sensor_source: tuple[str, int] | None = None
        # the one door per scan; its stream holds what the scans taught: laser lines, ring order, mounting, intensity
        # scale (pass3d_ros.core.stream)
        self._pipeline = ScanPipeline(params.read_config(self, Stage1Config, STAGE1_PREFIX), clock=time.monotonic,
                                      intensity_match=False)
        self._next_config = self._pipeline.config  # the stage-1 values set last, for the worker (_take_changes)
        self._intensity_scale: float | None = None  # the intensity_scale the stream's full scale was read under
        self._noted: dict[str, float] = {}  # when each topic of the input checks was last logged
        # proposals in the input's layout (pass3d_ros.ros.input_layout), for segmentation_node's as_input / background
        self._full = (check_layout(self.get_parameter("output_layout").value) == AS_INPUT
                      or bool(self.get_parameter("publish_background").value))
        self.add_on_set_parameters_callback(self._on_set_parameters)

        started = time.perf_counter()
        self.get_logger().info("stage 1: loading the compiled kernels (the first start after an install compiles "
                               "them with numba, about 20-30 s; later starts read numba's cache)")
        warm_up()
        scan_checks.warm_up()
        warm_up_codec()
        self.get_logger().info(f"stage 1 ready (numba warm-up {1e3 * (time.perf_counter() - started):.0f} ms)")

        self.proposals_pub = self.output_publisher(PointCloud2, "proposals_topic")
        self.boxes_pub = self.output_publisher(MarkerArray, "boxes_topic")
        self.start_worker(self._process, "stage1")

    @property
    def config(self) -> Stage1Config:
        """The stage-1 parameters the next scan runs with."""
        return self._next_config

    @property
    def stream(self) -> ScanStream:
        """What this node's stream learned and holds (laser lines, mounting, body, intensity scale)."""
        return self._pipeline.stream

    def _on_set_parameters(self, changed: list[Parameter]) -> Any:
        """Refuse invalid stage-1 values; hand valid ones to the worker for the next frame (`_take_changes`)."""
        start_up_only = ("input_topic", "proposals_topic", "boxes_topic", "input_qos", "output_qos", "output_layout",
                         "publish_background")
        fixed = [p.name for p in changed if p.name in start_up_only]
        if fixed:
            return params.result(False, f"{', '.join(fixed)} can only be set at start-up")
        config, reason = params.validate_changes(self, Stage1Config, changed, STAGE1_PREFIX)
        if config is None:
            return params.result(False, reason)
        if config != self._next_config:
            self._next_config = config
        return params.result(True)

    def _take_changes(self) -> float:
        """Before a frame, on the worker's thread: take up the stage-1 values and the intensity_scale set since the
        last frame, and return that intensity_scale. New stage-1 values forget the held laser lines (the mounting,
        body and full scale stay: the sensor did not move); a new intensity_scale forgets the stream's full scale,
        read afresh from the next scans (else a corrected 1/255 stays divided by the 255 held for FRAMES_TO_LOWER
        scans). Done here, not in the parameter callback, so a frame in hand ends with the values it began with and
        cannot hold its lines again after the reset."""
        if self._next_config is not self._pipeline.config:
            self._pipeline.config = self._next_config
            self.stream.lines.reset()
        scale = self.get_parameter("intensity_scale").value
        if self._intensity_scale is not None and scale != self._intensity_scale:
            self.stream.restart_scale()
        self._intensity_scale = scale
        return scale

    def _report_sensor(self, result: Stage1Result) -> None:
        """Log the stream's ring source and effective stage-1 values when they first appear or the source changes
        (only on a change, so not throttled: a throttle would hide the change that matters); warn (throttled) when
        rings could not be recovered and came from elevation bins."""
        source = (result.ring_source, result.sensor.n_rings if result.sensor else 0)
        if source != self._sensor_source:
            self._sensor_source = source
            scale = result.sensor.describe() if result.sensor else "no scale"
            self.get_logger().info(f"rings from {result.ring_source}: {scale}")
        if result.ring_source == "elevation_bins":
            self.get_logger().warning(
                "ring: rings could not be recovered (no ring field, no firing order, no laser lines found); binned by "
                "elevation, which splits or merges lasers: publish the driver's ring field or set stage1.sensor",
                throttle_duration_sec=LOG_PERIOD_S)

    def _log_notes(self, notes: list[Note]) -> None:
        """Log what the input checks repaired: throttled per topic (one rclpy call site would throttle every topic
        together), a change of the stream's scale always."""
        now = time.monotonic()
        for note in notes:
            if note.throttle and now - self._noted.get(note.topic, -LOG_PERIOD_S) < LOG_PERIOD_S:
                continue
            self._noted[note.topic] = now
            self.get_logger().warning(note.text)

    def _report_ring_field(self, result: Stage1Result) -> None:
        """Log the ring field's numbering when the stream's order is first measured or changes; warn (once per
        measurement) when the field does not fit the points and is ignored."""
        order = result.ring_order
        if order is None or order is self._ring_order:
            return
        self._ring_order = order
        if order.fits:
            self.get_logger().info(f"ring field: numbered {order.convention.replace('_', '-')} (measured from the "
                                   f"points' elevations; {100 * order.fit_share:.0f} % of returns fit their ring)")
        else:
            self.get_logger().warning(
                f"ring field: does not fit the points (only {100 * order.fit_share:.0f} % of returns sit at their "
                "ring's elevation); ignored, rings recovered from the points (set use_ring_field false to silence)")

    _mounting_said: tuple[Any, Any] = (None, None)  # the held mounting last logged, and the sensor_height it was
    # checked against (a class default: each node assigns its own)

    def _report_mounting(self) -> None:
        """Log the stream's mounting once it is held (INFO), and what it says is wrong (WARN: a hand-set
        sensor_height more than 0.3 m off it, a sensor read upside down, readings that disagree), again only when the
        held mounting or the sensor_height changes (pass3d_ros.core.stage1.mounting)."""
        held = self.stream.mounting.held
        if held is None or (held, self.config.sensor_height) == self._mounting_said:
            return
        if held is not self._mounting_said[0]:
            levelled = level_rotation(held) is not None
            said = "; the scans are levelled before stage 1" if levelled else ""
            self.get_logger().info(f"mounting: {held}{said}")
            for text in self.stream.mounting.unsure():
                self.get_logger().warning(f"mounting: {text}")
        self._mounting_said = (held, self.config.sensor_height)
        for problem in mounting_problems(self.config, held):
            self.get_logger().warning(f"mounting: {problem}")

    _body_said: Any = None  # the held body reading last logged (a class default: each node assigns its own)

    def _report_body(self) -> None:
        """With stage1.min_range auto: log the vehicle's own returns once their reading is held (INFO), what it
        leaves out or why nothing (pass3d_ros.core.self_returns)."""
        held = self.stream.body.held
        if held is None or held is self._body_said:
            return
        self._body_said = held
        reach = (f"returns nearer than {held.radius_m:.1f} m are left out from now on" if held.radius_m > 0.0 else
                 "nothing left out")
        self.get_logger().info(f"vehicle's own returns (stage1.min_range auto): {held.note}; {reach}")

    def diagnostic_extras(self) -> tuple[dict[str, float | int | str], list[str]]:
        """`ring_field`: the numbering measured in the input's ring field (none, top_down, bottom_up, driver_order,
        unfit); an unfit field turns the status WARN. `mounting`: none, estimating (scans read so far) or held;
        `sensor_height_m`, `sensor_tilt_deg`, `sensor_roll_deg`, `sensor_pitch_deg`: the estimate
        (pass3d_ros.core.stage1.mounting), `mounting_levelled`: the held one levels the scans; a held one that disagrees
        with a hand-set sensor_height by more than 0.3 m, reads upside down, or was read from readings that disagree,
        or no ground read at all, turns the status WARN. `min_range_m`: with stage1.min_range auto, the body radius held
        (0 until read, and when the vehicle showed none)."""
        order = self._ring_order
        warnings = ["ring field does not fit the points: ignored, rings recovered"] if order and not order.fits else []
        values: dict[str, float | int | str] = {"ring_field": "none" if order is None else order.convention}
        holder = self.stream.mounting
        estimate = holder.estimate
        values["mounting"] = ("held" if holder.held is not None else
                              f"estimating ({holder.readings} of {holder.scans} scans)" if estimate else "none")
        if estimate is not None:
            values.update({"sensor_height_m": round(estimate.height_m, 3),
                           "sensor_tilt_deg": round(estimate.tilt_deg, 2),
                           "sensor_roll_deg": round(estimate.roll_deg, 2),
                           "sensor_pitch_deg": round(estimate.pitch_deg, 2)})
        values["mounting_levelled"] = bool(holder.held is not None and level_rotation(holder.held) is not None)
        warnings += [f"mounting: {problem}" for problem in mounting_problems(self.config, holder.held)]
        warnings += [f"mounting: {text}" for text in holder.unsure()]
        if self.config.min_range == AUTO:
            values["min_range_m"] = self.stream.body.radius_m
        return values, warnings

    def _process(self, msg: PointCloud2) -> Outcome | None:
        """One frame: decode, propose, publish; a malformed or empty frame is logged and skipped."""
        received = time.perf_counter()
        clock = self.step_clock()
        try:
            decoded = decode(msg)
            scan = to_xyzi(decoded, skip_nans=True)
        except PointCloud2Error as exc:
            self.get_logger().warning(f"skipping malformed PointCloud2: {exc}", throttle_duration_sec=LOG_PERIOD_S)
            return self.skipped("malformed")
        if self.follow_frame(msg.header.frame_id, "the stream's laser lines, mounting, body and intensity scale are "
                             "read again (one sensor per input topic)"):
            self._ring_order, self._sensor_source = None, None
        self._pipeline.follow(msg.header.frame_id)
        prepared = self._pipeline.prepare(scan.points, scan.ring, intensity_scale=self._take_changes(),
                                          use_ring=self.get_parameter("use_ring_field").value)
        self._log_notes(prepared.notes)
        if len(prepared.points) == 0:
            self.get_logger().warning("skipping empty PointCloud2", throttle_duration_sec=LOG_PERIOD_S)
            return self.skipped("empty")
        points, field = prepared.points, prepared.field  # field: the driver's ring numbering, published as it came
        clock.mark("decode")
        result = self._pipeline.stage1(prepared).result
        clock.mark("compute")
        self._report_mounting()
        self._report_body()
        self._report_sensor(result)
        self._report_ring_field(result)
        field_used = prepared.ring is not None and result.ring_order is not None and result.ring_order.fits
        out_ring = field if field_used else result.ring
        # the input as it came: always in memory (a view; the segmentation node decides), on the wire when asked
        source = input_source(decoded, msg.height, msg.width, len(scan.points), prepared.kept) \
            if self.sink is not None or self._full else None
        if self.sink is not None:
            self.sink(ProposalFrame(msg.header, points, out_ring, result.cluster_id, result.cluster_id2, source,
                                    result.level, result.ground, result.people_only()))
            clock.mark("sink")
        if self.sink is None or self.proposals_pub.get_subscription_count() > 0:
            if self._full:
                # stage 1's columns carry the reserved __pass3d_ prefix: only an input already holding them (one of
                # these messages fed back in) collides (pass3d_ros.ros.input_layout)
                replaced = source.replaced(STAGE1_COLUMNS)
                if replaced:
                    self.warn_once("replaced", f"the input's field(s) {', '.join(replaced)} are replaced by stage 1's "
                                   "on /pass3d/proposals (output_layout as_input / publish_background): the "
                                   f"{WIRE_PREFIX} prefix is reserved for this package's own columns")
                full = full_proposals_cloud(source, points, result.cluster_id, result.cluster_id2, result.ground,
                                            out_ring, result.level, result.people_only())
                cloud = encode(full, header=msg.header, height=source.height, is_dense=source.is_dense)
            else:
                cloud = encode(proposals_cloud(points, result, out_ring), header=msg.header)
            clock.mark("encode")
            self.proposals_pub.publish(cloud)
            clock.mark("publish")
        if self.get_parameter("publish_boxes").value and self.boxes_pub.get_subscription_count() > 0:
            markers = boxes_to_markers(result.boxes, msg.header, "proposals", level=result.level)
            clock.mark("encode")
            self.boxes_pub.publish(markers)
            clock.mark("publish")
        self.stats.frame(clock.steps_ms)
        steps = " ".join(f"{k}={v:.1f}" for k, v in result.timings_ms.items())
        self.get_logger().info(
            f"{len(points)} points, {len(result.boxes)} proposals, stage1 ms: {steps}, "
            f"node {1e3 * (time.perf_counter() - received):.1f} ms, dropped {self.worker.counters.dropped}"
            f"{self.missed_note()}",
            throttle_duration_sec=LOG_PERIOD_S,
        )


def main(argv: list[str] | None = None) -> int:
    """`ros2 run pass3d_ros cluster_proposal_node [--ros-args ...]`."""
    return run_nodes("cluster_proposal_node", [ClusterProposalNode], argv)


if __name__ == "__main__":
    sys.exit(main())
