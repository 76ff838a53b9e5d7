"""QoS profiles by name: `sensor` (best effort, what LiDAR drivers publish) and `reliable` (what rviz2 wants);
an input may also be `auto`: whatever its publishers offer."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

QOS_NAMES: tuple[str, ...] = ("sensor", "reliable")
AUTO = "auto"
INPUT_QOS_NAMES: tuple[str, ...] = (AUTO, *QOS_NAMES)
RELIABILITY_WORDS = {"sensor": "best effort", "reliable": "reliable"}
INPUT_QOS_HELP = ("QoS of the input subscription: auto (reliable when every publisher offers reliable, else best "
                  "effort; re-checked every second), sensor (best effort) or reliable")


def offered_qos(publishers: Iterable[Any]) -> str:
    """The QoS name that takes everything `publishers` (TopicEndpointInfo) send: `reliable` when every one offers
    reliable, else `sensor` (best effort matches any publisher, also none yet)."""
    names = [endpoint_qos(info) for info in publishers]
    return "reliable" if names and all(name == "reliable" for name in names) else "sensor"


def endpoint_qos(info: Any) -> str:
    """A publisher's or subscription's (TopicEndpointInfo) reliability as a QoS name: `reliable` or `sensor`."""
    return "reliable" if info.qos_profile.reliability == ReliabilityPolicy.RELIABLE else "sensor"


def qos_profile(name: str, depth: int = 5) -> QoSProfile:
    """Keep-last `depth`, volatile QoS: best effort for `sensor`, reliable for `reliable`."""
    if name not in QOS_NAMES:
        raise ValueError(f"unknown QoS profile {name!r}, expected one of {', '.join(QOS_NAMES)}")
    if depth < 1:
        raise ValueError(f"QoS depth must be >= 1, got {depth}")
    reliability = ReliabilityPolicy.BEST_EFFORT if name == "sensor" else ReliabilityPolicy.RELIABLE
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=reliability,
        durability=DurabilityPolicy.VOLATILE,
    )


def latched_profile() -> QoSProfile:
    """Reliable, transient local, keep-last 1: a subscriber that comes late still gets the last message sent."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
