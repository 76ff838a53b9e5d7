"""`output_layout: as_input` and `publish_background` through real nodes (both the two-node layout over
/pass3d/proposals and the one-process pipeline): an Ouster-like organized cloud (32 beams, no-return cells at
(0, 0, 0), NaN and implausible points, per-point t, reflectivity, ring or Autoware's channel, ambient, range) comes
back point for point in the input's layout with every field as it came, and the background cloud is the input less
its object points."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from helpers.ros import STAMP0, Collector, Ros, columns, connect, ros_session, wait_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

from pass3d_ros.bench import benchmark
from pass3d_ros.classes import BACKGROUND, FOREGROUND
from pass3d_ros.core import scan_checks
from pass3d_ros.core.stage1 import propose
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, encode, extend_cloud
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.inprocess import in_memory_factories
from pass3d_ros.ros.input_layout import (
    STAGE1_COLUMNS,
    WIRE_PREFIX,
    InputSource,
    full_proposals_cloud,
    input_source,
    labeled_as_input,
)
from pass3d_ros.ros.proposals import proposal_frame, proposals_cloud
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode
from pass3d_ros.synthetic.dataset import generate_frame

pytestmark = pytest.mark.ros

HEIGHT, WIDTH = 32, 2048
INPUT_FIELDS = ("x", "y", "z", "t", "reflectivity", "ring", "ambient", "range", "intensity")
ADDED = ("cluster_id", "track_id", "confidence", "rgb", "label")  # track_id: tracking is on by default
Layout = Callable[[Ros, list[Parameter]], None]


def two_nodes(ros: Ros, overrides: list[Parameter]) -> None:
    """cluster_proposal_node and segmentation_node joined by /pass3d/proposals, both given `overrides` (one params
    file)."""
    ros.add(ClusterProposalNode(context=ros.context, parameter_overrides=overrides))
    ros.add(SegmentationNode(context=ros.context,
                             parameter_overrides=[Parameter("classifier", value="size_rules"), *overrides]))


def pipeline(ros: Ros, overrides: list[Parameter]) -> None:
    """pass3d_pipeline's two nodes, joined in memory."""
    cluster, segmentation = in_memory_factories()
    ros.add(cluster(context=ros.context, parameter_overrides=overrides))
    ros.add(segmentation(context=ros.context,
                         parameter_overrides=[Parameter("classifier", value="size_rules"), *overrides]))


LAYOUTS = pytest.mark.parametrize("layout", [two_nodes, pipeline], ids=["two_nodes", "pipeline"])


@pytest.fixture(scope="module")
def beams32() -> Frame:
    """A synthetic HDL-32E scan (32 beams) with cars and people."""
    return generate_frame(seed=5, index=0, sensor="hdl32e")


def ouster_cloud(frame: Frame, intensity: type = np.uint16, ring: str = "ring") -> np.ndarray:
    """`frame` on a 32 x WIDTH grid, row-major, Ouster-like fields with padding, the beam in field `ring` (Autoware's
    drivers: `channel`); empty cells are no-returns at (0, 0, 0), some of them NaN, three implausible."""
    size = np.dtype(intensity).itemsize
    dtype = np.dtype({"names": [ring if name == "ring" else name for name in INPUT_FIELDS],
                      "formats": [np.float32] * 3 + [np.uint32, np.uint16, np.uint16, np.uint16, np.uint32, intensity],
                      "offsets": [0, 4, 8, 12, 16, 18, 20, 24, 32], "itemsize": 32 + max(size, 8) + 8})
    points = frame.points
    column = ((np.pi - np.arctan2(points[:, 1], points[:, 0])) / (2 * np.pi) * WIDTH).astype(np.int64) % WIDTH
    cell = frame.ring.astype(np.int64) * WIDTH + column
    _, first = np.unique(cell, return_index=True)  # one point per cell
    cloud = np.zeros(HEIGHT * WIDTH, dtype)
    taken = cell[first]
    for k, axis in enumerate("xyz"):
        cloud[axis][taken] = points[first, k]
    rng = np.random.default_rng(0)
    scale = {np.uint16: 65535, np.uint8: 255}.get(intensity, 1.0)
    cloud["intensity"][taken] = np.round(points[first, 3] * scale) if scale != 1.0 else points[first, 3]
    cells = np.arange(HEIGHT * WIDTH)
    cloud["t"] = (cells % WIDTH) * 48_828
    cloud["reflectivity"] = rng.integers(0, 65535, len(cloud))
    cloud[ring] = cells // WIDTH
    cloud["ambient"] = rng.integers(0, 65535, len(cloud))
    cloud["range"][taken] = (1000 * np.linalg.norm(points[first, :3], axis=1)).astype(np.uint32)
    empty = np.setdiff1d(cells, taken)
    assert len(empty) > 0.1 * len(cloud), "no-returns fill part of the grid"
    odd = rng.choice(empty, 43, replace=False)
    for axis in "xyz":
        cloud[axis][odd[:40]] = np.nan
    cloud["x"][odd[40:]] = 1e6  # implausible
    return cloud


def message(cloud: np.ndarray, stamp: int = STAMP0) -> PointCloud2:
    return encode(cloud, stamp_ns=stamp, frame_id="os_lidar", height=HEIGHT)


def returns(cloud: np.ndarray) -> np.ndarray:
    """The rows stage 1 reads: finite, plausible, not at (0, 0, 0)."""
    xyz = np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float32)
    return scan_checks.plausible_points(xyz) & scan_checks.returns(np.nan_to_num(xyz))


def same_bytes(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def label_once(layout: Layout, cloud: np.ndarray, overrides: list[Parameter], background: bool = False
               ) -> tuple[PointCloud2, PointCloud2 | None, MarkerArray]:
    """One scan through fresh nodes: the labeled cloud, the background cloud (when asked) and the objects."""
    with ros_session() as ros:
        layout(ros, overrides)
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        objects = Collector(ros, MarkerArray, "/pass3d/objects")
        outputs = [labeled, objects]
        if background:
            outputs.append(Collector(ros, PointCloud2, "/pass3d/background"))
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, *outputs)
        pub.publish(message(cloud))
        got = [c.wait(1)[0] for c in outputs]
        return got[0], got[2] if background else None, got[1]


@pytest.fixture(scope="module")
def compact_labels(beams32: Frame) -> Iterator[np.ndarray]:
    """The compact layout's /pass3d/labeled for the Ouster-like scan (two nodes, defaults)."""
    msg, _, _ = label_once(two_nodes, ouster_cloud(beams32), [])
    yield columns(msg).copy()


def test_default_compact_has_only_the_points_stage1_read(beams32: Frame, compact_labels: np.ndarray) -> None:
    cloud = ouster_cloud(beams32)
    rows = returns(cloud)
    assert compact_labels.dtype.names == ("x", "y", "z", "intensity", "ring", "cluster_id", "label", "confidence",
                                          "rgb", "track_id")  # track_id: tracking is on by default
    for axis in "xyz":  # compact keeps the input order of the points read: a join by position
        np.testing.assert_array_equal(compact_labels[axis], cloud[axis][rows])
    assert np.isin(compact_labels["label"], FOREGROUND).sum() > 100


@LAYOUTS
def test_as_input_keeps_the_input_layout_and_the_background_is_the_rest(
        beams32: Frame, compact_labels: np.ndarray, layout: Layout) -> None:
    cloud = ouster_cloud(beams32)
    overrides = [Parameter("output_layout", value="as_input"), Parameter("publish_background", value=True)]
    msg, background_msg, objects = label_once(layout, cloud, overrides, background=True)

    assert (msg.height, msg.width, msg.header.frame_id) == (HEIGHT, WIDTH, "os_lidar")
    assert not msg.is_dense
    out = columns(msg)
    assert out.dtype.names == (*INPUT_FIELDS, *ADDED)
    for name in INPUT_FIELDS:
        assert same_bytes(out[name], cloud[name]), name
    rows = returns(cloud)
    assert (out["label"][~rows] == BACKGROUND).all() and (out["cluster_id"][~rows] == -1).all()
    assert (out["confidence"][~rows] == 0).all()
    np.testing.assert_array_equal(out["label"][rows], compact_labels["label"])
    np.testing.assert_array_equal(out["cluster_id"][rows], compact_labels["cluster_id"])
    np.testing.assert_array_equal(out["confidence"][rows], compact_labels["confidence"])
    for wire in (m for m in objects.markers if m.type == Marker.LINE_LIST):
        xy = np.array([(p.x, p.y) for p in wire.points])
        assert not ((xy.min(axis=0) <= 0) & (xy.max(axis=0) >= 0)).all(), "a box holds the origin"

    kept = np.flatnonzero(out["label"] == BACKGROUND)
    assert 0 < len(kept) < len(out) - 100
    assert (background_msg.height, background_msg.width) == (1, len(kept))
    background = columns(background_msg)
    assert background.dtype.names == INPUT_FIELDS
    for name in INPUT_FIELDS:
        assert same_bytes(background[name], cloud[name][kept]), name


def colliding_cloud(frame: Frame) -> np.ndarray:
    """The Ouster-like scan with driver fields named like stage 1's columns on the compact proposals message
    (`ground`, `cluster_id2`, `cluster_id`) and like the full one's of old (`stage1_intensity`), each holding values
    of its own at every row (no-returns and NaN points too)."""
    cloud = ouster_cloud(frame)
    rng = np.random.default_rng(7)
    n = len(cloud)
    own = rng.uniform(0, 300, n).astype(np.float32)
    own[::97] = np.nan  # a driver's NaN is carried as it came
    return extend_cloud(cloud, {"ground": rng.integers(0, 255, n).astype(np.uint8),
                                "cluster_id2": rng.integers(-5000, 5000, n).astype(np.int32),
                                "stage1_intensity": own,
                                "cluster_id": rng.integers(0, 65535, n).astype(np.uint16)})


def test_input_fields_named_like_stage1_columns_cross_proposals_untouched(
        beams32: Frame, capfd: pytest.CaptureFixture[str]) -> None:
    """Two nodes over /pass3d/proposals publish byte for byte what pass3d_pipeline publishes in memory, with the
    input's ground, cluster_id2, stage1_intensity and cluster_id fields as they came (the labeled cloud replaces
    cluster_id only, as documented, in both)."""
    cloud = colliding_cloud(beams32)
    names = cloud.dtype.names
    overrides = [Parameter("output_layout", value="as_input"), Parameter("publish_background", value=True)]
    apart = label_once(two_nodes, cloud, overrides, background=True)
    joined = label_once(pipeline, cloud, overrides, background=True)
    for msg, background_msg in (apart[:2], joined[:2]):
        out = columns(msg)
        assert out.dtype.names == (*(name for name in names if name != "cluster_id"), *ADDED)
        for name in ("ground", "cluster_id2", "stage1_intensity", "t", "ring", "intensity"):
            assert same_bytes(out[name], cloud[name]), name
        assert np.isin(out["label"], FOREGROUND).sum() > 100
        kept = np.flatnonzero(out["label"] == BACKGROUND)
        background = columns(background_msg)
        assert background.dtype.names == names
        for name in names:
            assert same_bytes(background[name], cloud[name][kept]), name
    for a, b in zip(apart[:2], joined[:2], strict=True):
        assert same_message(a, b)
    assert "replaced by stage 1's" not in capfd.readouterr().err


def same_message(a: PointCloud2, b: PointCloud2) -> bool:
    """The same cloud, field for field (name, offset, type, count, order) and byte for byte."""
    return ([(f.name, f.offset, f.datatype, f.count) for f in a.fields] ==
            [(f.name, f.offset, f.datatype, f.count) for f in b.fields]
            and (a.height, a.width, a.point_step, a.row_step, a.is_dense) ==
            (b.height, b.width, b.point_step, b.row_step, b.is_dense)
            and bytes(a.data) == bytes(b.data))


def test_compact_labels_from_full_proposals_carry_stage1_rings(beams32: Frame) -> None:
    """publish_background alone (compact /pass3d/labeled, full proposals): without a ring field in the input, the
    compact cloud's ring is stage 1's over /pass3d/proposals too, as in memory."""
    cloud = extend_cloud(ouster_cloud(beams32), drop=("ring",))
    overrides = [Parameter("publish_background", value=True)]
    apart = label_once(two_nodes, cloud, overrides, background=True)
    joined = label_once(pipeline, cloud, overrides, background=True)
    assert "ring" in columns(apart[0]).dtype.names
    for a, b in zip(apart[:2], joined[:2], strict=True):
        assert same_message(a, b)


@pytest.mark.parametrize("intensity", [np.uint8, np.float64], ids=["uint8", "float64"])
def test_uint8_and_float64_intensity_are_labelled(beams32: Frame, intensity: type) -> None:
    cloud = ouster_cloud(beams32, intensity)
    msg, _, _ = label_once(two_nodes, cloud, [Parameter("output_layout", value="as_input")])
    out = columns(msg)
    assert out["intensity"].dtype == np.dtype(intensity) and same_bytes(out["intensity"], cloud["intensity"])
    assert np.isin(out["label"], FOREGROUND).sum() > 100


def test_channel_is_read_as_the_ring_and_carried_through(beams32: Frame, compact_labels: np.ndarray) -> None:
    cloud = ouster_cloud(beams32, ring="channel")
    cloud["channel"] = HEIGHT - 1 - cloud["channel"]  # numbered bottom-up, unlike the recovered laser lines
    rows = returns(cloud)
    compact = columns(label_once(two_nodes, cloud, [])[0])
    np.testing.assert_array_equal(compact["ring"], cloud["channel"][rows])  # read as the ring: the outputs carry it
    np.testing.assert_array_equal(compact["label"], compact_labels["label"])  # as when named ring, top-down
    msg, _, _ = label_once(two_nodes, cloud, [Parameter("output_layout", value="as_input")])
    out = columns(msg)
    assert out.dtype.names == (*cloud.dtype.names, *ADDED) and (msg.height, msg.width) == (HEIGHT, WIDTH)
    assert same_bytes(out["channel"], cloud["channel"]) and same_bytes(out["t"], cloud["t"])
    np.testing.assert_array_equal(out["label"][rows], compact_labels["label"])


def test_as_input_without_a_source_publishes_compact_and_warns_once(
        beams32: Frame, capfd: pytest.CaptureFixture[str]) -> None:
    cloud = ouster_cloud(beams32)
    with ros_session() as ros:
        ros.add(ClusterProposalNode(context=ros.context))  # compact proposals
        ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules"), Parameter("output_layout", value="as_input"),
            Parameter("publish_background", value=True)]))
        labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
        background = Collector(ros, PointCloud2, "/pass3d/background")
        pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
        connect(pub, labeled, background)
        for k in range(2):
            pub.publish(message(cloud, STAMP0 + k))
            labeled.wait(k + 1)
            background.wait(k + 1)
    out = columns(labeled.messages[-1])
    assert labeled.messages[-1].height == 1 and len(out) == returns(cloud).sum()
    back = columns(background.messages[-1])
    assert back.dtype.names == ("x", "y", "z", "intensity", "ring") and len(back) == (out["label"] == 0).sum()
    err = capfd.readouterr().err
    assert err.count("set output_layout as_input on cluster_proposal_node too") == 1, err
    assert err.count("the background cloud has only x, y, z, intensity, ring") == 1, err


def test_labeled_as_input_maps_each_point_to_its_row() -> None:
    cloud = np.zeros(6, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "u1")]))
    cloud["x"] = [np.nan, 1, 0, 2, 3, 4]
    cloud["label"] = 9  # an input field of the same name is replaced
    source = input_source(cloud, 2, 3, read=5, kept=np.array([0, 3, 4]))  # (0, 0, 0) and x=2 left out
    assert isinstance(source, InputSource) and not source.is_dense
    np.testing.assert_array_equal(source.positions, [1, 4, 5])
    compact = {"cluster_id": np.array([0, -1, 0], np.int32), "confidence": np.array([1, 0.5, 1], np.float32),
               "rgb": np.zeros(3, np.float32), "label": np.array([1, 0, 1], np.uint8)}
    out = columns(encode(labeled_as_input(source, compact), height=2))
    assert out.dtype.names == ("x", "y", "z", "cluster_id", "confidence", "rgb", "label")
    np.testing.assert_array_equal(out["label"], [0, 1, 0, 0, 0, 1])
    tracked = columns(encode(labeled_as_input(source, {**compact, "track_id": np.array([7, -1, 7], np.int32)}),
                             height=2))  # with tracking on: each point's track id, -1 at the rows not read
    assert tracked.dtype.names == ("x", "y", "z", "cluster_id", "track_id", "confidence", "rgb", "label")
    np.testing.assert_array_equal(tracked["track_id"], [-1, 7, -1, -1, -1, 7])
    np.testing.assert_array_equal(out["cluster_id"], [-1, 0, -1, -1, -1, 0])
    assert same_bytes(out["x"], cloud["x"])
    trimmed = extend_cloud(cloud, rows=out["label"] == 0, drop=("label",))
    assert trimmed.dtype.itemsize == 12 and same_bytes(trimmed["x"], cloud["x"][[0, 2, 3, 4]])
    swapped = cloud.astype(cloud.dtype.newbyteorder(">"))  # a big-endian input: converted, same values
    back = columns(encode(labeled_as_input(dataclasses.replace(source, cloud=swapped), compact), height=2))
    np.testing.assert_array_equal(back["x"], cloud["x"])
    np.testing.assert_array_equal(back["label"], out["label"])


def test_full_proposals_carry_the_input_untouched_and_stage1_under_its_prefix() -> None:
    names = ("x", "y", "z", "intensity", "ring", "ground", "cluster_id", "cluster_id2", "stage1_intensity")
    cloud = np.zeros(5, np.dtype({"names": names, "formats": ["<f4"] * 4 + ["<u2", "u1", "<i4", "<i4", "<f4"],
                                  "offsets": [0, 4, 8, 12, 16, 18, 20, 24, 28], "itemsize": 36}))
    cloud["x"] = [1, np.nan, 2, 3, 4]
    for name, values in {"intensity": [9, 9, 9, 9, 9], "ring": [7, 6, 5, 4, 3], "ground": [1, 2, 3, 4, 5],
                         "cluster_id": [50, 51, 52, 53, 54], "cluster_id2": [-9, -8, -7, -6, -5],
                         "stage1_intensity": [np.nan, 0.5, 0.25, 2, 3]}.items():
        cloud[name] = values
    source = input_source(cloud, 1, 5, read=4, kept=np.array([0, 1, 3]))  # rows 0, 2, 4 read
    points = np.array([[1, 0, 0, 0.1], [2, 0, 0, 0.2], [4, 0, 0, 0.4]], np.float32)
    ring = np.array([30, 31, 32], np.uint16)  # stage 1's, not the driver's
    msg = encode(full_proposals_cloud(source, points, np.array([0, -1, 1]), np.array([-1, 0, -1]),
                                      np.array([True, False, True]), ring))
    wire = [f.name for f in msg.fields]
    assert wire == [*names, *STAGE1_COLUMNS] and all(name.startswith(WIRE_PREFIX) for name in STAGE1_COLUMNS)
    frame = proposal_frame(msg)
    np.testing.assert_array_equal(frame.points, points)
    np.testing.assert_array_equal(frame.ring, ring)
    np.testing.assert_array_equal(frame.cluster_id, [0, -1, 1])
    np.testing.assert_array_equal(frame.cluster_id2, [-1, 0, -1])
    np.testing.assert_array_equal(frame.ground, [True, False, True])  # stage 1's, not the input's own ground field
    np.testing.assert_array_equal(frame.source.positions, [0, 2, 4])
    assert frame.source.cloud.dtype.names == names
    for name in names:
        assert same_bytes(frame.source.cloud[name], cloud[name]), name

    old = encode(extend_cloud(cloud, {"stage1_intensity": np.zeros(5, np.float32)}))  # an older cluster node's
    with pytest.raises(PointCloud2Error, match="older cluster_proposal_node"):
        proposal_frame(old)


def test_old_full_proposals_are_refused_with_one_warning(capfd: pytest.CaptureFixture[str]) -> None:
    cloud = np.zeros(100, np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("cluster_id", "<i4"),
                                    ("cluster_id2", "<i4"), ("ground", "u1"), ("stage1_intensity", "<f4")]))
    cloud["x"] = np.linspace(5, 10, 100)
    with ros_session() as ros:
        node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules")]))
        pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
        assert wait_until(lambda: pub.get_subscription_count() >= 1)
        time.sleep(0.2)
        for k in range(3):
            pub.publish(encode(cloud, stamp_ns=STAMP0 + k))
        assert wait_until(lambda: node.worker.counters.skipped + node.worker.counters.dropped >= 3
                          and node.worker.idle())
        assert node.worker.counters.failed == 0 and node.worker.counters.processed == 0
    err = capfd.readouterr().err
    assert err.count("from an older cluster_proposal_node") == 1, err


def test_layout_benchmark_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert benchmark.main(["layout", "--repeat", "1", "--width", "512"]) == 0
    out = capsys.readouterr().out
    assert out.count("labeled as_input") == 2 and "Ouster-like organized 64 x 512" in out


def test_compact_proposals_carry_stage1_s_ground_for_tracking() -> None:
    frame = generate_frame(seed=3, index=0)
    result = propose(frame.points, frame.ring)
    read = proposal_frame(encode(proposals_cloud(frame.points, result), stamp_ns=STAMP0))
    assert read.ground is not None and read.ground.any()
    np.testing.assert_array_equal(read.ground, result.ground)


def test_both_proposal_forms_carry_the_people_only_points() -> None:
    """rerun_dropped's parts (Stage1Result.people_only) cross /pass3d/proposals in the compact and the full form, and
    the column is left out where there are none."""
    frame = generate_frame(seed=3, index=0)
    result = propose(frame.points, frame.ring)
    assert proposal_frame(encode(proposals_cloud(frame.points, result), stamp_ns=STAMP0)).people_only is None
    flags = np.zeros(result.n_proposals, dtype=bool)
    flags[-1] = True
    result = dataclasses.replace(result, gives_way=flags)
    people = result.people_only()
    assert people is not None and people.any()
    compact = proposal_frame(encode(proposals_cloud(frame.points, result), stamp_ns=STAMP0))
    np.testing.assert_array_equal(compact.people_only, people)
    n = len(frame.points)
    cloud = np.zeros(n, np.dtype([(name, "<f4") for name in "xyz"]))
    for k, name in enumerate("xyz"):
        cloud[name] = frame.points[:, k]
    source = input_source(cloud, 1, n, read=n, kept=None)
    full = proposal_frame(encode(full_proposals_cloud(source, frame.points, result.cluster_id, result.cluster_id2,
                                                      result.ground, result.ring, people_only=people)))
    np.testing.assert_array_equal(full.people_only, people)
