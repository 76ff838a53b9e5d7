"""Publishing a bag's messages from a node at the recorded pace (or faster, or looped): `replay`, the library side of
`pass3d_replay BAG`. The stored CDR bytes go out unchanged, headers and stamps as recorded."""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.duration import Duration

from pass3d_ros.core.stage1.config import ConfigError
from pass3d_ros.data.bag import BagError, iter_raw, select_topic
from pass3d_ros.ros.diagnostics import DIAGNOSTICS_TOPIC
from pass3d_ros.ros.qos import latched_profile, qos_profile

REPLAY_STATUS = "pass3d_replay"  # the /diagnostics status a replay ends with: what it published (a recorder reads it)
ACK_TIMEOUT_S = 5.0  # a reliable replay waits this long at most for its subscribers to acknowledge every message


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
            if qos == "reliable" and not stop.is_set():  # exiting earlier would lose what is still in flight
                publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            stop.wait(linger)
    finally:
        if publisher is not None:
            node.destroy_publisher(publisher)
    return stats


def announce(node: Any, stats: ReplayStats, loop: bool, timeout: float = 1.0) -> None:
    """Say on /diagnostics (reliable, latched) what the replay published, so a recorder can tell how many of those it
    got; waits up to `timeout` s for the subscribers' acknowledgement."""
    values = {"topic": stats.topic, "published": stats.published, "passes": stats.passes, "loop": int(loop)}
    status = DiagnosticStatus(level=DiagnosticStatus.OK, name=REPLAY_STATUS, hardware_id="pass3d",
                              message=f"published {stats.published} messages on {stats.topic}",
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = [status]
    publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, latched_profile())
    try:
        publisher.publish(msg)
        publisher.wait_for_all_acked(Duration(seconds=timeout))
    finally:
        node.destroy_publisher(publisher)
