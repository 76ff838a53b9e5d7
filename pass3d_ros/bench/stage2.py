"""Stage 2 speed: ms per frame for all of a frame's proposals in one batched forward pass."""

from __future__ import annotations

import argparse
import time
from typing import cast

import numpy as np
import torch

from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.pointnet2 import PointNet2Seg, count_parameters, make_config
from pass3d_ros.core.stage2.segmentation import (
    Segmenter,
    make_checkpoint,
    nearest_first,
    predict_probabilities,
    prepare_proposals,
)
from pass3d_ros.core.threads import limit_threads
from pass3d_ros.data.spec import DatasetError
from pass3d_ros.tools.cli import add_data, add_threads, add_weights, number, torch_device

# (length, width, height) of the constructed proposals: car, pedestrian, cyclist, background clutter.
_SHAPES = np.array([[4.2, 1.7, 1.6], [0.7, 0.6, 1.8], [1.8, 0.7, 1.7], [2.5, 1.5, 2.5]])


def constructed_frame(
    proposals: int, seed: int = 0, min_points: int = 50, max_points: int = 2000, background: int = 100_000
) -> tuple[np.ndarray, list[np.ndarray]]:
    """A frame of `background` scattered points plus `proposals` box-shaped clusters whose point counts are
    log-uniform in [min_points, max_points]; returns points (N, 4) and the member indices."""
    rng = np.random.default_rng(seed)
    chunks = [rng.uniform([-60, -60, -2, 0], [60, 60, 1, 1], (background, 4))]
    members, start = [], background
    for _ in range(proposals):
        count = int(np.exp(rng.uniform(np.log(min_points), np.log(max_points))))
        size = _SHAPES[rng.integers(len(_SHAPES))] * rng.uniform(0.8, 1.2, 3)
        local = rng.uniform(-size / 2, size / 2, (count, 3))
        yaw = rng.uniform(-np.pi, np.pi)
        c, s = np.cos(yaw), np.sin(yaw)
        centre = np.append(rng.uniform(5, 40) * np.array([np.cos(yaw * 3), np.sin(yaw * 3)]), -1.0)
        xyz = np.stack([local[:, 0] * c - local[:, 1] * s, local[:, 0] * s + local[:, 1] * c, local[:, 2]], 1) + centre
        chunks.append(np.column_stack([xyz, rng.uniform(0, 1, count)]))
        members.append(np.arange(start, start + count))
        start += count
    return np.concatenate(chunks).astype(np.float32), members


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark stage2`."""
    parser.add_argument("--config", choices=["lite", "paper"], default="lite", help="model configuration")
    add_weights(parser, "checkpoint to time instead of random weights", metavar=None)
    add_data(parser, "use stage-1 proposals of this data", required=False, repeatable=False)
    parser.add_argument("--frames", type=number(int, 1), default=3, help="frames of --data to time")
    parser.add_argument("--proposals", type=number(int, 1), default=30,
                        help="proposals per constructed frame (cap with --data)")
    parser.add_argument("--max-points", type=number(int, 1), default=2000, help="largest proposal (points)")
    parser.add_argument("--repeats", type=number(int, 1), default=15, help="timed frames (after 2 warm-up frames)")
    add_threads(parser, metavar=None, low=1)
    parser.add_argument("--device", type=torch_device, default="cpu", help="cpu or cuda")
    parser.add_argument("--seed", type=number(int, 0), default=0)


def _median_ms(values: list[float]) -> float:
    return float(np.median(values) * 1e3)


def _frames(args: argparse.Namespace) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """Frames to time: one constructed frame, or stage-1 proposals of the first --frames frames of --data."""
    if args.data is None:
        return [constructed_frame(args.proposals, args.seed, max_points=args.max_points)]
    from itertools import islice

    from pass3d_ros.core.pipeline import ScanPipeline
    from pass3d_ros.data.spec import open_dataset

    pipeline = ScanPipeline()
    out = []
    for frame in islice(open_dataset(args.data), args.frames):
        proposed = pipeline.propose(frame.points, frame.ring)
        out.append((proposed.points, proposed.nonempty_members()))
    if not out:
        raise DatasetError(f"{args.data}: no frames to time")
    return out


def run(args: argparse.Namespace) -> int:
    """Time Segmenter.segment and print medians (wall and process CPU time; the latter sums the threads)."""
    limits = limit_threads(args.threads)
    torch.manual_seed(args.seed)
    cap = max(args.proposals, 1)
    frames = _frames(args)  # before the network is built: a --data without frames is refused at once
    weights = args.weights or make_checkpoint(PointNet2Seg(make_config(args.config)))
    segmenter = cast(Segmenter, open_classifier(weights, device=args.device, max_proposals=cap))  # a network
    config = segmenter.config
    params = count_parameters(PointNet2Seg(config))
    for points, members in frames[:1] * 2:
        segmenter.segment(points, members)
    total, cpu, prep, net, proposals, member_points = [], [], [], [], [], []
    for r in range(args.repeats):
        points, members = frames[r % len(frames)]
        chosen = nearest_first(points, members, cap)
        kept = [members[i] for i in chosen]
        proposals.append(len(kept))
        member_points.append(sum(len(m) for m in kept))
        t0, c0 = time.perf_counter(), time.process_time()
        segmenter.segment(points, members)
        total.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        t0 = time.perf_counter()
        batch = prepare_proposals(points, kept, config, sampling=segmenter.sampling)
        t1 = time.perf_counter()
        predict_probabilities(segmenter.model, batch, segmenter.device)
        prep.append(t1 - t0)
        net.append(time.perf_counter() - t1)
    per_frame = _median_ms(total)
    cores = sum(cpu) / sum(total)
    mean_proposals = float(np.mean(proposals))
    print(
        f"stage2 config={config.name} points/sample={config.num_points} params={params} device={args.device} "
        f"threads={args.threads} proposals/frame={mean_proposals:.1f} member points/frame={np.mean(member_points):.0f}"
        f" frames={len(frames)} source={args.data or 'constructed'}"
    )
    print(f"  {limits.describe()}")
    print(
        f"  ms per frame (median of {args.repeats}): {per_frame:.1f}   ms per cluster: "
        f"{per_frame / max(mean_proposals, 1):.2f}   process CPU ms per frame: {_median_ms(cpu):.1f}"
    )
    print(f"  CPU / wall over the timed frames: {sum(cpu) * 1e3:.0f} / {sum(total) * 1e3:.0f} ms = {cores:.2f} cores "
          f"busy (--threads {args.threads})")
    print(
        f"  canonical+sampling {_median_ms(prep):.1f} ms, network {_median_ms(net):.1f} ms, "
        f"fastest..slowest frame {min(total) * 1e3:.1f}..{max(total) * 1e3:.1f} ms"
    )
    return 0
