"""Shared fixtures, each declared here once: the real KITTI development frames when they are there at all
(`kitti_dev`), the one ROS harness (`ros`, from test/helpers/ros.py; DDS domains per process so pytest-xdist workers
never cross-talk), the synthetic scan most node tests use (`frame`, `proposal_columns`), the shipped and an untrained
checkpoint; test markers. Shared code that is not a fixture lives in test/helpers; no test module imports another.

The folders mirror pass3d_ros/ (test/core/stage1/ tests pass3d_ros/core/stage1/, ...); test/package/ checks the
package as a whole (docs, launch configs, dependencies, this layout).

Markers: `ros` (needs rclpy and a DDS: the node and live tests), `kitti` (needs the real KITTI development
frames, skipped with a message when they are absent), `slow` (left out of `make test`; `make test-slow` and CI run
them). `pytest -m "not ros"` leaves the ROS tests out. A test is marked `ros` when it takes the `ros` fixture (here)
or lives where a folder's conftest.py says ROS is needed (all of test/ros/, test/evaluation/test_evaluate.py:
helpers.markers). A broken rclpy fails the ROS tests instead of skipping them; only PASS3D_SKIP_ROS_TESTS=1 (never
set by `.ci/run`) leaves those folders' ROS modules uncollected, for a machine that knowingly has no ROS.
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from helpers.ros import PROCESS_DOMAIN, Ros, domain, ros_session

from pass3d_ros.core.stage2 import pointnet2
from pass3d_ros.core.stage2.segmentation import Segmenter, make_checkpoint
from pass3d_ros.data.frame import Frame
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.weights import DEFAULT_WEIGHTS

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the tests that use the real KITTI frames `kitti` and those on a live rclpy context `ros` (the folders'
    conftest.py files mark the rest of the ROS tests)."""
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


@pytest.fixture
def ros() -> Iterator[Ros]:
    """A private rclpy context on this process's next DDS domain, a spinning executor and a probe node
    (helpers.ros.Ros): the one ROS harness of the tests."""
    with ros_session() as session:
        yield session


@pytest.fixture(scope="session", autouse=True)
def dds_domains_of_this_process() -> Iterator[None]:
    """ROS traffic of this test process stays on its own DDS domains (helpers.ros.domain), so pytest-xdist workers
    never hear each other: a child process started without ROS_DOMAIN_ID gets this process's own default domain,
    and run_live (also under pass3d_evaluate --live), which draws its domain from random.randint(100, 200) unless
    told one, draws from this process's share instead."""
    try:
        from pass3d_ros.evaluation import live
    except ImportError:  # a machine without ROS (PASS3D_SKIP_ROS_TESTS=1) makes no live runs
        live = None

    class Draws:
        def randint(self, a: int, b: int) -> int:
            return domain()

        def __getattr__(self, name: str) -> Any:
            return getattr(random, name)

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("ROS_DOMAIN_ID", str(PROCESS_DOMAIN))
        if live is not None:
            patch.setattr(live, "random", Draws())
        yield


@pytest.fixture(scope="session")
def frame() -> Frame:
    """A synthetic HDL-64E scan with cars and people, labels included (seed 5, frame 0)."""
    scan = generate_frame(seed=5, index=0)
    assert np.count_nonzero(scan.labels) > 1000
    return scan


@pytest.fixture(scope="session")
def proposal_columns(frame: Frame) -> dict[str, np.ndarray]:
    """A valid /pass3d/proposals cloud of `frame`, as columns, built by stage 1 (shared: change a copy)."""
    from pass3d_ros.core.stage1 import propose
    from pass3d_ros.ros.proposals import proposals_cloud

    return proposals_cloud(frame.points, propose(frame.points, frame.ring))


@pytest.fixture(scope="session")
def shipped() -> Segmenter:
    """The shipped `lite` weights, loaded once."""
    return Segmenter(DEFAULT_WEIGHTS)


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
