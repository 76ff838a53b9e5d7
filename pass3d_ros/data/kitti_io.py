"""File helpers shared by the KITTI-family readers: validated .bin I/O, natural ordering, box labelling."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from pass3d_ros.classes import BACKGROUND, IGNORE
from pass3d_ros.data.frame import Box3D
from pass3d_ros.msgs.errors import DatasetError

# KITTI annotates objects only where the front camera sees; SqueezeSeg and PASS3D score the front 90 degrees.
FRONT_VIEW_HALF_ANGLE_DEG = 45.0
FRAME_PERIOD_NS = 100_000_000  # 10 Hz: the stamp of frame k when a dataset stores no time
# KITTI box kinds (object labels and raw tracklets alike) of vehicles that are no car: background under SqueezeSeg's
# rule, the points an evaluation may leave out of the car score (Frame.vehicle_other)
OTHER_VEHICLE_KINDS: tuple[str, ...] = ("Van", "Truck")
POINT_BYTES = 16  # x, y, z, reflectance as float32

_DIGITS = re.compile(r"(\d+)")
_TRAILING_DIGITS = re.compile(r"(\d+)$")


def natural_key(name: str) -> list[int | str]:
    """Sort key that orders `frame2` before `frame10` (digit runs compare as numbers)."""
    return [int(part) if part.isdigit() else part for part in _DIGITS.split(name)]


def require_dir(path: Path, what: str) -> Path:
    """`path` if it is a directory, else a DatasetError naming it and what it should hold."""
    if not path.is_dir():
        raise DatasetError(f"{path}: {what} directory not found")
    return path


def read_text(path: Path, what: str) -> str:
    """The text of `path`; DatasetError naming it and `what` it holds when it cannot be read or is not UTF-8 text
    (a binary or corrupt file would otherwise escape as a UnicodeDecodeError)."""
    try:
        return path.read_text()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read {what} ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: cannot read {what} (not text: byte {exc.start} is not UTF-8)") from None


def sorted_files(directory: Path, suffix: str) -> list[Path]:
    """Files of `directory` ending in `suffix`, in natural order; DatasetError if the folder is missing."""
    require_dir(directory, f"'{suffix}' file")
    return sorted((p for p in directory.iterdir() if p.is_file() and p.name.endswith(suffix)),
                  key=lambda p: natural_key(p.name))


def frame_stamp(stamps: list[int] | None, index: int, source: Path) -> int:
    """The stamp of frame `index`: its line of the dataset's time file `source` (DatasetError when there is none),
    or index x FRAME_PERIOD_NS when the dataset stores no time (`stamps` None)."""
    if stamps is None:
        return index * FRAME_PERIOD_NS
    if index < len(stamps):
        return stamps[index]
    raise DatasetError(f"{source}: no line for frame {index}")


def frame_index(stem: str, position: int) -> int:
    """Frame number from the trailing digits of a file stem (KITTI names), else the listing position."""
    match = _TRAILING_DIGITS.search(stem)
    return int(match.group(1)) if match else position


def read_bin(path: Path) -> np.ndarray:
    """Points N x 4 float32 of a KITTI velodyne .bin, in file order; DatasetError if missing or mis-sized."""
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read point file ({exc.strerror})") from exc
    if size % POINT_BYTES:
        raise DatasetError(f"{path}: size {size} bytes is not a multiple of {POINT_BYTES} (x, y, z, i float32)")
    return np.fromfile(path, dtype="<f4").reshape(-1, 4)


def read_frame_bin(path: Path) -> np.ndarray | None:
    """Points of a velodyne .bin as `read_bin`, or None (after a one-line warning on stderr naming the file) when
    it is empty: the readers skip such a frame rather than yield a scan without points."""
    points = read_bin(path)
    if len(points) == 0:
        print(f"warning: {path}: empty point file (0 bytes), frame skipped", file=sys.stderr)
        return None
    return points


def count_point_files(directory: Path) -> int:
    """Number of non-empty .bin files in `directory` (the frames a reader yields)."""
    return sum(1 for p in sorted_files(directory, ".bin") if p.stat().st_size > 0)


def write_bin(path: Path, points: np.ndarray) -> None:
    """Write N x 4 points as little-endian float32, the KITTI velodyne layout."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.ascontiguousarray(points[:, :4], dtype="<f4").tofile(path)


def label_points_in_boxes(xyz: np.ndarray, boxes: Iterable[Box3D]) -> tuple[np.ndarray, np.ndarray]:
    """Per-point (labels uint8, instance int32) from the foreground boxes; a later box wins an overlap."""
    n = len(xyz)
    labels = np.full(n, BACKGROUND, dtype=np.uint8)
    instance = np.full(n, -1, dtype=np.int32)
    for box in boxes:
        if box.label == BACKGROUND:
            continue
        inside = box.contains(xyz)
        labels[inside] = box.label
        instance[inside] = box.instance
    return labels, instance


def points_in_kinds(xyz: np.ndarray, boxes: Iterable[Box3D], kinds: tuple[str, ...] = OTHER_VEHICLE_KINDS
                    ) -> np.ndarray:
    """Mask of the points inside a box whose kind is one of `kinds` (default: the non-car vehicles)."""
    inside = np.zeros(len(xyz), dtype=bool)
    for box in boxes:
        if box.kind in kinds:
            inside |= box.contains(xyz)
    return inside


def ignore_outside_front_view(xyz: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Labels with points outside the front 90 degrees set to IGNORE: KITTI boxes exist only in the camera view,
    so a car behind the sensor is unannotated, not background (SqueezeSeg's and the paper's protocol)."""
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    labels = labels.copy()
    labels[np.abs(azimuth) > FRONT_VIEW_HALF_ANGLE_DEG] = IGNORE
    return labels


def read_stamp_lines(path: Path, parse: Callable[[str], int]) -> list[int]:
    """One stamp (ns) per non-empty line of a KITTI time file; DatasetError naming the file and line on a bad one
    (`parse` raises ValueError with what is wrong)."""
    stamps = []
    for number, line in enumerate(read_text(path, "time file").splitlines(), 1):
        if not line.strip():
            continue
        try:
            stamps.append(parse(line))
        except ValueError as exc:
            raise DatasetError(f"{path}:{number}: {exc}") from exc
    return stamps
