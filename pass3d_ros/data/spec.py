"""`FORMAT:PATH` dataset specs, the one way every tool names its input (`--data`, repeatable).

`resolve_dataset(text)` parses a spec once and looks its reader up once; the `Dataset` it returns opens, counts
and shards the frames. Formats live in a registry: the data layer's readers are registered here (imported on first
use: the bag reader needs rosbags), and a package above registers its own when imported (`import
pass3d_ros.synthetic` adds `synthetic:`; every command-line tool does), so this layer never loads one by name.

Options every format takes ride on the spec after a comma, as the synthetic reader's own do
(`kitti_object:DIR,crop=front`, `synthetic:frames=5,seed=1,crop=front`); they are parsed here, once, and the rest
goes to the reader untouched. `crop=front` keeps only the points ahead of the sensor within 45 degrees of its axis
(x > 0, |azimuth| <= 45 degrees: the front camera's field of view as the project applies it, the view KITTI's
boxes cover), as KITTI's `velodyne_reduced` scans are cut: in firing order, per-point labels, ground, rings and
instances cut alike, boxes without a kept point dropped (pass3d_ros.data.frame.crop_frame).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from pass3d_ros.data.frame import Frame, crop_frame, front_view_mask
from pass3d_ros.data.kitti_io import FRONT_VIEW_HALF_ANGLE_DEG
from pass3d_ros.msgs.errors import DatasetError

Keep = Callable[[int], bool]  # a frame's position in its spec -> whether this shard makes it
# crop name -> the half angle (degrees) of the azimuth sector ahead of the sensor it keeps
CROPS: dict[str, float] = {"front": FRONT_VIEW_HALF_ANGLE_DEG}
SPEC_OPTIONS: tuple[str, ...] = ("crop",)  # options of every format, parsed by resolve_dataset


@dataclass(frozen=True)
class DatasetFormat:
    """A format's reader: `read(path)` yields Frames; `count(path)` is the frame count when it is cheap to tell;
    `read_shard(path, keep)` yields None for the frames `keep` refuses, without making them."""

    read: Callable[[str], Iterator[Frame]]
    count: Callable[[str], int | None] | None = None
    read_shard: Callable[[str, Keep], Iterator[Frame | None]] | None = None


def _kitti_object() -> DatasetFormat:
    from pass3d_ros.data import kitti_object

    return DatasetFormat(kitti_object.read_kitti_object, kitti_object.count_frames)


def _kitti_raw() -> DatasetFormat:
    from pass3d_ros.data import kitti_raw

    return DatasetFormat(kitti_raw.read_kitti_raw, kitti_raw.count_frames)


def _semantickitti() -> DatasetFormat:
    from pass3d_ros.data import semantickitti

    return DatasetFormat(semantickitti.read_semantickitti, semantickitti.count_frames)


def _squeezeseg() -> DatasetFormat:
    from pass3d_ros.data import squeezeseg

    return DatasetFormat(squeezeseg.read_squeezeseg, squeezeseg.count_frames)


def _bag() -> DatasetFormat:
    from pass3d_ros.data import bag

    return DatasetFormat(bag.read_bag, bag.count_frames)


# format name -> loader (imports the reader module when a spec of that format is first resolved)
_LOADERS: dict[str, Callable[[], DatasetFormat]] = {
    "kitti_object": _kitti_object,
    "kitti_raw": _kitti_raw,
    "semantickitti": _semantickitti,
    "squeezeseg": _squeezeseg,
    "bag": _bag,
}
_LOADED: dict[str, DatasetFormat] = {}


def register_format(name: str, loader: Callable[[], DatasetFormat]) -> None:
    """Make `name:PATH` specs resolvable; `loader` is called once, when the first such spec is resolved."""
    _LOADERS[name] = loader
    _LOADED.pop(name, None)


def _format(name: str) -> DatasetFormat:
    if name not in _LOADED:
        _LOADED[name] = _LOADERS[name]()
    return _LOADED[name]


@dataclass(frozen=True)
class Dataset:
    """One `FORMAT:PATH` spec, parsed and its reader looked up: its frames, their count, a shard of them."""

    format: str
    path: str
    reader: DatasetFormat = field(repr=False, compare=False)
    crop: str = ""  # a name of CROPS, "" for whole scans

    def __str__(self) -> str:
        return f"{self.format}:{self.path}" + (f",crop={self.crop}" if self.crop else "")

    def apply_crop(self, frame: Frame) -> Frame:
        """`frame` cut as the spec asks (itself when whole)."""
        if not self.crop:
            return frame
        return crop_frame(frame, front_view_mask(frame.points, CROPS[self.crop]))

    def frames(self) -> Iterator[Frame]:
        """The frames, in order (cropped when the spec asks)."""
        frames = self.reader.read(self.path)
        return frames if not self.crop else (self.apply_crop(frame) for frame in frames)

    def count(self) -> int | None:
        """The frame count for progress bars when the reader can tell cheaply, else None."""
        return None if self.reader.count is None else self.reader.count(self.path)

    def shard(self, keep: Keep) -> Iterator[Frame | None]:
        """The frames in order, None in place of each whose position k fails `keep(k)` (made only if the reader
        cannot skip it)."""
        if self.reader.read_shard is not None:
            shard = self.reader.read_shard(self.path, keep)
            return shard if not self.crop else (None if f is None else self.apply_crop(f) for f in shard)
        return (frame if keep(k) else None for k, frame in enumerate(self.frames()))


def split_options(spec: str, rest: str) -> tuple[str, dict[str, str]]:
    """(the reader's part, {option: value}) of a spec's text after `FORMAT:`: the comma-separated items named in
    SPEC_OPTIONS are taken out wherever they stand, everything else is left to the reader as it was written.
    DatasetError (naming `spec`) on a repeated option or a bad value."""
    kept: list[str] = []
    options: dict[str, str] = {}
    for item in rest.split(","):
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in SPEC_OPTIONS:
            kept.append(item)
            continue
        if key in options:
            raise DatasetError(f"dataset spec {spec!r}: {key}= given twice")
        value = value.strip().lower()
        if key == "crop" and value not in CROPS:
            raise DatasetError(f"dataset spec {spec!r}: unknown crop {value!r}, crops: {', '.join(CROPS)}")
        options[key] = value
    return ",".join(kept), options


def resolve_dataset(spec: str | Dataset) -> Dataset:
    """Parse `FORMAT:PATH[,crop=front]` and look its reader up (a Dataset is returned as it is); DatasetError names
    the spec and the known formats when the format is unknown, and the known values of an option given a bad one."""
    if isinstance(spec, Dataset):
        return spec
    fmt, sep, rest = spec.partition(":")
    known = ", ".join(_LOADERS)
    if not sep or not rest:
        raise DatasetError(f"dataset spec {spec!r}: expected FORMAT:PATH, formats: {known}")
    if fmt not in _LOADERS:
        raise DatasetError(f"dataset spec {spec!r}: unknown format {fmt!r}, formats: {known}")
    path, options = split_options(spec, rest)
    if not path.strip(", "):
        raise DatasetError(f"dataset spec {spec!r}: expected FORMAT:PATH[,crop=front], got options only")
    return Dataset(fmt, path, _format(fmt), crop=options.get("crop", ""))


def resolve_datasets(specs: Iterable[str | Dataset]) -> list[Dataset]:
    """`resolve_dataset` of each spec, in order."""
    return [resolve_dataset(spec) for spec in specs]


def refuse_repeated_recordings(specs: Iterable[str | Dataset], consequence: str) -> None:
    """DatasetError naming the first spec that names the same recording as one before it (symlinks and spellings of
    its path resolved, the same crop), with what reading it twice would do (`consequence`)."""
    seen: dict[tuple[str, str, str], str] = {}
    for spec in specs:
        dataset = resolve_dataset(spec)
        path, sep, topic = dataset.path.partition("#")
        place = os.path.realpath(path) if os.path.exists(path) else path
        key = (dataset.format, place + sep + topic, dataset.crop)
        if key in seen:
            raise DatasetError(f"--data {spec}: the same recording as --data {seen[key]}; give each recording once "
                               f"({consequence})")
        seen[key] = str(spec)


def open_dataset(spec: str | Dataset) -> Iterator[Frame]:
    """Yield the frames of one dataset spec, in order."""
    return resolve_dataset(spec).frames()


def open_datasets(specs: Iterable[str | Dataset]) -> Iterator[Frame]:
    """Yield the frames of several specs, one after the other."""
    for dataset in resolve_datasets(specs):
        yield from dataset.frames()


def open_datasets_shard(specs: Iterable[str | Dataset], rank: int, world: int) -> Iterator[Frame | None]:
    """The frames of several specs in order, with None in place of every frame whose position is not
    rank (mod world): data-parallel training builds only its own share. A reader with a `read_shard` skips the
    others without making them (synthetic scans cost far more to generate than to skip)."""
    position = 0
    for dataset in resolve_datasets(specs):
        offset = position

        def keep(k: int, offset: int = offset) -> bool:
            return (offset + k) % world == rank

        for frame in dataset.shard(keep):
            yield frame
            position += 1


def count_frames(spec: str | Dataset) -> int | None:
    """Frame count for progress bars when the reader can tell cheaply, else None."""
    return resolve_dataset(spec).count()
