"""Evaluation that sees small effects (issue 37): objects found by range bin, and car scored strictly beside car with
the points of vans / trucks / buses left out (Frame.vehicle_other, as the KITTI and SemanticKITTI readers mark them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.classes import BACKGROUND, CAR, IGNORE, PEDESTRIAN
from pass3d_ros.core.metrics import (
    OBJECT_RANGE_EDGES_M,
    ObjectRecall,
    SegmentationMetrics,
    format_objects,
    ignore_vehicles,
    range_bin_names,
)
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage2.segmentation import SegmentResult
from pass3d_ros.data import semantickitti
from pass3d_ros.data.frame import Box3D, Frame, crop_frame
from pass3d_ros.data.kitti_io import write_bin
from pass3d_ros.data.kitti_object import write_kitti_object_frame
from pass3d_ros.data.spec import resolve_dataset
from pass3d_ros.evaluation.offline import evaluate_full, iter_frames
from pass3d_ros.evaluation.report import CAR_VEHICLES_IGNORED, format_full

BINS = ["0-15", "15-30", "30-50", "50+"]


def blob(x: float, y: float, n: int = 12, z: float = 0.0) -> np.ndarray:
    """n points whose horizontal centroid is exactly (x, y): pairs mirrored about it in x."""
    offsets = np.tile([-0.5, 0.5], n // 2)
    return np.column_stack([x + offsets, np.full(n, y), np.full(n, z)])


def test_range_bins_are_one_constant_with_names() -> None:
    assert OBJECT_RANGE_EDGES_M == (15.0, 30.0, 50.0)
    assert range_bin_names() == BINS
    assert range_bin_names((10.0, 25.5)) == ["0-10", "10-25.5", "25.5+"]
    with pytest.raises(ValueError, match="increasing"):
        ObjectRecall(edges=(30.0, 15.0))


def test_objects_are_binned_by_the_horizontal_range_of_their_centroid() -> None:
    # cars: 12 m ahead but 10 m up (3D range 15.6, horizontal 12: bin 0-15), exactly 15 m (bin 15-30, missed),
    # 40 m to the side (30-50), 60 m behind (50+, missed), and a 5-point car at 5 m (too small: no object);
    # pedestrian at 20 m (15-30, found)
    parts = [(CAR, blob(12.0, 0.0, z=10.0), True), (CAR, blob(15.0, 0.0), False), (CAR, blob(0.0, 40.0), True),
             (CAR, blob(-60.0, 0.0), False), (CAR, blob(5.0, 0.0, n=6)[:5], True), (PEDESTRIAN, blob(0.0, -20.0), True)]
    xyz = np.concatenate([p for _, p, _ in parts])
    truth = np.concatenate([np.full(len(p), c) for c, p, _ in parts])
    instance = np.concatenate([np.full(len(p), k) for k, (_, p, _) in enumerate(parts)])
    predicted = np.concatenate([np.full(len(p), c if hit else BACKGROUND) for c, p, hit in parts])
    objects = ObjectRecall()
    objects.update(truth, predicted, instance, xyz)
    objects.update(truth, predicted, instance, xyz)  # a second identical frame: counts double
    summary = objects.summary()
    by_range = summary["by_range"]
    assert by_range["bins"] == BINS and by_range["edges_m"] == [15.0, 30.0, 50.0] and by_range["frames"] == 2
    cars = by_range["classes"]["car"]
    assert [(cars[b]["found"], cars[b]["objects"]) for b in BINS] == [(2, 2), (0, 2), (2, 2), (0, 2)]
    assert cars["0-15"]["recall"] == 1.0 and cars["15-30"]["recall"] == 0.0
    assert cars["0-15"]["interval"]["frames"] == 2
    peds = by_range["classes"]["pedestrian"]
    assert [(peds[b]["found"], peds[b]["objects"]) for b in BINS] == [(0, 0), (2, 2), (0, 0), (0, 0)]
    assert peds["0-15"]["recall"] is None
    for name, row in summary["classes"].items():  # the bins split the overall count exactly
        assert sum(by_range["classes"][name][b]["objects"] for b in BINS) == row["objects"]
        assert sum(by_range["classes"][name][b]["found"] for b in BINS) == row["found"]
    lines = format_objects(summary)
    assert lines[0].startswith("objects found") and "car 4 of 8" in lines[0]
    assert "objects found by range" in lines[1] and all(f"{b} m" in lines[2] for b in BINS)
    car_line = next(line for line in lines if line.strip().startswith("car"))
    assert car_line.split()[1:] == ["2", "/", "2", "100%", "0", "/", "2", "0%", "2", "/", "2", "100%",
                                    "0", "/", "2", "0%"]
    assert "-" in next(line for line in lines if line.strip().startswith("cyclist"))


def test_objects_without_points_have_no_range_table() -> None:
    objects = ObjectRecall()
    objects.update(np.full(12, CAR), np.full(12, CAR), np.zeros(12, int))
    summary = objects.summary()
    assert summary["classes"]["car"]["found"] == 1 and summary["by_range"] is None
    assert len(format_objects(summary)) == 1
    with pytest.raises(ValueError, match="points"):
        objects.update(np.full(12, CAR), np.full(12, CAR), np.zeros(12, int), np.zeros((11, 3)))


def test_van_points_called_car_change_the_ignored_score_not_the_strict_one() -> None:
    # 10 car points called car; a van (5 background points) called car; 5 other background points called background
    truth = np.array([CAR] * 10 + [BACKGROUND] * 10, dtype=np.uint8)
    predicted = np.array([CAR] * 15 + [BACKGROUND] * 5, dtype=np.uint8)
    van = np.zeros(20, dtype=bool)
    van[10:15] = True
    van[0] = True  # a car point inside the van box too: stays car
    with_van, without = SegmentationMetrics(), SegmentationMetrics()
    with_van.update("a", truth, predicted, vehicle_other=van)
    without.update("a", truth, predicted)
    a, b = with_van.summary(), without.summary()
    assert a["classes"] == b["classes"] and a["classes"]["car"]["iou"] == pytest.approx(10 / 15)  # strict: unchanged
    relaxed = a["car_vehicles_ignored"]
    assert relaxed["iou"] == 1.0 and relaxed["precision"] == 1.0 and relaxed["points"] == 10
    assert relaxed["ignored_points"] == 5 and relaxed["frames_known"] == 1 and relaxed["frames_with_vehicles"] == 1
    same = b["car_vehicles_ignored"]  # no vehicles known: identical to strict
    assert {k: same[k] for k in ("precision", "recall", "iou", "points", "interval")} == b["classes"]["car"]
    assert same["ignored_points"] == 0 and same["frames_known"] == same["frames_with_vehicles"] == 0


def test_ignore_vehicles_leaves_labelled_and_unknown_points() -> None:
    truth = np.array([BACKGROUND, CAR, IGNORE, BACKGROUND], dtype=np.uint8)
    mask = np.array([True, True, True, False])
    assert ignore_vehicles(truth, mask).tolist() == [IGNORE, CAR, IGNORE, BACKGROUND]
    assert truth[0] == BACKGROUND, "a copy"
    assert ignore_vehicles(truth, None) is truth and ignore_vehicles(truth, np.zeros(4, bool)) is truth
    with pytest.raises(ValueError, match="shape"):
        ignore_vehicles(truth, mask[:3])


def test_semantickitti_marks_trucks_buses_and_other_vehicles(tmp_path: Path) -> None:
    semantic = np.array([10, 13, 18, 20, 252, 257, 258, 259, 40, 99, 16], dtype=np.uint32)
    raw = semantic | (np.arange(len(semantic), dtype=np.uint32) << 16)
    expected = [False, True, True, True, False, True, True, True, False, False, False]
    assert semantickitti.decode_vehicle_other(raw).tolist() == expected
    seq = tmp_path / "00"
    points = np.zeros((len(raw), 4), np.float32)
    points[:, 0] = np.arange(len(raw)) + 1.0
    write_bin(seq / "velodyne" / "000000.bin", points)
    (seq / "labels").mkdir()
    raw.astype("<u4").tofile(seq / "labels" / "000000.label")
    (frame,) = semantickitti.read_semantickitti(seq)
    assert frame.vehicle_other.tolist() == expected
    assert frame.labels[~frame.vehicle_other].tolist() == [CAR, CAR, BACKGROUND, BACKGROUND, BACKGROUND]
    cropped = crop_frame(frame, frame.points[:, 0] > 3.0)
    assert cropped.vehicle_other.tolist() == expected[3:]


def test_kitti_object_marks_van_and_truck_boxes(tmp_path: Path) -> None:
    points = np.zeros((6, 4), np.float32)
    points[:, :3] = [[10, 0, 0], [20, 0, 0], [30, 0, 0], [40, 0, 0], [10, 0.5, 0], [50, 0, 0]]
    boxes = [Box3D(np.array([10.0, 0, 0]), np.array([2.0, 0.5, 1.0]), 0.0, CAR, 0, "Car"),
             Box3D(np.array([10.0, 0, 0]), np.array([5.0, 2.0, 2.0]), 0.0, BACKGROUND, 1, "Van"),
             Box3D(np.array([20.0, 0, 0]), np.array([5.0, 2.0, 2.0]), 0.0, BACKGROUND, 2, "Truck"),
             Box3D(np.array([30.0, 0, 0]), np.array([5.0, 2.0, 2.0]), 0.0, BACKGROUND, 3, "Tram"),
             Box3D(np.array([40.0, 0, 0]), np.array([1.0, 1.0, 2.0]), 0.0, BACKGROUND, 4, "Misc")]
    write_kitti_object_frame(tmp_path, Frame("000000", points, boxes=boxes))
    (frame,) = resolve_dataset(f"kitti_object:{tmp_path}").frames()
    assert [b.kind for b in frame.boxes] == ["Car", "Van", "Truck", "Tram", "Misc"]
    assert frame.vehicle_other.tolist() == [True, True, False, False, True, False]
    assert frame.labels.tolist() == [CAR, BACKGROUND, BACKGROUND, BACKGROUND, BACKGROUND, BACKGROUND]
    assert ignore_vehicles(frame.labels, frame.vehicle_other).tolist() == [CAR, IGNORE, BACKGROUND, BACKGROUND,
                                                                           IGNORE, BACKGROUND]


class AllCar:
    """A stage-2 stand-in that calls every point car: the score then follows from the labels alone."""

    kind = "all_car"
    max_proposals = 1000

    def warm_up(self) -> None:
        """Nothing to warm."""

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        """Every point car."""
        n = len(points)
        return SegmentResult(np.full(n, CAR, np.uint8), np.ones(n, np.float32), np.full(len(members), CAR, np.int16))


def test_full_evaluation_reports_both_car_scores_and_the_range_table(frame: Frame, tmp_path: Path) -> None:
    """A synthetic scan written as KITTI object data with a Van box over background points ahead: everything called
    car, so strict car IoU = car / scored points and the ignored one = car / (scored - van background points)."""
    ahead = (frame.labels == BACKGROUND) & (frame.points[:, 0] > 8.0) & (np.abs(frame.points[:, 1]) < 4.0)
    centre = frame.points[np.flatnonzero(ahead)[0], :3].astype(np.float64)
    van = Box3D(centre, np.array([5.0, 2.0, 2.5]), 0.0, BACKGROUND, len(frame.boxes), "Van")
    write_kitti_object_frame(tmp_path, Frame("000000", frame.points, boxes=[*frame.boxes, van]))
    spec = f"kitti_object:{tmp_path}"
    (read,) = resolve_dataset(spec).frames()
    scored = read.labels != IGNORE
    cars = int(np.count_nonzero(read.labels == CAR))
    dropped = int(np.count_nonzero(read.vehicle_other & (read.labels == BACKGROUND) & scored))
    assert cars > 500 and dropped > 0
    summary = evaluate_full(iter_frames([spec], None, False), Stage1Config(), AllCar(), intensity_match=False)
    strict, relaxed = summary["classes"]["car"], summary["car_vehicles_ignored"]
    assert strict["iou"] == pytest.approx(cars / np.count_nonzero(scored))
    assert relaxed["iou"] == pytest.approx(cars / (np.count_nonzero(scored) - dropped))
    assert relaxed["iou"] > strict["iou"]
    assert relaxed["ignored_points"] == dropped and relaxed["frames_known"] == 1 and relaxed["points"] == cars
    by_range = summary["objects"]["by_range"]
    assert by_range["bins"] == BINS
    assert sum(row["objects"] for row in by_range["classes"]["car"].values()) == summary["objects"]["classes"]["car"][
        "objects"] > 0
    text = format_full({**summary, "classifier": {"kind": "size_rules", "device": "cpu", "threads": 1}})
    lines = text.splitlines()
    row = next(k for k, line in enumerate(lines) if line.startswith(CAR_VEHICLES_IGNORED))
    assert lines[row - 1].startswith("car ") and f"{100 * relaxed['iou']:.1f}" in lines[row]
    assert f"{dropped} background points on vans / trucks / buses left out, in 1 frame(s)" in text
    assert "objects found by range" in text
