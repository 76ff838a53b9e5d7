"""KITTI 3D object benchmark reader and writer (`kitti_object:DIR`, DIR holding velodyne/, label_2/, calib/).

Conventions:
- Boxes in label_2 are in the rectified camera frame (x right, y down, z forward): h w l, the bottom centre
  x y z, and rotation_y about camera y, with the length along object-x = (cos ry, 0, -sin ry). They are
  mapped into the velodyne frame through inv(R0_rect * Tr_velo_to_cam): centre at mid-height, size
  (l, w, h), yaw = the azimuth of the mapped heading. The slight roll/pitch of a real calibration is dropped
  (Box3D turns about z only), which moves a box edge by about a centimetre.
- Point labels follow SqueezeSeg: inside a Car / Pedestrian / Cyclist box -> that class, else background.
  Boxes of other types (Van, Truck, Tram, Person_sitting, Misc) are kept with label 0; DontCare is skipped.
  Points inside a Van or Truck box are marked in Frame.vehicle_other (kitti_io.OTHER_VEHICLE_KINDS).
- box.instance = the box's position in the frame's box list; foreground points carry it in `instance`.
- KITTI object frames carry no time: stamp = frame number (digits of the file name) x 100 ms.
- A frame without label_2/<name>.txt has labels None and no boxes; a label file needs its calib file.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.data.frame import Box3D, Frame
from pass3d_ros.data.kitti_io import (
    FRAME_PERIOD_NS,
    count_point_files,
    frame_index,
    ignore_outside_front_view,
    label_points_in_boxes,
    points_in_kinds,
    read_frame_bin,
    read_text,
    require_dir,
    sorted_files,
    write_bin,
)
from pass3d_ros.msgs.errors import DatasetError

KITTI_TYPE_TO_LABEL: dict[str, int] = {"Car": CAR, "Pedestrian": PEDESTRIAN, "Cyclist": CYCLIST}
LABEL_TO_KITTI_TYPE: dict[int, str] = {CAR: "Car", PEDESTRIAN: "Pedestrian", CYCLIST: "Cyclist", BACKGROUND: "Misc"}

# The axis permutation velodyne (x fwd, y left, z up) -> camera (x right, y down, z fwd), no offset.
VELO_TO_CAM_PERMUTATION = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
_CALIB_ALIASES = {"Tr_velo_cam": "Tr_velo_to_cam", "R_rect": "R0_rect"}


def parse_calib(path: Path) -> np.ndarray:
    """4 x 4 matrix R0_rect * Tr_velo_to_cam (velodyne -> rectified camera) from a KITTI calib file."""
    values: dict[str, np.ndarray] = {}
    text = read_text(path, "calibration")
    for number, line in enumerate(text.splitlines(), 1):
        key, sep, rest = line.partition(":")
        if not sep:
            continue
        try:
            entry = np.array(rest.split(), dtype=np.float64)
        except ValueError as exc:
            raise DatasetError(f"{path}:{number}: non-numeric calibration entry {key.strip()!r}") from exc
        if not np.isfinite(entry).all():
            raise DatasetError(f"{path}:{number}: non-finite calibration entry {key.strip()!r}")
        values[_CALIB_ALIASES.get(key.strip(), key.strip())] = entry
    for key, size in (("Tr_velo_to_cam", 12), ("R0_rect", 9)):
        if key not in values or values[key].size != size:
            raise DatasetError(f"{path}: calibration needs {key} with {size} numbers")
    tr = np.eye(4)
    tr[:3, :] = values["Tr_velo_to_cam"].reshape(3, 4)
    r0 = np.eye(4)
    r0[:3, :3] = values["R0_rect"].reshape(3, 3)
    velo_to_cam = r0 @ tr
    if np.linalg.matrix_rank(velo_to_cam) < 4:
        raise DatasetError(f"{path}: R0_rect * Tr_velo_to_cam is singular, so boxes cannot be mapped to the velodyne")
    return velo_to_cam


def camera_box_to_velo(dims_hwl: np.ndarray, bottom_xyz: np.ndarray, rotation_y: float,
                       velo_to_cam: np.ndarray) -> tuple[np.ndarray, float]:
    """Velodyne-frame (mid-height centre, yaw) of a camera-frame KITTI box."""
    h = dims_hwl[0]
    cam_to_velo = np.linalg.inv(velo_to_cam)
    centre_cam = np.array([bottom_xyz[0], bottom_xyz[1] - h / 2.0, bottom_xyz[2], 1.0])
    centre = (cam_to_velo @ centre_cam)[:3]
    heading = cam_to_velo[:3, :3] @ np.array([math.cos(rotation_y), 0.0, -math.sin(rotation_y)])
    return centre, math.atan2(heading[1], heading[0])


def velo_box_to_camera(box: Box3D, velo_to_cam: np.ndarray) -> tuple[np.ndarray, float]:
    """Camera-frame (bottom centre, rotation_y) of a velodyne-frame box: the inverse of camera_box_to_velo."""
    bottom = np.asarray(box.center, dtype=np.float64) - np.array([0.0, 0.0, box.size[2] / 2.0])
    location = (velo_to_cam @ np.append(bottom, 1.0))[:3]
    heading = velo_to_cam[:3, :3] @ np.array([math.cos(box.yaw), math.sin(box.yaw), 0.0])
    return location, math.atan2(-heading[2], heading[0])


def read_label_file(path: Path, velo_to_cam: np.ndarray) -> list[Box3D]:
    """Velodyne-frame boxes of one label_2 file (DontCare skipped)."""
    text = read_text(path, "label file")
    boxes: list[Box3D] = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        if not fields or fields[0] == "DontCare":
            continue
        if len(fields) < 15:
            raise DatasetError(f"{path}:{number}: expected 15 fields (type ... rotation_y), got {len(fields)}")
        try:
            numbers = np.array(fields[8:15], dtype=np.float64)
        except ValueError as exc:
            raise DatasetError(f"{path}:{number}: non-numeric box dimensions / location / rotation") from exc
        if not np.isfinite(numbers).all():
            raise DatasetError(f"{path}:{number}: non-finite box dimensions / location / rotation")
        dims, location, rotation_y = numbers[0:3], numbers[3:6], float(numbers[6])
        centre, yaw = camera_box_to_velo(dims, location, rotation_y, velo_to_cam)
        kind = fields[0]
        boxes.append(Box3D(center=centre, size=np.array([dims[2], dims[1], dims[0]]), yaw=yaw,
                           label=KITTI_TYPE_TO_LABEL.get(kind, BACKGROUND), instance=len(boxes), kind=kind))
    return boxes


def _frames(root: Path, bins: list[Path]) -> Iterator[Frame]:
    for position, bin_path in enumerate(bins):
        name = bin_path.stem
        points = read_frame_bin(bin_path)
        if points is None:
            continue
        stamp = frame_index(name, position) * FRAME_PERIOD_NS
        label_path = root / "label_2" / f"{name}.txt"
        if not label_path.is_file():
            yield Frame(name=name, points=points, stamp_ns=stamp)
            continue
        calib_path = root / "calib" / f"{name}.txt"
        if not calib_path.is_file():
            raise DatasetError(f"{calib_path}: calibration missing for label file {label_path.name}")
        boxes = read_label_file(label_path, parse_calib(calib_path))
        labels, instance = label_points_in_boxes(points[:, :3], boxes)
        labels = ignore_outside_front_view(points, labels)
        yield Frame(name=name, points=points, stamp_ns=stamp, labels=labels, instance=instance, boxes=boxes,
                    vehicle_other=points_in_kinds(points[:, :3], boxes))


def read_kitti_object(path: str | Path) -> Iterator[Frame]:
    """Frames of a KITTI object split folder (e.g. object/training), in natural file order."""
    root = require_dir(Path(path), "KITTI object")
    bins = sorted_files(root / "velodyne", ".bin")
    return _frames(root, bins)


def count_frames(path: str | Path) -> int | None:
    """Number of velodyne scans, or None when the folder is missing."""
    velodyne = Path(path) / "velodyne"
    return count_point_files(velodyne) if velodyne.is_dir() else None


def _kitti_type(box: Box3D) -> str:
    """The type written for a box: its kind when that reads back as its label, else the label's KITTI name."""
    kind = box.kind.strip()
    single_token = bool(kind) and len(kind.split()) == 1 and kind != "DontCare"
    if single_token and KITTI_TYPE_TO_LABEL.get(kind, BACKGROUND) == box.label:
        return kind
    return LABEL_TO_KITTI_TYPE.get(box.label, "Misc")


def _calib_text() -> str:
    """An identity-like calibration: camera axes permuted from velodyne's, no offset, a plausible stereo rig."""
    k = np.array([[721.5377, 0.0, 609.5593], [0.0, 721.5377, 172.854], [0.0, 0.0, 1.0]])
    lines = []
    for index, baseline_x in enumerate((0.0, -0.5372, 0.0599, -0.4731)):
        p = k @ np.hstack([np.eye(3), [[baseline_x], [0.0], [0.0]]])
        lines.append(f"P{index}: " + " ".join(f"{v:.12e}" for v in p.ravel()))
    lines.append("R0_rect: " + " ".join(f"{v:.12e}" for v in np.eye(3).ravel()))
    lines.append("Tr_velo_to_cam: " + " ".join(f"{v:.12e}" for v in VELO_TO_CAM_PERMUTATION.ravel()))
    lines.append("Tr_imu_to_velo: " + " ".join(f"{v:.12e}" for v in np.eye(3, 4).ravel()))
    return "\n".join(lines) + "\n"


def write_kitti_object_frame(root: Path, frame: Frame) -> None:
    """Write velodyne/, label_2/ and calib/ files for one frame, so read_kitti_object gives its boxes back.

    Read back, box.instance is the box's position in frame.boxes, and a frame without boxes is all background.
    """
    root = Path(root)
    write_bin(root / "velodyne" / f"{frame.name}.bin", frame.points)
    velo_to_cam = np.eye(4)
    velo_to_cam[:3, :] = VELO_TO_CAM_PERMUTATION
    lines = []
    for box in frame.boxes:
        location, rotation_y = velo_box_to_camera(box, velo_to_cam)
        alpha = math.remainder(rotation_y - math.atan2(location[0], location[2]), 2.0 * math.pi)
        length, width, height = box.size
        numbers = " ".join(repr(float(v)) for v in (height, width, length, *location, rotation_y))
        lines.append(f"{_kitti_type(box)} 0.00 0 {float(alpha)!r} 0.00 0.00 0.00 0.00 {numbers}")
    (root / "label_2").mkdir(parents=True, exist_ok=True)
    (root / "label_2" / f"{frame.name}.txt").write_text("".join(f"{line}\n" for line in lines))
    (root / "calib").mkdir(parents=True, exist_ok=True)
    (root / "calib" / f"{frame.name}.txt").write_text(_calib_text())
