"""SemanticKITTI sequence reader and writer (`semantickitti:SEQ_DIR`, e.g. .../sequences/00).

Layout: velodyne/<NNNNNN>.bin, labels/<NNNNNN>.label (uint32: semantic = v & 0xFFFF, instance = v >> 16),
times.txt (seconds per frame). Conventions:
- Classes: car = 10 car + 252 moving-car; pedestrian = 30 person + 254 moving-person; cyclist = 31 bicyclist
  + 253 moving-bicyclist (the rider). 11 bicycle, 15 motorcycle, 32 motorcyclist and 255 moving-motorcyclist
  are background: the PASS3D / SqueezeSeg classes have no motorcyclist, and SemanticKITTI labels a ridden
  bicycle 11 apart from its rider, so its cyclist points are fewer than a KITTI box would give.
- Non-car vehicles (Frame.vehicle_other): 13 bus, 18 truck, 20 other-vehicle and their moving 257, 258, 259;
  background like every other class outside the three.
- Ground mask: 40 road, 44 parking, 48 sidewalk, 49 other-ground, 60 lane-marking, 72 terrain.
- Instance: Frame.instance = (v >> 16) - 1, so SemanticKITTI's 0 (no instance) becomes -1; the writer
  stores instance + 1. Labels None when labels/ is missing (or that frame's .label file is).
- Stamps: times.txt seconds converted exactly through decimal; without it, frame number x 100 ms.
- Ring field: velodyne_ring/<NNNNNN>.bin (uint16 a point) or .npy (integers), where a conversion kept the
  driver's ring (this project's other_sensors and unlabelled_sensors do); read as Frame.ring, any numbering.
- Writer: car 10, pedestrian 30, cyclist 31, ground background 40 (road), other background 99
  (other-object); times.txt is not written, so read-back stamps are frame number x 100 ms.
"""

from __future__ import annotations

from collections.abc import Iterator
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.kitti_io import (
    count_point_files,
    frame_index,
    frame_stamp,
    read_frame_bin,
    read_stamp_lines,
    require_dir,
    sorted_files,
    write_bin,
)
from pass3d_ros.msgs.errors import DatasetError

SEMANTIC_TO_LABEL: dict[int, int] = {10: CAR, 252: CAR, 30: PEDESTRIAN, 254: PEDESTRIAN, 31: CYCLIST, 253: CYCLIST}
GROUND_CLASSES: tuple[int, ...] = (40, 44, 48, 49, 60, 72)
OTHER_VEHICLE_CLASSES: tuple[int, ...] = (13, 18, 20, 257, 258, 259)  # bus, truck, other-vehicle, and moving
LABEL_TO_SEMANTIC: dict[int, int] = {BACKGROUND: 99, CAR: 10, PEDESTRIAN: 30, CYCLIST: 31}
GROUND_SEMANTIC = 40

_LABEL_LUT = np.zeros(1 << 16, dtype=np.uint8)
_LABEL_LUT[list(SEMANTIC_TO_LABEL)] = list(SEMANTIC_TO_LABEL.values())
_GROUND_LUT = np.zeros(1 << 16, dtype=bool)
_GROUND_LUT[list(GROUND_CLASSES)] = True
_OTHER_VEHICLE_LUT = np.zeros(1 << 16, dtype=bool)
_OTHER_VEHICLE_LUT[list(OTHER_VEHICLE_CLASSES)] = True
_SEMANTIC_OF_LABEL = np.array([LABEL_TO_SEMANTIC[k] for k in sorted(LABEL_TO_SEMANTIC)], dtype=np.uint32)


def decode_labels(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(labels uint8 0..3, ground bool, instance int32 with -1 = none) from raw SemanticKITTI uint32 values."""
    raw = np.asarray(raw, dtype=np.uint32)
    semantic = raw & 0xFFFF
    instance = (raw >> 16).astype(np.int32) - 1
    return _LABEL_LUT[semantic], _GROUND_LUT[semantic], instance


def decode_vehicle_other(raw: np.ndarray) -> np.ndarray:
    """Mask of the points whose raw SemanticKITTI class is a bus, truck or other vehicle (moving or not)."""
    return _OTHER_VEHICLE_LUT[np.asarray(raw, dtype=np.uint32) & 0xFFFF]


def encode_labels(labels: np.ndarray, ground: np.ndarray | None, instance: np.ndarray | None) -> np.ndarray:
    """Raw SemanticKITTI uint32 values for project labels (see the module notes for the mapping)."""
    labels = np.asarray(labels, dtype=np.intp)
    if labels.size and (labels.min() < 0 or labels.max() >= len(_SEMANTIC_OF_LABEL)):
        raise ValueError(f"labels must lie in 0..{len(_SEMANTIC_OF_LABEL) - 1}")
    semantic = _SEMANTIC_OF_LABEL[labels]
    if ground is not None:
        semantic[np.asarray(ground, dtype=bool) & (labels == BACKGROUND)] = GROUND_SEMANTIC
    if instance is None:
        return semantic
    upper = np.asarray(instance, dtype=np.int64) + 1
    if upper.size and (upper.min() < 0 or upper.max() > 0xFFFF):
        raise ValueError("instance ids must lie in -1..65534 to fit SemanticKITTI's 16 upper bits")
    return semantic | (upper.astype(np.uint32) << 16)


def _seconds_to_ns(line: str) -> int:
    try:
        seconds = Decimal(line.strip())
    except InvalidOperation:
        raise ValueError(f"not a time in seconds: {line.strip()!r}") from None
    problem = f"not a finite time in seconds: {line.strip()!r}"
    if not seconds.is_finite():
        raise ValueError(problem)
    try:
        return int((seconds * 1_000_000_000).to_integral_value())
    except ArithmeticError:  # an exponent past what decimal holds (decimal.Overflow)
        raise ValueError(problem) from None


def read_times(path: Path) -> list[int]:
    """Stamps in ns from a times.txt of seconds, converted through decimal so no digit is lost."""
    return read_stamp_lines(path, _seconds_to_ns)


def _read_per_point(path: Path, n_points: int, dtype: str) -> np.ndarray:
    """One little-endian `dtype` value per point from a raw file; DatasetError unless its size says exactly that."""
    size, width = path.stat().st_size, np.dtype(dtype).itemsize
    if size != width * n_points:
        name = np.dtype(dtype).name
        raise DatasetError(f"{path}: {size} bytes, expected {width * n_points} (one {name} for each of {n_points} "
                           "points)")
    return np.fromfile(path, dtype=dtype)


def read_label_file(path: Path, n_points: int) -> np.ndarray:
    """Raw uint32 labels of one .label file; DatasetError unless it holds exactly one value per point."""
    return _read_per_point(path, n_points, "<u4")


def read_ring_file(path: Path, n_points: int) -> np.ndarray:
    """The ring field of one scan from a side file (uint16 .bin, or a 1-D integer .npy); DatasetError unless it holds
    one value in 0..65535 for each point."""
    if path.suffix == ".bin":
        return _read_per_point(path, n_points, "<u2").astype(np.uint16)
    try:
        ring = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable .npy ring file ({exc})") from None
    if ring.shape != (n_points,) or ring.dtype.kind not in "iu" or (ring.size and not 0 <= ring.min() <= ring.max()
                                                                      <= np.iinfo(np.uint16).max):
        raise DatasetError(f"{path}: {ring.dtype} {ring.shape}, expected {n_points} integer rings in 0..65535")
    return ring.astype(np.uint16)


def _ring_path(seq: Path, name: str) -> Path | None:
    """The side file holding scan `name`'s ring field, None when there is none."""
    for suffix in (".bin", ".npy"):
        path = seq / "velodyne_ring" / f"{name}{suffix}"
        if path.is_file():
            return path
    return None


def _frames(seq: Path, bins: list[Path], stamps: list[int] | None) -> Iterator[Frame]:
    labels_dir = seq / "labels"
    for position, bin_path in enumerate(bins):
        name = bin_path.stem
        index = frame_index(name, position)
        stamp = frame_stamp(stamps, index, seq / "times.txt")
        points = read_frame_bin(bin_path)
        if points is None:
            continue
        ring_path = _ring_path(seq, name)
        ring = None if ring_path is None else read_ring_file(ring_path, len(points))
        label_path = labels_dir / f"{name}.label"
        if not label_path.is_file():
            yield Frame(name=name, points=points, stamp_ns=stamp, ring=ring)
            continue
        raw = read_label_file(label_path, len(points))
        labels, ground, instance = decode_labels(raw)
        yield Frame(name=name, points=points, stamp_ns=stamp, ring=ring, labels=labels, ground=ground,
                    instance=instance, vehicle_other=decode_vehicle_other(raw))


def read_semantickitti(path: str | Path) -> Iterator[Frame]:
    """Frames of one SemanticKITTI sequence folder, with labels, ground and instances where labelled."""
    seq = require_dir(Path(path), "SemanticKITTI sequence")
    bins = sorted_files(seq / "velodyne", ".bin")
    times_path = seq / "times.txt"
    stamps = read_times(times_path) if times_path.is_file() else None
    return _frames(seq, bins, stamps)


def count_frames(path: str | Path) -> int | None:
    """Number of velodyne scans of the sequence, or None when the folder is missing."""
    velodyne = Path(path) / "velodyne"
    return count_point_files(velodyne) if velodyne.is_dir() else None


def write_semantickitti_frame(seq_dir: Path, frame: Frame) -> None:
    """Write velodyne/<name>.bin and, when the frame has labels, labels/<name>.label."""
    seq_dir = Path(seq_dir)
    write_bin(seq_dir / "velodyne" / f"{frame.name}.bin", frame.points)
    if frame.labels is None:
        return
    raw = encode_labels(frame.labels, frame.ground, frame.instance)
    (seq_dir / "labels").mkdir(parents=True, exist_ok=True)
    raw.astype("<u4").tofile(seq_dir / "labels" / f"{frame.name}.label")
