"""Recording live topics into a bag at their header stamps: `Recorder` (a writer thread owns the bag) and the ROS
graph look-ups a recording needs (`discover_types`, `recording_qos`, `publishers_note`); the library side of
`pass3d_replay --record`."""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import ReliabilityPolicy

from pass3d_ros.data.bag import TYPESTORE, BagError, BagWriter, message_stamp_ns
from pass3d_ros.data.outputs import error_text
from pass3d_ros.msgs.pointcloud2 import POINTCLOUD2_TYPE
from pass3d_ros.ros.bag_replay import REPLAY_STATUS, ros_message_class
from pass3d_ros.ros.diagnostics import DIAGNOSTICS_TOPIC, status_values
from pass3d_ros.ros.input_watch import Coverage, coverage
from pass3d_ros.ros.qos import offered_qos, qos_profile

DISCOVERY_TIMEOUT_S = 10.0  # how long `discover_types` waits for a topic to appear in the ROS graph


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
        self.stamps: dict[str, list[int]] = {topic: [] for topic in self.topics}  # header stamps received
        self.first_at: float | None = None  # monotonic time of the first message
        self.replay: dict[str, float | str | None] | None = None  # pass3d_replay's last status, when one was seen
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
        if DIAGNOSTICS_TOPIC not in self.topics:  # pass3d_replay says there how many it published
            self._subscriptions.append(node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                                self._on_diagnostics, 10))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == REPLAY_STATUS:
                self.replay = status_values(status)

    def coverage(self, topic: str | None = None) -> Coverage:
        """How many messages of `topic` (default: the first) arrived of how many its stamps imply (first..last at
        its period) and, for the first topic, of how many a pass3d_replay on this domain published (one pass,
        seen on /diagnostics)."""
        topic = topic or next(iter(self.topics))
        published = None
        replay = self.replay
        if replay is not None and topic == next(iter(self.topics)) and replay.get("passes") == 1:
            published = int(replay["published"] or 0) or None
        return coverage(self.stamps[topic], published)

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
            stamped = message_stamp_ns(self.topics[topic], raw)
            stamp = stamped or self.node.get_clock().now().nanoseconds
            self._queue.put_nowait((topic, stamp, raw))
            if stamped:
                self.stamps[topic].append(stamped)
            if self.first_at is None:
                self.first_at = time.monotonic()
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

    def record_until(self, executor: Any, *, duration: float | None = None, count: int | None = None,
                     poll: float = 0.05) -> None:
        """Spin `executor` (it holds the node) until `duration` s pass after the first message (or after the start,
        when none came by then) or the first topic has `count` messages written (neither given: until interrupted),
        raising a failed write. Counting from the first message, a recorder started well before the publisher
        (another shell, a busy machine) keeps the whole stream. Ctrl-C propagates with what was recorded kept for
        `close()`; any other exception aborts the recording first."""
        first = next(iter(self.topics))
        start = time.monotonic()
        try:
            while not ((duration is not None and time.monotonic() - (self.first_at or start) >= duration)
                       or (count is not None and self.counts[first] >= count)):
                executor.spin_once(timeout_sec=poll)
                if self.error is not None:
                    raise self.error
        except KeyboardInterrupt:
            raise
        except BaseException:
            self.abort()
            raise

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
    """The ROS domain this process is on, for the line that says a topic was not found."""
    return os.environ.get("ROS_DOMAIN_ID", "0 (default)")


def recording_qos(node: Any, topic: str) -> str:
    """The QoS name to record `topic` with, as `ros2 bag record` adapts: `sensor` (best effort) when any known
    publisher is best effort or none is known yet (best effort matches every publisher), else `reliable`."""
    return offered_qos(node.get_publishers_info_by_topic(topic))


def publishers_note(node: Any, topics: Mapping[str, str]) -> str:
    """`topic: N publisher(s) (QoS ...)` per topic, for the line that says a recording got nothing."""
    parts = []
    for topic in topics:
        infos = node.get_publishers_info_by_topic(topic)
        kinds = sorted({"best effort" if info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT else "reliable"
                        for info in infos})
        parts.append(f"{topic}: {len(infos)} publisher(s)" + (f" ({', '.join(kinds)})" if kinds else ""))
    return "; ".join(parts)
