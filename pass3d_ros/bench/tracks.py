"""Tracker speed: one stream's Tracker.update per scan with N moving objects, median and 95th percentile.

`pass3d_benchmark tracks [--objects 60] [--scans 200] [--seed 0]`: N objects (half cars, half pedestrians) moving at
constant velocities through 10 Hz scans, each scan's detections jittered by 0.1 m; the tracker's cost per scan (issue
target: <= 1 ms at 60 objects) and how many ids it kept (N when every object kept its track).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pass3d_ros.classes import CAR, PEDESTRIAN
from pass3d_ros.core.stream.tracks import Tracker


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the tracks suite."""
    parser.add_argument("--objects", type=int, default=60, metavar="N", help="objects a scan (default 60)")
    parser.add_argument("--scans", type=int, default=200, metavar="S", help="scans at 10 Hz (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")


def run(args: argparse.Namespace) -> int:
    """Time the tracker and print the numbers."""
    rng = np.random.default_rng(args.seed)
    start = rng.uniform(-40.0, 40.0, (args.objects, 2))
    labels = np.where(np.arange(args.objects) % 2 == 0, CAR, PEDESTRIAN)
    speed = np.where(labels == CAR, 8.0, 1.4)[:, None] * rng.normal(size=(args.objects, 2))
    sizes = np.where(labels[:, None] == CAR, [4.0, 1.7, 1.5], [0.6, 0.6, 1.7])
    tracker = Tracker()
    took, ids = [], set()
    for k in range(args.scans):
        xy = start + speed * 0.1 * k + rng.normal(0.0, 0.1, (args.objects, 2))
        centers = np.column_stack([xy, np.full(args.objects, -1.0)])
        began = time.perf_counter()
        out = tracker.update(centers, sizes, labels, np.full(args.objects, 0.8), 0.1 * k)
        took.append(1e3 * (time.perf_counter() - began))
        ids.update(o.track_id for o in out)
    took_ms = np.array(took[10:])  # the first scans make the tracks
    print(f"tracker, {args.objects} objects a scan, {args.scans} scans at 10 Hz: median {np.median(took_ms):.3f} ms, "
          f"p95 {np.percentile(took_ms, 95):.3f} ms; ids used {len(ids)} for {args.objects} objects")
    return 0
