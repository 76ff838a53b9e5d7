"""The one ROS harness of the tests: a private rclpy context on a DDS domain of its own with a single-threaded
executor spinning in a thread (as the executables run the nodes), a probe node to talk with, and the waits.

Domains: every session takes the next domain of this test process's share (`domain()`); the share's first,
PROCESS_DOMAIN, is the process's ROS_DOMAIN_ID for children started without one. Under pytest-xdist each worker has
a disjoint share, so two workers never hear each other's traffic; a process starts its share at a random place, so
two test runs on one machine rarely meet, and consecutive sessions of one process never share a domain. The shares
leave out 0 (a real robot's default) and 100..200, where run_live draws its own domain unless told one (conftest
hands it this process's share too). rclpy is imported only when a session starts, so this module imports on a
machine without ROS.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import random
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from pass3d_ros.data.frame import Frame

STAMP0 = 1_700_000_000_123_456_789
WAIT_S = 30.0
DOMAINS = [*range(1, 100), *range(201, 233)]  # Fast DDS's ports allow 0..232 on Linux


def _worker_share() -> list[int]:
    """This process's domains: under pytest-xdist worker gwK of N takes every N-th domain from the K-th."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    count = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    share = DOMAINS[index % count::count]
    start = random.randrange(len(share))
    return share[start:] + share[:start]


_SHARE = _worker_share()
PROCESS_DOMAIN = _SHARE[0]  # ROS_DOMAIN_ID of this process, so of children started without one (conftest sets it)
_DOMAINS = itertools.cycle(_SHARE[1:])


def domain() -> int:
    """The next DDS domain of this process's share (see the module docstring), never PROCESS_DOMAIN."""
    return next(_DOMAINS)


class Ros:
    """A private context on its own domain, a single-threaded executor spinning in a thread, `make_node` and `add`
    for nodes spun there, and `probe` (made on first use) to publish and subscribe with."""

    def __init__(self, domain_id: int | None = None) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.domain = domain() if domain_id is None else domain_id
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Any] = []
        self._probe: Any = None
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        """Spin until closed; a context shut down under it (Ctrl-C) ends the spin, as in the executables. Spun a
        step at a time so that close() stops the thread before it shuts the executor down: shut down under a running
        spin(), the executor raised in this thread now and then (a warning in the test run)."""
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            while not self._stop.is_set() and self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)

    def add(self, node: Any) -> Any:
        """Spin `node` (made with context=self.context) here; it is destroyed on close."""
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def make_node(self, name: str) -> Any:
        """A plain node named `name`_<pid>, spun here."""
        import rclpy

        return self.add(rclpy.create_node(f"{name}_{os.getpid()}", context=self.context))

    @property
    def probe(self) -> Any:
        """The test's own node: publishers to the nodes under test, Collectors of their outputs."""
        if self._probe is None:
            import rclpy

            self._probe = self.add(rclpy.create_node(f"probe_{random.getrandbits(32):08x}", context=self.context))
        return self._probe

    def close(self) -> None:
        import rclpy

        self._stop.set()
        self.thread.join(timeout=5)
        self.executor.shutdown()
        for node in reversed(self.nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@contextlib.contextmanager
def ros_session(domain_id: int | None = None) -> Iterator[Ros]:
    """A Ros for a `with` block (the `ros` fixture in conftest wraps one)."""
    session = Ros(domain_id)
    try:
        yield session
    finally:
        session.close()


class Collector:
    """Messages of one topic received by the probe node, in arrival order."""

    def __init__(self, ros: Ros, msg_type: type, topic: str, qos: str = "reliable") -> None:
        from pass3d_ros.ros.qos import qos_profile

        self.messages: list = []
        self.cond = threading.Condition()
        self.sub = ros.probe.create_subscription(msg_type, topic, self._on, qos_profile(qos, 20))

    def _on(self, msg) -> None:
        with self.cond:
            self.messages.append(msg)
            self.cond.notify_all()

    def wait(self, count: int, timeout: float = WAIT_S) -> list:
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.messages) >= count, timeout), (
                f"{self.sub.topic_name}: {len(self.messages)} of {count} messages"
            )
            return list(self.messages)


def wait_until(predicate: Callable[[], bool], timeout: float = WAIT_S) -> bool:
    """Whether `predicate` holds within `timeout` seconds (it is asked once more at the deadline)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return bool(predicate())
        time.sleep(0.01)
    return True


def connect(publisher, *collectors: Collector) -> None:
    """Wait until every endpoint is matched, plus a moment for the other side of discovery."""
    assert wait_until(lambda: publisher.get_subscription_count() >= 1), "input not matched"
    assert wait_until(lambda: all(c.sub.get_publisher_count() >= 1 for c in collectors)), "outputs not matched"
    time.sleep(0.3)


def scan_message(frame: Frame, stamp_ns: int, with_ring: bool = True, frame_id: str = "velodyne_test"):
    """`frame` as a sensor_msgs/PointCloud2 (x, y, z, intensity and, with_ring, ring)."""
    from pass3d_ros.data.bag_convert import frame_cloud
    from pass3d_ros.msgs.pointcloud2 import encode

    cloud = frame_cloud(frame if with_ring else Frame(frame.name, frame.points))
    return encode(cloud, stamp_ns=stamp_ns, frame_id=frame_id)


def columns(msg) -> np.ndarray:
    """A PointCloud2's points as a structured array."""
    from pass3d_ros.msgs.pointcloud2 import decode

    return decode(msg)
