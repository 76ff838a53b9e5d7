"""Both real nodes in-process: real publishers, subscribers and services on a real executor spun in a thread.

Every test runs in a private rclpy context on a DDS domain of its own (helpers.ros), so parallel test runs and a
real robot on the default domain never see each other's traffic.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.ros import STAMP0, WAIT_S, Collector, Ros, columns, connect, scan_message, wait_until
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from pass3d_ros.classes import BACKGROUND, NUM_CLASSES, packed_rgb
from pass3d_ros.core.objects import frame_objects
from pass3d_ros.core.stage1 import Stage1Config, proposal_members, propose
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.segmentation import people_only
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier
from pass3d_ros.data.bag import read_bag
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.live import run_live
from pass3d_ros.evaluation.report import score
from pass3d_ros.msgs.pointcloud2 import encode, header_stamp_ns
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.input_layout import STAGE1_PEOPLE_ONLY
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode
from pass3d_ros.weights import DEFAULT_WEIGHTS_NAME, WEIGHTS_DIR

pytestmark = pytest.mark.ros

PROPOSAL_FIELDS = ("x", "y", "z", "intensity", "ring", "ground", "cluster_id", "cluster_id2")


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bags") / "synthetic"
    convert(["synthetic:frames=3,seed=9"], out, with_labels=True, progress=False, log=lambda _: None)
    return out


# ---- cluster_proposal_node ----

def test_proposals_keep_header_order_and_match_offline(ros: Ros, frame: Frame) -> None:
    ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    boxes = Collector(ros, MarkerArray, "/pass3d/proposal_boxes")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds, boxes)

    pub.publish(scan_message(frame, STAMP0))
    first = clouds.wait(1)[0]
    pub.publish(scan_message(frame, STAMP0 + 100_000_000, with_ring=False))
    second = clouds.wait(2)[1]

    for msg, stamp, ring in ((first, STAMP0, frame.ring), (second, STAMP0 + 100_000_000, None)):
        assert header_stamp_ns(msg) == stamp and msg.header.frame_id == "velodyne_test"
        cloud = columns(msg)
        offline = propose(frame.points, ring)
        people = offline.people_only()  # rerun_dropped's parts, flagged only where there are some
        assert cloud.dtype.names == PROPOSAL_FIELDS + (() if people is None else (STAGE1_PEOPLE_ONLY,))
        if people is not None:
            np.testing.assert_array_equal(cloud[STAGE1_PEOPLE_ONLY].astype(bool), people)
        got = np.stack([cloud[k] for k in ("x", "y", "z", "intensity")], axis=1)
        assert got.tobytes() == frame.points.tobytes(), "point order and values must be kept"
        assert offline.n_proposals > 3
        np.testing.assert_array_equal(cloud["cluster_id"], offline.cluster_id)
        np.testing.assert_array_equal(cloud["cluster_id2"], offline.cluster_id2)
        np.testing.assert_array_equal(cloud["ground"].astype(bool), offline.ground)
        np.testing.assert_array_equal(cloud["ring"], offline.ring)
    np.testing.assert_array_equal(columns(first)["ring"], frame.ring)

    markers = boxes.wait(2)[0].markers
    assert markers[0].action == Marker.DELETEALL
    assert markers[0].header.stamp == first.header.stamp
    wires = [m for m in markers[1:] if m.type == Marker.LINE_LIST]
    assert len(wires) == propose(frame.points, frame.ring).n_proposals


def test_malformed_and_empty_frames_are_skipped(ros: Ros, frame: Frame, capfd: pytest.CaptureFixture[str]) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)

    short = scan_message(frame, STAMP0 + 1)
    short.data = short.data[: len(short.data) - 10]  # shorter than width * point_step
    no_z = scan_message(frame, STAMP0 + 2)
    no_z.fields = [f for f in no_z.fields if f.name != "z"]
    empty = encode({"x": np.zeros(0, np.float32), "y": np.zeros(0, np.float32), "z": np.zeros(0, np.float32)},
                   stamp_ns=STAMP0 + 3)
    for count, msg in enumerate((short, no_z, empty), start=1):
        pub.publish(msg)  # one at a time: the one-slot mailbox must not drop them unprocessed
        assert wait_until(lambda n=count: node.worker.counters.skipped >= n and node.worker.idle())
    pub.publish(scan_message(frame, STAMP0 + 4))
    got = clouds.wait(1)
    time.sleep(0.2)

    assert [header_stamp_ns(m) for m in clouds.messages] == [STAMP0 + 4], "only the good frame comes out"
    counters = node.worker.counters
    assert counters.failed == 0 and counters.dropped == 0 and (counters.processed, counters.skipped) == (1, 3)
    assert node.skip_reasons == {"malformed": 2, "empty": 1}
    assert len(columns(got[0])) == len(frame.points)
    err = capfd.readouterr().err
    assert "skipping malformed PointCloud2" in err and "skipping empty PointCloud2" in err


def test_parameters_are_validated_at_run_time(ros: Ros, frame: Frame) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context))
    client = AsyncParameterClient(ros.probe, node.get_name())
    assert client.wait_for_services(timeout_sec=WAIT_S)

    def set_remote(name: str, value) -> bool:
        future = client.set_parameters([Parameter(name, value=value)])
        assert wait_until(future.done)
        return future.result().results[0].successful

    assert not set_remote("stage1.th_ring", -1.0)
    assert not set_remote("stage1.th_ring", "wide")  # wrong type
    assert not set_remote("input_topic", "/elsewhere")  # start-up only
    assert node.config.th_ring == 0.5 and node.get_parameter("stage1.th_ring").value == 0.5
    assert set_remote("stage1.th_ring", 0.25)
    assert node.config.th_ring == 0.25

    changed = propose(frame.points, frame.ring, Stage1Config(th_ring=0.25))
    assert not np.array_equal(changed.cluster_id, propose(frame.points, frame.ring).cluster_id)
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    pub.publish(scan_message(frame, STAMP0))
    np.testing.assert_array_equal(columns(clouds.wait(1)[0])["cluster_id"], changed.cluster_id)


def test_a_run_time_change_is_validated_once_by_the_config(ros: Ros, monkeypatch: pytest.MonkeyPatch) -> None:
    node = ros.add(ClusterProposalNode(context=ros.context))
    checked: list[Stage1Config] = []
    validate = Stage1Config.validate
    monkeypatch.setattr(Stage1Config, "validate", lambda self: checked.append(self) or validate(self))
    assert node.set_parameters([Parameter("stage1.th_prop", value=0.75)])[0].successful
    assert checked == [node.config] and node.config.th_prop == 0.75
    refused = node.set_parameters([Parameter("stage1.enlarge", value=[0.1, 0.1])])[0]
    assert not refused.successful and refused.reason == "Stage1Config: enlarge needs 3 values (x, y, z), got 2"
    assert len(checked) == 2 and node.config.enlarge == (0.1, 0.1, 0.4)


def test_a_namespace_moves_the_outputs_and_keeps_the_sensor_topic(ros: Ros, frame: Frame) -> None:
    """Two pipelines side by side (`ros2 launch ... namespace:=car1`): the outputs are relative names, so they move
    under the nodes' namespace and the two nodes still meet there; the driver's topic stays absolute."""
    ros.add(ClusterProposalNode(context=ros.context, namespace="car1"))
    ros.add(SegmentationNode(context=ros.context, namespace="car1",
                             parameter_overrides=[Parameter("classifier", value="size_rules")]))
    labeled = Collector(ros, PointCloud2, "/car1/pass3d/labeled")
    boxes = Collector(ros, MarkerArray, "/car1/pass3d/proposal_boxes")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, labeled, boxes)
    pub.publish(scan_message(frame, STAMP0))
    assert header_stamp_ns(labeled.wait(1)[0]) == STAMP0
    assert boxes.wait(1)
    names = dict(ros.probe.get_topic_names_and_types())
    assert "/car1/pass3d/proposals" in names and "/pass3d/labeled" not in names


# ---- segmentation_node ----

@pytest.mark.parametrize("kind", ["size_rules", "network"])
def test_labeled_cloud_matches_offline(ros: Ros, frame: Frame, lite_weights: Path, kind: str) -> None:
    weights = str(lite_weights) if kind == "network" else ""
    ros.add(ClusterProposalNode(context=ros.context))
    ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter("classifier", value=kind), Parameter("weights", value=weights)]))
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    objects = Collector(ros, MarkerArray, "/pass3d/objects")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, labeled, objects)
    pub.publish(scan_message(frame, STAMP0))
    msg = labeled.wait(1)[0]

    assert header_stamp_ns(msg) == STAMP0 and msg.header.frame_id == "velodyne_test"
    cloud = columns(msg)
    assert {"label", "confidence", "rgb", "cluster_id"} <= set(cloud.dtype.names)
    assert len(cloud) == len(frame.points), "every point is labeled"
    assert cloud["label"].max() < NUM_CLASSES

    stage1 = propose(frame.points, frame.ring)
    members = proposal_members(stage1.cluster_id, stage1.cluster_id2)
    classifier = open_classifier(weights, kind)
    expected = people_only(classifier.segment(frame.points, members), members, stage1.people_only())
    published = frame_objects(frame.points, stage1.cluster_id, expected.proposal_class, expected.labels,
                              expected.confidence)  # each point's label settled within its own proposal
    np.testing.assert_array_equal(cloud["label"], published.labels)
    np.testing.assert_array_equal(cloud["cluster_id"], published.cluster_id)
    np.testing.assert_allclose(cloud["confidence"], expected.confidence, rtol=1e-5, atol=1e-6)
    assert cloud["rgb"].tobytes() == packed_rgb(published.labels).tobytes()
    outside = (stage1.cluster_id < 0) & (stage1.cluster_id2 < 0)
    assert np.all(cloud["label"][outside] == BACKGROUND)
    if kind == "size_rules":
        assert np.count_nonzero(cloud["label"]) > 1000, "the scene has cars; size rules must find some"

    markers = objects.wait(1)[0].markers
    assert markers[0].action == Marker.DELETEALL
    wires = [m for m in markers[1:] if m.type == Marker.LINE_LIST]
    assert len(wires) == len(published.objects) > 0


def test_bad_weights_fail_at_construction(ros: Ros, tmp_path: Path, lite_weights: Path) -> None:
    def make(**values):
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        return SegmentationNode(context=ros.context, parameter_overrides=overrides)

    missing = tmp_path / "nowhere.pt"
    with pytest.raises(ValueError, match=re.escape(str(missing))):
        make(classifier="network", weights=str(missing))
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"not a (readable PyTorch|pass3d) checkpoint") as unreadable:
        make(classifier="network", weights=str(garbage))
    assert str(garbage) in str(unreadable.value)
    checkpoint = torch.load(lite_weights, weights_only=True)
    del checkpoint["state_dict"][next(iter(checkpoint["state_dict"]))]
    broken = tmp_path / "broken.pt"
    torch.save(checkpoint, broken)
    with pytest.raises(ValueError, match=re.escape(str(broken)) + ".*do not fit"):
        make(classifier="network", weights=str(broken))
    with pytest.raises(ValueError, match="unknown classifier"):
        make(classifier="svm")
    with pytest.raises(ValueError, match="output_qos"):
        make(classifier="size_rules", output_qos="fast")
    if not (WEIGHTS_DIR / DEFAULT_WEIGHTS_NAME).is_file():
        with pytest.raises(OSError, match=DEFAULT_WEIGHTS_NAME):
            make(classifier="network")


# ---- a bag through both live nodes ----

def offline_labels(frame: Frame) -> np.ndarray:
    """The labels the nodes publish for `frame`, made offline: each point's label settled within its own (primary)
    proposal (core.objects.frame_objects), as a point in two of rerun_dropped's people parts can be named twice."""
    stage1 = propose(frame.points, frame.ring)
    members = proposal_members(stage1.cluster_id, stage1.cluster_id2)
    result = people_only(SizeRuleClassifier().segment(frame.points, members), members, stage1.people_only())
    return frame_objects(frame.points, stage1.cluster_id, result.proposal_class, result.labels,
                         result.confidence).labels


def test_bag_through_live_nodes_lockstep(small_bag: Path, tmp_path: Path) -> None:
    record = tmp_path / "labeled_bag"
    result = run_live(small_bag, lockstep=True, rate=1.0, timeout_s=WAIT_S, record_out=record,
                      node_parameters={"segmentation_node": {"classifier": "size_rules"}})
    frames = list(read_bag(small_bag))
    assert result.frames_in == result.frames_out == 3 and result.dropped == 0
    assert result.mismatched == result.timeouts == result.skipped == result.unmatched_outputs == 0
    assert [f.stamp_ns for f in result.frames] == [f.stamp_ns for f in frames]
    for got, frame in zip(result.frames, frames, strict=True):
        np.testing.assert_array_equal(got.truth, frame.labels)
        np.testing.assert_array_equal(got.predicted, offline_labels(frame))
        assert got.latency_ms > 0 and 0 < got.stage1_ms < got.latency_ms
    counters = result.node_counters
    assert counters["cluster_proposal_node"]["processed"] == counters["segmentation_node"]["processed"] == 3

    recorded = list(read_bag(record, labels="predicted"))
    assert [f.stamp_ns for f in recorded] == [f.stamp_ns for f in frames]
    for rec, got in zip(recorded, result.frames, strict=True):
        np.testing.assert_array_equal(rec.labels, got.predicted)

    scores = score(result)
    assert scores["frames"] == 3 and scores["live"]["frames_out"] == 3 and scores["live"]["dropped"] == 0
    assert scores["live"]["latency_ms"]["median"] == pytest.approx(float(np.median(result.latency_ms)))
    car = scores["per_class"]["car"]
    truth = np.concatenate([f.labels for f in frames])
    assert car["points"] == int(np.count_nonzero(truth == 1))
    assert 0.0 < car["iou"] <= 1.0 and scores["mean_iou"] is not None


def test_bag_free_running_counts_drops(small_bag: Path) -> None:
    result = run_live(small_bag, lockstep=False, rate=0.0, timeout_s=WAIT_S, keep_labels=False,
                      node_parameters={"segmentation_node": {"classifier": "size_rules"}})
    assert result.frames_in == 3 and 1 <= result.frames_out <= 3
    assert result.dropped == 3 - result.frames_out
    assert all(f.truth is None and f.predicted is None for f in result.frames)
    assert result.labeled_frames == result.frames_out and result.confusion.matrix.sum() > 0
    stamps = [f.stamp_ns for f in result.frames]
    assert stamps == sorted(stamps) and stamps[-1] == max(f.stamp_ns for f in read_bag(small_bag))


def test_run_live_rejects_unknown_parameters(small_bag: Path) -> None:
    with pytest.raises(ValueError, match="unknown node"):
        run_live(small_bag, node_parameters={"segmenter": {}})
    with pytest.raises(ValueError, match=r"stage1\.th_ring"):
        run_live(small_bag, node_parameters={"cluster_proposal_node": {"stage1.th_ring": -1.0}})
    with pytest.raises(ValueError, match=r"unknown parameter.*stage1\.th_rnig"):
        run_live(small_bag, node_parameters={"cluster_proposal_node": {"stage1.th_rnig": 0.5}})


# ---- the demo ----

def test_demo_small_drive(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools import demo

    out = tmp_path / "demo"
    assert demo.main(["--frames=2", "--seed=3", f"--out={out}", "--classifier=size_rules"]) == 0
    printed = capsys.readouterr().out
    assert "mean IoU" in printed and "latency" in printed and str(out / "labeled_bag") in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["live"]["frames_in"] == metrics["live"]["frames_out"] == 2
    assert metrics["classifier"] == {"kind": "size_rules", "weights": None}
    assert len(list(read_bag(out / "labeled_bag"))) == 2
    assert sorted(p.name for p in (out / "bev").iterdir()) == ["000000.png", "000001.png"]
    assert "4 bird's-eye views" in printed, "two panels (ground truth | prediction) per picture"
    assert demo.main(["--frames=1", f"--out={out}", "--classifier=size_rules"]) == 0, "its own folder is reused"
    assert len(list(read_bag(out / "labeled_bag"))) == 1

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert demo.main([f"--out={foreign}", "--classifier=size_rules"]) == 2
    assert "not empty" in capsys.readouterr().err and sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    if not (WEIGHTS_DIR / DEFAULT_WEIGHTS_NAME).is_file():
        assert demo.main([f"--out={tmp_path / 'net'}", "--classifier=network"]) == 2
        assert DEFAULT_WEIGHTS_NAME in capsys.readouterr().err
        assert demo.choose_classifier("auto", None)[0] == "size_rules"
        assert "NOT the PASS3D network" in demo.choose_classifier("auto", None)[2]
