"""Markers by folder: a folder's conftest.py marks the tests that need ROS (rclpy and a DDS) with `ros`, and leaves
their modules uncollected where PASS3D_SKIP_ROS_TESTS=1 (a machine that knowingly has no ROS; `.ci/run` never sets
it). test/ros/ needs ROS throughout; another folder names its few modules that do. Tests elsewhere that take the
`ros` fixture are marked by test/conftest.py."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import pytest


def skip_ros_tests() -> bool:
    """True where PASS3D_SKIP_ROS_TESTS=1: the ROS modules are not collected at all (a broken rclpy fails them)."""
    return os.environ.get("PASS3D_SKIP_ROS_TESTS") == "1"


def mark_ros(items: Iterable[pytest.Item], folder: Path, modules: Iterable[str] | None = None) -> None:
    """Mark `ros` every test under `folder`, or only those of its `modules` (file names) when given."""
    names = None if modules is None else set(modules)
    for item in items:
        path = Path(item.path).resolve()
        if path.is_relative_to(folder) and (names is None or (path.parent == folder and path.name in names)):
            item.add_marker(pytest.mark.ros)
