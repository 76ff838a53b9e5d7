"""test_evaluate.py runs `pass3d_evaluate --live`, run_live and `pass3d_benchmark live`: the nodes over a DDS. Its
tests carry the `ros` marker, and PASS3D_SKIP_ROS_TESTS=1 leaves it uncollected (helpers.markers); the other
evaluation tests run offline."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.markers import mark_ros, skip_ros_tests

ROS_MODULES = ["test_evaluate.py"]
collect_ignore = ROS_MODULES if skip_ros_tests() else []


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    mark_ros(items, Path(__file__).resolve().parent, ROS_MODULES)
