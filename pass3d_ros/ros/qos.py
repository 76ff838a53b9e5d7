"""QoS profiles by name: `sensor` (best effort, what LiDAR drivers publish) and `reliable` (what rviz2 wants)."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

QOS_NAMES: tuple[str, ...] = ("sensor", "reliable")


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
