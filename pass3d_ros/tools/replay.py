"""`pass3d_replay`: publish a bag's clouds at recorded pace, or record live topics into a bag.

    pass3d_replay BAG [--rate R] [--loop] [--topic T] [--publish-topic P] [--qos sensor|reliable]
                  [--wait-subscribers N] [--wait-timeout S]
    pass3d_replay --record TOPIC[:TYPE] [--record ...] --out BAG [--duration S | --count N]
                  [--discovery-timeout S] [--qos sensor|reliable]

Replay publishes the stored CDR bytes unchanged (headers and stamps as recorded), paced by the bag's
times divided by R (R = 0: as fast as possible), once N subscribers (default 1) match or S s (default 10)
passed; a reliable replay waits for its subscribers' acknowledgements before it exits, and every replay ends with a
`pass3d_replay` status on /diagnostics saying how many it published. Both modes
start DDS with the shipped Fast DDS large-cloud profile unless FASTRTPS_DEFAULT_PROFILES_FILE is set (see
`pass3d_ros.ros.dds_profile`). Recording writes each message at its header stamp; with --count it stops after N
messages on the first topic, with --duration S s after the first message (or after the start when none came), and
says how many of the first topic's messages it got of how many their stamps imply (and of how many a replay on the
domain published), with a warning when some are missing. A topic's type comes from the ROS graph (waiting up to
--discovery-timeout s for it; a topic never seen is an error unless TOPIC:TYPE names the type). Like
`ros2 bag record`, each topic is subscribed with the QoS its publishers offer: best effort if any publisher is
best effort (or none is known yet), else reliable; --qos overrides. A recording that received nothing leaves
no bag and exits 1. A write that fails (a full disk) stops the recording: the messages recorded before it are kept
as a valid bag, one line says so, exit 2. --force replaces only a bag (never the working folder). Ctrl-C before
--count / --duration is reached keeps what was recorded (a complete bag) and exits 130 (SIGTERM: 143).
The in-process API is `pass3d_ros.ros.bag_replay.replay` and `pass3d_ros.ros.recorder.Recorder`; this module
parses the arguments, calls them and reports.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from pass3d_ros.data.bag import STORAGES, VERSIONS, check_bag_target
from pass3d_ros.data.outputs import out_path
from pass3d_ros.ros.bag_replay import announce, replay
from pass3d_ros.ros.dds_profile import apply_shipped_profile
from pass3d_ros.ros.qos import QOS_NAMES
from pass3d_ros.ros.recorder import (
    DISCOVERY_TIMEOUT_S,
    EmptyRecordingError,
    Recorder,
    discover_types,
    publishers_note,
    recording_qos,
)
from pass3d_ros.tools.cli import EXIT_SIGINT, Interrupted, check_bag_writable, number, run_tool

EXIT_EMPTY = 1  # a recording that received no message
WAIT_SUBSCRIBERS = 1  # a replay waits for this many subscribers (--wait-subscribers) ...
WAIT_TIMEOUT_S = 10.0  # ... for at most this long (--wait-timeout)


def build_parser() -> argparse.ArgumentParser:
    """The command line of `pass3d_replay`."""
    parser = argparse.ArgumentParser(
        prog="pass3d_replay", description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("bag", nargs="?", help="bag to replay")
    parser.add_argument("--rate", type=number(float, 0.0), default=1.0,
                        help="pace factor (default 1; 0 = as fast as possible)")
    parser.add_argument("--loop", action="store_true", help="replay until Ctrl-C")
    parser.add_argument("--topic", help="bag topic to replay (default: its only PointCloud2 topic)")
    parser.add_argument("--publish-topic", help="publish under this name instead")
    parser.add_argument("--qos", choices=QOS_NAMES,
                        help="QoS (default: sensor to replay; to record, what the publishers offer)")
    parser.add_argument("--wait-subscribers", type=int, default=WAIT_SUBSCRIBERS, metavar="N",
                        help=f"wait for N subscribers before publishing (default {WAIT_SUBSCRIBERS}; 0: don't wait)")
    parser.add_argument("--wait-timeout", type=number(float, 0.0), default=WAIT_TIMEOUT_S, metavar="S",
                        help=f"publish anyway after S s without them (default {WAIT_TIMEOUT_S:g})")
    parser.add_argument("--record", action="append", metavar="TOPIC[:TYPE]",
                        help="record this topic (repeatable); TYPE defaults to what the ROS graph says")
    parser.add_argument("--discovery-timeout", type=number(float, 0.0), default=DISCOVERY_TIMEOUT_S, metavar="S",
                        help=f"wait up to S s for --record topics to appear (default {DISCOVERY_TIMEOUT_S:g})")
    parser.add_argument("--out", help="bag to write when recording")
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--duration", type=number(float, 0.0, low_open=True),
                      help="record for S seconds from the first message (default: until Ctrl-C)")
    stop.add_argument("--count", type=int, help="record N messages of the first topic (default: until Ctrl-C)")
    parser.add_argument("--storage", choices=sorted(STORAGES), default="mcap", help="storage plugin (default mcap)")
    parser.add_argument("--rosbag-version", type=int, choices=VERSIONS, default=9, help="rosbag2 version (9 or 8)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out bag")
    return parser


def _record(args: argparse.Namespace, node: Any, executor: Any) -> int:
    out = out_path(args.out)
    check_bag_target(out, force=args.force)  # before waiting for the topics: an --out that cannot be used fails now
    check_bag_writable(out)
    topics = discover_types(node, args.record, args.discovery_timeout)
    qos = {topic: args.qos or recording_qos(node, topic) for topic in topics}
    recorder = Recorder(node, topics, args.out, storage=args.storage, version=args.rosbag_version,
                        force=args.force, qos=qos, limit=args.count)
    start = time.monotonic()
    listing = ", ".join(f"{t} ({m}, {'best effort' if qos[t] == 'sensor' else 'reliable'})" for t, m in topics.items())
    print(f"recording {listing} into {args.out}", file=sys.stderr)
    status = 0
    try:
        recorder.record_until(executor, duration=args.duration, count=args.count)
    except KeyboardInterrupt as exc:  # keep what was recorded, like `ros2 bag record`
        if args.duration is not None or args.count is not None:
            status = exc.status if isinstance(exc, Interrupted) else EXIT_SIGINT
    seconds = time.monotonic() - start
    try:
        path = recorder.close()
    except EmptyRecordingError:
        print(f"pass3d_replay: error: recorded nothing in {seconds:.1f} s ({publishers_note(node, topics)}); "
              f"{args.out} not written", file=sys.stderr)
        return status or EXIT_EMPTY
    counts = ", ".join(f"{topic}: {n}" for topic, n in recorder.counts.items())
    stopped = ", interrupted before the stop condition" if status else ""
    print(f"recorded {sum(recorder.counts.values())} messages in {seconds:.1f} s to {path} ({counts}){stopped}")
    report = recorder.coverage()
    if report.got:
        first = next(iter(recorder.topics))
        known = f"; pass3d_replay published {report.published}" if report.published is not None else ""
        every = f"stamps every {1e3 * report.period_s:.0f} ms" if report.period_s else "one stamp"
        print(f"{first}: got {report.got} of {report.expected} messages the stream implies ({every}{known})")
        if report.missing:
            print(f"pass3d_replay: warning: {report.missing} of {report.expected} messages on {first} never arrived "
                  "(missing stamps; the nodes' /diagnostics count their drops and input gaps)", file=sys.stderr)
    silent = [topic for topic, n in recorder.counts.items() if n == 0]
    if silent:
        print(f"pass3d_replay: warning: no message on {', '.join(silent)}", file=sys.stderr)
    return status


def _replay(args: argparse.Namespace, node: Any) -> int:
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:  # Ctrl-C / SIGTERM end a replay cleanly, with its summary
        stats = replay(args.bag, node, topic=args.topic, publish_topic=args.publish_topic, rate=args.rate,
                       loop=args.loop, qos=args.qos or "sensor", min_subscribers=args.wait_subscribers,
                       wait_timeout=args.wait_timeout, stop=stop)
        announce(node, stats, args.loop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(f"published {stats.published} messages on {stats.topic} in {stats.seconds:.2f} s "
          f"({stats.rate_hz:.2f} Hz, {stats.passes} full pass(es), rate x{args.rate:g})"
          + (", stopped by Ctrl-C" if stop.is_set() else ""))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Console entry point: exit 0 on success, 1 when a recording got nothing, 2 on a user error, 130 / 143 when
    interrupted (a recording with --count / --duration keeps what it got)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.record:
        if args.out is None:
            parser.error("--record needs --out BAG")
        if args.bag:
            parser.error("give either a BAG to replay or --record topics, not both")
        if (args.count is not None and args.count < 1) or (args.duration is not None and args.duration <= 0):
            parser.error("--count and --duration must be positive")
        if args.discovery_timeout < 0:
            parser.error("--discovery-timeout must be >= 0")
    elif not args.bag:
        parser.error("give a BAG to replay or --record TOPIC --out BAG")
    if args.wait_subscribers < 0 or args.wait_timeout < 0:
        parser.error("--wait-subscribers and --wait-timeout must be >= 0")
    return run_tool("pass3d_replay", lambda: _run(args))


def _run(args: argparse.Namespace) -> int:
    profile_note = apply_shipped_profile()
    if profile_note:
        print(f"pass3d_replay: {profile_note}", file=sys.stderr)
    rclpy.init(args=None, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("pass3d_replay")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        return _record(args, node, executor) if args.record else _replay(args, node)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
