"""PointCloud2 codec speed: decode / encode of an rclpy message, median and min over repeats after a warm-up call."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from pass3d_ros.msgs.pointcloud2 import columns_to_cloud, decode, decode_xyzi, encode
from pass3d_ros.tools.cli import number


def sample_cloud(points: int, seed: int = 0) -> np.ndarray:
    """A pipeline-output-like cloud: x, y, z, intensity float32, ring uint16, cluster_id int32, label uint8."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-60.0, 60.0, (points, 3)).astype(np.float32)
    return columns_to_cloud(
        {
            "x": xyz[:, 0],
            "y": xyz[:, 1],
            "z": xyz[:, 2],
            "intensity": rng.random(points, dtype=np.float32),
            "ring": rng.integers(0, 64, points).astype(np.uint16),
            "cluster_id": rng.integers(-1, 30, points).astype(np.int32),
            "label": rng.integers(0, 4, points).astype(np.uint8),
        }
    )


def time_ms(func: Callable[[], Any], repeat: int) -> tuple[float, float]:
    """(median, min) wall time of `func` in milliseconds over `repeat` calls after one untimed call (the first
    compiles or loads numba kernels: hundreds of ms); results are kept alive so fresh memory is timed."""
    results, times = [func()], []
    for _ in range(repeat):
        start = time.perf_counter()
        results.append(func())
        times.append(time.perf_counter() - start)
        if len(results) > 4:
            results.pop(0)
    return float(np.median(times)) * 1e3, float(np.min(times)) * 1e3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark codec`."""
    parser.add_argument("--points", type=number(int, 1), default=120_000, help="points per cloud (default 120000)")
    parser.add_argument("--repeat", type=number(int, 1), default=50, help="timed repetitions (default 50)")


def run(args: argparse.Namespace) -> int:
    """Time encode (structured array / dict of columns), decode and decode-to-N x 4; print the numbers."""
    cloud = sample_cloud(args.points)
    msg = encode(cloud, frame_id="velodyne", stamp_ns=1)
    if not np.array_equal(decode(msg), cloud):
        print("pass3d_benchmark: codec round trip FAILED", file=sys.stderr)
        return 1
    columns = {name: np.ascontiguousarray(cloud[name]) for name in cloud.dtype.names}
    fields = ", ".join(f"{f.name}:{cloud.dtype.fields[f.name][0]}@{f.offset}" for f in msg.fields)
    print(f"cloud: {args.points} points, point_step {msg.point_step} B, {len(msg.data) / 1e6:.2f} MB; fields {fields}")
    print(f"message: {type(msg).__module__}.{type(msg).__name__}; {args.repeat} timed repeats after one untimed call")
    rows = [
        ("encode", time_ms(lambda: encode(cloud, frame_id="velodyne", stamp_ns=1), args.repeat)),
        ("encode_dict", time_ms(lambda: encode(columns, frame_id="velodyne", stamp_ns=1), args.repeat)),
        ("decode", time_ms(lambda: decode(msg), args.repeat)),
        ("decode_xyzi", time_ms(lambda: decode_xyzi(msg), args.repeat)),
    ]
    for name, (median, low) in rows:
        print(f"{name:12s} median {median:8.3f} ms   min {low:8.3f} ms")
    return 0
