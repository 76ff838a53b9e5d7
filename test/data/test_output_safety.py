"""Writers that cannot destroy what they did not make (issue 40, item 3): --force replaces only this package's own
outputs and never the working folder or an input; an empty --out is an error; a full disk is one line, leaves no
half-written output (a recorder keeps a valid bag of what it recorded); kitti2bag's --topic and --frame-id."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest
from helpers.ros import ros_session
from rosbags.rosbag2 import Reader, Writer

import pass3d_ros.data.outputs as outputs
from pass3d_ros.data import bag_convert
from pass3d_ros.data.bag import TYPESTORE, BagWriter, topic_name_problem
from pass3d_ros.data.outputs import MARKER, OutputError, out_path, protected_reason, write_text_atomic
from pass3d_ros.evaluation import segmenting
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, columns_to_cloud, encode
from pass3d_ros.tools import cli, evaluate, kitti2bag, pseudo_label, segment, simulate

SPEC = "synthetic:frames=2,seed=3"


def one_error_line(err: str, prog: str, *names: object) -> str:
    """The single stderr line of a failed tool, naming each of `names`, with no traceback or raw errno text."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: error: ") and "Traceback" not in err and "[Errno" not in err, err
    for name in names:
        assert str(name) in lines[0], err
    return lines[0]


def write_scans(root: Path, frames: int = 2) -> Path:
    """A tiny unlabelled SemanticKITTI sequence (velodyne/*.bin only)."""
    rng = np.random.default_rng(0)
    (root / "velodyne").mkdir(parents=True)
    for index in range(frames):
        points = rng.uniform(-20, 20, (200, 4)).astype(np.float32)
        points[:, 3] = rng.uniform(0, 1, 200)
        points.tofile(root / "velodyne" / f"{index:06d}.bin")
    return root


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def fail_after(count: int):
    """A replacement for rosbags' Writer.write that fills the disk after `count` messages."""
    real = Writer.write
    calls: list[int] = []

    def write(self, connection, timestamp, data):
        calls.append(1)
        if len(calls) > count:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, connection, timestamp, data)

    return write


# ------------------------------------------------------------------------------------------- the shared rule


def test_out_path_refuses_the_empty_string() -> None:
    with pytest.raises(OutputError, match="--out is empty"):
        out_path("")
    assert out_path("x") == Path("x")


def test_protected_paths(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    work = tmp_path / "a" / "work"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    data = tmp_path / "data" / "seq"
    data.mkdir(parents=True)
    (tmp_path / "link").symlink_to(work)
    assert "working folder" in protected_reason(".")
    assert "working folder" in protected_reason(tmp_path / "link")
    assert "holds the working folder" in protected_reason("..")
    assert "root" in protected_reason("/")
    assert "an input" in protected_reason(data, [data])
    assert "holds an input" in protected_reason(tmp_path / "data", [data])
    assert protected_reason(tmp_path / "out", [data]) is None
    assert protected_reason(data / "pred", [data]) is None


def test_run_tool_speaks_plain_words(capsys: pytest.CaptureFixture[str]) -> None:
    def denied() -> int:
        raise PermissionError(errno.EACCES, "Permission denied", "/some/out")

    def full() -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    assert cli.run_tool("tool", denied) == 2
    assert one_error_line(capsys.readouterr().err, "tool") == "tool: error: /some/out: permission denied"
    assert cli.run_tool("tool", full) == 2
    assert one_error_line(capsys.readouterr().err, "tool") == "tool: error: disk full (no space left on device)"


def test_json_write_leaves_nothing_on_a_full_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "eval.json"
    target.write_text("old\n")
    real_fdopen = os.fdopen

    class Full:
        def __init__(self, *args, **kwargs) -> None:
            self.stream = real_fdopen(*args, **kwargs)

        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            self.stream.close()

        def write(self, _text: str) -> int:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs.os, "fdopen", Full)
    with pytest.raises(outputs.DiskFullError, match=f"{target}: disk full"):
        write_text_atomic(target, "{}\n")
    assert listing(tmp_path) == ["eval.json"] and target.read_text() == "old\n"


def test_evaluate_json_on_a_full_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "eval.json"

    class FullDiskOs:
        """`os` as the outputs module sees it, on a full disk: only its renames fail (numba's cache, which also
        renames through `os.replace`, is left alone)."""

        def __getattr__(self, name: str) -> object:
            return getattr(os, name)

        @staticmethod
        def replace(*_args) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs, "os", FullDiskOs())
    code = evaluate.main(["--stage1-only", "--data", "synthetic:frames=1,seed=1", "--json", str(target),
                          "--no-progress"])
    assert code == 2
    one_error_line(capsys.readouterr().err, "pass3d_evaluate", target, "disk full")
    assert listing(tmp_path) == [], "no 0-byte or partial --json file"


# ----------------------------------------------------------------------------------------------- kitti2bag


def test_kitti2bag_refuses_an_empty_out_and_the_working_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "precious.txt").write_text("mine")
    assert kitti2bag.main(["--data", SPEC, "--out", "", "--force", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "--out is empty")
    for out in (".", str(tmp_path), ".."):
        assert kitti2bag.main(["--data", SPEC, "--out", out, "--force", "--no-progress"]) == 2
        line = one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "working folder")
        assert "partial" not in line
    assert listing(tmp_path) == ["precious.txt"]


def test_kitti2bag_force_replaces_only_a_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "keep.txt").write_text("mine")
    assert kitti2bag.main(["--data", SPEC, "--out", str(folder), "--force", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", folder, "not a bag")
    assert listing(folder) == ["keep.txt"]
    bag = tmp_path / "bag"
    assert kitti2bag.main(["--data", SPEC, "--out", str(bag), "--no-progress"]) == 0
    assert kitti2bag.main(["--data", "synthetic:frames=3,seed=3", "--out", str(bag), "--force", "--no-progress"]) == 0
    with Reader(bag) as reader:
        assert reader.message_count == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "notes"]


def test_kitti2bag_never_replaces_its_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "in" / "bag"
    assert kitti2bag.main(["--data", SPEC, "--out", str(bag), "--no-progress"]) == 0
    capsys.readouterr()
    scans = write_scans(tmp_path / "seq")
    before = listing(tmp_path)
    for out in (bag, bag.parent):
        assert kitti2bag.main(["--data", f"bag:{bag}", "--out", str(out), "--force", "--no-progress"]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "input")
    assert kitti2bag.main(["--data", f"semantickitti:{scans}", "--out", str(scans), "--force", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "input")
    assert listing(tmp_path) == before


@pytest.mark.parametrize("topic", ["", "1abc", "/a//b", "/a/", "/a b", "/a/9b", "/ä", "a~b", "/{a"])
def test_kitti2bag_refuses_an_invalid_topic(topic: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bag"
    assert kitti2bag.main(["--data", SPEC, "--out", str(out), "--topic", topic, "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "--topic", "not a valid ROS 2 topic name")
    assert not out.exists()


def test_topic_names_ros_accepts() -> None:
    for name in ("/velodyne_points", "velodyne", "~/points", "/a/b_2/c", "/{ns}/points", "_hidden"):
        assert topic_name_problem(name) is None, name


def test_kitti2bag_refuses_an_empty_frame_id(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bag"
    assert kitti2bag.main(["--data", SPEC, "--out", str(out), "--frame-id", "", "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", "--frame-id")
    assert not out.exists()


def test_kitti2bag_full_disk_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(Writer, "write", fail_after(1))
    out = tmp_path / "bag"
    assert kitti2bag.main(["--data", "synthetic:frames=3,seed=3", "--out", str(out), "--no-progress"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_kitti2bag", out, "disk full (no space left on device)")
    assert listing(tmp_path) == [], "no half-written bag, no build folder"


# ---------------------------------------------------------------------------------------------- the recorder


def test_bag_writer_keeps_what_it_wrote(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "rec"
    cloud = columns_to_cloud({name: np.zeros(5, np.float32) for name in ("x", "y", "z", "intensity")})
    raw = TYPESTORE.serialize_cdr(encode(cloud, frame_id="v", stamp_ns=1, typestore=TYPESTORE), POINTCLOUD2_TYPE)
    monkeypatch.setattr(Writer, "write", fail_after(3))
    writer = BagWriter(out).open()
    for stamp in range(1, 4):
        writer.write_raw("/points", POINTCLOUD2_TYPE, stamp, raw)
    with pytest.raises(outputs.DiskFullError, match=f"{out}: disk full"):
        writer.write_raw("/points", POINTCLOUD2_TYPE, 4, raw)
    assert writer.keep_written() == (out, 3)
    with Reader(out) as reader:
        assert [t for _, t, _ in reader.messages()] == [1, 2, 3]
    assert [p.name for p in tmp_path.iterdir()] == ["rec"], "no build folder left"
    writer.abort()
    assert out.is_dir(), "abort after keep_written leaves the kept bag"


def test_recorder_keeps_a_valid_bag_on_a_full_disk(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pass3d_ros.ros.bag_replay import replay
    from pass3d_ros.ros.recorder import Recorder, RecordingWriteError

    source = tmp_path / "source"
    bag_convert.convert(["synthetic:frames=6,seed=2"], source, progress=False, log=lambda _: None)
    monkeypatch.setattr(Writer, "write", fail_after(3))
    out = tmp_path / "recorded"
    topic = f"/full_{os.getpid()}"
    with ros_session() as ros:
        recorder = Recorder(ros.make_node("recorder"), {topic: POINTCLOUD2_TYPE}, out, qos="reliable")
        replay(source, ros.make_node("pub"), publish_topic=topic, rate=0.0, qos="reliable", min_subscribers=1)
        with pytest.raises(RecordingWriteError) as caught:
            recorder.wait(6, timeout=10.0)
        recorder.abort()
    message = str(caught.value)
    assert "disk full" in message and "kept the 3 message(s)" in message and str(out) in message
    assert "\n" not in message and "[Errno" not in message
    with Reader(out) as reader:
        assert reader.message_count == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recorded", "source"]


# ----------------------------------------------------------------------------- folder outputs and their marker


def test_pseudo_label_refuses_the_working_folder_and_its_input(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    scans = write_scans(tmp_path / "seq")
    monkeypatch.chdir(tmp_path)
    before = listing(tmp_path)
    for out in ("", "."):
        assert pseudo_label.main(["--data", f"semantickitti:{scans}", "--out", out, "--force", "--no-progress"]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_pseudo_label", "empty" if not out else "working folder")
    for out in (scans, scans / "velodyne"):
        assert pseudo_label.main(["--data", f"semantickitti:{scans}", "--out", str(out), "--force",
                                  "--no-progress"]) == 2
        one_error_line(capsys.readouterr().err, "pass3d_pseudo_label", out)
    assert listing(tmp_path) == before


def test_pseudo_label_force_replaces_only_its_own_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pseudo"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    args = ["--data", "synthetic:frames=1,seed=98", "--out", str(out), "--no-progress", "--force"]
    assert pseudo_label.main(args) == 2
    one_error_line(capsys.readouterr().err, "pass3d_pseudo_label", out, "not a pseudo-label folder")
    assert listing(out) == ["keep.txt"]
    (out / MARKER).write_text("written by pass3d_pseudo_label\n")
    assert pseudo_label.main(args) == 0
    assert not (out / "keep.txt").exists() and (out / MARKER).is_file() and (out / "summary.json").is_file()


def test_segment_force_needs_its_marker(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "labels").mkdir()
    (out / "labels" / "mine.label").write_bytes(b"\0" * 4)
    args = ["--data", "synthetic:frames=1,seed=1", "--out", str(out), "--classifier", "size_rules", "--no-progress",
            "--no-png", "--force"]
    assert segment.main(args, log=lambda _: None) == 2
    one_error_line(capsys.readouterr().err, "pass3d_segment", out, "not an output folder of pass3d_segment")
    assert listing(out) == ["labels", "labels/mine.label"]
    fresh = tmp_path / "fresh"
    assert segment.main([*args[:3], str(fresh), *args[4:]], log=lambda _: None) == 0
    assert (fresh / MARKER).is_file()
    assert segment.main([*args[:3], str(fresh), *args[4:]], log=lambda _: None) == 0
    monkeypatch.chdir(fresh)
    assert segment.main([*args[:3], ".", *args[4:]], log=lambda _: None) == 2
    one_error_line(capsys.readouterr().err, "pass3d_segment", "working folder")


def test_segment_full_disk_leaves_the_output_as_it_was(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    class FullDiskWords:
        """Label words whose file write meets a full disk."""

        def astype(self, _dtype: str) -> FullDiskWords:
            return self

        def tofile(self, _path: Path) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(segmenting, "to_semantic_kitti", lambda _labels: FullDiskWords())
    out = tmp_path / "out"
    assert segment.main(["--data", SPEC, "--out", str(out), "--classifier", "size_rules", "--no-progress",
                         "--no-png"], log=lambda _: None) == 2
    one_error_line(capsys.readouterr().err, "pass3d_segment", out, "disk full")
    assert listing(tmp_path) == []


def test_simulate_force_needs_its_marker_and_a_full_disk_leaves_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    assert simulate.main(["--frames", "1", "--out", str(foreign), "--force"]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_simulate", foreign, "not a folder of pass3d_simulate")
    assert simulate.main(["--frames", "1", "--out", ""]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_simulate", "--out is empty")
    out = tmp_path / "seq"
    assert simulate.main(["--frames", "1", "--out", str(out)]) == 0
    assert simulate.main(["--frames", "1", "--start", "1", "--out", str(out), "--force"]) == 0
    assert sorted(p.name for p in (out / "velodyne").iterdir()) == ["000000.bin", "000001.bin"]
    capsys.readouterr()

    def full(_folder: Path, _frame: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setitem(simulate.WRITERS, "semantickitti", full)
    fresh = tmp_path / "fresh"
    assert simulate.main(["--frames", "1", "--out", str(fresh)]) == 2
    one_error_line(capsys.readouterr().err, "pass3d_simulate", fresh, "disk full")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign", "seq"]
