"""What output_layout as_input and publish_background cost per frame: building and encoding /pass3d/labeled
(compact vs as_input), the background cloud, and /pass3d/proposals (compact vs in the input's layout, and reading it
back), for a KITTI-size synthetic scan as a KITTI-like cloud and as an Ouster-like organized one."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from pass3d_ros.bench.codec import time_ms
from pass3d_ros.core.stage2.segmentation import SegmentResult
from pass3d_ros.data.bag_convert import frame_cloud
from pass3d_ros.data.frame import Frame
from pass3d_ros.msgs.pointcloud2 import decode, encode, to_xyzi
from pass3d_ros.ros.input_layout import background_cloud, full_proposals_cloud, input_source, labeled_as_input
from pass3d_ros.ros.proposals import ProposalFrame, proposal_frame
from pass3d_ros.ros.segmentation_node import labeled_cloud
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.tools.cli import number

OUSTER = np.dtype({"names": ["x", "y", "z", "t", "reflectivity", "ring", "ambient", "range", "intensity"],
                   "formats": ["<f4"] * 3 + ["<u4", "<u2", "<u2", "<u2", "<u4", "<u2"],
                   "offsets": [0, 4, 8, 12, 16, 18, 20, 24, 32], "itemsize": 48})


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark layout`."""
    parser.add_argument("--repeat", type=number(int, 1), default=50, help="timed repetitions (default 50)")
    parser.add_argument("--width", type=number(int, 1), default=2048,
                        help="columns of the organized cloud (default 2048)")


def organized(frame: Frame, width: int) -> np.ndarray:
    """`frame` on a rings x `width` grid with Ouster-like fields (48-byte points); empty cells at (0, 0, 0)."""
    rings = int(frame.ring.max()) + 1
    column = ((np.pi - np.arctan2(frame.points[:, 1], frame.points[:, 0])) / (2 * np.pi) * width).astype(int) % width
    cell = frame.ring.astype(int) * width + column
    _, first = np.unique(cell, return_index=True)
    grid = np.zeros(rings * width, OUSTER)
    for k, axis in enumerate("xyz"):
        grid[axis][cell[first]] = frame.points[first, k]
    grid["intensity"][cell[first]] = np.round(frame.points[first, 3] * 65535)
    grid["ring"] = np.arange(len(grid)) // width
    return grid


def timings(msg: Any, repeat: int) -> list[tuple[str, tuple[float, float]]]:
    """(step, (median, min) ms) for one input message; labels and ids are random, the costs do not depend on them."""
    cloud = decode(msg)
    scan = to_xyzi(cloud, skip_nans=True)
    keep = np.flatnonzero((scan.points[:, :3] != 0).any(axis=1))  # the no-returns, as the input checks leave them out
    points, n = scan.points[keep], len(keep)
    rng = np.random.default_rng(0)
    labels = rng.choice(4, n, p=[0.9, 0.06, 0.02, 0.02]).astype(np.uint8)
    result = SegmentResult(labels, rng.random(n).astype(np.float32), np.zeros(0, np.int16))
    ids, ground = rng.integers(-1, 30, n).astype(np.int32), np.zeros(n, bool)
    source = input_source(cloud, msg.height, msg.width, len(scan.points), None if n == len(cloud) else keep)
    ring = np.zeros(n, np.uint16) if scan.ring is None else scan.ring[keep]
    frame = ProposalFrame(msg.header, points, ring, ids, ids, source)
    compact_proposals = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2], "intensity": points[:, 3],
                         "ring": ring, "ground": ground.astype(np.uint8), "cluster_id": ids, "cluster_id2": ids}

    def as_input() -> Any:
        columns = labeled_cloud(frame, labels, ids, result.confidence)
        return encode(labeled_as_input(source, columns), header=msg.header, height=source.height,
                      is_dense=source.is_dense)

    def full() -> Any:
        return encode(full_proposals_cloud(source, points, ids, ids, ground, ring), header=msg.header,
                      height=source.height, is_dense=source.is_dense)

    full_msg, compact_msg = full(), encode(compact_proposals, header=msg.header)
    return [
        ("labeled compact", time_ms(lambda: encode(labeled_cloud(frame, labels, ids, result.confidence),
                                                   header=msg.header, is_dense=True), repeat)),
        ("labeled as_input", time_ms(as_input, repeat)),
        ("background", time_ms(lambda: encode(background_cloud(source, labels), header=msg.header), repeat)),
        ("proposals compact", time_ms(lambda: encode(compact_proposals, header=msg.header), repeat)),
        ("proposals as_input", time_ms(full, repeat)),
        ("read proposals compact", time_ms(lambda: proposal_frame(compact_msg), repeat)),
        ("read proposals as_input", time_ms(lambda: proposal_frame(full_msg), repeat)),
    ]


def run(args: argparse.Namespace) -> int:
    """Print (median, min) ms of each step for both clouds."""
    frame = generate_frame(seed=5, index=0)  # HDL-64E, KITTI's sensor
    clouds = [("KITTI-like x y z intensity (float32) ring (uint16), unorganized", encode(frame_cloud(frame))),
              (f"Ouster-like organized {int(frame.ring.max()) + 1} x {args.width}, 48-byte points, no-returns kept",
               encode(organized(frame, args.width), height=int(frame.ring.max()) + 1))]
    for name, msg in clouds:
        print(f"{name}: {msg.width * msg.height} points, {len(msg.data) / 1e6:.1f} MB; {args.repeat} timed repeats "
              "after one untimed call")
        for step, (median, low) in timings(msg, args.repeat):
            print(f"  {step:24s} median {median:7.2f} ms   min {low:7.2f} ms")
    return 0
