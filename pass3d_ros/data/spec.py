"""`FORMAT:PATH` dataset specs, the one way every tool names its input (`--data`, repeatable)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from pass3d_ros.data.frame import Frame

# format name -> "module:function"; the function takes the text after the colon and yields Frames.
READERS: dict[str, str] = {
    "kitti_object": "pass3d_ros.data.kitti_object:read_kitti_object",
    "kitti_raw": "pass3d_ros.data.kitti_raw:read_kitti_raw",
    "semantickitti": "pass3d_ros.data.semantickitti:read_semantickitti",
    "squeezeseg": "pass3d_ros.data.squeezeseg:read_squeezeseg",
    "synthetic": "pass3d_ros.synthetic.dataset:read_synthetic",
    "bag": "pass3d_ros.data.bag:read_bag",
}


class DatasetError(ValueError):
    """A dataset spec or a file it names is unusable; the message names the spec or file and the problem."""


@dataclass(frozen=True)
class DatasetSpec:
    format: str
    path: str

    def __str__(self) -> str:
        return f"{self.format}:{self.path}"


def parse_spec(text: str) -> DatasetSpec:
    """Split `FORMAT:PATH`, checking the format is known."""
    fmt, sep, rest = text.partition(":")
    if not sep or not rest:
        raise DatasetError(f"dataset spec {text!r}: expected FORMAT:PATH, formats: {', '.join(READERS)}")
    if fmt not in READERS:
        raise DatasetError(f"dataset spec {text!r}: unknown format {fmt!r}, formats: {', '.join(READERS)}")
    return DatasetSpec(fmt, rest)


def _reader(fmt: str) -> Callable[[str], Iterator[Frame]]:
    module, func = READERS[fmt].split(":")
    return getattr(importlib.import_module(module), func)


def open_dataset(spec: str | DatasetSpec) -> Iterator[Frame]:
    """Yield the frames of one dataset spec, in order."""
    if isinstance(spec, str):
        spec = parse_spec(spec)
    return _reader(spec.format)(spec.path)


def open_datasets(specs: list[str]) -> Iterator[Frame]:
    """Yield the frames of several specs, one after the other."""
    for spec in specs:
        yield from open_dataset(spec)


def open_datasets_shard(specs: list[str], rank: int, world: int) -> Iterator[Frame | None]:
    """The frames of several specs in order, with None in place of every frame whose position is not
    rank (mod world): data-parallel training builds only its own share. A reader with a `read_shard(path, keep)`
    skips the others without making them (synthetic scans cost far more to generate than to skip)."""
    position = 0
    for text in specs:
        spec = parse_spec(text)
        module, _ = READERS[spec.format].split(":")
        shard_reader = getattr(importlib.import_module(module), "read_shard", None)
        offset = position

        def keep(k: int, offset: int = offset) -> bool:
            return (offset + k) % world == rank

        frames = shard_reader(spec.path, keep) if shard_reader else (
            frame if keep(k) else None for k, frame in enumerate(open_dataset(spec)))
        for frame in frames:
            yield frame
            position += 1


def count_frames(spec: str | DatasetSpec) -> int | None:
    """Frame count for progress bars when the reader can tell cheaply, else None."""
    if isinstance(spec, str):
        spec = parse_spec(spec)
    module, _ = READERS[spec.format].split(":")
    counter = getattr(importlib.import_module(module), "count_frames", None)
    return counter(spec.path) if counter else None
