"""Dataset frames -> a rosbag2 of PointCloud2 messages: the library behind `pass3d_kitti2bag`, the demo and the
live evaluation.

One message per frame, points in their original order and values: x, y, z, intensity float32, ring uint16
when the source knows it, the ground truth as `label_gt` uint8 on request (not `label`: that is what the pipeline's
outputs predict, see pass3d_ros.data.bag). Header stamp = the frame's stamp. A dataset without absolute
time (its first frame is stamped 0, e.g. KITTI object: frame number x 100 ms) is shifted to start at
2020-01-01T00:00:00Z, or 100 ms after the previous dataset's last frame, keeping its own spacing. The bag is
built beside its destination and renamed into place only when complete.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pass3d_ros.data.bag import TRUTH_FIELD, TYPESTORE, BagError, BagWriter, topic_name_problem
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import dataset_paths
from pass3d_ros.data.spec import Dataset, DatasetError, resolve_datasets
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE, columns_to_cloud, encode

SYNTHETIC_START_NS = 1_577_836_800 * 1_000_000_000  # 2020-01-01T00:00:00Z
FRAME_GAP_NS = 100_000_000  # 10 Hz
MAX_STAMP_NS = 2**31 * 1_000_000_000 - 1  # a ROS header's stamp: int32 seconds, not before 1970 in a bag


@dataclass
class ConvertStats:
    """What a conversion wrote."""

    frames: int = 0
    points: int = 0
    first_stamp_ns: int = 0
    last_stamp_ns: int = 0
    synthesized: tuple[str, ...] = ()
    out_of_order: int = 0


def frame_cloud(frame: Frame, with_labels: bool = False) -> np.ndarray:
    """The frame as a structured cloud: x, y, z, intensity float32, ring uint16 if known, label_gt uint8 on request."""
    columns: dict[str, np.ndarray] = {
        "x": frame.points[:, 0],
        "y": frame.points[:, 1],
        "z": frame.points[:, 2],
        "intensity": frame.points[:, 3],
    }
    if frame.ring is not None:
        columns["ring"] = np.asarray(frame.ring, dtype=np.uint16)
    if with_labels:
        if frame.labels is None:
            raise DatasetError(f"frame {frame.name}: no point labels, but --with-labels asks for them")
        columns[TRUTH_FIELD] = np.asarray(frame.labels, dtype=np.uint8)
    return columns_to_cloud(columns)


def convert(
    specs: Sequence[str | Dataset],
    out: str | Path,
    *,
    storage: str = "mcap",
    version: int = 9,
    topic: str = "/velodyne_points",
    frame_id: str = "velodyne",
    with_labels: bool = False,
    force: bool = False,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> ConvertStats:
    """Write the frames of `specs` into the bag `out`; nothing is left at `out` if anything fails. `force` replaces
    only an existing bag, never an input or a folder holding one."""
    if not specs:
        raise DatasetError("no --data given")
    problem = topic_name_problem(topic)
    if problem is not None:
        raise BagError(f"topic {topic!r} is not a valid ROS 2 topic name: {problem}")
    if not frame_id.strip():
        raise BagError("frame_id is empty; the clouds need a frame to be shown in")
    datasets = resolve_datasets(specs)
    counts = [dataset.count() for dataset in datasets]
    total = None if None in counts else sum(c for c in counts if c is not None)
    stats = ConvertStats()
    synthesized: list[str] = []
    writer = BagWriter(out, storage=storage, version=version, force=force, log=log, inputs=dataset_paths(datasets))
    bar = tqdm(total=total, unit="frame", desc=Path(out).name, disable=None if progress else True)  # None: TTY only
    with writer, bar:
        for dataset in datasets:
            offset: int | None = None
            for frame in dataset.frames():
                if offset is None:
                    offset = 0
                    if frame.stamp_ns == 0:
                        offset = stats.last_stamp_ns + FRAME_GAP_NS if stats.frames else SYNTHETIC_START_NS
                        synthesized.append(str(dataset))
                stamp = frame.stamp_ns + offset
                if not 0 <= stamp <= MAX_STAMP_NS:
                    raise DatasetError(f"{dataset}: frame {frame.name}: stamp {stamp / 1e9:.9g} s is outside what a "
                                       f"ROS header holds (0 to {MAX_STAMP_NS // 1_000_000_000} s)")
                try:
                    cloud = frame_cloud(frame, with_labels)
                except DatasetError as exc:
                    raise DatasetError(f"{dataset}: {exc}") from None
                msg = encode(cloud, frame_id=frame_id, stamp_ns=stamp, typestore=TYPESTORE)
                writer.write_raw(topic, POINTCLOUD2_TYPE, stamp, TYPESTORE.serialize_cdr(msg, POINTCLOUD2_TYPE))
                if stats.frames == 0:
                    stats.first_stamp_ns = stamp
                elif stamp <= stats.last_stamp_ns:
                    stats.out_of_order += 1
                stats.frames += 1
                stats.points += len(cloud)
                stats.last_stamp_ns = stamp
                bar.update(1)
        if stats.frames == 0:
            raise DatasetError(f"{', '.join(map(str, datasets))}: no frames to write")
    stats.synthesized = tuple(synthesized)
    for spec in synthesized:
        log(f"note: {spec} has no absolute time (first stamp 0): stamped from its frame times + a fixed start")
    if stats.out_of_order:
        log(f"warning: {stats.out_of_order} frame(s) not stamped after their predecessor")
    return stats
