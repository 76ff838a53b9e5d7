"""`pass3d_replay`: publish a bag's clouds at recorded pace, or record live topics into a bag.

    pass3d_replay BAG [--rate R] [--loop] [--topic T] [--publish-topic P] [--qos sensor|reliable]
                  [--wait-subscribers N] [--wait-timeout S]
    pass3d_replay --record TOPIC[:TYPE] [--record ...] --out BAG [--duration S | --count N]
                  [--discovery-timeout S] [--qos sensor|reliable]

Replay publishes the stored CDR bytes unchanged (headers and stamps as recorded), paced by the bag's
times divided by R (R = 0: as fast as possible), once N subscribers (default 1) match or S s (default 10)
passed. Both modes start DDS with the shipped Fast DDS large-cloud profile unless FASTRTPS_DEFAULT_PROFILES_FILE
is set (see `pass3d_ros.ros.dds_profile`). Recording writes each message at its header stamp; with
--count it stops after N messages on the first topic. A topic's type comes from the ROS graph (waiting up to
--discovery-timeout s for it; a topic never seen is an error unless TOPIC:TYPE names the type). Like
`ros2 bag record`, each topic is subscribed with the QoS its publishers offer: best effort if any publisher is
best effort (or none is known yet), else reliable; --qos overrides. A recording that received nothing leaves
no bag and exits 1. A write that fails (a full disk) stops the recording: the messages recorded before it are kept
as a valid bag, one line says so, exit 2. --force replaces only a bag (never the working folder). Ctrl-C before
--count / --duration is reached keeps what was recorded (a complete bag) and exits 130 (SIGTERM: 143).
`replay()` and `Recorder` are the in-process API.
"""

from __future__ import annotations

import argparse
import importlib
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from pass3d_ros.core.stage1.config import ConfigError
from pass3d_ros.data.bag import (
    STORAGES,
    TYPESTORE,
    VERSIONS,
    BagError,
    BagWriter,
    iter_raw,
    message_stamp_ns,
    select_topic,
)
from pass3d_ros.data.outputs import out_path
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE
from pass3d_ros.ros.dds_profile import apply_shipped_profile
from pass3d_ros.ros.qos import QOS_NAMES, offered_qos, qos_profile
from pass3d_ros.tools.cli import EXIT_SIGINT, Interrupted, error_text, number, run_tool

EXIT_EMPTY = 1  # a recording that received no message
DISCOVERY_TIMEOUT_S = 10.0
WAIT_SUBSCRIBERS = 1  # a replay waits for this many subscribers (--wait-subscribers) ...
WAIT_TIMEOUT_S = 10.0  # ... for at most this long (--wait-timeout)


def ros_message_class(msgtype: str) -> type:
    """The rclpy message class of `pkg/msg/Name`."""
    try:
        package, kind, name = msgtype.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise BagError(f"message type {msgtype!r} is not available to rclpy here") from None


@dataclass
class ReplayStats:
    """What `replay` published."""

    topic: str
    published: int = 0
    passes: int = 0
    seconds: float = 0.0

    @property
    def rate_hz(self) -> float:
        """Messages per second of wall time."""
        return self.published / self.seconds if self.seconds > 0 else 0.0


def wait_for_subscribers(publisher: Any, count: int, timeout: float, stop: threading.Event) -> bool:
    """Poll until `publisher` has `count` matched subscribers; False on timeout or stop."""
    deadline = time.monotonic() + timeout
    while publisher.get_subscription_count() < count:
        if time.monotonic() >= deadline or stop.wait(0.02):
            return False
    return True


def _wait_for_subscribers(node: Any, publisher: Any, topic: str, count: int, timeout: float,
                          stop: threading.Event) -> None:
    """`wait_for_subscribers`, with a line before and one after that say what it waits for and what it got."""
    logger = node.get_logger()
    logger.info(f"{topic}: waiting up to {timeout:g} s for {count} subscriber(s) before publishing")
    started = time.monotonic()
    if wait_for_subscribers(publisher, count, timeout, stop):
        logger.info(f"{topic}: {publisher.get_subscription_count()} subscriber(s) after "
                    f"{time.monotonic() - started:.1f} s; publishing")
    elif not stop.is_set():
        logger.warning(f"{topic}: {publisher.get_subscription_count()} of {count} subscriber(s) after {timeout:g} s; "
                       "publishing anyway (is the subscriber running, on this ROS_DOMAIN_ID?)")


def replay(
    bag: str | Path,
    node: Any,
    *,
    topic: str | None = None,
    publish_topic: str | None = None,
    rate: float = 1.0,
    loop: bool = False,
    qos: str = "sensor",
    depth: int = 5,
    min_subscribers: int = 0,
    wait_timeout: float = 10.0,
    settle: float = 0.25,
    linger: float = 0.2,
    stop: threading.Event | None = None,
    on_publish: Callable[[int, int], None] | None = None,
) -> ReplayStats:
    """Publish `topic` of `bag` (default: its only PointCloud2 topic) from `node` at bag pace / rate; blocks.

    Waits for `min_subscribers` (+ `settle` s for their side of discovery); no spinning needed.
    """
    if rate < 0:
        raise ConfigError(f"rate must be >= 0, got {rate}")
    path = Path(bag)
    chosen = select_topic(path, topic)
    stop = stop or threading.Event()
    out_topic = publish_topic or chosen
    publisher = None
    stats = ReplayStats(out_topic)
    start = time.monotonic()
    try:
        while not stop.is_set():
            pass_start, first_ns, last_ns, before = None, 0, 0, stats.published
            for conn, stamp_ns, raw in iter_raw(path, chosen):
                if publisher is None:
                    profile = qos_profile(qos, depth)
                    publisher = node.create_publisher(ros_message_class(conn.msgtype), out_topic, profile)
                    if min_subscribers:
                        _wait_for_subscribers(node, publisher, out_topic, min_subscribers, wait_timeout, stop)
                        # the subscriber side may match a moment later; best effort would drop the first cloud
                        stop.wait(settle)
                    start = time.monotonic()
                if pass_start is None:
                    pass_start, first_ns = time.monotonic(), stamp_ns
                if rate > 0:
                    delay = pass_start + (stamp_ns - first_ns) / 1e9 / rate - time.monotonic()
                    if delay > 0 and stop.wait(delay):
                        break
                if stop.is_set():
                    break
                publisher.publish(bytes(raw))
                last_ns = stamp_ns
                if on_publish is not None:
                    on_publish(stats.published, stamp_ns)
                stats.published += 1
            else:
                stats.passes += 1
            sent = stats.published - before
            if not loop or sent == 0:
                break
            if rate > 0 and sent > 1:  # one mean message gap before the next pass keeps the pace
                stop.wait((last_ns - first_ns) / 1e9 / rate / (sent - 1))
        stats.seconds = time.monotonic() - start
        if publisher is not None:
            stop.wait(linger)
    finally:
        if publisher is not None:
            node.destroy_publisher(publisher)
    return stats


class EmptyRecordingError(BagError):
    """`Recorder.close()` found nothing recorded: no bag was written."""


class RecordingWriteError(BagError):
    """Writing the recording failed (a full disk); the message says what was kept."""


class Recorder:
    """Records topics of a node the caller spins into a bag at header stamps; `close()` keeps, `abort()` drops it.

    A writer thread owns the bag (sqlite3 objects stay in one thread); `limit` caps the first topic. `qos` is a
    profile name for every topic or {topic: name}. A bag without any message is never finished: `close()`
    removes it and raises EmptyRecordingError.
    """

    def __init__(
        self,
        node: Any,
        topics: Mapping[str, str] | Sequence[str],
        out: str | Path,
        *,
        storage: str = "mcap",
        version: int = 9,
        force: bool = False,
        qos: str | Mapping[str, str] = "reliable",
        depth: int = 100,
        queue_size: int = 256,
        limit: int | None = None,
    ) -> None:
        self.node = node
        self.limit = limit
        self.topics: dict[str, str] = (
            dict(topics) if isinstance(topics, Mapping) else dict.fromkeys(topics, POINTCLOUD2_TYPE)
        )
        if not self.topics:
            raise BagError("nothing to record: no topics")
        for msgtype in self.topics.values():
            if msgtype not in TYPESTORE.types:
                raise BagError(f"message type {msgtype!r} unknown to the ROS 2 Jazzy typestore")
        classes = {topic: ros_message_class(msgtype) for topic, msgtype in self.topics.items()}
        self.qos: dict[str, str] = {topic: qos if isinstance(qos, str) else qos[topic] for topic in self.topics}
        profiles = {topic: qos_profile(name, depth) for topic, name in self.qos.items()}
        self.empty = False
        self.counts: dict[str, int] = dict.fromkeys(self.topics, 0)
        self._accepted = 0
        self.dropped = 0
        self.error: BaseException | None = None
        self._changed = threading.Condition()
        self._queue: queue.Queue[tuple[str, int, bytes] | str] = queue.Queue(maxsize=queue_size)
        self._writer = BagWriter(out, storage=storage, version=version, force=force)
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, name="pass3d-recorder", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self.error is not None:
            raise self.error
        self._subscriptions = [
            node.create_subscription(cls, topic, partial(self._on_message, topic), profiles[topic], raw=True)
            for topic, cls in classes.items()
        ]

    @property
    def out(self) -> Path:
        """The bag being written."""
        return self._writer.out

    def _run(self) -> None:
        """Writer thread: open the bag, write queued messages, then close or abort it on request."""
        try:
            self._writer.open()
        except BaseException as exc:
            self.error = exc
            return
        finally:
            self._ready.set()
        while True:
            item = self._queue.get()
            if isinstance(item, str):
                break
            topic, stamp, raw = item
            if self.error is not None:
                continue
            try:
                self._writer.write_raw(topic, self.topics[topic], stamp, raw)
            except Exception as exc:  # kept and re-raised by wait()/close()
                failure = self._keep_written(exc)
                with self._changed:
                    self.error = failure
                    self._changed.notify_all()
                continue
            with self._changed:
                self.counts[topic] += 1
                self._changed.notify_all()
        try:
            self.empty = item == "close" and self.error is None and not any(self.counts.values())
            if item == "close" and self.error is None and not self.empty:
                self._writer.close()
            else:
                self._writer.abort()
        except BaseException as exc:
            self.error = self.error or exc

    def _keep_written(self, exc: Exception) -> Exception:
        """After a failed write (a full disk): keep the messages written so far as a valid bag when it can be
        finished; the error to report, saying what was kept."""
        kept = self._writer.keep_written()
        if kept is not None:
            path, count = kept
            what = f"kept the {count} message(s) recorded before it as a valid bag {path}"
        else:
            what = "no bag kept" if any(self.counts.values()) else "nothing had been recorded; no bag written"
        return RecordingWriteError(f"{error_text(exc)}; stopped recording, {what}")

    def _on_message(self, topic: str, raw: bytes) -> None:
        if topic == next(iter(self.topics)):
            if self.limit is not None and self._accepted >= self.limit:
                return
            self._accepted += 1
        try:
            stamp = message_stamp_ns(self.topics[topic], raw) or self.node.get_clock().now().nanoseconds
            self._queue.put_nowait((topic, stamp, raw))
        except queue.Full:
            self.dropped += 1
        except Exception as exc:  # an executor must not die of a bad message; wait()/close() re-raise it
            with self._changed:
                self.error = exc
                self._changed.notify_all()

    def wait(self, count: int | None = None, *, topic: str | None = None, timeout: float | None = None) -> bool:
        """Block until `topic` (default: the first) has `count` messages written, or `timeout` s pass."""
        topic = topic or next(iter(self.topics))
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._changed:
            while self.error is None and (count is None or self.counts[topic] < count):
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._changed.wait(remaining)
            if self.error is not None:
                raise self.error
            return True

    def _finish(self, action: str) -> None:
        for subscription in self._subscriptions:
            self.node.destroy_subscription(subscription)
        self._subscriptions = []
        if self._thread.is_alive():
            self._queue.put(action)
            self._thread.join()

    def close(self) -> Path:
        """Stop listening, write what is queued and finish the bag; returns its path. Nothing recorded:
        the bag is removed and EmptyRecordingError raised."""
        self._finish("close")
        if self.error is not None:
            raise self.error
        if self.empty:
            raise EmptyRecordingError(f"{self.out}: no message arrived on {', '.join(self.topics)}; no bag written")
        return self.out

    def abort(self) -> None:
        """Stop listening and remove everything written."""
        self._finish("abort")

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


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
                      help="record for S seconds (default: until Ctrl-C)")
    stop.add_argument("--count", type=int, help="record N messages of the first topic (default: until Ctrl-C)")
    parser.add_argument("--storage", choices=sorted(STORAGES), default="mcap", help="storage plugin (default mcap)")
    parser.add_argument("--rosbag-version", type=int, choices=VERSIONS, default=9, help="rosbag2 version (9 or 8)")
    parser.add_argument("--force", action="store_true", help="replace an existing --out bag")
    return parser


def discover_types(node: Any, specs: Sequence[str], timeout: float = DISCOVERY_TIMEOUT_S,
                   poll: float = 0.05) -> dict[str, str]:
    """TOPIC[:TYPE] -> {topic: type}; an unnamed type is the one the ROS graph reports, waited for up to `timeout` s.

    BagError naming the topics the graph never showed, or a topic the graph gives several types.
    """
    topics: dict[str, str] = {}
    for spec in specs:
        topic, _, msgtype = spec.partition(":")
        if not topic:
            raise BagError(f"--record {spec!r}: empty topic name")
        topics[topic] = msgtype
    deadline = time.monotonic() + timeout
    while True:
        unknown = [topic for topic, msgtype in topics.items() if not msgtype]
        if not unknown:
            return topics
        graph = dict(node.get_topic_names_and_types())
        for topic in unknown:
            types = graph.get(topic) or []
            if len(types) > 1:
                raise BagError(f"{topic} is published with several types ({', '.join(types)}); "
                               f"name one: --record {topic}:TYPE")
            if types:
                topics[topic] = types[0]
        if all(topics.values()):
            return topics
        if time.monotonic() >= deadline:
            missing = ", ".join(topic for topic, msgtype in topics.items() if not msgtype)
            raise BagError(f"topic(s) {missing} not found in the ROS graph within {timeout:g} s (ROS_DOMAIN_ID "
                           f"{_domain_id()}); start the publisher first, raise --discovery-timeout, or give the type "
                           f"as TOPIC:pkg/msg/Type to wait for it while recording")
        time.sleep(poll)


def _domain_id() -> str:
    return os.environ.get("ROS_DOMAIN_ID", "0 (default)")


def recording_qos(node: Any, topic: str) -> str:
    """The QoS name to record `topic` with, as `ros2 bag record` adapts: `sensor` (best effort) when any known
    publisher is best effort or none is known yet (best effort matches every publisher), else `reliable`."""
    return offered_qos(node.get_publishers_info_by_topic(topic))


def _publishers_note(node: Any, topics: Mapping[str, str]) -> str:
    """`topic: N publisher(s) (QoS ...)` per topic, for the line that says a recording got nothing."""
    parts = []
    for topic in topics:
        infos = node.get_publishers_info_by_topic(topic)
        kinds = sorted({"best effort" if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT else "reliable"
                        for info in infos})
        parts.append(f"{topic}: {len(infos)} publisher(s)" + (f" ({', '.join(kinds)})" if kinds else ""))
    return "; ".join(parts)


def _record(args: argparse.Namespace, node: Any, executor: Any) -> int:
    out_path(args.out)
    topics = discover_types(node, args.record, args.discovery_timeout)
    qos = {topic: args.qos or recording_qos(node, topic) for topic in topics}
    recorder = Recorder(node, topics, args.out, storage=args.storage, version=args.rosbag_version,
                        force=args.force, qos=qos, limit=args.count)
    first = next(iter(topics))
    start = time.monotonic()
    stop_given = args.duration is not None or args.count is not None
    listing = ", ".join(f"{t} ({m}, {'best effort' if qos[t] == 'sensor' else 'reliable'})" for t, m in topics.items())
    print(f"recording {listing} into {args.out}", file=sys.stderr)
    status = 0
    try:
        while not (
            (args.duration is not None and time.monotonic() - start >= args.duration)
            or (args.count is not None and recorder.counts[first] >= args.count)
        ):
            executor.spin_once(timeout_sec=0.05)
            if recorder.error is not None:
                raise recorder.error
    except KeyboardInterrupt as exc:  # keep what was recorded, like `ros2 bag record`
        if stop_given:
            status = exc.status if isinstance(exc, Interrupted) else EXIT_SIGINT
    except BaseException:
        recorder.abort()
        raise
    seconds = time.monotonic() - start
    try:
        path = recorder.close()
    except EmptyRecordingError:
        print(f"pass3d_replay: error: recorded nothing in {seconds:.1f} s ({_publishers_note(node, topics)}); "
              f"{args.out} not written", file=sys.stderr)
        return status or EXIT_EMPTY
    counts = ", ".join(f"{topic}: {n}" for topic, n in recorder.counts.items())
    stopped = ", interrupted before the stop condition" if status else ""
    print(f"recorded {sum(recorder.counts.values())} messages in {seconds:.1f} s to {path} ({counts}){stopped}")
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
