"""KITTI raw drive reader (`kitti_raw:DRIVE_DIR`, e.g. .../2011_09_26/2011_09_26_drive_0001_sync).

Layout: velodyne_points/data/<NNNNNNNNNN>.bin, velodyne_points/timestamps.txt, tracklet_labels.xml.
Conventions:
- Tracklets are in the velodyne frame (devkit convention): pose (tx, ty, tz) is the box's bottom centre,
  rz its yaw, l along the heading. Box3D centre = (tx, ty, tz + h/2), size (l, w, h); rx, ry are ignored.
  Pose k of a tracklet belongs to frame first_frame + k; frame k is velodyne_points/data/<k>.bin.
- Labels follow SqueezeSeg: points in a Car / Pedestrian / Cyclist box take that class, all else (Van,
  Truck, Tram, Person (sitting), Misc, no box) background. box.instance = the tracklet's index in the file,
  stable across frames; foreground points carry it in `instance`. No tracklet file -> labels None.
  Points inside a Van or Truck box are marked in Frame.vehicle_other (kitti_io.OTHER_VEHICLE_KINDS).
- Stamps: timestamps.txt ("2011-09-26 13:02:25.964389445", read as UTC) to integer ns exactly; without
  the file, frame number x 100 ms.
- Frame name: SqueezeSeg's `2011_09_26_0001_0000000000` when the folder is named like a KITTI drive,
  so names match SqueezeSeg's lidar_2d files and ImageSet lists; else the file stem.
"""

from __future__ import annotations

import calendar
import math
import re
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.data.frame import Box3D, Frame
from pass3d_ros.data.kitti_io import (
    count_point_files,
    frame_index,
    frame_stamp,
    ignore_outside_front_view,
    label_points_in_boxes,
    points_in_kinds,
    read_frame_bin,
    read_stamp_lines,
    require_dir,
    sorted_files,
)
from pass3d_ros.msgs.errors import DatasetError

TRACKLET_TYPE_TO_LABEL: dict[str, int] = {"Car": CAR, "Pedestrian": PEDESTRIAN, "Cyclist": CYCLIST}
_DRIVE_NAME = re.compile(r"^(\d{4}_\d{2}_\d{2})_drive_(\d{4})")
_STAMP = re.compile(r"^(\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2})(?:\.(\d+))?$")


def parse_timestamp_ns(text: str) -> int:
    """Nanoseconds since the epoch of a KITTI stamp `YYYY-MM-DD HH:MM:SS.fffffffff`, exact (no float)."""
    match = _STAMP.match(text.strip())
    if not match:
        raise ValueError(f"not a KITTI timestamp: {text.strip()!r}")
    seconds = calendar.timegm(time.strptime(match.group(1), "%Y-%m-%d %H:%M:%S"))
    fraction = (match.group(2) or "")[:9].ljust(9, "0")
    return seconds * 1_000_000_000 + int(fraction)


def read_timestamps(path: Path) -> list[int]:
    """All stamps of a timestamps.txt, in ns; DatasetError naming the file and line on a bad entry."""
    return read_stamp_lines(path, parse_timestamp_ns)


def _child_float(node: ET.Element, tag: str, path: Path) -> float:
    child = node.find(tag)
    if child is None or child.text is None:
        raise DatasetError(f"{path}: tracklet entry lacks <{tag}>")
    try:
        value = float(child.text)
    except ValueError as exc:
        raise DatasetError(f"{path}: <{tag}> is not a number: {child.text.strip()!r}") from exc
    if not math.isfinite(value):
        raise DatasetError(f"{path}: <{tag}> is not a finite number: {child.text.strip()!r}")
    return value


def read_tracklets(path: Path) -> dict[int, list[Box3D]]:
    """Boxes per frame number from a KITTI tracklet_labels.xml (velodyne frame, mid-height centres)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise DatasetError(f"{path}: cannot parse tracklet XML ({exc})") from exc
    tracklets = root if root.tag == "tracklets" else root.find("tracklets")
    if tracklets is None:
        raise DatasetError(f"{path}: no <tracklets> element")
    per_frame: dict[int, list[Box3D]] = defaultdict(list)
    for index, item in enumerate(tracklets.findall("item")):
        kind = (item.findtext("objectType") or "").strip()
        height, width, length = (_child_float(item, tag, path) for tag in ("h", "w", "l"))
        first_frame = int(_child_float(item, "first_frame", path))
        poses = item.find("poses")
        for k, pose in enumerate(poses.findall("item") if poses is not None else []):
            tx, ty, tz, rz = (_child_float(pose, tag, path) for tag in ("tx", "ty", "tz", "rz"))
            per_frame[first_frame + k].append(Box3D(
                center=np.array([tx, ty, tz + height / 2.0]), size=np.array([length, width, height]), yaw=rz,
                label=TRACKLET_TYPE_TO_LABEL.get(kind, BACKGROUND), instance=index, kind=kind))
    return dict(per_frame)


def _frame_name(drive: Path, stem: str) -> str:
    match = _DRIVE_NAME.match(drive.name)
    return f"{match.group(1)}_{match.group(2)}_{stem}" if match else stem


def _frames(drive: Path, bins: list[Path], stamps: list[int] | None,
            boxes: dict[int, list[Box3D]] | None) -> Iterator[Frame]:
    for position, bin_path in enumerate(bins):
        index = frame_index(bin_path.stem, position)
        stamp = frame_stamp(stamps, index, drive / "velodyne_points" / "timestamps.txt")
        points = read_frame_bin(bin_path)
        if points is None:
            continue
        name = _frame_name(drive, bin_path.stem)
        if boxes is None:
            yield Frame(name=name, points=points, stamp_ns=stamp)
            continue
        frame_boxes = boxes.get(index, [])
        labels, instance = label_points_in_boxes(points[:, :3], frame_boxes)
        labels = ignore_outside_front_view(points, labels)
        yield Frame(name=name, points=points, stamp_ns=stamp, labels=labels, instance=instance,
                    boxes=list(frame_boxes), vehicle_other=points_in_kinds(points[:, :3], frame_boxes))


def read_kitti_raw(path: str | Path) -> Iterator[Frame]:
    """Frames of one KITTI raw drive, with tracklet labels when tracklet_labels.xml is there."""
    drive = require_dir(Path(path), "KITTI raw drive")
    bins = sorted_files(drive / "velodyne_points" / "data", ".bin")
    stamp_path = drive / "velodyne_points" / "timestamps.txt"
    stamps = read_timestamps(stamp_path) if stamp_path.is_file() else None
    tracklet_path = drive / "tracklet_labels.xml"
    boxes = read_tracklets(tracklet_path) if tracklet_path.is_file() else None
    return _frames(drive, bins, stamps, boxes)


def count_frames(path: str | Path) -> int | None:
    """Number of velodyne scans of the drive, or None when the folder is missing."""
    data = Path(path) / "velodyne_points" / "data"
    return count_point_files(data) if data.is_dir() else None
