"""Bag tools: kitti2bag conversion, the bag: reader, safe writing, replay and recording over real rclpy."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.ros import wait_until
from rosbags.rosbag2 import Reader

import pass3d_ros.data.bag_convert as bag_convert
import pass3d_ros.tools.kitti2bag as kitti2bag
from pass3d_ros.data.bag import TYPESTORE, BagError, BagWriter, read_bag
from pass3d_ros.data.spec import Dataset, DatasetError, DatasetFormat, open_dataset
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, decode, encode, header_stamp_ns

SEMANTIC_OF = np.array([99, 10, 30, 31], dtype=np.uint32)  # background, car, person, bicyclist


def write_sequence(root: Path, frames: int = 4, seed: int = 0, labels: bool = True) -> Path:
    """A SemanticKITTI-layout sequence with awkward values (NaN, -0.0, denormals) to prove bit identity."""
    rng = np.random.default_rng(seed)
    seq = root / "seq"
    (seq / "velodyne").mkdir(parents=True)
    if labels:
        (seq / "labels").mkdir()
    for k in range(frames):
        points = rng.normal(0, 10, (300 + 17 * k, 4)).astype(np.float32)
        points[:, 3] = rng.random(len(points), dtype=np.float32)
        points[0, 0], points[1, 1], points[2, 2] = np.nan, -0.0, np.float32(1e-42)
        points.tofile(seq / "velodyne" / f"{k:06d}.bin")
        if labels:
            SEMANTIC_OF[rng.integers(0, 4, len(points))].tofile(seq / "labels" / f"{k:06d}.label")
    return seq


def expected_labels(seq: Path, k: int) -> np.ndarray:
    semantic = np.fromfile(seq / "labels" / f"{k:06d}.label", dtype=np.uint32)
    return np.argmax(semantic[:, None] == SEMANTIC_OF[None, :], axis=1).astype(np.uint8)


def read_messages(bag: Path) -> list[tuple[str, int, object]]:
    with Reader(bag) as reader:
        return [(c.topic, t, TYPESTORE.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]


@pytest.mark.parametrize(("storage", "version"), [("mcap", 9), ("mcap", 8), ("sqlite3", 9), ("sqlite3", 8)])
def test_convert_and_read_back(tmp_path: Path, storage: str, version: int) -> None:
    seq = write_sequence(tmp_path)
    out = tmp_path / "bag"
    code = kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", f"--storage={storage}",
                           f"--rosbag-version={version}", "--with-labels", "--no-progress", "--topic=/scan"])
    assert code == 0
    meta = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == version and meta["storage_identifier"] == storage
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "seq"], "no temporary folder may remain"
    messages = read_messages(out)
    assert len(messages) == 4
    for k, (topic, bag_time, msg) in enumerate(messages):
        original = np.fromfile(seq / "velodyne" / f"{k:06d}.bin", dtype="<f4").reshape(-1, 4)
        cloud = decode(msg)
        assert topic == "/scan" and msg.header.frame_id == "velodyne"
        assert cloud.dtype.names == ("x", "y", "z", "intensity", "label_gt")
        got = np.stack([cloud[name] for name in ("x", "y", "z", "intensity")], axis=1)
        assert got.tobytes() == original.tobytes(), f"frame {k} not bit-identical"
        assert np.array_equal(cloud["label_gt"], expected_labels(seq, k))
        assert bag_time == header_stamp_ns(msg) == bag_convert.SYNTHETIC_START_NS + k * bag_convert.FRAME_GAP_NS
    frames = list(open_dataset(f"bag:{out}"))
    assert [f.name for f in frames] == ["000000", "000001", "000002", "000003"]
    assert frames[2].points.tobytes() == np.fromfile(seq / "velodyne" / "000002.bin", "<f4").tobytes()
    assert np.array_equal(frames[3].labels, expected_labels(seq, 3)) and frames[0].ring is None


def test_labels_only_on_request_and_required(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = write_sequence(tmp_path, frames=2, labels=False)
    out = tmp_path / "bag"
    bag_convert.convert([f"semantickitti:{seq}"], out, progress=False, log=lambda _: None)
    assert decode(read_messages(out)[0][2]).dtype.names == ("x", "y", "z", "intensity")
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={tmp_path / 'b2'}", "--with-labels",
                           "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and "000000" in err and "no point labels" in err and "Traceback" not in err
    assert not (tmp_path / "b2").exists()


def test_ring_and_absolute_stamps_are_kept(tmp_path: Path) -> None:
    from pass3d_ros.data.frame import Frame

    rng = np.random.default_rng(5)
    stamps = [1_317_000_000_123_456_789 + k * 103_000_000 for k in range(3)]
    frames = [Frame(name=f"f{k}", points=rng.random((50, 4), dtype=np.float32), stamp_ns=stamps[k],
                    ring=rng.integers(0, 64, 50).astype(np.uint16)) for k in range(3)]
    source = Dataset("kitti_raw", "fake", DatasetFormat(read=lambda _: iter(frames), count=lambda _: 3))
    stats = bag_convert.convert([source], tmp_path / "b", progress=False, log=lambda _: None)
    assert stats.synthesized == () and stats.first_stamp_ns == stamps[0]
    back = list(read_bag(str(tmp_path / "b")))
    assert [f.stamp_ns for f in back] == stamps
    for before, after in zip(frames, back, strict=True):
        assert after.ring.dtype == np.uint16 and np.array_equal(after.ring, before.ring)
        assert after.points.tobytes() == before.points.tobytes()


def test_refuses_overwrite_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = write_sequence(tmp_path, frames=2)
    out = tmp_path / "bag"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err and (out / "keep.txt").read_text() == "mine"
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", "--no-progress", "--force"]) == 2
    assert "not a bag" in capsys.readouterr().err and (out / "keep.txt").read_text() == "mine"
    (out / "keep.txt").unlink()
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", "--no-progress", "--force"]) == 0
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", "--no-progress", "--force"]) == 0
    assert len(read_messages(out)) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "seq"]


def test_interrupt_leaves_no_bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seq = write_sequence(tmp_path, frames=4)
    out = tmp_path / "bag"
    calls = []
    real_encode = bag_convert.encode

    def interrupting_encode(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            partial = [p for p in tmp_path.iterdir() if p.name.startswith(".bag.partial-")]
            assert len(partial) == 1 and not out.exists()
            assert not list(partial[0].rglob("metadata.yaml")), "an unfinished bag must not look complete"
            raise KeyboardInterrupt
        return real_encode(*args, **kwargs)

    monkeypatch.setattr(bag_convert, "encode", interrupting_encode)
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={out}", "--no-progress"]) == 130
    assert len(calls) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_bad_input_file_is_named_and_cleaned_up(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = write_sequence(tmp_path, frames=3)
    (seq / "velodyne" / "000002.bin").write_bytes(b"\0" * 10)
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={tmp_path / 'bag'}", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "000002.bin" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert kitti2bag.main([f"--data=nope:{seq}", f"--out={tmp_path / 'bag'}"]) == 2


@pytest.mark.parametrize(("times", "frame"), [("-5\n-4.9", "000000"), ("0\n1e30", "000001")])
def test_stamp_a_ros_header_cannot_hold_names_the_frame(tmp_path: Path, times: str, frame: str,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """A frame time before 1970 or past a header's int32 seconds is refused naming the dataset and frame, never a
    struct.error traceback from the serializer nor a message that names neither."""
    seq = write_sequence(tmp_path, frames=2)
    (seq / "times.txt").write_text(f"{times}\n")
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={tmp_path / 'bag'}", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"semantickitti:{seq}: frame {frame}" in err and "ROS header" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_bag_topic_selection(tmp_path: Path) -> None:
    out = tmp_path / "two"
    with BagWriter(out, storage="sqlite3") as writer:
        for topic, value in (("/a", 1.0), ("/b", 2.0)):
            cloud = {"x": np.full(3, value, np.float32), "y": np.zeros(3, np.float32),
                     "z": np.zeros(3, np.float32), "ring": np.arange(3, dtype=np.uint16)}
            writer.write(topic, encode(cloud, stamp_ns=7, typestore=TYPESTORE), 7)
    with pytest.raises(DatasetError, match=r"2 sensor_msgs/msg/PointCloud2 topics \(/a, /b\)"):
        read_bag(str(out))
    frames = list(read_bag(f"{out}#/b"))
    assert len(frames) == 1 and frames[0].points[0, 0] == 2.0 and frames[0].stamp_ns == 7
    assert np.array_equal(frames[0].ring, [0, 1, 2]) and frames[0].labels is None
    assert next(read_bag(f"{out}#a")).points[0, 0] == 1.0
    with pytest.raises(DatasetError, match="no sensor_msgs/msg/PointCloud2 topic '/c'"):
        read_bag(f"{out}#/c")
    with pytest.raises(DatasetError, match="cannot open"):
        read_bag(str(tmp_path / "missing"))
    with pytest.raises(BagError, match="unknown storage"):
        BagWriter(tmp_path / "x", storage="zip")


def test_real_frames_round_trip(kitti_dev: Path, tmp_path: Path) -> None:
    specs = [f"semantickitti:{kitti_dev}/semantickitti/sequences/00", f"kitti_object:{kitti_dev}/object/training"]
    out = tmp_path / "real"
    stats = bag_convert.convert(specs, out, with_labels=True, progress=False, log=lambda _: None)
    originals = [frame for spec in specs for frame in open_dataset(spec)]
    assert stats.frames == len(originals) > 0 and stats.out_of_order == 0
    back = list(open_dataset(f"bag:{out}"))
    assert len(back) == len(originals)
    for before, after in zip(originals, back, strict=True):
        assert after.points.tobytes() == before.points.tobytes(), before.name
        assert np.array_equal(after.labels, before.labels), before.name
    stamps = [frame.stamp_ns for frame in back]
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_messages_a_corrupt_mcap_loses_are_an_error_not_a_shorter_bag(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """rosbags silently skips a message record whose channel id is corrupt: reading and converting such a bag name
    it and say how many of the messages its metadata lists were lost, rather than go on with fewer frames."""
    seq = write_sequence(tmp_path, frames=4)
    out = tmp_path / "bag"
    stats = bag_convert.convert([f"semantickitti:{seq}"], out, progress=False, log=lambda _: None)
    mcap = out / "bag.mcap"
    data = bytearray(mcap.read_bytes())
    stamp = stats.first_stamp_ns + 2 * bag_convert.FRAME_GAP_NS  # the third message: log time = publish time
    at = data.index(stamp.to_bytes(8, "little") * 2)
    data[at - 6:at - 4] = b"\xff\xff"  # its channel id, just before its sequence number
    mcap.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"bag.*3 of the 4 messages"):
        list(read_bag(str(out)))
    assert kitti2bag.main([f"--data=bag:{out}", f"--out={tmp_path / 'copy'}", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "3 of the 4 messages" in err and "Traceback" not in err
    assert not (tmp_path / "copy").exists()


# ---- live ROS: replay to a real subscriber, record what is published ----

def small_bag(tmp_path: Path, frames: int = 8) -> Path:
    seq = write_sequence(tmp_path, frames=frames)
    out = tmp_path / "small"
    bag_convert.convert([f"semantickitti:{seq}"], out, with_labels=True, progress=False, log=lambda _: None)
    return out


def collect(node, topic: str, qos: str):
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.qos import qos_profile

    received: list[tuple[float, object]] = []
    node.create_subscription(PointCloud2, topic, lambda m: received.append((time.monotonic(), m)), qos_profile(qos, 50))
    return received


def test_replay_to_real_subscriber(ros, tmp_path: Path) -> None:
    from pass3d_ros.ros.bag_replay import replay

    bag = small_bag(tmp_path)
    topic = f"/replay_{os.getpid()}"
    received = collect(ros.make_node("sub"), topic, "sensor")
    stats = replay(bag, ros.make_node("pub"), publish_topic=topic, rate=2.0, min_subscribers=1)
    assert stats.published == 8 and stats.passes == 1
    assert 0.7 * 0.35 <= stats.seconds < 3.0, stats.seconds  # 7 gaps of 100 ms at x2 = 0.35 s
    assert wait_until(lambda: len(received) == 8, 10.0), f"received {len(received)} of 8"
    originals = [frame for _, _, frame in read_messages(bag)]
    for (_, got), want in zip(received, originals, strict=True):
        assert header_stamp_ns(got) == header_stamp_ns(want)
        assert decode(got).tobytes() == decode(want).tobytes()


def test_replay_loop_until_stopped(ros, tmp_path: Path) -> None:
    from pass3d_ros.ros.bag_replay import replay

    bag = small_bag(tmp_path, frames=4)
    stop = threading.Event()
    seen: list[int] = []

    def on_publish(index: int, stamp_ns: int) -> None:
        seen.append(stamp_ns)
        if index == 9:
            stop.set()

    stats = replay(bag, ros.make_node("looper"), rate=0.0, loop=True, stop=stop, on_publish=on_publish, linger=0.0)
    assert stats.published == 10 and stats.passes == 2
    assert seen[:4] == seen[4:8] == [bag_convert.SYNTHETIC_START_NS + k * bag_convert.FRAME_GAP_NS for k in range(4)]


def test_record_round_trip_from_replay(ros, tmp_path: Path) -> None:
    from visualization_msgs.msg import Marker, MarkerArray

    from pass3d_ros.ros.bag_replay import replay
    from pass3d_ros.ros.qos import qos_profile
    from pass3d_ros.ros.recorder import Recorder

    bag = small_bag(tmp_path, frames=6)
    topic, markers_topic = f"/rec_{os.getpid()}", f"/rec_markers_{os.getpid()}"
    recorder_node = ros.make_node("recorder")
    out = tmp_path / "recorded"
    recorder = Recorder(recorder_node, {topic: POINTCLOUD2_TYPE, markers_topic: "visualization_msgs/msg/MarkerArray"},
                        out, storage="sqlite3", qos="sensor")
    pub_node = ros.make_node("pub")
    marker_pub = pub_node.create_publisher(MarkerArray, markers_topic, qos_profile("reliable", 10))
    assert wait_until(lambda: marker_pub.get_subscription_count() > 0, 10.0)
    marker = Marker(action=Marker.DELETEALL)
    marker.header.stamp.sec, marker.header.stamp.nanosec = 42, 5
    marker_pub.publish(MarkerArray(markers=[marker]))
    stats = replay(bag, pub_node, publish_topic=topic, rate=4.0, min_subscribers=1)
    assert stats.published == 6
    assert recorder.wait(6, timeout=10.0) and recorder.wait(1, topic=markers_topic, timeout=5.0)
    assert not out.exists(), "a bag being recorded must not be in place yet"
    assert recorder.close() == out
    with Reader(bag) as original, Reader(out) as recorded:
        want = [(t, raw) for _, t, raw in original.messages()]
        conns = [c for c in recorded.connections if c.topic == topic]
        got = [(t, raw) for _, t, raw in recorded.messages(connections=conns)]
        marks = [(t, c.msgtype) for c, t, _ in recorded.messages() if c.topic == markers_topic]
    assert got == want, "recorded clouds must equal the replayed bag: same bytes at header stamps"
    assert marks == [(42_000_000_005, "visualization_msgs/msg/MarkerArray")]


def test_recorder_abort_and_overwrite(ros, tmp_path: Path) -> None:
    from pass3d_ros.ros.recorder import Recorder

    node = ros.make_node("rec2")
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match="exists"):
        Recorder(node, [f"/x_{os.getpid()}"], tmp_path / "exists")
    with pytest.raises(RuntimeError), Recorder(node, [f"/x_{os.getpid()}"], tmp_path / "aborted"):
        raise RuntimeError("boom")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists"]


def test_replay_cli_subprocess(ros, tmp_path: Path) -> None:
    bag = small_bag(tmp_path, frames=5)
    topic = f"/cli_{os.getpid()}"
    received = collect(ros.make_node("cli_sub"), topic, "sensor")
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros.domain))
    result = subprocess.run(
        [sys.executable, "-m", "pass3d_ros.tools.replay", str(bag), "--publish-topic", topic, "--rate", "5",
         "--wait-subscribers", "1"],
        capture_output=True, text=True, env=env, timeout=60, check=False,
    )
    assert result.returncode == 0, result.stderr
    assert f"published 5 messages on {topic}" in result.stdout
    arrived = wait_until(lambda: len(received) == 5, 10.0)
    assert arrived, f"received {[header_stamp_ns(m) % 10**10 for _, m in received]}"


def test_replay_cli_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    from pass3d_ros.tools.replay import main

    with pytest.raises(SystemExit) as exc:
        main(["--record", "/x"])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([])


def test_record_cli_subprocess(ros, tmp_path: Path) -> None:
    from sensor_msgs.msg import PointCloud2

    from pass3d_ros.ros.qos import qos_profile

    topic = f"/cli_rec_{os.getpid()}"
    node = ros.make_node("cli_pub")
    publisher = node.create_publisher(PointCloud2, topic, qos_profile("reliable", 10))
    out = tmp_path / "cli.bag"
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros.domain))
    proc = subprocess.Popen(
        [sys.executable, "-m", "pass3d_ros.tools.replay", "--record", topic, "--out", str(out), "--count", "3",
         "--storage", "sqlite3", "--rosbag-version", "8"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    sent: dict[int, bytes] = {}
    stamp = 1_000_000_000
    deadline = time.monotonic() + 30
    while proc.poll() is None and time.monotonic() < deadline:
        cols = {"x": np.full(4, stamp, np.float32), "y": np.zeros(4, np.float32), "z": np.zeros(4, np.float32)}
        publisher.publish(encode(cols, stamp_ns=stamp, frame_id="velodyne"))
        sent[stamp] = decode(encode(cols)).tobytes()
        stamp += 50_000_000
        time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "recorded 3 messages" in stdout
    messages = read_messages(out)
    assert len(messages) == 3
    for _, bag_time, msg in messages:
        assert bag_time == header_stamp_ns(msg) and decode(msg).tobytes() == sent[bag_time]
    assert yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["version"] == 8


def test_bag_without_pointcloud2_lists_what_it_has(tmp_path: Path) -> None:
    """A bag whose only topic has another type names that topic and its type, not just `none`."""
    out = tmp_path / "strings"
    string = TYPESTORE.types["std_msgs/msg/String"]
    with BagWriter(out) as writer:
        writer.write("/chatter", string(data="hello"), 5)
    with pytest.raises(DatasetError, match=r"no sensor_msgs/msg/PointCloud2 topic; the bag has "
                                           r"/chatter \(std_msgs/msg/String\)"):
        read_bag(str(out))
    with pytest.raises(DatasetError, match=r"topic '/velodyne_points'; the bag has /chatter \(std_msgs/msg/String\)"):
        read_bag(f"{out}#/velodyne_points")


# ---- ground truth in `label_gt`: an output bag is never scored against its own predictions ----

def output_like_bag(tmp_path: Path, legacy_truth: bool = False) -> tuple[Path, np.ndarray]:
    """A bag shaped like /pass3d/labeled (label, confidence, rgb, cluster_id); with `legacy_truth` an input bag
    with only a `label` field. Returns (bag, the label column)."""
    rng = np.random.default_rng(3)
    n = 400
    labels = rng.integers(0, 4, n).astype(np.uint8)
    cloud = {"x": rng.normal(0, 10, n).astype(np.float32), "y": rng.normal(0, 10, n).astype(np.float32),
             "z": rng.normal(0, 1, n).astype(np.float32), "intensity": rng.random(n, dtype=np.float32),
             "label": labels}
    if not legacy_truth:
        cloud |= {"cluster_id": np.full(n, -1, np.int32), "confidence": np.ones(n, np.float32),
                  "rgb": np.zeros(n, np.float32)}
    out = tmp_path / ("legacy" if legacy_truth else "output")
    with BagWriter(out) as writer:
        for k in range(2):
            stamp = bag_convert.SYNTHETIC_START_NS + k * bag_convert.FRAME_GAP_NS
            writer.write("/pass3d/labeled", encode(cloud, stamp_ns=stamp, typestore=TYPESTORE), stamp)
    return out, labels


def test_output_bag_has_no_ground_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, labels = output_like_bag(tmp_path)
    frames = list(read_bag(str(bag)))
    assert [f.labels for f in frames] == [None, None], "an output's `label` is a prediction, not ground truth"
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and "label_gt" in err and "prediction" in err
    predicted = list(read_bag(str(bag), labels="predicted"))
    assert all(np.array_equal(f.labels, labels) for f in predicted)
    legacy, legacy_labels = output_like_bag(tmp_path, legacy_truth=True)
    assert np.array_equal(next(read_bag(str(legacy))).labels, legacy_labels), "a legacy input bag keeps `label`"
    assert capsys.readouterr().err == ""
    with pytest.raises(ValueError, match="labels must be"):
        read_bag(str(bag), labels="both")


def test_evaluate_refuses_to_score_an_output_bag_against_itself(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    import pass3d_ros.tools.evaluate as evaluate

    bag, _ = output_like_bag(tmp_path)
    code = evaluate.main(["--data", f"bag:{bag}", "--classifier", "size_rules", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2, "scoring predictions against themselves would report 100 % IoU"
    assert "no point labels" in err and "label_gt" in err


def test_label_gt_beside_an_output_label_is_the_truth(tmp_path: Path) -> None:
    from pass3d_ros.data.bag import truth_field
    from pass3d_ros.evaluation.live import LiveEvalError, _input_frame

    n = 50
    truth, predicted = np.full(n, 2, np.uint8), np.ones(n, np.uint8)
    cloud = {"x": np.arange(n, dtype=np.float32), "y": np.zeros(n, np.float32), "z": np.zeros(n, np.float32),
             "label": predicted, "label_gt": truth, "confidence": np.ones(n, np.float32)}
    out = tmp_path / "both"
    with BagWriter(out) as writer:
        writer.write("/c", encode(cloud, stamp_ns=9, typestore=TYPESTORE), 9)
    assert np.array_equal(next(read_bag(str(out))).labels, truth)
    assert np.array_equal(next(read_bag(str(out), labels="predicted")).labels, predicted)
    assert truth_field(("x", "label")) == "label" and truth_field(("x", "label", "rgb")) is None
    assert truth_field(("x", "label", "rgb", "label_gt")) == "label_gt" and truth_field(("x",)) is None
    raw = TYPESTORE.serialize_cdr(encode(cloud, stamp_ns=9, typestore=TYPESTORE), POINTCLOUD2_TYPE)
    assert np.array_equal(_input_frame(raw, POINTCLOUD2_TYPE)[2], truth)
    del cloud["label_gt"]
    raw = TYPESTORE.serialize_cdr(encode(cloud, stamp_ns=9, typestore=TYPESTORE), POINTCLOUD2_TYPE)
    with pytest.raises(LiveEvalError, match="prediction, not ground truth"):
        _input_frame(raw, POINTCLOUD2_TYPE)


def test_label_gt_of_other_class_ids_names_the_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """label_gt holding ids that are no class here (SemanticKITTI's raw 10 and 40, or corrupt data): a DatasetError
    naming the bag, the message and the ids, and exit 2 from a tool; it was a ValueError traceback when scoring."""
    import pass3d_ros.tools.evaluate as evaluate
    from pass3d_ros.data.spec import DatasetError

    n = 50
    truth = np.tile(np.array([0, 1, 10, 40, 255], np.uint8), n // 5)
    cloud = {"x": np.arange(n, dtype=np.float32), "y": np.ones(n, np.float32), "z": np.zeros(n, np.float32),
             "label_gt": truth}
    out = tmp_path / "raw_ids"
    with BagWriter(out) as writer:
        writer.write("/c", encode(cloud, stamp_ns=9, typestore=TYPESTORE), 9)
    with pytest.raises(DatasetError, match=r"raw_ids.*: message 0: labels 10, 40 are no class id"):
        list(read_bag(str(out)))
    assert evaluate.main(["--data", f"bag:{out}", "--classifier", "size_rules", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "raw_ids" in err and "Traceback" not in err, err


def test_label_gt_must_be_one_per_point() -> None:
    from types import SimpleNamespace

    from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, fields_dtype

    fields = [SimpleNamespace(name=name, offset=4 * k, datatype=7, count=1) for k, name in enumerate("xyz")]
    fields.append(SimpleNamespace(name="label_gt", offset=12, datatype=2, count=2))
    with pytest.raises(PointCloud2Error, match="'label_gt': count 2 not supported"):
        fields_dtype(fields, 16)



def label_bag(path: Path, labels: np.ndarray) -> Path:
    """A one-message bag of a PointCloud2 whose label_gt field is `labels`."""
    n = len(labels)
    cloud = {"x": np.arange(n, dtype=np.float32), "y": np.zeros(n, np.float32), "z": np.zeros(n, np.float32),
             "label_gt": labels}
    with BagWriter(path) as writer:
        writer.write("/c", encode(cloud, stamp_ns=9, typestore=TYPESTORE), 9)
    return path


@pytest.mark.parametrize(("dtype", "wild"), [(np.int32, 257), (np.int8, -1), (np.float32, 1.5), (np.float32, np.nan)])
def test_a_label_gt_uint8_cannot_hold_is_refused_not_wrapped(tmp_path: Path, dtype: type, wild: float) -> None:
    """label_gt of any type reads its class ids; a value uint8 cannot hold names the message (the bag reader) or the
    field (live evaluation), where a cast read 257 as car, -1 as unknown, 1.5 as car."""
    from pass3d_ros.evaluation.live import LiveEvalError, _input_frame

    good = label_bag(tmp_path / "good", np.array([0, 1, 2, 3], dtype=dtype))
    assert np.array_equal(next(read_bag(str(good))).labels, [0, 1, 2, 3])
    bad = label_bag(tmp_path / "bad", np.array([0, 1, 2, wild], dtype=dtype))
    with pytest.raises(DatasetError, match="message 0: field 'label_gt' holds"):
        next(read_bag(str(bad)))
    with Reader(bad) as reader:
        raw = next(iter(reader.messages()))[2]
    with pytest.raises(LiveEvalError, match="label_gt field holds ids other than"):
        _input_frame(raw, POINTCLOUD2_TYPE)

# ---- progress bars only on a terminal ----

def test_no_progress_bar_when_stderr_is_not_a_terminal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = write_sequence(tmp_path, frames=2)
    assert kitti2bag.main([f"--data=semantickitti:{seq}", f"--out={tmp_path / 'bag'}"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "frame/s" not in err and "it/s" not in err, f"a bar was drawn into a pipe: {err!r}"
