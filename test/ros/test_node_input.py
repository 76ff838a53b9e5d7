"""Hostile and implausible input through the real nodes: malformed proposals clouds are skipped without memory
blow-ups, implausible scans are warned about and still processed, Ctrl-C under load stays quiet, and the shipped
weights label a live frame."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import rclpy
from helpers.ros import STAMP0, Collector, Ros, columns, connect, scan_message, wait_until
from helpers.scans import no_laser_lines_scan
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2

from pass3d_ros.bench.stage1 import same_partition
from pass3d_ros.core.stage1 import proposal_members, propose, synthetic_scan
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, decode, encode
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.input_layout import LEVEL_COLUMNS, STAGE1_PEOPLE_ONLY
from pass3d_ros.ros.proposals import members_from_cloud, proposal_frame, proposal_ids, proposals_cloud
from pass3d_ros.ros.qos import qos_profile
from pass3d_ros.ros.segmentation_node import SegmentationNode
from pass3d_ros.synthetic.dataset import generate_frame

pytestmark = pytest.mark.ros

MEMORY_BOUND_MIB = 200


def with_column(base: dict[str, np.ndarray], name: str, values: np.ndarray | None) -> dict[str, np.ndarray]:
    """A copy of `base` with column `name` replaced (None drops it)."""
    out = {k: v for k, v in base.items() if k != name}
    if values is not None:
        out[name] = values
    return out


def malformed_clouds(base: dict[str, np.ndarray], stamp: int) -> dict[str, PointCloud2]:
    """Every way a proposals cloud can carry ids a sender chose badly, by name."""
    n = len(base["x"])
    ids = base["cluster_id"]

    def changed_ids(edit: Callable[[np.ndarray], None], name: str = "cluster_id") -> dict[str, np.ndarray]:
        values = base[name].copy()
        edit(values)
        return with_column(base, name, values)

    cases = {
        "huge": changed_ids(lambda v: v.__setitem__(0, 2**31 - 1)),
        "huge_id2": changed_ids(lambda v: v.__setitem__(-1, 2**31 - 1), "cluster_id2"),
        "just_past_n": changed_ids(lambda v: v.__setitem__(0, n)),
        "negative": changed_ids(lambda v: v.__setitem__(0, -7)),
        "sparse_millions": with_column(base, "cluster_id", np.where(ids >= 0, ids * 1_000_003, -1).astype(np.int32)),
        "float": with_column(base, "cluster_id", ids.astype(np.float32)),
        "missing": with_column(base, "cluster_id", None),
        "empty": {k: v[:0] for k, v in base.items()},
    }
    msgs = {name: encode(cols, stamp_ns=stamp) for name, cols in cases.items()}
    wide_columns = {k: v for k, v in base.items() if k != "cluster_id"}
    wide_columns["cluster_xx"] = np.stack([ids, ids], axis=1)
    wide = encode(wide_columns, stamp_ns=stamp)
    for field in wide.fields:
        if field.name == "cluster_xx":
            field.name = "cluster_id"
    msgs["count_2"] = wide
    msgs["people_only_count_2"] = encode({**base, STAGE1_PEOPLE_ONLY: np.ones((n, 2), np.uint8)}, stamp_ns=stamp)
    noise = encode(base, stamp_ns=stamp)
    noise.data = np.random.default_rng(0).integers(0, 256, len(noise.data), dtype=np.uint8).tobytes()
    msgs["random_bytes"] = noise
    return msgs


def peak_rss_mib() -> float:
    """The process's peak resident set (VmHWM) in MiB."""
    with open("/proc/self/status") as status:
        line = next(line for line in status if line.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024


def reset_peak_rss() -> bool:
    """Reset VmHWM to the current RSS (Linux clear_refs 5); False where the kernel does not allow it."""
    try:
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")
    except OSError:
        return False
    return True


# ---- the decode step, without ROS ----

def test_proposal_ids_outside_the_cloud_are_malformed() -> None:
    def cloud(ids: np.ndarray) -> np.ndarray:
        return decode(encode({"x": np.zeros(len(ids), np.float32), "y": np.zeros(len(ids), np.float32),
                              "z": np.zeros(len(ids), np.float32), "cluster_id": ids}))

    with pytest.raises(PointCloud2Error, match=r"'cluster_id' holds ids 0\.\.2147483647, expected -1 .* 0\.\.2"):
        proposal_ids(cloud(np.array([0, 1, 2**31 - 1], np.int32)))
    with pytest.raises(PointCloud2Error, match=r"'cluster_id' holds ids -2\.\.1"):
        proposal_ids(cloud(np.array([-2, 1, 0], np.int32)))
    with pytest.raises(PointCloud2Error, match=r"'cluster_id' has dtype float32, expected an integer"):
        proposal_ids(cloud(np.array([0.0, 1.0], np.float32)))
    members = members_from_cloud(cloud(np.array([-1, 4, 0, 4, -1], np.int8)))
    assert [m.tolist() for m in members] == [[2], [1, 3]], "sparse ids: one list per distinct id"


@pytest.mark.parametrize("name", ["cluster_id", "cluster_id2", "label"])
def test_codec_rejects_wide_id_and_label_fields(name: str) -> None:
    msg = encode({"x": np.zeros(3, np.float32), "y": np.zeros(3, np.float32), "z": np.zeros(3, np.float32),
                  "wide": np.zeros((3, 2), np.int32)})
    msg.fields[-1].name = name
    with pytest.raises(PointCloud2Error, match=rf"field '{name}': count 2 not supported, must be 1"):
        decode(msg)


@pytest.mark.parametrize("name", ["ground", STAGE1_PEOPLE_ONLY, LEVEL_COLUMNS[0]])
def test_a_wide_stage1_column_is_malformed(proposal_columns: dict[str, np.ndarray], name: str) -> None:
    n = len(proposal_columns["x"])
    cols = {k: v for k, v in proposal_columns.items() if k not in LEVEL_COLUMNS}
    cols.update({k: np.zeros(n, np.float32) for k in LEVEL_COLUMNS})
    cols[name] = np.ones((n, 2), np.float32 if name in LEVEL_COLUMNS else np.uint8)
    with pytest.raises(PointCloud2Error, match=rf"field\(s\) {name} with count > 1, expected 1"):
        proposal_frame(encode(cols))


@pytest.mark.parametrize("kind", ["zeros", "shuffled"])
def test_level_columns_that_are_no_rotation_are_malformed(proposal_columns: dict[str, np.ndarray], kind: str) -> None:
    """Level coordinates must be the points turned by one rotation (read back by Kabsch): all zeros, or rows of other
    points, would give an arbitrary level frame."""
    n = len(proposal_columns["x"])
    xyz = np.column_stack([proposal_columns[k] for k in "xyz"]).astype(np.float64)
    tilt = np.radians(5.0)
    turn = np.array([[np.cos(tilt), 0.0, np.sin(tilt)], [0.0, 1.0, 0.0], [-np.sin(tilt), 0.0, np.cos(tilt)]])
    level = (xyz @ turn.T).astype(np.float32)
    cols = {k: v for k, v in proposal_columns.items() if k not in LEVEL_COLUMNS}
    cols.update({k: level[:, i] for i, k in enumerate(LEVEL_COLUMNS)})
    assert np.allclose(proposal_frame(encode(cols)).level, turn, atol=1e-4)  # a true rotation is read back
    bad = np.zeros((n, 3), np.float32) if kind == "zeros" else level[np.random.default_rng(3).permutation(n)]
    cols.update({k: bad[:, i] for i, k in enumerate(LEVEL_COLUMNS)})
    with pytest.raises(PointCloud2Error, match=r"no rotation of the points' x, y, z"):
        proposal_frame(encode(cols))


def test_codec_names_a_point_step_numpy_cannot_hold() -> None:
    msg = encode({"x": np.zeros(1, np.float32), "y": np.zeros(1, np.float32), "z": np.zeros(1, np.float32)})
    msg.point_step = msg.row_step = 2**31
    with pytest.raises(PointCloud2Error, match=r"point_step 2147483648 too large \(at most 2147483647"):
        decode(msg)


def test_members_from_stage1_ids_match_proposal_members(proposal_columns: dict[str, np.ndarray]) -> None:
    members = members_from_cloud(decode(encode(proposal_columns)))
    expected = proposal_members(proposal_columns["cluster_id"], proposal_columns["cluster_id2"])
    assert len(members) == len(expected) > 3
    assert all(np.array_equal(a, b) for a, b in zip(members, expected, strict=True))


# ---- segmentation_node ----

def test_fuzzed_proposals_are_skipped_and_the_next_frame_labeled(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    """Each malformed cloud is skipped with a warning (not a `frame failed`), memory stays bounded, and the valid
    frame after it is labeled."""
    node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter("classifier", value="size_rules")]))
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    connect(pub, labeled)
    bad = malformed_clouds(proposal_columns, STAMP0)
    good = encode(proposal_columns, stamp_ns=STAMP0 + 1)
    pub.publish(good)
    labeled.wait(1)
    measured = reset_peak_rss()
    rss_before = peak_rss_mib()

    started = time.monotonic()
    for count, (name, msg) in enumerate(bad.items(), start=1):
        pub.publish(msg)
        assert wait_until(lambda n=count: node.worker.counters.skipped >= n and node.worker.idle()), name
        assert node.worker.counters.failed == 0, f"{name}: must be skipped, not fail"
        pub.publish(good)
        assert len(labeled.wait(count + 1)) == count + 1, f"no labeled frame after {name}"
    took = time.monotonic() - started

    assert all(msg.header.stamp.nanosec == good.header.stamp.nanosec for msg in labeled.messages)
    assert wait_until(lambda: node.worker.counters.processed == len(bad) + 1 and node.worker.idle())
    assert node.worker.counters.skipped == len(bad)
    assert node.worker.counters.dropped == 0 and node.worker.counters.failed == 0
    if measured:
        assert peak_rss_mib() - rss_before < MEMORY_BOUND_MIB, "a malformed message must not size the work"
    assert took < 30.0
    err = capfd.readouterr().err
    assert "skipping malformed proposals cloud: field 'cluster_id' holds ids" in err
    assert "frame failed" not in err


def test_each_malformed_proposals_cloud_is_skipped_by_name(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    """One fresh node per case, so the throttled warning of each case is seen: it names the problem."""
    expected = {
        "huge": "'cluster_id' holds ids", "huge_id2": "'cluster_id2' holds ids", "negative": "expected -1 (none)",
        "float": "expected an integer type", "missing": "no cluster_id field", "count_2": "'cluster_id': count 2",
        "empty": "skipping empty proposals cloud", "random_bytes": "skipping malformed proposals cloud",
    }
    bad = malformed_clouds(proposal_columns, STAMP0)
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    for name, needle in expected.items():
        node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
            Parameter("classifier", value="size_rules")]))
        assert wait_until(lambda: pub.get_subscription_count() >= len(ros.nodes) - 1)
        time.sleep(0.2)
        capfd.readouterr()
        pub.publish(bad[name])
        assert wait_until(lambda n=node: n.worker.counters.skipped >= 1 and n.worker.idle()), name
        err = capfd.readouterr().err
        assert needle in err and "frame failed" not in err, (name, err)
        assert node.worker.counters.failed == 0
        ros.executor.remove_node(node)
        ros.nodes.remove(node)
        node.destroy_node()


def test_shutdown_mid_frame_is_quiet(
    ros: Ros, proposal_columns: dict[str, np.ndarray], capfd: pytest.CaptureFixture[str]
) -> None:
    """Ctrl-C shuts the context down while a worker is mid-frame: its failed publish must log no error."""
    node = ros.add(SegmentationNode(context=ros.context, parameter_overrides=[
        Parameter("classifier", value="size_rules")]))
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    assert wait_until(lambda: pub.get_subscription_count() >= 1)
    time.sleep(0.3)
    inside, release = threading.Event(), threading.Event()
    segment = node.classifier.segment

    def slow_segment(*args, **kwargs):
        inside.set()
        release.wait(10)
        return segment(*args, **kwargs)

    node.classifier.segment = slow_segment
    pub.publish(encode(proposal_columns, stamp_ns=STAMP0))
    assert inside.wait(10), "the frame never reached the worker"
    rclpy.shutdown(context=ros.context)
    release.set()
    assert wait_until(node.worker.idle, 10)
    node.stop_worker()
    err = capfd.readouterr().err
    assert "frame failed" not in err and "[ERROR]" not in err, err


@pytest.fixture(scope="module")
def people_frame() -> Frame:
    """A synthetic HDL-64E scan whose proposals hold cars, pedestrians and cyclists (12, 3 and 2 of them)."""
    return generate_frame(seed=7, index=0)


def test_shipped_weights_label_a_live_frame(ros: Ros, people_frame: Frame) -> None:
    """Guards the shipped network predicting background everywhere (the other node tests use random weights):
    the default node labels cars and people close to the offline Segmenter, and every class that some proposal holds
    mostly (20 points or more; a person of 3 points that no proposal holds cannot be labelled by stage 2)."""
    frame = people_frame
    cloud = proposals_cloud(frame.points, propose(frame.points, frame.ring))
    ros.add(SegmentationNode(context=ros.context))  # weights "" = the shipped pass3d_lite.pt
    labeled = Collector(ros, PointCloud2, "/pass3d/labeled")
    pub = ros.probe.create_publisher(PointCloud2, "/pass3d/proposals", qos_profile("reliable"))
    connect(pub, labeled)
    pub.publish(encode(cloud, stamp_ns=STAMP0))
    got = np.bincount(columns(labeled.wait(1)[0])["label"], minlength=4)

    members = proposal_members(cloud["cluster_id"], cloud["cluster_id2"])
    offline = open_classifier("").segment(frame.points, members)
    expected = np.bincount(offline.labels, minlength=4)
    assert np.abs(got - expected).max() <= 0.02 * len(frame.points), (got, expected)
    proposed = {int(np.bincount(frame.labels[m][frame.labels[m] < 4], minlength=4).argmax())
                for m in members if len(m) >= 20}
    assert proposed >= {1, 2, 3}, proposed
    for cls in (1, 2, 3):
        assert got[cls] > 0, f"class {cls} is held by a proposal but never predicted: {got}"
        assert expected[cls] > 0


# ---- cluster_proposal_node ----

def test_implausible_scans_warn_and_are_still_processed(
    ros: Ros, frame: Frame, capfd: pytest.CaptureFixture[str]
) -> None:
    """0..255 intensity, rings past the sensor's lasers, and absurd or infinite points: one warning each, naming
    the field, and a proposals cloud that matches the repaired frame."""
    ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)

    bright = Frame(frame.name, frame.points * np.array([1, 1, 1, 255], np.float32), ring=frame.ring)
    pub.publish(scan_message(bright, STAMP0))
    out = columns(clouds.wait(1)[0])
    np.testing.assert_allclose(out["intensity"], frame.points[:, 3], atol=1e-6)
    np.testing.assert_array_equal(out["cluster_id"], propose(frame.points, frame.ring).cluster_id)

    wild_ring = frame.ring.copy()
    wild_ring[::1000] = 65535
    pub.publish(scan_message(Frame(frame.name, frame.points, ring=wild_ring), STAMP0 + 1))
    out = columns(clouds.wait(2)[1])
    np.testing.assert_array_equal(out["cluster_id"], propose(frame.points, None).cluster_id)
    assert out["ring"].max() < 64

    far = np.array([[1e6, 0, 0, 0.5], [np.inf, 1, 1, 0.5], [0, -np.inf, 0, 0.5], [0, 0, 2e4, 0.5]], np.float32)
    pub.publish(scan_message(Frame(frame.name, np.concatenate([far[:2], frame.points, far[2:]])), STAMP0 + 2))
    out = columns(clouds.wait(3)[2])
    assert len(out) == len(frame.points)
    np.testing.assert_array_equal(out["cluster_id"], propose(frame.points, None).cluster_id)

    err = capfd.readouterr().err
    assert "intensity: values " in err and "after intensity_scale 1, expected 0..1" in err
    assert "ring: values up to 65535, expected 0..127" in err
    assert "x/y/z: dropping 4 points with non-finite or absurd coordinates" in err


def test_ring_field_past_the_named_sensor_warns(ros: Ros, frame: Frame, capfd: pytest.CaptureFixture[str]) -> None:
    """stage1.sensor vlp16 on a 64-laser scan: its ring field cannot be a VLP-16's; the node says so, naming the
    parameter, and recovers the rings from the points instead of trusting them."""
    ros.add(ClusterProposalNode(context=ros.context, parameter_overrides=[Parameter("stage1.sensor", value="vlp16")]))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    pub.publish(scan_message(frame, STAMP0))
    clouds.wait(1)
    err = capfd.readouterr().err
    assert f"ring: values up to {int(frame.ring.max())}, expected 0..15 (stage1.sensor vlp16)" in err, err


def stream_with_counted_searches(ros: Ros) -> tuple[Any, Collector, list[int], Callable[..., Any]]:
    """A cluster node fed by a probe publisher, its proposals collector, and a laser-line search that records each
    call in the returned list (monkeypatch it over `ring.rings_from_lines` once the expected result is computed)."""
    from pass3d_ros.core.stage1 import ring

    searches: list[int] = []
    search = ring.rings_from_lines

    def counted(points: np.ndarray, sensor: str = "auto", tilted: bool = False) -> ring.Rings | None:
        searches.append(len(points))
        return search(points, sensor, tilted)

    ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    return pub, clouds, searches, counted


def test_shuffled_stream_searches_its_laser_lines_once(ros: Ros, monkeypatch: pytest.MonkeyPatch) -> None:
    """Scans in no firing order and without a ring field: the node finds the laser lines on the first scan and reads
    the next scans' rings off them (no second search), with the proposals of the scan's own search."""
    from pass3d_ros.core.stage1 import ring

    pub, clouds, searches, counted = stream_with_counted_searches(ros)
    points = synthetic_scan(points_per_ring=900)  # a scan whose lines the search finds (see the README on others)
    expected = propose(points)
    monkeypatch.setattr(ring, "rings_from_lines", counted)
    for k in range(3):
        order = np.random.default_rng(k).permutation(len(points))
        pub.publish(scan_message(Frame("scan", np.ascontiguousarray(points[order])), STAMP0 + k))
        out = columns(clouds.wait(k + 1)[k])
        assert same_partition(out["cluster_id"], expected.cluster_id[order])
        np.testing.assert_array_equal(out["ring"], expected.ring[order])
    assert len(searches) == 1


def test_stream_without_laser_lines_searches_again_only_after_the_retry_time(
        ros: Ros, monkeypatch: pytest.MonkeyPatch) -> None:
    """Scans in which no line search can find laser lines: the node searches on the first, bins the next ones by
    elevation without searching, and searches again once LINE_SEARCH_RETRY_S has passed."""
    from pass3d_ros.core.stage1 import ring
    from pass3d_ros.core.stream import lines as held_lines

    pub, clouds, searches, counted = stream_with_counted_searches(ros)
    points = no_laser_lines_scan()
    expected = propose(points)
    monkeypatch.setattr(ring, "rings_from_lines", counted)
    monkeypatch.setattr(held_lines, "LINE_SEARCH_RETRY_S", 3600.0)
    monkeypatch.setattr(held_lines, "LINE_SEARCH_FIRST_RETRY_S", 3600.0)  # no retry on the clock's own time
    for k in range(4):
        if k == 3:
            monkeypatch.setattr(held_lines, "LINE_SEARCH_RETRY_S", 0.0)
        pub.publish(scan_message(Frame("scan", points), STAMP0 + k))
        out = columns(clouds.wait(k + 1)[k])
        assert same_partition(out["cluster_id"], expected.cluster_id)
        assert len(searches) == (1 if k < 3 else 2)


def test_a_bottom_up_ring_field_gives_the_proposals_of_a_top_down_one(ros: Ros, frame: Frame) -> None:
    """velodyne_pointcloud numbers ring 0 as the lowest laser: the node measures the numbering once, says so in the
    log and on /diagnostics, gives the proposals of the top-down field, and publishes the driver's ring as it came."""
    from diagnostic_msgs.msg import DiagnosticArray

    node = ClusterProposalNode(context=ros.context)
    ros.add(node)
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    bottom_up = (int(frame.ring.max()) - frame.ring).astype(np.uint16)
    for k in range(2):
        pub.publish(scan_message(Frame(frame.name, frame.points, ring=bottom_up), STAMP0 + k))
        clouds.wait(k + 1)
    outs = [columns(msg) for msg in clouds.wait(2)]
    expected = propose(frame.points, frame.ring).cluster_id
    for out in outs:
        np.testing.assert_array_equal(out["cluster_id"], expected)
        np.testing.assert_array_equal(out["ring"], bottom_up)
    status = []
    ros.probe.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: status.extend(msg.status), 10)
    assert wait_until(lambda: any(kv.key == "ring_field" for s in status for kv in s.values))
    found = {kv.key: kv.value for s in status for kv in s.values if s.name.endswith("cluster_proposal_node")}
    assert found["ring_field"] == "bottom_up"


def test_one_corrupt_cloud_changes_no_later_scans_intensities(
    ros: Ros, frame: Frame, capfd: pytest.CaptureFixture[str]
) -> None:
    """A 0..1 stream, one cloud whose intensities are garbage, then good scans: every later scan goes out with its
    own intensities (one corrupt cloud used to set the stream's scale and zero ~50 scans after it)."""
    ros.add(ClusterProposalNode(context=ros.context))
    clouds = Collector(ros, PointCloud2, "/pass3d/proposals")
    pub = ros.probe.create_publisher(PointCloud2, "/velodyne_points", qos_profile("reliable"))
    connect(pub, clouds)
    garbage = frame.points.copy()
    garbage[:, 3] = np.random.default_rng(0).integers(0, 2**32, len(garbage), dtype=np.uint32).view(np.float32)
    scans = [frame.points] * 3 + [garbage] + [frame.points] * 4
    for k, points in enumerate(scans):  # one at a time: the node keeps only the newest frame
        pub.publish(scan_message(Frame(frame.name, points, ring=frame.ring), STAMP0 + k))
        clouds.wait(k + 1)
    outs = [columns(msg) for msg in clouds.wait(len(scans))]
    for out in outs[4:]:
        np.testing.assert_allclose(out["intensity"], frame.points[:, 3], atol=1e-6)
    assert "intensity: a corrupt scan" in capfd.readouterr().err
