"""Tracker speed: one stream's tracker and the vote on points per scan with N moving objects, median and 95th
percentile over the scans after the first 10 (which make the tracks).

`pass3d_benchmark tracks [--objects 60] [--scans 200] [--points 120000] [--seed 0] [--track KEY=VALUE]`: N objects (half
cars, half pedestrians) moving at constant velocities through 10 Hz scans, each scan's detections jittered by 0.1 m, in
a scan of `--points` points of which each object holds 300 (the rest background); per scan `track_scan` with the scan's
points (the footprints, the tracker's update, then the voted classes and track ids onto the objects and their points:
what a node or `pass3d_evaluate --tracking` runs; every object is seen, so no track waits to be held) is timed, and the
tracker's update alone (centres only). Issue target: <= 1 ms at 60 objects. Ids used: N when every object kept its
track.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.objects import FrameObjects, LabelledObject
from pass3d_ros.core.stage2.config import tracker_from_params
from pass3d_ros.core.stream.tracks import Tracker
from pass3d_ros.core.tracked_scan import track_scan
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import number

POINTS_PER_OBJECT = 300
UNTIMED_SCANS = 10  # the first scans make the tracks; the medians are over the scans after them


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the tracks suite."""
    parser.add_argument("--objects", type=int, default=60, metavar="N", help="objects a scan (default 60)")
    parser.add_argument("--scans", type=int, default=200, metavar="S", help="scans at 10 Hz (default 200)")
    parser.add_argument("--points", type=int, default=120_000, metavar="P",
                        help="points a scan (default 120000, a KITTI HDL-64E scan)")
    parser.add_argument("--seed", type=number(int, 0), default=0, help="random seed (default 0)")
    parser.add_argument("--track", action="append", default=[], metavar="KEY=VALUE",
                        help="a tracker setting as the segmentation node names it, repeatable "
                             "(track_fill_shapes=true: what the fill costs)")


def scan_objects(xy: np.ndarray, labels: np.ndarray, sizes: np.ndarray, owner: np.ndarray, points: np.ndarray
                 ) -> FrameObjects:
    """One scan's published objects: object k's box at `xy[k]`, its points where `owner == k` (moved into its box in
    `points`, the scan's x, y, z; the others stay where they are)."""
    inside = owner >= 0
    points[inside, :2] = xy[owner[inside]] + points[inside, 3:5] * sizes[owner[inside], :2]
    objects = [LabelledObject((float(x), float(y), -1.0), tuple(size), 0.0, int(label), 0.8, k)
               for k, ((x, y), label, size) in enumerate(zip(xy, labels, sizes, strict=True))]
    point_labels = np.where(owner >= 0, labels[np.maximum(owner, 0)], BACKGROUND).astype(np.uint8)
    return FrameObjects(point_labels, owner.astype(np.int32), objects)


def run(args: argparse.Namespace) -> int:
    """Time the tracker and the vote and print the numbers."""
    if args.objects < 1 or args.scans <= UNTIMED_SCANS or args.points < args.objects * POINTS_PER_OBJECT:
        raise UserError(f"tracks needs --objects >= 1, --scans >= {UNTIMED_SCANS + 1} and --points >= "
                        f"{POINTS_PER_OBJECT} x --objects")
    rng = np.random.default_rng(args.seed)
    start = rng.uniform(-40.0, 40.0, (args.objects, 2))
    labels = np.where(np.arange(args.objects) % 2 == 0, CAR, PEDESTRIAN)
    speed = np.where(labels == CAR, 8.0, 1.4)[:, None] * rng.normal(size=(args.objects, 2))
    sizes = np.where(labels[:, None] == CAR, [4.0, 1.7, 1.5], [0.6, 0.6, 1.7])
    owner = np.full(args.points, -1, np.int64)
    owner[rng.choice(args.points, args.objects * POINTS_PER_OBJECT, replace=False)] = np.repeat(
        np.arange(args.objects), POINTS_PER_OBJECT)
    points = np.column_stack([rng.uniform(-50.0, 50.0, (args.points, 2)), rng.uniform(-1.7, 0.5, args.points),
                              rng.uniform(-0.5, 0.5, (args.points, 2))])  # x, y, z and each point's place in its box
    settings = tracker_from_params(args.track)
    tracker, alone = Tracker(settings), Tracker(settings)
    took, took_alone, ids = [], [], set()
    for k in range(args.scans):
        xy = start + speed * 0.1 * k + rng.normal(0.0, 0.1, (args.objects, 2))
        objects = scan_objects(xy, labels, sizes, owner, points)
        began = time.perf_counter()
        out = track_scan(tracker, objects, 0.1 * k, points=points[:, :3])
        took.append(1e3 * (time.perf_counter() - began))
        centers = np.column_stack([xy, np.full(args.objects, -1.0)])
        began = time.perf_counter()
        alone.update(centers, sizes, labels, np.full(args.objects, 0.8), 0.1 * k)
        took_alone.append(1e3 * (time.perf_counter() - began))
        ids.update(o.track_id for o in out.tracked)
    both, update = np.array(took[UNTIMED_SCANS:]), np.array(took_alone[UNTIMED_SCANS:])  # the first make the tracks
    changed = f" ({', '.join(args.track)})" if args.track else ""
    print(f"{args.objects} objects a scan of {args.points} points, {args.scans} scans at 10 Hz{changed}:")
    print(f"  timed: the last {len(both)} of the {args.scans} scans (the first {UNTIMED_SCANS} make the tracks)")
    print(f"  tracker + vote on points (track_scan): median {np.median(both):.3f} ms, p95 "
          f"{np.percentile(both, 95):.3f} ms")
    print(f"  tracker update alone: median {np.median(update):.3f} ms, p95 {np.percentile(update, 95):.3f} ms")
    print(f"  ids used {len(ids)} for {args.objects} objects")
    return 0
