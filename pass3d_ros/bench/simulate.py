"""Synthetic scan generation speed: seconds per frame of one sensor (default KITTI's HDL-64E), one thread:
scene, ray casting, noise and labels."""

from __future__ import annotations

import argparse
import time

import numpy as np

from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import number

TARGET_S_PER_FRAME = 0.5
TARGET_SENSOR = "hdl64e"  # the target is an HDL-64E frame's (docs/performance.md)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark simulate`."""
    parser.add_argument("--frames", type=int, default=10, help="frames to time (default 10)")
    parser.add_argument("--seed", type=number(int, 0), default=0, help="sequence seed (default 0)")
    from pass3d_ros.synthetic.sensor import SENSOR_NAMES

    parser.add_argument("--sensor", type=str.lower, default="hdl64e",
                        help=f"LiDAR model: {', '.join(SENSOR_NAMES)} (default hdl64e)")


def run(args: argparse.Namespace) -> int:
    """Time generate_frame after one untimed first call (numba compilation or cache load) and print medians."""
    from pass3d_ros.synthetic import dataset as ds
    from pass3d_ros.synthetic import scene as sc
    from pass3d_ros.synthetic.sensor import SENSOR_NAMES, ray_bundle, sensor_model

    if args.frames < 1:
        raise UserError("--frames must be at least 1")
    if args.sensor not in SENSOR_NAMES:
        raise UserError(f"unknown --sensor {args.sensor!r}; known: {', '.join(SENSOR_NAMES)}")
    sensor = sensor_model(args.sensor)
    start = time.perf_counter()
    ds.generate_frame(args.seed + 1, 0, sensor)
    first = time.perf_counter() - start
    wall, cpu, points = [], [], []
    for index in range(args.frames):
        t0, c0 = time.perf_counter(), time.process_time()
        frame = ds.generate_frame(args.seed, index, sensor)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        points.append(len(frame.points))
    scene_s, cast_s, post_s = [], [], []
    for index in range(args.frames):
        rng = np.random.default_rng(np.random.SeedSequence([args.seed, index]))
        t0 = time.perf_counter()
        scene = sc.generate_scene(rng)
        t1 = time.perf_counter()
        ds.simulate_scan(scene, rng, sensor)
        t2 = time.perf_counter()
        origins, dirs, _ = ray_bundle(sensor, rng)
        ds.cast_scene(scene, origins, dirs, sensor.max_range_m)
        t3 = time.perf_counter()
        scene_s.append(t1 - t0)
        cast_s.append(t3 - t2)
        post_s.append(max(t2 - t1 - (t3 - t2), 0.0))
    med = float(np.median(wall))
    print(f"simulate: {args.frames} {args.sensor} frames of seed {args.seed}, single thread")
    print(f"  first call (numba compile or cache load), excluded: {first:.2f} s")
    print(f"  s/frame wall: median {med:.3f}  min {min(wall):.3f}  max {max(wall):.3f}")
    print(f"  s/frame cpu:  median {float(np.median(cpu)):.3f}")
    print(f"  stages (median): scene {float(np.median(scene_s)):.3f} s, rays + cast {float(np.median(cast_s)):.3f} s, "
          f"noise + labels + boxes {float(np.median(post_s)):.3f} s")
    print(f"  points/frame: median {int(np.median(points))}  min {min(points)}  max {max(points)}")
    if args.sensor == TARGET_SENSOR:
        verdict = "ok" if med <= TARGET_S_PER_FRAME else "SLOWER THAN TARGET"
        print(f"  target <= {TARGET_S_PER_FRAME} s/frame (HDL-64E): {verdict}")
    else:
        print(f"  target <= {TARGET_S_PER_FRAME} s per HDL-64E frame: not judged on {args.sensor}")
    return 0
