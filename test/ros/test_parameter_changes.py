"""Parameters changed on running nodes: a stage-1 change or a new intensity_scale reaches the next scan with the
stream's held state reset where it must be (and only there), a stage-2 change set while a frame is in stage 2 waits
for the next frame, an unknown name is refused naming it, and use_sim_time is taken by both nodes."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import rclpy
from helpers.ros import STAMP0, WAIT_S, Ros, domain, scan_message, wait_until
from rclpy.context import Context
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from pass3d_ros.core import stage1
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import encode, header_stamp_ns
from pass3d_ros.ros import segmentation_node
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.segmentation_node import SegmentationNode

pytestmark = pytest.mark.ros

PERIOD_NS = 100_000_000


@pytest.fixture
def context() -> Iterator[Context]:
    """A private rclpy context on a domain of its own; nodes made in it are fed through `submit`, not spun."""
    context = Context()
    rclpy.init(context=context, domain_id=domain())
    yield context
    rclpy.try_shutdown(context=context)


class Stage1Calls:
    """Records what each scan's stage 1 was given (the held lines, ring order and scale, and the points); with
    `hold` set, the next call waits until `release` is set (a scan in hand while a parameter changes)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.calls: list[dict] = []
        self.entered = threading.Event()
        self.release = threading.Event()
        self.hold = False
        propose = stage1.propose

        def recorded(points: np.ndarray, ring: np.ndarray | None, config: stage1.Stage1Config, **given):
            self.calls.append({**given, "points": points.copy(), "config": config})
            if self.hold:
                self.hold = False
                self.entered.set()
                assert self.release.wait(WAIT_S)
            return propose(points, ring, config, **given)

        monkeypatch.setattr(stage1, "propose", recorded)


def feed(node: ClusterProposalNode, msg) -> None:
    """Submit one scan and wait until the node has finished it."""
    done = node.worker.counters.processed + 1
    node.submit(msg, header_stamp_ns(msg))
    assert wait_until(lambda: node.worker.counters.processed >= done and node.idle())


def test_a_stage1_change_during_a_scan_resets_the_lines_for_the_next(context: Context, frame: Frame,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    calls = Stage1Calls(monkeypatch)
    node = ClusterProposalNode(context=context)
    try:
        feed(node, scan_message(frame, STAMP0))
        assert node.stream.lines.ring_order is not None and node.stream.lines.scale() is not None
        assert node.set_parameters([Parameter("publish_boxes", value=False)])[0].successful
        assert node.stream.lines.ring_order is not None, "a change of no stage-1 value keeps what the stream learned"

        calls.hold = True
        msg = scan_message(frame, STAMP0 + PERIOD_NS)
        node.submit(msg, header_stamp_ns(msg))
        assert calls.entered.wait(WAIT_S)
        assert node.set_parameters([Parameter("stage1.th_ring", value=0.25)])[0].successful
        assert node.config.th_ring == 0.25
        calls.release.set()
        assert wait_until(lambda: node.worker.counters.processed == 2 and node.idle())
        assert calls.calls[1]["config"].th_ring == 0.5, "the scan in hand finishes with what it began with"

        feed(node, scan_message(frame, STAMP0 + 2 * PERIOD_NS))
        third = calls.calls[2]
        assert third["config"].th_ring == 0.25
        assert (third["ring_order"], third["scale"], third["lines"]) == (None, None, None), \
            "the next scan starts with the lines reset, not with those the scan in hand held after the reset"
    finally:
        node.destroy_node()


def test_a_new_intensity_scale_applies_to_the_next_scan(context: Context, frame: Frame,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    calls = Stage1Calls(monkeypatch)
    node = ClusterProposalNode(context=context)
    bytes_frame = Frame(frame.name, frame.points * np.array([1, 1, 1, 255], np.float32), ring=frame.ring)
    try:
        for k in range(4):  # a 0..255 driver with intensity_scale 1: the stream holds a full scale of 255
            feed(node, scan_message(bytes_frame, STAMP0 + k * PERIOD_NS))
        assert node.stream.scale.divisor == 255.0
        expected = float(frame.points[:, 3].max())
        assert calls.calls[-1]["points"][:, 3].max() == pytest.approx(expected, rel=1e-5)

        assert node.set_parameters([Parameter("intensity_scale", value=1 / 255)])[0].successful
        feed(node, scan_message(bytes_frame, STAMP0 + 4 * PERIOD_NS))
        assert calls.calls[-1]["points"][:, 3].max() == pytest.approx(expected, rel=1e-5), \
            "the corrected intensity_scale must not be divided by the full scale held before it"
    finally:
        node.destroy_node()


def test_an_unknown_name_is_refused_naming_it(ros: Ros, context: Context) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context))
    client = AsyncParameterClient(ros.probe, node.get_name())
    assert client.wait_for_services(timeout_sec=WAIT_S)
    future = client.set_parameters([Parameter("stage1.th_rnig", value=0.3)])  # as `ros2 param set` asks
    assert wait_until(future.done)
    result = future.result().results[0]
    assert not result.successful
    assert "'stage1.th_rnig' (did you mean 'stage1.th_ring'?)" in result.reason, result.reason
    assert node.config.th_ring == 0.5

    segmentation = SegmentationNode(context=context, parameter_overrides=[Parameter("classifier", value="size_rules")])
    try:
        with pytest.raises(ParameterNotDeclaredException, match=r"'min_confidance' \(did you mean 'min_confidence'"):
            segmentation.set_parameters([Parameter("min_confidance", value=0.5)])
    finally:
        segmentation.destroy_node()


def test_both_nodes_take_use_sim_time_at_run_time(context: Context) -> None:
    nodes = [ClusterProposalNode(context=context),
             SegmentationNode(context=context, parameter_overrides=[Parameter("classifier", value="size_rules")])]
    try:
        for node in nodes:
            result = node.set_parameters([Parameter("use_sim_time", value=True)])[0]
            assert result.successful, (node.get_name(), result.reason)
            assert node.get_clock().ros_time_is_active
    finally:
        for node in nodes:
            node.destroy_node()


def test_segmentation_node_refuses_start_up_parameters_and_changes_none(context: Context) -> None:
    node = SegmentationNode(context=context, parameter_overrides=[Parameter("classifier", value="size_rules")])
    try:
        refused = node.set_parameters_atomically([Parameter("min_confidence", value=0.3),
                                                  Parameter("weights", value="other.pt")])
        assert not refused.successful and refused.reason == "weights can only be set at start-up"
        assert node.get_parameter("min_confidence").value == 0.0
        assert node.set_parameters([Parameter("max_proposals", value=12)])[0].successful
        assert node.classifier.max_proposals == 12
    finally:
        node.destroy_node()


class HeldStage2:
    """Holds the next frame of a segmentation node between its budget and the classifier (`level_points`, called
    between them, waits until `release` is set), and records each classifier call: proposals read, its limit."""

    def __init__(self, node: SegmentationNode, monkeypatch: pytest.MonkeyPatch) -> None:
        self.calls: list[tuple[int, int]] = []
        self.entered = threading.Event()
        self.release = threading.Event()
        level = segmentation_node.level_points

        def held(points: np.ndarray, rotation: np.ndarray | None) -> np.ndarray:
            if not self.entered.is_set():
                self.entered.set()
                assert self.release.wait(WAIT_S)
            return level(points, rotation)

        monkeypatch.setattr(segmentation_node, "level_points", held)
        segment = node.classifier.segment

        def recorded(points: np.ndarray, members: list[np.ndarray]):
            self.calls.append((len(members), node.classifier.max_proposals))
            return segment(points, members)

        node.classifier.segment = recorded


@pytest.fixture
def node(context: Context) -> Iterator[SegmentationNode]:
    """A segmentation node with the size-rules classifier, stage 2 in this process."""
    node = SegmentationNode(context=context, in_memory=True,
                            parameter_overrides=[Parameter("classifier", value="size_rules")])
    yield node
    node.destroy_node()


def change_during_first_frame(node: SegmentationNode, held: HeldStage2, columns: dict[str, np.ndarray],
                              change: Parameter) -> None:
    """Submit `columns` as scan 0, set `change` while the node holds it between its budget and the classifier, then
    let it go on."""
    msg = encode(columns, stamp_ns=STAMP0)
    node.submit(msg, header_stamp_ns(msg))
    assert held.entered.wait(WAIT_S)
    assert node.set_parameters([change])[0].successful
    held.release.set()


def segment_once(node: SegmentationNode, columns: dict[str, np.ndarray], k: int) -> None:
    """Submit the proposals cloud `columns` as scan `k` and wait until the node has finished it."""
    msg = encode(columns, stamp_ns=STAMP0 + k * PERIOD_NS)
    node.submit(msg, header_stamp_ns(msg))
    assert wait_until(lambda: node.worker.counters.received == k + 1 and node.idle())


def test_a_max_proposals_change_during_a_frame_waits_for_the_next(
    node: SegmentationNode, proposal_columns: dict[str, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    held = HeldStage2(node, monkeypatch)
    count = len(np.unique(proposal_columns["cluster_id"][proposal_columns["cluster_id"] >= 0]))
    assert count > 2
    change_during_first_frame(node, held, proposal_columns, Parameter("max_proposals", value=2))
    assert wait_until(lambda: node.worker.counters.processed == 1 and node.idle())
    assert held.calls == [(count, 128)], "the frame in hand is budgeted and classified with what it began with"
    assert node.proposals_cut == 0

    segment_once(node, proposal_columns, 1)
    assert held.calls[1] == (2, 2) and node.classifier.max_proposals == 2
    assert node.proposals_cut == count - 2


def test_a_stage2_timeout_change_during_a_frame_waits_for_the_next(
    node: SegmentationNode, proposal_columns: dict[str, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    held = HeldStage2(node, monkeypatch)
    segment = node.classifier.segment

    def slow(points: np.ndarray, members: list[np.ndarray]):
        time.sleep(0.3)  # longer than the stage2_timeout set during it, far within the one it began with
        return segment(points, members)

    node.classifier.segment = slow
    change_during_first_frame(node, held, proposal_columns, Parameter("stage2_timeout", value=0.1))
    assert wait_until(lambda: node.worker.counters.received == 1 and node.idle())
    assert (node.frames_late, node.counters().processed) == (0, 1), \
        "the frame in hand is held to the stage2_timeout it began with"

    segment_once(node, proposal_columns, 1)
    assert (node.frames_late, node.counters().dropped) == (1, 1), "the next frame is held to the new one"
