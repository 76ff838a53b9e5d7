"""Stage 1 speed: per-step medians over repeated runs, and pypatchworkpp ground removal side by side.

`pass3d_benchmark stage1 [--data FORMAT:PATH ...] [--repeat R] [--limit N] [--order ORDER] [--param KEY=VALUE ...]
[--json PATH]`. Without --data it times a built-in synthetic scan; --param times stage 1 with a parameter changed (read
as `pass3d_evaluate --param` reads it: `--param join_fragments=true`). `--order column|shuffled|all` also times the
same scans reordered column by column (one azimuth step, all lasers) or shuffled, and reports each order's median and
its ratio to the firing order measured in the same run, the ring source, and whether the proposals agree.
pypatchworkpp (Patchwork++) is an optional peer, not a dependency:
when it is importable its ground estimation runs on the same frames, and the time ratio is printed.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from pass3d_ros.core.stage1 import STEPS, Stage1Config, Stage1Result, propose, synthetic_scan, warm_up
from pass3d_ros.core.stage1.config import parse_params
from pass3d_ros.core.stage1.ring import LaserLines
from pass3d_ros.core.stream.lines import LineHolder
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.outputs import write_text_atomic
from pass3d_ros.data.spec import DatasetError, resolve_datasets
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import add_data, add_param, check_writable

PATCHWORK_HINT = "pip install pypatchworkpp"
REORDERINGS: tuple[str, ...] = ("column", "shuffled")
COLUMN_DEG = 0.17  # azimuth step of a column in the column-major reordering (about an HDL-64E's)


def reorder(points: np.ndarray, ring: np.ndarray, how: str, seed: int = 0) -> np.ndarray:
    """Permutation of a scan (rings known) into `how` order: "column" (azimuth column by column, all rings of
    one column top-down), "shuffled" (random), "firing" (identity)."""
    if how == "firing":
        return np.arange(len(points))
    if how == "shuffled":
        return np.random.default_rng(seed).permutation(len(points))
    if how == "column":
        az = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2.0 * np.pi)
        column = np.floor(az / np.deg2rad(COLUMN_DEG)).astype(np.int64)
        return np.lexsort((ring, column))
    raise ValueError(f"unknown order {how!r}")


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two per-point cluster labelings (-1 = none) are the same up to a permutation of labels."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if a.shape != b.shape or not np.array_equal(a < 0, b < 0):
        return False
    pairs = np.unique(np.stack([a[a >= 0], b[b >= 0]]), axis=1)
    return len(np.unique(pairs[0])) == pairs.shape[1] == len(np.unique(pairs[1]))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the stage1 suite."""
    add_data(parser, "dataset spec, repeatable; default: a built-in synthetic 64-ring scan", metavar="FORMAT:PATH",
             required=False)
    parser.add_argument("--repeat", type=int, default=20, metavar="R", help="runs per frame (default 20)")
    parser.add_argument("--limit", type=int, default=10, metavar="N", help="at most N frames per spec (default 10)")
    parser.add_argument("--no-patchwork", action="store_true", help="skip the pypatchworkpp comparison")
    parser.add_argument("--order", choices=("firing", *REORDERINGS, "all"), default="firing",
                        help="point order(s) to time besides firing order (default: firing only)")
    add_param(parser, "time stage 1 with a Stage1Config parameter changed, repeatable (e.g. join_fragments=true)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON here")


def load_frames(specs: list[str], limit: int) -> tuple[list[Frame], list[int]]:
    """Frames to time: the specs' first `limit` frames each, or the built-in synthetic scan; and each frame's stream
    (the position of its spec): laser lines are held within one."""
    if not specs:
        return [Frame("synthetic-builtin", synthetic_scan(points_per_ring=1800))], [0]
    frames: list[Frame] = []
    streams: list[int] = []
    for position, dataset in enumerate(resolve_datasets(specs)):
        for index, frame in enumerate(dataset.frames()):
            if index >= limit:
                break
            frames.append(frame)
            streams.append(position)
    return frames, streams


def time_stage1(frames: list[Frame], repeat: int, config: Stage1Config,
                streams: list[int] | None = None) -> dict[str, list[float]]:
    """Wall-clock milliseconds per step of every run (frames x repeats), after a warm-up, and the thread's
    CPU milliseconds per run ("cpu"): on a shared machine wall time also counts waiting for a core.

    The frames of one stream (`streams`: one number per frame, default all one) are timed as a live node sees them
    (pass3d_ros.core.stream.lines): every run of a frame is given the laser lines and the sensor's resolution held
    after the frames before it (none for a stream's first frame, which searches and reads on every run), never those
    read off the frame itself."""
    warm_up()
    times: dict[str, list[float]] = {step: [] for step in (*STEPS, "cpu")}
    holder = LineHolder()
    for frame, stream in zip(frames, streams or [0] * len(frames), strict=True):
        holder.follow(stream)
        given, scale = holder.lines(), holder.scale()
        first = propose(frame.points, frame.ring, config, given, scale=scale)
        holder.hold(given, first.lines)
        holder.hold_scale(first.sensor)
        for _ in range(repeat):
            cpu = time.thread_time()
            result = propose(frame.points, frame.ring, config, given, scale=scale)
            times["cpu"].append(1e3 * (time.thread_time() - cpu))
            for step in STEPS:
                times[step].append(result.timings_ms[step])
    return times


def time_orders(frames: list[Frame], repeat: int, config: Stage1Config, orders: tuple[str, ...]) -> dict:
    """Median total ms of stage 1 on the frames in firing order and reordered, measured in one run, with each
    order's ratio to firing order, ring sources and proposal agreement; printed.

    The orders take turns, one run each per round, and a ratio is the median over rounds of the order's time over
    the firing order's in the same round: this machine's speed drifts by up to 2x within seconds, and timing one
    order after the other turned that drift into the ratios. Each reordering is timed twice: "cold", every scan
    searched for its laser lines, and "stream", each scan given the lines held after the frame before it (the
    first frame: after the last) as a live node holds them: from a different scan, so they are checked, never read
    off the scan they label. With one frame both are the same scan's (said)."""
    rows = ("firing", *(f"{how} {kind}" for how in orders for kind in ("cold", "stream")))
    times: dict[str, list[float]] = {row: [] for row in rows}
    ratios: dict[str, list[float]] = {row: [] for row in rows}
    sources: dict[str, set[str]] = {row: set() for row in rows}
    agree = {row: 0 for row in rows}
    bases = [propose(frame.points, frame.ring, config) for frame in frames]
    carried = _stream_lines(frames, bases, config)
    for index, (frame, base) in enumerate(zip(frames, bases, strict=True)):
        runs = {}
        for row in rows:
            how, _, kind = row.partition(" ")
            order = reorder(frame.points, base.ring, how)
            pts = np.ascontiguousarray(frame.points[order])
            ring = None if frame.ring is None else frame.ring[order]
            lines = carried[index - 1] if kind == "stream" else None
            result = propose(pts, ring, config, lines)
            agree[row] += same_partition(result.cluster_id, base.cluster_id[order])
            sources[row].add(result.ring_source)
            runs[row] = (pts, ring, lines)
        for _ in range(repeat):
            this_round = {row: propose(pts, ring, config, lines).timings_ms["total"]
                          for row, (pts, ring, lines) in runs.items()}
            for row, ms in this_round.items():
                times[row].append(ms)
                ratios[row].append(ms / this_round["firing"])
    report = {}
    print(f"point order ({len(frames)} frame(s), median total ms; ratio to firing order: median over rounds of the "
          f"same round's times; stream: laser lines held after "
          f"{'the frame before' if len(frames) > 1 else 'the same scan (one frame)'}):")
    for row, values in times.items():
        median, ratio = statistics.median(values), statistics.median(ratios[row])
        report[row] = {"ms_median": median, "ratio": ratio, "ring_sources": sorted(sources[row]),
                       "same_proposals": agree[row], "frames": len(frames)}
        print(f"  {row:<15} {median:8.3f} ms  x{ratio:5.2f}  rings: {', '.join(sorted(sources[row]))}"
              f"  same proposals: {agree[row]}/{len(frames)}")
    return report


def _stream_lines(frames: list[Frame], results: list[Stage1Result], config: Stage1Config) -> list[LaserLines | None]:
    """The laser lines a live node holds after each frame, as the cluster node carries them: the frame's own (its
    firing-order result has none, so the frame shuffled is searched, given the lines held before it), else those
    held before."""
    holder = LineHolder()
    out: list[LaserLines | None] = []
    for frame, result in zip(frames, results, strict=True):
        if result.lines is None:
            given = holder.lines()
            shuffled = np.ascontiguousarray(frame.points[reorder(frame.points, result.ring, "shuffled")])
            holder.hold(given, propose(shuffled, None, config, given).lines)
        else:
            holder.hold(None, result.lines)
        out.append(holder.held)
    return out


def time_patchwork(frames: list[Frame], repeat: int, sensor_height: float) -> list[float] | None:
    """Milliseconds of every pypatchworkpp ground estimation (frames x repeats), None when it is absent."""
    try:
        import pypatchworkpp
    except ImportError:
        return None
    params = pypatchworkpp.Parameters()
    params.verbose = False
    params.sensor_height = sensor_height
    estimator = pypatchworkpp.patchworkpp(params)
    times = []
    for frame in frames:
        cloud = np.ascontiguousarray(frame.points, dtype=np.float64)
        estimator.estimateGround(cloud)
        for _ in range(repeat):
            start = time.perf_counter()
            estimator.estimateGround(cloud)
            times.append(1e3 * (time.perf_counter() - start))
    return times


def _times(ours: float, theirs: float) -> str:
    """"N.Nx faster than" or "N.Nx slower than": `ours` against `theirs` (both ms), the ratio always at least 1."""
    ours, theirs = max(ours, 1e-9), max(theirs, 1e-9)
    return f"{theirs / ours:.1f}x faster than" if ours <= theirs else f"{ours / theirs:.1f}x slower than"


def run(args: argparse.Namespace) -> int:
    """Time stage 1 (and pypatchworkpp) and print the medians."""
    if args.repeat < 1 or args.limit < 1:
        raise UserError("--repeat and --limit must be >= 1")
    if args.json:
        check_writable(args.json, folder=False, what="--json file")
    config = parse_params(args.param)
    frames, streams = load_frames(args.data, args.limit)
    if not frames:
        raise DatasetError(f"{', '.join(args.data)}: no frames to time")
    times = time_stage1(frames, args.repeat, config, streams)
    points = int(np.median([len(f.points) for f in frames]))
    medians = {step: statistics.median(values) for step, values in times.items()}
    print(f"stage 1: {len(frames)} frame(s), median {points} points, {args.repeat} run(s) each, median ms per step")
    for step in STEPS:
        print(f"  {step:<11} {medians[step]:7.3f}")
    print(f"  {'total CPU':<11} {medians['cpu']:7.3f}  (thread CPU time; wall time also counts waiting for a core)")
    report = {"frames": len(frames), "points_median": points, "repeat": args.repeat, "stage1_ms_median": medians,
              "config": config.to_dict()}
    if not args.no_patchwork:
        patchwork = time_patchwork(frames, args.repeat, config.seed_height)
        if patchwork is None:
            print(f"pypatchworkpp: absent (optional peer for a side-by-side ground timing: {PATCHWORK_HINT})")
            report["patchwork_ms_median"] = None
        else:
            pw = statistics.median(patchwork)
            print(f"pypatchworkpp ground estimation: {pw:.3f} ms median on the same frames")
            print(f"  stage 1's ground step ({medians['ground']:.3f} ms: the wait for its ground thread and the final "
                  f"test) is {_times(medians['ground'], pw)} Patchwork++'s; all of stage 1 takes "
                  f"{medians['total'] / pw:.2f}x Patchwork++'s ground time")
            report["patchwork_ms_median"] = pw
    if args.order != "firing":
        report["orders"] = time_orders(frames, args.repeat, config, REORDERINGS if args.order == "all" else
                                       (args.order,))
    if args.json:
        write_text_atomic(args.json, json.dumps(report, indent=2) + "\n")
    return 0
