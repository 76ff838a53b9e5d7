"""Live-path throughput and memory: a synthetic drive replayed at 10 Hz x rate through both live nodes.

`pass3d_benchmark live [--frames N] [--hz F | --rate R] [--seconds S] [--soak] [--warmup S] [--load N]
                       [--layout one-process|in-memory|two-process] [--overlap] [--process] [--tracking] [--drive]
                       [--input-qos auto|sensor|reliable]
                       [--classifier network|size_rules] [--weights W] [--threads N] [--seed K] [--json PATH]`

Sustain test: N synthetic HDL-64E frames (about 120k points each) are written to a temporary bag and
played back to back, stamps shifted each pass, for about --seconds (default 60) at 10 Hz x --rate through
cluster_proposal_node and segmentation_node running in this process (pass3d_ros.evaluation.live.run_live,
free-running: a node that is still busy drops the stale frame and counts it). Printed: frames in / out,
dropped, output rate, latency median / p95, per-stage medians, each node's counters.
--soak: the same for --seconds (default 600), watching this process's resident memory (VmRSS from
/proc/self/status, sampled every second): after the warm-up (default the first 30 s) and at the end
(medians over 10 s, or over half the time after the warm-up when that is shorter), the growth between them in %,
and the slope of a straight line fitted to the samples after the warm-up. The memory figures are printed on every
run; only --soak changes the default duration.
Runs of two minutes or more also print one row per minute of input: frames in / out, median latency,
and how busy the CPUs were, in all and by this process (other work on a shared machine slows the nodes).

Conditions: --hz sets the input rate (default 10; --rate R is the same as --hz 10R, R x the bag's pace);
--load N starts N processes that each keep one CPU busy for the whole run (a reproducible busy robot) and
stops them at the end; --layout picks where the nodes run (see pass3d_ros.evaluation.live: `one-process` with
a PointCloud2 between the nodes, `in-memory` hand-off, `two-process` with the nodes in a child `pass3d_pipeline`);
--input-qos sets the cluster node's input QoS (the replayer publishes reliable; `sensor` = best effort).
Printed beside the live figures: each node's step medians from its /diagnostics counters (where the time
goes: slot wait, decode, compute, encode, publish), and the offline compute time (stage 1 + stage 2 on the
same frames, in this process, under the same load, before and after the live run) with the ratio live latency / compute.

Everything shares the machine: the replaying evaluator (decoding inputs and outputs to match them) runs
in this process beside both nodes, so on a small machine it takes CPU time the nodes would otherwise get.
The target is the paper's: keep up with a 10 Hz sensor with at most 100 ms latency.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pass3d_ros.core.threads import limit_threads
from pass3d_ros.data.outputs import write_text_atomic
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.tools.cli import add_threads, add_weights, check_writable, number

if TYPE_CHECKING:
    from pass3d_ros.core.stage2 import Classifier
    from pass3d_ros.evaluation.live import LiveResult

SENSOR_HZ = 10.0
TARGET_LATENCY_MS = 100.0
SUSTAIN_SECONDS = 60.0
SOAK_SECONDS = 600.0
WINDOW_S = 60.0  # runs of at least two windows print one row per window
MEMORY_SPAN_S = 10.0  # the memory "after warm-up" and "at the end" are medians over this long


def rss_mib(status: Path = Path("/proc/self/status")) -> float | None:
    """Resident memory of this process in MiB (VmRSS), None where /proc is not there."""
    try:
        for line in status.read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def cpu_times(stat: Path = Path("/proc/stat")) -> list[int] | None:
    """The machine's cumulative CPU jiffies (user nice system idle iowait irq softirq steal), None without /proc."""
    try:
        fields = stat.read_text().splitlines()[0].split()
    except (OSError, IndexError):
        return None
    return [int(v) for v in fields[1:9]] if fields and fields[0] == "cpu" else None


def cpu_share(before: list[int] | None, after: list[int] | None) -> dict | None:
    """Busy and steal shares (%) of all CPUs between two cpu_times(); steal = time a hypervisor gave the
    CPUs to someone else, the contention a shared machine hides from `top`."""
    if before is None or after is None:
        return None
    delta = [b - a for a, b in zip(before, after, strict=True)]
    total = sum(delta)
    if total <= 0:
        return None
    idle = delta[3] + delta[4]
    return {"busy_pct": 100.0 * (total - idle - delta[7]) / total, "steal_pct": 100.0 * delta[7] / total}


class RssSampler:
    """Samples rss_mib() every `period` seconds in a daemon thread: (seconds since start, MiB) pairs in
    `samples`, and (seconds, machine cpu_times(), this process's CPU seconds) in `cpu`."""

    def __init__(self, period: float = 1.0) -> None:
        self.period = period
        self.samples: list[tuple[float, float]] = []
        self.cpu: list[tuple[float, list[int] | None, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pass3d-rss", daemon=True)
        self._start = 0.0

    def __enter__(self) -> RssSampler:
        self._start = time.perf_counter()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()

    def _sample(self) -> None:
        now = time.perf_counter() - self._start
        value = rss_mib()
        if value is not None:
            self.samples.append((now, value))
        self.cpu.append((now, cpu_times(), time.process_time()))

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.period)


def memory_report(samples: list[tuple[float, float]], warmup_s: float, span_s: float = MEMORY_SPAN_S) -> dict:
    """Resident memory after the warm-up and at the end, each the median of the samples over `span_s`, or over half
    the time after the warm-up when that is shorter, so the two never read the same samples (RSS swings by tens of
    MiB as large arrays come and go), growth between them in %, the peak, and the slope (MiB / min) of a straight
    line fitted to every sample after the warm-up."""
    if not samples:
        return {"available": False}
    after = [(t, m) for t, m in samples if t >= warmup_s]
    peak = float(max(m for _, m in samples))
    if len(after) < 2:
        return {"available": True, "warmup_s": warmup_s, "after_warmup_mib": None, "end_mib": samples[-1][1],
                "growth_pct": None, "peak_mib": peak, "slope_mib_per_min": None}
    t = np.array([s[0] for s in after])
    m = np.array([s[1] for s in after])
    span = min(span_s, float(t[-1] - t[0]) / 2.0)
    first = float(np.median(m[t <= t[0] + span]))
    last = float(np.median(m[t >= t[-1] - span]))
    slope = float(np.polyfit(t, m, 1)[0]) * 60.0 if np.ptp(t) > 0 else None
    return {
        "available": True,
        "warmup_s": warmup_s,
        "after_warmup_mib": first,
        "end_mib": last,
        "growth_pct": float(100.0 * (last - first) / first),
        "peak_mib": peak,
        "slope_mib_per_min": slope,
        "window_s": float(t[-1] - t[0]),
        "span_s": span,
    }


def window_rows(result: LiveResult, sampler: RssSampler, input_hz: float, window_s: float) -> list[dict]:
    """Per `window_s` of input time: frames in and out, median latency, machine busy % and this process's
    share. Frames fall in a window by publish time (replay index / input_hz); CPU samples are aligned by
    assuming publishing began result.wall_s before the sampler stopped (off by the teardown, under a second)."""
    if not sampler.cpu or input_hz <= 0:
        return []
    offset = max(sampler.cpu[-1][0] - result.wall_s, 0.0)
    count = max(1, math.ceil(result.frames_in / input_hz / window_s))
    rows = []
    for w in range(count):
        lo, hi = w * window_s, (w + 1) * window_s
        frames = [f for f in result.frames if lo <= f.index / input_hz < hi]
        inside = [c for c in sampler.cpu if lo <= c[0] - offset <= hi]
        cpu = cpu_share(inside[0][1], inside[-1][1]) if len(inside) > 1 else None
        span = inside[-1][0] - inside[0][0] if len(inside) > 1 else 0.0
        own = 100.0 * (inside[-1][2] - inside[0][2]) / (span * (os.cpu_count() or 1)) if span > 0 else None
        total = result.frames_in + result.skipped
        sent = max(min(math.ceil(hi * input_hz), total) - math.ceil(lo * input_hz), 0)
        rows.append({
            "from_s": lo, "frames_in": sent, "frames_out": len(frames),
            "latency_median_ms": float(np.median([f.latency_ms for f in frames])) if frames else None,
            "busy_pct": None if cpu is None else cpu["busy_pct"], "this_process_pct": own,
        })
    return rows


class CpuLoad:
    """N child processes that each spin one CPU (`while True: pass`) until the context ends."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.children: list[subprocess.Popen] = []

    def __enter__(self) -> CpuLoad:
        for _ in range(self.count):
            self.children.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
        return self

    def __exit__(self, *exc: object) -> None:
        for child in self.children:
            child.terminate()
        for child in self.children:
            try:
                child.wait(timeout=5)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()


def offline_compute_ms(bag: Path, classifier: Classifier, limit: int) -> dict | None:
    """Median / p95 ms of stage 1 + stage 2 (the nodes' compute through the one door, no codec, no ROS) over the
    bag's frames, each run twice (the first pass warms caches), at most `limit` frames."""
    from pass3d_ros.core.pipeline import ScanPipeline
    from pass3d_ros.core.stage1 import warm_up
    from pass3d_ros.data.bag import read_bag

    warm_up()
    classifier.warm_up()
    frames = [f for _, f in zip(range(limit), read_bag(bag), strict=False)]
    pipeline = ScanPipeline(classifier=classifier)
    times, stage1 = [], []
    for _ in range(2):
        for frame in frames:
            started = time.perf_counter()
            proposed = pipeline.propose(frame.points, frame.ring)
            middle = time.perf_counter()
            pipeline.segment(proposed)
            times.append(1e3 * (time.perf_counter() - started))
            stage1.append(1e3 * (middle - started))
    if not times:
        return None
    half = times[len(times) // 2:]
    return {"median": float(np.median(half)), "p95": float(np.percentile(half, 95)),
            "stage1_median": float(np.median(stage1[len(stage1) // 2:])), "frames": len(frames)}


def bracket(before: dict | None, after: dict | None) -> dict | None:
    """Offline compute measured before and after the live run: the means of their figures, and both medians
    (other work on the machine may change between them)."""
    if before is None or after is None:
        return before or after
    merged = {key: (before[key] + after[key]) / 2.0 for key in ("median", "p95", "stage1_median")}
    return {**merged, "frames": before["frames"], "median_before": before["median"], "median_after": after["median"]}


def _pct(value: float | None) -> str:
    return "  n/a" if value is None else f"{value:5.0f}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pass3d_benchmark live`."""
    parser.add_argument("--frames", type=int, default=10, metavar="N", help="synthetic frames in the bag (default 10)")
    parser.add_argument("--seed", type=number(int, 0), default=7, help="synthetic scene seed (default 7)")
    parser.add_argument("--rate", type=number(float, 0.0, low_open=True), default=1.0, metavar="R",
                        help="play at 10 Hz x R (default 1)")
    parser.add_argument("--hz", type=number(float, 0.0, low_open=True), metavar="F",
                        help="input rate in Hz (overrides --rate; default 10)")
    parser.add_argument("--load", type=int, default=0, metavar="N",
                        help="N competing processes, each spinning one CPU during the run (default 0)")
    parser.add_argument("--layout", choices=("one-process", "in-memory", "two-process"), default="in-memory",
                        help="where the nodes run (default in-memory: the pass3d_pipeline layout)")
    parser.add_argument("--tracking", action="store_true",
                        help="segmentation_node's `tracking`: the tracker and its class vote on every scan")
    parser.add_argument("--drive", action="store_true",
                        help="the frames are one synthetic drive (synthetic:drive=N: objects persist from scan to "
                        "scan, as tracks expect) instead of N unrelated scenes")
    parser.add_argument("--overlap", action="store_true",
                        help="segmentation_node's `overlap`: stage 2 on its own thread beside the next scan's stage 1 "
                             "(in-memory and two-process layouts)")
    parser.add_argument("--process", action="store_true",
                        help="segmentation_node's `process`: the classifier in a child process (its CPU counts as "
                             "another process's below)")
    parser.add_argument("--input-qos", choices=("auto", "sensor", "reliable"),
                        help="the cluster node's input QoS (default: its parameter default, auto)")
    parser.add_argument("--seconds", type=number(float, 0.0, low_open=True), metavar="S",
                        help=f"replay length (default {SUSTAIN_SECONDS:.0f}; {SOAK_SECONDS:.0f} with --soak)")
    parser.add_argument("--soak", action="store_true", help="long run watching resident memory")
    parser.add_argument("--warmup", type=number(float, 0.0), default=30.0, metavar="S",
                        help="memory reference taken this long after start (default 30; a quarter of a shorter run)")
    parser.add_argument("--classifier", choices=("network", "size_rules"), help="stage-2 classifier (default network)")
    add_weights(parser)
    add_threads(parser)
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the numbers as JSON here")


def _line(stats: dict | None) -> str:
    if stats is None:
        return "n/a"
    return f"median {stats['median']:.1f} ms, p95 {stats['p95']:.1f} ms, max {stats['max']:.1f} ms"


def run(args: argparse.Namespace) -> int:
    """Run the replay and print what it measured; UserError on bad options or weights, or a live run that could not
    start."""
    from pass3d_ros.core.stage2 import open_classifier

    seconds = args.seconds if args.seconds is not None else (SOAK_SECONDS if args.soak else SUSTAIN_SECONDS)
    if args.hz is not None:
        args.rate = args.hz / SENSOR_HZ
    if args.frames < 1 or seconds <= 0 or args.rate <= 0 or args.threads < 1 or args.load < 0:
        raise UserError("--frames, --seconds, --rate, --hz and --threads must be positive, --load >= 0")
    if args.json:
        check_writable(args.json, folder=False, what="--json file")
    classifier = open_classifier(args.weights, args.classifier)
    kind, weights = classifier.kind, classifier.weights
    from pass3d_ros.data.bag_convert import convert
    from pass3d_ros.evaluation.live import run_live
    from pass3d_ros.evaluation.report import score

    limit_threads(args.threads)
    warmup = args.warmup if args.warmup < seconds else seconds / 4.0
    bag_seconds = args.frames / SENSOR_HZ / args.rate
    repeat = max(1, math.ceil(seconds / bag_seconds))
    spec = f"synthetic:{'drive' if args.drive else 'frames'}={args.frames},seed={args.seed}"
    print(f"classifier {kind}{f' ({weights})' if weights else ''}, torch threads {args.threads}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, layout {args.layout}"
          f"{' (stage 2 overlapping stage 1)' if args.overlap else ''}"
          f"{' (classifier in a child process)' if args.process else ''}"
          f"{', tracking on' if args.tracking else ''}, "
          f"competing CPU hogs {args.load}", flush=True)
    cluster_parameters = {"input_qos": args.input_qos} if args.input_qos else {}
    with tempfile.TemporaryDirectory(prefix="pass3d_bench_live_") as workdir:
        bag = Path(workdir) / "drive"
        convert([spec], bag, progress=False, log=lambda _: None)
        print(f"{spec} -> {repeat} pass(es) = {repeat * args.frames} frames at {SENSOR_HZ * args.rate:g} Hz "
              f"(~{repeat * bag_seconds:.0f} s)", flush=True)
        with CpuLoad(args.load):
            before = offline_compute_ms(bag, classifier, limit=args.frames)
            cpu_before, own_before, wall_before = cpu_times(), time.process_time(), time.perf_counter()
            with RssSampler() as sampler:
                result = run_live(
                    bag, lockstep=False, rate=args.rate, keep_labels=False, repeat=repeat, timeout_s=30.0,
                    node_parameters={"segmentation_node": {"classifier": kind, "weights": weights or "",
                                                           "overlap": args.overlap, "process": args.process,
                                                           "tracking": args.tracking},
                                     "cluster_proposal_node": cluster_parameters},
                    log_level="warn", layout=args.layout,
                )
            cpu_after, own_after, wall_after = cpu_times(), time.process_time(), time.perf_counter()
            compute = bracket(before, offline_compute_ms(bag, classifier, limit=args.frames))
    cpu = cpu_share(cpu_before, cpu_after)
    if cpu is not None:
        own = (own_after - own_before) / ((wall_after - wall_before) * (os.cpu_count() or 1))
        cpu["this_process_pct"] = 100.0 * own
    scores = score(result)
    live = scores["live"]
    memory = memory_report(sampler.samples, warmup)
    latency = live["latency_ms"]
    met = (live["output_hz"] or 0.0) >= 0.95 * SENSOR_HZ * args.rate and result.dropped == 0 and \
        latency is not None and latency["median"] <= TARGET_LATENCY_MS
    ratio = latency["median"] / compute["median"] if compute and latency else None
    print(f"frames in {result.frames_in}, out {result.frames_out}, dropped {result.dropped} "
          f"({100.0 * result.dropped / max(result.frames_in, 1):.1f} %), in {live['wall_s']:.1f} s")
    print(f"output rate {live['output_hz'] or 0.0:.2f} Hz (input {SENSOR_HZ * args.rate:g} Hz)")
    print(f"latency publish -> /pass3d/labeled: {_line(latency)}")
    print(f"stage 1 (publish -> /pass3d/proposals): {_line(live['stage_ms']['stage1'])}")
    print(f"stage 2 (/pass3d/proposals -> /pass3d/labeled): {_line(live['stage_ms']['stage2'])}")
    for node, counters in live["nodes"].items():
        print(f"{node}: " + ", ".join(f"{k} {v}" for k, v in counters.items()))
    for node, stats in result.node_stats.items():
        steps = ", ".join(f"{k[:-7]} {v:.1f}" for k, v in stats.items() if k.endswith("_p50_ms") and v is not None
                          and not k.startswith("latency"))
        gaps = f"input gaps {stats.get('input_gaps') or 0:.0f} ({stats.get('frames_missed_upstream') or 0:.0f} frames)"
        print(f"{node} step medians ms: {steps or 'n/a'}; {gaps}")
    if compute is not None:
        print(f"offline compute (stage 1 + stage 2, same frames, same load, before / after the live run): "
              f"median {compute.get('median_before', compute['median']):.1f} / "
              f"{compute.get('median_after', compute['median']):.1f}, mean {compute['median']:.1f} ms "
              f"(stage 1 {compute['stage1_median']:.1f}), p95 {compute['p95']:.1f} ms; live median latency / "
              f"compute = {'n/a' if ratio is None else f'{ratio:.2f}'}")
        bound = min(SENSOR_HZ * args.rate, 1e3 / compute["median"])
        print(f"output rate / what the offline compute allows ({bound:.2f} Hz) = "
              f"{(live['output_hz'] or 0) / bound:.2f}")
    if memory["available"] and memory["after_warmup_mib"] is not None:
        print(f"resident memory (medians over {memory['span_s']:.1f} s): {memory['after_warmup_mib']:.1f} MiB after "
              f"{warmup:.1f} s, {memory['end_mib']:.1f} MiB at the end ({memory['growth_pct']:+.2f} % over "
              f"{memory['window_s']:.0f} s; fitted {memory['slope_mib_per_min']:+.2f} MiB/min), "
              f"peak {memory['peak_mib']:.1f} MiB")
    else:
        print("resident memory: not available (no /proc/self/status, or the run was too short)")
    if cpu is not None:
        others = max(cpu["busy_pct"] - cpu["this_process_pct"], 0.0)
        print(f"CPUs during the run: {cpu['busy_pct']:.0f} % busy of {os.cpu_count()}: this process "
              f"{cpu['this_process_pct']:.0f} %, other processes {others:.0f} % (it slows the nodes)")
    windows = window_rows(result, sampler, SENSOR_HZ * args.rate, WINDOW_S) if seconds >= 2 * WINDOW_S else []
    if windows:
        print(f"per {WINDOW_S:.0f} s of input (busy: all CPUs; ours: this process):")
        print(f"  {'from s':>6} {'in':>5} {'out':>5} {'lat ms':>7} {'busy %':>6} {'ours %':>6}")
        for row in windows:
            lat = row["latency_median_ms"]
            print(f"  {row['from_s']:>6.0f} {row['frames_in']:>5} {row['frames_out']:>5} "
                  f"{'n/a' if lat is None else f'{lat:.0f}':>7} {_pct(row['busy_pct']):>6} "
                  f"{_pct(row['this_process_pct']):>6}")
    print(f"target ({SENSOR_HZ * args.rate:g} Hz out, no drops, median latency <= {TARGET_LATENCY_MS:.0f} ms): "
          + ("met" if met else "NOT met"))
    if args.json:
        report = {"classifier": {"kind": kind, "weights": weights, "threads": args.threads}, "data": spec,
                  "repeat": repeat, "seconds": seconds, "rate": args.rate, "hz": SENSOR_HZ * args.rate,
                  "layout": args.layout, "load": args.load, "input_qos": args.input_qos,
                  "node_stats": result.node_stats, "offline_compute_ms": compute, "latency_to_compute": ratio,
                  "compute_bound_hz": min(SENSOR_HZ * args.rate, 1e3 / compute["median"]) if compute else None,
                  "live": live, "memory": memory, "cpu": cpu,
                  "rss_samples": [[round(t, 2), round(m, 2)] for t, m in sampler.samples],
                  "windows": windows,
                  "target_met": met}
        write_text_atomic(args.json, json.dumps(report, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
