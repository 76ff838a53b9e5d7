"""Every test in test/ros/ runs real nodes, bags or processes over rclpy and a DDS: each carries the `ros` marker, and
PASS3D_SKIP_ROS_TESTS=1 leaves the folder uncollected (helpers.markers)."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.markers import mark_ros, skip_ros_tests

collect_ignore_glob = ["test_*.py"] if skip_ros_tests() else []


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    mark_ros(items, Path(__file__).resolve().parent)
