"""SqueezeSeg lidar_2d reader (`squeezeseg:DIR` or `squeezeseg:DIR@SPLITFILE`).

Each .npy is an H x W x 6 image (64 x 512 in SqueezeSeg's release, the front 90 degrees of a KITTI raw scan):
x, y, z, intensity (KITTI reflectance 0..1, kept as is), range, label (0 background, 1 car, 2 pedestrian,
3 cyclist: the project's ids already). Conventions:
- `DIR@SPLITFILE` reads only the frames listed in SPLITFILE (SqueezeSeg's ImageSet/{train,val,all}.txt,
  one name per line, `.npy` optional), in the list's order. The text is split at its last `@` unless the
  whole text names an existing directory. SPLITFILE is a path of its own (relative to the working
  directory), e.g. `squeezeseg:data/lidar_2d@data/ImageSet/val.txt`.
- Points are emitted ring by ring (ring = row, row 0 first; in SqueezeSeg row 0 is the top laser, as the
  first ring of a KITTI .bin is), and within a row in rising azimuth, the order of a KITTI .bin
  (a ring starts just left of straight ahead and turns counter-clockwise). SqueezeSeg puts the vehicle's
  left (+y) at column 0, so a row is read from its last column to its first; the reader checks that
  direction on each file's own points and follows the data should a file run the other way.
- Empty pixels (range <= 0, or x = y = z = 0) are dropped; nothing else is.
- Stamp: the trailing frame number of the name (`2011_09_26_0001_0000000010` -> 10) x 100 ms.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.kitti_io import FRAME_PERIOD_NS, frame_index, read_text, require_dir, sorted_files
from pass3d_ros.msgs.errors import DatasetError

CHANNELS = 6  # x, y, z, intensity, range, label


def read_split_list(path: str | Path) -> list[str]:
    """Frame names of a SqueezeSeg ImageSet list, in file order, without any `.npy` suffix."""
    path = Path(path)
    lines = read_text(path, "split list").splitlines()
    names = [line.strip().removesuffix(".npy") for line in lines]
    return [name for name in names if name]


def parse_path(path: str | Path) -> tuple[Path, Path | None]:
    """(directory, split file or None) of a `DIR` or `DIR@SPLITFILE` path."""
    text = str(path)
    if Path(text).is_dir() or "@" not in text:
        return Path(text), None
    directory, _, split = text.rpartition("@")
    return Path(directory), Path(split)


def _listing(path: str | Path) -> list[Path]:
    directory, split = parse_path(path)
    require_dir(directory, "SqueezeSeg lidar_2d")
    if split is None:
        return sorted_files(directory, ".npy")
    files = [directory / f"{name}.npy" for name in read_split_list(split)]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise DatasetError(f"{missing[0]}: listed in {split} but missing ({len(missing)} listed files missing)")
    return files


def load_image(path: Path) -> np.ndarray:
    """The H x W x 6 float array of one lidar_2d file; DatasetError naming the file when it is not one."""
    try:
        image = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable .npy file ({exc})") from exc
    if image.ndim != 3 or image.shape[2] != CHANNELS:
        raise DatasetError(f"{path}: expected an H x W x {CHANNELS} array, got shape {image.shape}")
    if image.dtype.kind not in "fiu":
        raise DatasetError(f"{path}: expected real numbers, got {image.dtype}")
    return image


def _azimuth_falls_with_column(image: np.ndarray, valid: np.ndarray) -> bool:
    """Whether azimuth decreases along a row (SqueezeSeg's layout); decided from the file's own points."""
    width = image.shape[1]
    rows, cols = np.nonzero(valid)
    azimuth = np.arctan2(image[rows, cols, 1], image[rows, cols, 0])
    left, right = azimuth[cols < width // 2], azimuth[cols >= width // 2]
    if len(left) == 0 or len(right) == 0:
        return True
    return float(np.median(left)) >= float(np.median(right))


def image_to_frame(image: np.ndarray, name: str, stamp_ns: int = 0, source: str = "") -> Frame:
    """Frame of one SqueezeSeg image: non-empty pixels ring by ring, each ring in rising azimuth."""
    xyz, rng = image[..., :3], image[..., 4]
    valid = (rng > 0) & np.any(xyz != 0, axis=-1)
    if _azimuth_falls_with_column(image, valid):
        image, valid = image[:, ::-1], valid[:, ::-1]
    rows = np.broadcast_to(np.arange(image.shape[0])[:, None], valid.shape)
    pixels = image[valid]
    labels = np.rint(pixels[:, 5])
    if not np.all((labels >= 0) & (labels < NUM_CLASSES)):  # NaN fails both tests
        raise DatasetError(f"{source or name}: label channel outside 0..{NUM_CLASSES - 1}")
    return Frame(name=name, points=pixels[:, :4].astype(np.float32), stamp_ns=stamp_ns,
                 ring=rows[valid].astype(np.uint16), labels=labels.astype(np.uint8))


def _frames(files: list[Path]) -> Iterator[Frame]:
    for position, path in enumerate(files):
        stamp = frame_index(path.stem, position) * FRAME_PERIOD_NS
        yield image_to_frame(load_image(path), path.stem, stamp, str(path))


def read_squeezeseg(path: str | Path) -> Iterator[Frame]:
    """Frames of a lidar_2d folder (natural name order), or of the frames a split list names."""
    return _frames(_listing(path))


def count_frames(path: str | Path) -> int | None:
    """Number of frames the folder (or split list) gives, or None when it cannot be listed."""
    try:
        return len(_listing(path))
    except DatasetError:
        return None

