"""Shared fixtures: where the real KITTI development frames are, when they are there at all; test markers.

Markers: `ros` (needs rclpy and a DDS: the node and live tests), `kitti` (needs the real KITTI development
frames, skipped with a message when they are absent). `pytest -m "not ros"` leaves the ROS tests out. A
broken rclpy fails the ROS tests instead of skipping them; only PASS3D_SKIP_ROS_TESTS=1 (never set by
`.ci/run`) leaves their modules uncollected, for a machine that knowingly has no ROS.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import torch

from pass3d_ros.core.stage2 import pointnet2
from pass3d_ros.core.stage2.segmentation import make_checkpoint

REPO_ROOT = Path(__file__).resolve().parents[1]
ROS_TEST_MODULES = ["test_nodes.py", "test_evaluate.py", "test_recording.py", "test_node_input.py",
                    "test_realtime.py", "test_sensors_live.py", "test_transport.py", "test_quick_flow.py",
                    "test_segmentation_guard.py", "test_diagnostics_truth.py"]
collect_ignore = ROS_TEST_MODULES if os.environ.get("PASS3D_SKIP_ROS_TESTS") == "1" else []


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the tests that use the real KITTI frames `kitti` and those on a live rclpy context `ros`."""
    for item in items:
        fixtures = getattr(item, "fixturenames", ())
        if "kitti_dev" in fixtures:
            item.add_marker(pytest.mark.kitti)
        if "ros" in fixtures:
            item.add_marker(pytest.mark.ros)


def kitti_dev_root() -> Path | None:
    """$PASS3D_KITTI_DEV, else ../shared/data/kitti_dev beside the repository, else None."""
    candidates = [os.environ.get("PASS3D_KITTI_DEV"), REPO_ROOT.parent / "shared" / "data" / "kitti_dev"]
    for candidate in candidates:
        if candidate and Path(candidate).is_dir():
            return Path(candidate)
    return None


@pytest.fixture
def kitti_dev() -> Path:
    """Root of the real KITTI frames; skips the test when they are absent (licence: never in the repo)."""
    root = kitti_dev_root()
    if root is None:
        pytest.skip("real KITTI frames absent: set PASS3D_KITTI_DEV or place them in ../shared/data/kitti_dev")
    return root


@contextmanager
def private_ros(domain: int) -> Iterator[tuple[Callable[[str], Any], int]]:
    """(make_node, domain): a private rclpy context on `domain` with a single-threaded executor spinning in a
    thread; make_node(name) adds a node to it. Everything is shut down on exit."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    nodes: list[Any] = []

    def make_node(name: str) -> Any:
        node = rclpy.create_node(f"{name}_{os.getpid()}", context=context)
        executor.add_node(node)
        nodes.append(node)
        return node

    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield make_node, domain
    finally:
        executor.shutdown()
        thread.join(timeout=5)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.fixture(scope="module")
def lite_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained `lite` checkpoint: real network code, arbitrary but fixed weights."""
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("weights") / "lite_untrained.pt"
    torch.save(make_checkpoint(pointnet2.PointNet2Seg(pointnet2.make_config("lite"))), path)
    return path


@pytest.fixture(autouse=True)
def one_torch_thread():
    """One intra-op thread in every test: on a shared 2-core machine two spinning OpenMP threads stall each other."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
