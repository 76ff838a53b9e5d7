"""Dataset readers and writers: KITTI object, KITTI raw, SemanticKITTI, SqueezeSeg lidar_2d."""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, IGNORE, PEDESTRIAN
from pass3d_ros.data import kitti_object, kitti_raw, semantickitti, squeezeseg
from pass3d_ros.data.frame import Box3D, Frame
from pass3d_ros.data.kitti_io import ignore_outside_front_view, label_points_in_boxes, natural_key, read_bin
from pass3d_ros.data.spec import DatasetError, count_frames, open_dataset

RNG_SEED = 7


def _scan(n: int, rng: np.random.Generator) -> np.ndarray:
    """Random points spread around the sensor plus reflectance."""
    xyz = rng.uniform([-30, -30, -2.5], [30, 30, 2.0], size=(n, 3))
    return np.hstack([xyz, rng.uniform(0, 1, (n, 1))]).astype(np.float32)


def _points_near(box: Box3D, n: int, rng: np.random.Generator) -> np.ndarray:
    """Points in and just around a box, so that labelling edges matter."""
    local = rng.uniform(-0.65, 0.65, size=(n, 3)) * np.asarray(box.size)
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    xyz = np.column_stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1], local[:, 2]])
    xyz += box.center
    return np.hstack([xyz, rng.uniform(0, 1, (n, 1))]).astype(np.float32)


def _labelled_frame(name: str, boxes: list[Box3D], rng: np.random.Generator) -> Frame:
    points = np.vstack([_scan(3000, rng), *(_points_near(b, 400, rng) for b in boxes)])
    labels, instance = label_points_in_boxes(points[:, :3], boxes)
    return Frame(name=name, points=points, labels=labels, instance=instance, boxes=boxes)


def _angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


# ---------------------------------------------------------------- shared helpers


def test_natural_key_orders_numbers_numerically() -> None:
    names = ["f10.bin", "f2.bin", "f1.bin"]
    assert sorted(names, key=natural_key) == ["f1.bin", "f2.bin", "f10.bin"]


def test_bin_with_wrong_size_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "broken.bin"
    bad.write_bytes(b"\0" * 20)
    with pytest.raises(DatasetError, match=r"broken\.bin"):
        read_bin(bad)


def test_outside_the_front_view_labels_are_unknown() -> None:
    xyz = np.array([[10.0, 0.0, 0.0], [10.0, 9.0, 0.0], [10.0, 11.0, 0.0], [-10.0, 0.0, 0.0], [0.0, -5.0, 0.0]])
    labels = np.array([CAR, PEDESTRIAN, CAR, CYCLIST, BACKGROUND], dtype=np.uint8)
    out = ignore_outside_front_view(xyz, labels)
    assert out.tolist() == [CAR, PEDESTRIAN, IGNORE, IGNORE, IGNORE]
    assert labels.tolist() == [CAR, PEDESTRIAN, CAR, CYCLIST, BACKGROUND], "input must not be modified"


def test_label_points_in_boxes_ignores_background_boxes() -> None:
    xyz = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [9.0, 9.0, 9.0]])
    boxes = [Box3D(np.zeros(3), np.ones(3), 0.0, label=CAR, instance=4),
             Box3D(np.array([5.0, 0, 0]), np.ones(3), 0.0, label=BACKGROUND, instance=5, kind="Van")]
    labels, instance = label_points_in_boxes(xyz, boxes)
    assert labels.tolist() == [CAR, BACKGROUND, BACKGROUND]
    assert instance.tolist() == [4, -1, -1]


# ---------------------------------------------------------------- KITTI object


def _object_boxes() -> list[Box3D]:
    return [
        Box3D(np.array([12.0, -3.0, -0.9]), np.array([4.2, 1.8, 1.5]), 0.4, label=CAR, instance=0, kind="Car"),
        Box3D(np.array([6.0, 4.0, -0.8]), np.array([0.8, 0.6, 1.8]), -2.9, label=PEDESTRIAN, instance=1,
              kind="Pedestrian"),
        Box3D(np.array([-8.0, 2.0, -0.9]), np.array([1.8, 0.6, 1.7]), 3.1, label=CYCLIST, instance=2, kind=""),
        Box3D(np.array([-15.0, -10.0, -0.5]), np.array([5.0, 2.0, 2.2]), -1.2, label=BACKGROUND, instance=3,
              kind="Van"),
    ]


def test_kitti_object_write_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(RNG_SEED)
    frames = [_labelled_frame("000000", _object_boxes(), rng), _labelled_frame("000001", _object_boxes()[:1], rng)]
    for frame in frames:
        kitti_object.write_kitti_object_frame(tmp_path, frame)
    assert count_frames(f"kitti_object:{tmp_path}") == 2
    read = list(open_dataset(f"kitti_object:{tmp_path}"))
    assert [f.name for f in read] == ["000000", "000001"]
    assert [f.stamp_ns for f in read] == [0, 100_000_000]
    for original, back in zip(frames, read, strict=True):
        np.testing.assert_array_equal(back.points, original.points)
        np.testing.assert_array_equal(back.labels, ignore_outside_front_view(original.points, original.labels))
        np.testing.assert_array_equal(back.instance, original.instance)
        assert len(back.boxes) == len(original.boxes)
        for a, b in zip(original.boxes, back.boxes, strict=True):
            np.testing.assert_allclose(b.center, a.center, atol=1e-9)
            np.testing.assert_allclose(b.size, a.size, atol=1e-12)
            assert _angle_diff(a.yaw, b.yaw) < 1e-9
            assert (b.label, b.instance) == (a.label, a.instance)
            assert b.kind == (a.kind or "Cyclist")
    counts = np.bincount(read[0].labels[read[0].labels != IGNORE], minlength=4)
    assert np.all(counts[1:3] > 50), counts  # car and pedestrian in front; the cyclist behind is not annotated
    assert counts[CYCLIST] == 0 and np.sum(read[0].labels == IGNORE) > 0


def test_kitti_object_writer_uses_class_name_when_kind_disagrees(tmp_path: Path) -> None:
    box = Box3D(np.array([10.0, 0, -1]), np.array([4.0, 1.8, 1.5]), 0.0, label=CAR, kind="sedan")
    kitti_object.write_kitti_object_frame(tmp_path, Frame("000000", _scan(10, np.random.default_rng(0)), boxes=[box]))
    line = (tmp_path / "label_2" / "000000.txt").read_text().split()
    assert line[0] == "Car"
    assert len(line) == 15
    # camera frame: h w l; bottom centre velodyne (10, 0, -1.75) -> camera (-y, -z, x); rotation_y
    assert [float(v) for v in line[8:11]] == [1.5, 1.8, 4.0]
    np.testing.assert_allclose([float(v) for v in line[11:14]], [0.0, 1.75, 10.0])
    assert abs(float(line[14]) + math.pi / 2) < 1e-12  # heading +x_velo = +z_cam -> rotation_y = -pi/2


def _write_permutation_calib(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("P0: 1 0 0 0 0 1 0 0 0 0 1 0\nR0_rect: 1 0 0 0 1 0 0 0 1\n"
                    "Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n")


@pytest.mark.parametrize(
    ("rotation_y", "inside", "outside"),
    [
        # ry = 0: length along camera +x = velodyne -y
        (0.0, [[10.0, -2.0 + 1.9, -1.0], [10.0, -2.0, -0.3], [10.0, -2.0, -1.65]],
         [[10.0 + 1.0, -2.0, -1.0], [10.0, -2.0, -1.75], [10.0, -2.0 - 2.1, -1.0]]),
        # ry = pi/2: length along camera -z = velodyne -x
        (math.pi / 2, [[10.0 + 1.9, -2.0, -1.0], [10.0 - 1.9, -2.0 + 0.85, -1.0]],
         [[10.0, -2.0 + 1.0, -1.0], [10.0 + 2.1, -2.0, -1.0]]),
        # ry = pi/4: heading camera (1, 0, -1)/sqrt2 = velodyne (-1, -1)/sqrt2, the x = y diagonal
        (math.pi / 4, [[10.0 + 1.3, -2.0 + 1.3, -1.0], [10.0 - 1.3, -2.0 - 1.3, -1.0]],
         [[10.0 + 1.3, -2.0 - 1.3, -1.0], [10.0 - 1.3, -2.0 + 1.3, -1.0]]),
    ],
)
def test_kitti_object_camera_box_geometry_by_hand(
    tmp_path: Path, rotation_y: float, inside: list, outside: list
) -> None:
    xyz = np.array(inside + outside, dtype=np.float32)
    points = np.hstack([xyz, np.zeros((len(xyz), 1), np.float32)])
    (tmp_path / "velodyne").mkdir()
    points.tofile(tmp_path / "velodyne" / "000007.bin")
    _write_permutation_calib(tmp_path / "calib" / "000007.txt")
    (tmp_path / "label_2").mkdir()
    # Car: h 1.5, w 1.8, l 4.0, bottom centre camera (2, 1.7, 10) = velodyne (10, -2, -1.7)
    (tmp_path / "label_2" / "000007.txt").write_text(
        f"Car 0.00 0 0.0 0 0 0 0 1.5 1.8 4.0 2.0 1.7 10.0 {rotation_y}\n"
        "DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10\n")
    (frame,) = kitti_object.read_kitti_object(tmp_path)
    assert frame.stamp_ns == 7 * 100_000_000
    assert frame.labels.tolist() == [CAR] * len(inside) + [BACKGROUND] * len(outside)
    (box,) = frame.boxes
    np.testing.assert_allclose(box.center, [10.0, -2.0, -0.95])
    np.testing.assert_allclose(box.size, [4.0, 1.8, 1.5])
    assert _angle_diff(box.yaw, -rotation_y - math.pi / 2) < 1e-12


def test_kitti_object_missing_labels_and_bad_input(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    (tmp_path / "velodyne").mkdir()
    _scan(50, rng).tofile(tmp_path / "velodyne" / "000000.bin")
    (frame,) = kitti_object.read_kitti_object(tmp_path)
    assert frame.labels is None and frame.boxes == []
    (tmp_path / "label_2").mkdir()
    (tmp_path / "label_2" / "000000.txt").write_text("Car 0 0 0 0 0 0 0 1.5 1.8 4 0 1.7 10 0\n")
    with pytest.raises(DatasetError, match=r"calib[/\\]000000.txt"):
        list(kitti_object.read_kitti_object(tmp_path))
    _write_permutation_calib(tmp_path / "calib" / "000000.txt")
    (tmp_path / "label_2" / "000000.txt").write_text("Car 0 0 0 0 0 0 0 1.5 1.8 4\n")
    with pytest.raises(DatasetError, match=r"000000.txt:1"):
        list(kitti_object.read_kitti_object(tmp_path))
    (tmp_path / "velodyne" / "000000.bin").write_bytes(b"\0" * 24)
    with pytest.raises(DatasetError, match=r"000000.bin"):
        list(kitti_object.read_kitti_object(tmp_path))
    with pytest.raises(DatasetError, match="nowhere"):
        kitti_object.read_kitti_object(tmp_path / "nowhere")
    with pytest.raises(DatasetError, match="velodyne"):
        kitti_object.read_kitti_object(tmp_path / "label_2")


@pytest.mark.parametrize(
    ("label", "calib", "problem"),
    [
        ("Car 0 0 0 0 0 0 0 1.5 1.8 4 0 1.7 10 inf", None, r"label_2[/\\]000000.txt:1: non-finite"),
        ("Car 0 0 0 0 0 0 0 nan 1.8 4 0 1.7 10 0", None, r"label_2[/\\]000000.txt:1: non-finite"),
        (None, "R0_rect: 0 0 0 0 0 0 0 0 0\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n",
         r"calib[/\\]000000.txt: .*singular"),
        (None, "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 nan\n",
         r"calib[/\\]000000.txt:2: non-finite"),
    ],
)
def test_kitti_object_non_finite_or_singular_input_names_the_file(tmp_path: Path, label: str | None,
                                                                  calib: str | None, problem: str) -> None:
    """A label with inf / NaN numbers or a calibration that cannot be inverted is a DatasetError naming the file,
    never a `math domain error` or LinAlgError traceback, nor boxes at NaN."""
    (tmp_path / "velodyne").mkdir()
    _scan(50, np.random.default_rng(1)).tofile(tmp_path / "velodyne" / "000000.bin")
    _write_permutation_calib(tmp_path / "calib" / "000000.txt")
    if calib is not None:
        (tmp_path / "calib" / "000000.txt").write_text(calib)
    (tmp_path / "label_2").mkdir()
    (tmp_path / "label_2" / "000000.txt").write_text((label or "Car 0 0 0 0 0 0 0 1.5 1.8 4 0 1.7 10 0") + "\n")
    with pytest.raises(DatasetError, match=problem):
        list(kitti_object.read_kitti_object(tmp_path))


def test_text_files_that_are_not_text_name_the_file(tmp_path: Path) -> None:
    """A corrupt (non-UTF-8) label, calibration, time or split file is a DatasetError naming it, never a
    UnicodeDecodeError escaping the tools as a traceback."""
    binary = b"Car 0 0 \xff\xfe garbage\n"
    (tmp_path / "velodyne").mkdir()
    _scan(50, np.random.default_rng(1)).tofile(tmp_path / "velodyne" / "000000.bin")
    (tmp_path / "label_2").mkdir()
    (tmp_path / "label_2" / "000000.txt").write_bytes(binary)
    _write_permutation_calib(tmp_path / "calib" / "000000.txt")
    with pytest.raises(DatasetError, match=r"label_2[/\\]000000.txt: cannot read label file \(not text"):
        list(kitti_object.read_kitti_object(tmp_path))
    (tmp_path / "label_2" / "000000.txt").write_text("Car 0 0 0 0 0 0 0 1.5 1.8 4 0 1.7 10 0\n")
    (tmp_path / "calib" / "000000.txt").write_bytes(binary)
    with pytest.raises(DatasetError, match=r"calib[/\\]000000.txt: cannot read calibration \(not text"):
        list(kitti_object.read_kitti_object(tmp_path))
    drive = _write_drive(tmp_path / "raw", with_tracklets=False)
    (drive / "velodyne_points" / "timestamps.txt").write_bytes(binary)
    with pytest.raises(DatasetError, match=r"timestamps.txt: cannot read time file \(not text"):
        kitti_raw.read_kitti_raw(drive)
    (tmp_path / "split.txt").write_bytes(binary)
    with pytest.raises(DatasetError, match=r"split.txt: cannot read split list \(not text"):
        squeezeseg.read_split_list(tmp_path / "split.txt")


# ---------------------------------------------------------------- KITTI raw

TRACKLETS_XML = """<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>
<!DOCTYPE boost_serialization>
<boost_serialization signature="serialization::archive" version="9">
<tracklets class_id="0" tracking_level="0" version="0">
  <count>3</count>
  <item_version>1</item_version>
  <item class_id="1" tracking_level="0" version="1">
    <objectType>Car</objectType>
    <h>1.5</h><w>1.8</w><l>4.0</l>
    <first_frame>0</first_frame>
    <poses class_id="2" tracking_level="0" version="0">
      <count>2</count>
      <item_version>2</item_version>
      <item class_id="3" tracking_level="0" version="2">
        <tx>10.0</tx><ty>0.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>0.0</rz>
        <state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation>
        <amt_occlusion>-1</amt_occlusion><amt_occlusion_kf>-1</amt_occlusion_kf>
        <amt_border_l>-1</amt_border_l><amt_border_r>-1</amt_border_r><amt_border_kf>-1</amt_border_kf>
      </item>
      <item>
        <tx>11.0</tx><ty>0.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>1.5707963267948966</rz>
        <state>1</state><occlusion>0</occlusion><occlusion_kf>0</occlusion_kf><truncation>0</truncation>
      </item>
    </poses>
    <finished>1</finished>
  </item>
  <item>
    <objectType>Van</objectType>
    <h>2.0</h><w>2.0</w><l>5.0</l>
    <first_frame>0</first_frame>
    <poses><count>1</count><item_version>2</item_version>
      <item><tx>-10.0</tx><ty>5.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>0.3</rz></item>
    </poses>
    <finished>1</finished>
  </item>
  <item>
    <objectType>Pedestrian</objectType>
    <h>1.8</h><w>0.6</w><l>0.8</l>
    <first_frame>1</first_frame>
    <poses><count>1</count><item_version>2</item_version>
      <item><tx>5.0</tx><ty>5.0</ty><tz>-1.7</tz><rx>0</rx><ry>0</ry><rz>0.0</rz></item>
    </poses>
    <finished>1</finished>
  </item>
</tracklets>
</boost_serialization>
"""

RAW_POINTS = np.array([
    [10.0, 0.0, -1.65, 0.1],   # car in frame 0 (tz is the bottom: -1.7 .. -0.2); frame 1: 1 m across
    [10.0, 0.0, -1.75, 0.2],   # below the car
    [11.95, 0.5, -1.0, 0.3],   # car in frame 0 (length along x), outside in frame 1 (length along y)
    [11.0, 1.9, -1.0, 0.4],    # outside in frame 0, car in frame 1
    [-10.0, 5.0, -1.0, 0.5],   # van: background
    [5.0, 5.0, -0.5, 0.6],     # pedestrian from frame 1 on
], dtype=np.float32)


def _write_drive(root: Path, with_tracklets: bool = True) -> Path:
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_sync"
    data = drive / "velodyne_points" / "data"
    data.mkdir(parents=True)
    for k in range(2):
        RAW_POINTS.tofile(data / f"{k:010d}.bin")
    (drive / "velodyne_points" / "timestamps.txt").write_text(
        "2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.064389446\n")
    if with_tracklets:
        (drive / "tracklet_labels.xml").write_text(TRACKLETS_XML)
    return drive


def test_kitti_raw_tracklets_labels_and_stamps(tmp_path: Path) -> None:
    drive = _write_drive(tmp_path)
    assert count_frames(f"kitti_raw:{drive}") == 2
    f0, f1 = open_dataset(f"kitti_raw:{drive}")
    assert (f0.name, f1.name) == ("2011_09_26_0001_0000000000", "2011_09_26_0001_0000000001")
    base = int(datetime(2011, 9, 26, 13, 2, 25, tzinfo=UTC).timestamp())
    assert f0.stamp_ns == base * 10**9 + 964389445
    assert f1.stamp_ns - f0.stamp_ns == 100_000_001
    np.testing.assert_array_equal(f0.points, RAW_POINTS)
    # point 4 (inside the van) lies behind the sensor, outside the annotated front view: its label is unknown
    assert f0.labels.tolist() == [CAR, 0, CAR, 0, IGNORE, 0]
    assert f1.labels.tolist() == [0, 0, 0, CAR, IGNORE, PEDESTRIAN]
    assert f1.instance.tolist() == [-1, -1, -1, 0, -1, 2]
    assert [(b.kind, b.label, b.instance) for b in f0.boxes] == [("Car", CAR, 0), ("Van", BACKGROUND, 1)]
    np.testing.assert_allclose(f0.boxes[0].center, [10.0, 0.0, -0.95])
    np.testing.assert_allclose(f0.boxes[0].size, [4.0, 1.8, 1.5])
    assert f1.boxes[0].yaw == pytest.approx(math.pi / 2)


def test_kitti_raw_without_tracklets_and_bad_input(tmp_path: Path) -> None:
    drive = _write_drive(tmp_path, with_tracklets=False)
    frames = list(kitti_raw.read_kitti_raw(drive))
    assert len(frames) == 2 and all(f.labels is None and f.boxes == [] for f in frames)
    (drive / "tracklet_labels.xml").write_text("<tracklets><item>")
    with pytest.raises(DatasetError, match=r"tracklet_labels\.xml"):
        kitti_raw.read_kitti_raw(drive)
    (drive / "tracklet_labels.xml").unlink()
    (drive / "velodyne_points" / "timestamps.txt").write_text("2011-09-26 13:02:25.9\nyesterday\n")
    with pytest.raises(DatasetError, match=r"timestamps.txt:2"):
        kitti_raw.read_kitti_raw(drive)
    with pytest.raises(DatasetError, match="drive_0002"):
        kitti_raw.read_kitti_raw(tmp_path / "2011_09_26_drive_0002_sync")


@pytest.mark.parametrize("value", ["inf", "nan", "1e400"])
@pytest.mark.parametrize("tag", ["first_frame", "h", "rz"])
def test_kitti_raw_non_finite_tracklet_number_names_the_file(tmp_path: Path, tag: str, value: str) -> None:
    """inf / NaN in a tracklet is a DatasetError naming the file and the element, never an OverflowError traceback
    (first_frame) nor a box at NaN (size, pose)."""
    drive = _write_drive(tmp_path)
    start = TRACKLETS_XML.index(f"<{tag}>")
    end = TRACKLETS_XML.index(f"</{tag}>", start)
    (drive / "tracklet_labels.xml").write_text(TRACKLETS_XML[:start] + f"<{tag}>{value}" + TRACKLETS_XML[end:])
    with pytest.raises(DatasetError, match=rf"tracklet_labels\.xml: <{tag}> is not a finite number"):
        list(kitti_raw.read_kitti_raw(drive))


def test_kitti_raw_timestamp_parse_is_exact() -> None:
    assert kitti_raw.parse_timestamp_ns("1970-01-01 00:00:01.000000001") == 1_000_000_001
    assert kitti_raw.parse_timestamp_ns("1970-01-01 00:00:00.5") == 500_000_000
    assert kitti_raw.parse_timestamp_ns("2011-09-26 13:02:25.964389445") % 10**9 == 964389445


# ---------------------------------------------------------------- SemanticKITTI


def test_semantickitti_class_mapping() -> None:
    semantic = np.array([10, 252, 30, 254, 31, 253, 11, 15, 32, 255, 40, 44, 48, 49, 60, 72, 50, 99, 0], np.uint32)
    raw = semantic | (np.arange(len(semantic), dtype=np.uint32) << 16)
    labels, ground, instance = semantickitti.decode_labels(raw)
    assert labels.tolist() == [CAR, CAR, PEDESTRIAN, PEDESTRIAN, CYCLIST, CYCLIST] + [BACKGROUND] * 13
    assert ground.tolist() == [False] * 10 + [True] * 6 + [False] * 3
    assert instance.tolist() == list(range(-1, len(semantic) - 1))


def test_semantickitti_write_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(RNG_SEED)
    seq = tmp_path / "sequences" / "08"
    frames = []
    for k in range(2):
        points = _scan(500, rng)
        labels = rng.integers(0, 4, len(points)).astype(np.uint8)
        ground = (labels == BACKGROUND) & (points[:, 2] < -1.5)
        instance = np.where(labels > 0, rng.integers(0, 40, len(points)), -1).astype(np.int32)
        frames.append(Frame(f"{k:06d}", points, labels=labels, ground=ground, instance=instance))
        semantickitti.write_semantickitti_frame(seq, frames[-1])
    raw = np.fromfile(seq / "labels" / "000000.label", dtype=np.uint32)
    np.testing.assert_array_equal(raw & 0xFFFF == 40, frames[0].ground)
    (seq / "times.txt").write_text("0.000000e+00\n1.036224e-01\n")
    back = list(open_dataset(f"semantickitti:{seq}"))
    assert [f.stamp_ns for f in back] == [0, 103_622_400]
    for original, read in zip(frames, back, strict=True):
        assert read.name == original.name
        np.testing.assert_array_equal(read.points, original.points)
        np.testing.assert_array_equal(read.labels, original.labels)
        np.testing.assert_array_equal(read.ground, original.ground)
        np.testing.assert_array_equal(read.instance, original.instance)


@pytest.mark.parametrize("value", ["inf", "-Infinity", "nan", "1e999999999"])
def test_semantickitti_non_finite_time_names_the_line(tmp_path: Path, value: str) -> None:
    """A times.txt entry that is no finite time is a DatasetError naming the file and line, never an OverflowError
    or decimal.Overflow traceback."""
    seq = tmp_path / "00"
    semantickitti.write_semantickitti_frame(seq, Frame("000000", _scan(20, np.random.default_rng(2))))
    (seq / "times.txt").write_text(f"{value}\n")
    with pytest.raises(DatasetError, match=rf"times.txt:1: not a finite time in seconds: '{value}'"):
        list(semantickitti.read_semantickitti(seq))


def test_semantickitti_missing_labels_and_bad_sizes(tmp_path: Path) -> None:
    seq = tmp_path / "00"
    semantickitti.write_semantickitti_frame(seq, Frame("000000", _scan(20, np.random.default_rng(2))))
    (frame,) = semantickitti.read_semantickitti(seq)
    assert frame.labels is None and frame.ground is None and frame.stamp_ns == 0
    (seq / "labels").mkdir()
    np.zeros(19, np.uint32).tofile(seq / "labels" / "000000.label")
    with pytest.raises(DatasetError, match=r"000000.label"):
        list(semantickitti.read_semantickitti(seq))
    with pytest.raises(DatasetError, match="velodyne"):
        semantickitti.read_semantickitti(tmp_path)


def test_semantickitti_reads_a_ring_side_file_of_either_kind(tmp_path: Path) -> None:
    """velodyne_ring/<name>.bin (uint16) or .npy (integers), where a conversion kept the driver's ring, arrive as
    Frame.ring; a scan without one has none; a side file of the wrong size or kind names itself (exit 2)."""
    seq = tmp_path / "00"
    rng = np.random.default_rng(4)
    for name in ("000000", "000001", "000002"):
        semantickitti.write_semantickitti_frame(seq, Frame(name, _scan(30, rng)))
    (seq / "velodyne_ring").mkdir()
    ring = (np.arange(30) % 16).astype(np.uint16)
    ring.tofile(seq / "velodyne_ring" / "000000.bin")
    np.save(seq / "velodyne_ring" / "000001.npy", ring.astype(np.int64)[::-1])
    frames = list(open_dataset(f"semantickitti:{seq}"))
    np.testing.assert_array_equal(frames[0].ring, ring)
    np.testing.assert_array_equal(frames[1].ring, ring[::-1])
    assert frames[0].ring.dtype == frames[1].ring.dtype == np.uint16 and frames[2].ring is None
    ring[:29].tofile(seq / "velodyne_ring" / "000000.bin")
    with pytest.raises(DatasetError, match=r"000000.bin: 58 bytes, expected 60"):
        list(semantickitti.read_semantickitti(seq))
    ring.tofile(seq / "velodyne_ring" / "000000.bin")
    for bad in (np.full(30, -1), np.zeros(30, np.float32), np.zeros(29, np.int64)):
        np.save(seq / "velodyne_ring" / "000001.npy", bad)
        with pytest.raises(DatasetError, match=r"000001.npy: .*expected 30 integer rings"):
            list(semantickitti.read_semantickitti(seq))
    (seq / "velodyne_ring" / "000001.npy").write_bytes(b"not numpy")
    with pytest.raises(DatasetError, match=r"000001.npy: not a readable"):
        list(semantickitti.read_semantickitti(seq))


# ---------------------------------------------------------------- SqueezeSeg


def _squeezeseg_image(rng: np.random.Generator) -> np.ndarray:
    """4 x 8 lidar_2d image laid out as SqueezeSeg's: top laser in row 0, vehicle's left (+y) in column 0."""
    rows, cols = 4, 8
    elevation = np.radians(np.linspace(2.0, -20.0, rows))[:, None]
    azimuth = np.radians(np.linspace(40.0, -40.0, cols))[None, :]
    rng_m = rng.uniform(5, 40, (rows, cols))
    image = np.zeros((rows, cols, 6), np.float32)
    image[..., 0] = rng_m * np.cos(elevation) * np.cos(azimuth)
    image[..., 1] = rng_m * np.cos(elevation) * np.sin(azimuth)
    image[..., 2] = rng_m * np.sin(elevation)
    image[..., 3] = rng.uniform(0, 1, (rows, cols))
    image[..., 4] = rng_m
    image[..., 5] = rng.integers(0, 4, (rows, cols))
    image[0, 3] = 0.0  # empty pixel
    image[2, 5, 4] = 0.0  # no range
    return image


def test_squeezeseg_order_ring_and_empty_pixels(tmp_path: Path) -> None:
    image = _squeezeseg_image(np.random.default_rng(RNG_SEED))
    np.save(tmp_path / "2011_09_26_0001_0000000010.npy", image)
    np.save(tmp_path / "2011_09_26_0001_0000000011.npy", image[:, ::-1])
    a, b = squeezeseg.read_squeezeseg(tmp_path)
    assert a.stamp_ns == 10 * 100_000_000
    assert len(a.points) == 4 * 8 - 2
    assert a.ring.dtype == np.uint16 and a.ring.tolist() == [0] * 7 + [1] * 8 + [2] * 7 + [3] * 8
    azimuth = np.arctan2(a.points[:, 1], a.points[:, 0])
    for ring in range(4):
        assert np.all(np.diff(azimuth[a.ring == ring]) > 0)
    # both column directions give the same scan: the reader follows the data
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.labels, b.labels)
    valid = image[..., 4] > 0
    valid[0, 3] = False
    assert sorted(a.points[:, 3].tolist()) == sorted(image[valid][:, 3].tolist())
    expected_counts = np.bincount(image[valid][:, 5].astype(int), minlength=4)
    assert np.bincount(a.labels, minlength=4).tolist() == expected_counts.tolist()


def test_squeezeseg_split_list_spec(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    lidar = tmp_path / "lidar_2d"
    lidar.mkdir()
    names = [f"2011_09_26_0001_{k:010d}" for k in range(3)]
    for name in names:
        np.save(lidar / f"{name}.npy", _squeezeseg_image(rng))
    split = tmp_path / "ImageSet" / "val.txt"
    split.parent.mkdir()
    split.write_text(f"{names[2]}\n\n{names[0]}.npy\n")
    assert squeezeseg.read_split_list(split) == [names[2], names[0]]
    spec = f"squeezeseg:{lidar}@{split}"
    assert count_frames(spec) == 2
    assert [f.name for f in open_dataset(spec)] == [names[2], names[0]]
    assert [f.name for f in open_dataset(f"squeezeseg:{lidar}")] == names
    split.write_text("2011_09_26_0001_0000000099\n")
    with pytest.raises(DatasetError, match=r"0000000099\.npy"):
        squeezeseg.read_squeezeseg(f"{lidar}@{split}")
    with pytest.raises(DatasetError, match=r"nope\.txt"):
        squeezeseg.read_squeezeseg(f"{lidar}@{tmp_path / 'nope.txt'}")


def test_squeezeseg_bad_file_names_it(tmp_path: Path) -> None:
    np.save(tmp_path / "bad.npy", np.zeros((64, 512, 5), np.float32))
    with pytest.raises(DatasetError, match=r"bad\.npy"):
        list(squeezeseg.read_squeezeseg(tmp_path))
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    with pytest.raises(DatasetError, match=r"bad\.npy"):
        list(squeezeseg.read_squeezeseg(tmp_path))
    image = _squeezeseg_image(np.random.default_rng(4))
    image[1, 1, 5] = 7
    np.save(tmp_path / "bad.npy", image)
    with pytest.raises(DatasetError, match=r"bad\.npy"):
        list(squeezeseg.read_squeezeseg(tmp_path))


@pytest.mark.parametrize(("spoil", "problem"), [
    (lambda image: image.__setitem__((1, 1, 5), np.nan), r"bad\.npy: label channel"),
    (lambda image: image.astype(np.complex64), r"bad\.npy: expected real numbers, got complex64"),
    (lambda image: image.astype(str), r"bad\.npy: expected real numbers, got <U"),
])
def test_squeezeseg_nan_label_or_non_real_image_names_the_file(tmp_path: Path, spoil: Callable,
                                                                problem: str) -> None:
    """A NaN label is refused like any label outside 0..3 (not read as background), and an image of complex numbers
    or text is a DatasetError naming the file, not a TypeError traceback."""
    image = _squeezeseg_image(np.random.default_rng(4))
    spoiled = spoil(image)
    np.save(tmp_path / "bad.npy", image if spoiled is None else spoiled)
    with pytest.raises(DatasetError, match=problem):
        list(squeezeseg.read_squeezeseg(tmp_path))


# ---------------------------------------------------------------- real KITTI frames


def _independent_object_counts(root: Path, name: str, points: np.ndarray) -> np.ndarray:
    """Class counts with the camera-frame test: points go into the rectified camera, boxes stay put."""
    calib = {}
    for line in (root / "calib" / f"{name}.txt").read_text().splitlines():
        if ":" in line:
            key, values = line.split(":", 1)
            calib[key] = np.array([float(v) for v in values.split()])
    homogeneous = np.column_stack([points[:, :3].astype(np.float64), np.ones(len(points))])
    cam = (calib["R0_rect"].reshape(3, 3) @ (calib["Tr_velo_to_cam"].reshape(3, 4) @ homogeneous.T)).T
    classes = {"Car": CAR, "Pedestrian": PEDESTRIAN, "Cyclist": CYCLIST}
    labels = np.zeros(len(points), np.uint8)
    for line in (root / "label_2" / f"{name}.txt").read_text().splitlines():
        f = line.split()
        if f[0] not in classes:
            continue
        h, w, length, x, y, z, ry = (float(v) for v in f[8:15])
        dx, dy, dz = cam[:, 0] - x, cam[:, 1] - y, cam[:, 2] - z
        along = dx * math.cos(ry) - dz * math.sin(ry)
        across = dx * math.sin(ry) + dz * math.cos(ry)
        inside = (np.abs(along) <= length / 2) & (np.abs(across) <= w / 2) & (dy <= 0) & (dy >= -h)
        labels[inside] = classes[f[0]]
    return np.bincount(labels, minlength=4)


def test_real_kitti_object_frames(kitti_dev: Path) -> None:
    root = kitti_dev / "object" / "training"
    frames = list(open_dataset(f"kitti_object:{root}"))
    assert [f.name for f in frames] == ["000000", "000001", "000002"]
    for frame in frames:
        raw = np.fromfile(root / "velodyne" / f"{frame.name}.bin", dtype=np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(frame.points, raw)
        counts = np.bincount(frame.labels[frame.labels != IGNORE], minlength=4)
        expected = _independent_object_counts(root, frame.name, raw)
        print(frame.name, "reader", counts.tolist(), "camera-frame check", expected.tolist())
        # Box3D has no roll/pitch: the calibration's ~0.5 degree tilt may move a few edge points
        assert np.all(np.abs(counts[1:] - expected[1:]) <= np.maximum(3, 0.03 * expected[1:])), (counts, expected)
    assert 340 <= np.bincount(frames[0].labels, minlength=4)[PEDESTRIAN] <= 410
    assert np.bincount(frames[1].labels, minlength=4)[[CAR, CYCLIST]].min() > 0
    assert np.bincount(frames[2].labels, minlength=4)[CAR] > 0


def test_real_semantickitti_frames(kitti_dev: Path) -> None:
    seq = kitti_dev / "semantickitti" / "sequences" / "00"
    frames = list(open_dataset(f"semantickitti:{seq}"))
    assert len(frames) == 3
    for frame in frames:
        raw_points = np.fromfile(seq / "velodyne" / f"{frame.name}.bin", dtype=np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(frame.points, raw_points)
        raw = np.fromfile(seq / "labels" / f"{frame.name}.label", dtype=np.uint32)
        semantic = raw & 0xFFFF
        counts = np.bincount(frame.labels, minlength=4)
        print(frame.name, "labels", counts.tolist(), "ground", int(frame.ground.sum()))
        assert counts[CAR] == np.isin(semantic, [10, 252]).sum() > 0
        assert counts[PEDESTRIAN] == np.isin(semantic, [30, 254]).sum()
        assert counts[CYCLIST] == np.isin(semantic, [31, 253]).sum()
        np.testing.assert_array_equal(frame.ground, np.isin(semantic, [40, 44, 48, 49, 60, 72]))
        np.testing.assert_array_equal(frame.instance >= 0, (raw >> 16) > 0)


def test_empty_bin_is_skipped_with_one_warning_in_every_kitti_reader(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A 0-byte velodyne file is no 0-point frame: each KITTI reader names it on stderr once and skips it."""
    rng = np.random.default_rng(3)
    seq, obj = tmp_path / "seq", tmp_path / "object"
    for k in range(3):
        frame = Frame(name=f"{k:06d}", points=_scan(50, rng), labels=np.zeros(50, np.uint8))
        semantickitti.write_semantickitti_frame(seq, frame)
        kitti_object.write_kitti_object_frame(obj, frame)
    drive = _write_drive(tmp_path / "raw")
    empties = {
        "semantickitti": (seq, seq / "velodyne" / "000001.bin", ["000000", "000002"]),
        "kitti_object": (obj, obj / "velodyne" / "000001.bin", ["000000", "000002"]),
        "kitti_raw": (drive, drive / "velodyne_points" / "data" / "0000000000.bin", ["2011_09_26_0001_0000000001"]),
    }
    for fmt, (root, empty, names) in empties.items():
        empty.write_bytes(b"")
        capsys.readouterr()
        frames = list(open_dataset(f"{fmt}:{root}"))
        assert [f.name for f in frames] == names, fmt
        assert all(len(f.points) > 0 for f in frames)
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 1 and str(empty) in lines[0] and "skipped" in lines[0], (fmt, lines)
        assert count_frames(f"{fmt}:{root}") == len(names), fmt
