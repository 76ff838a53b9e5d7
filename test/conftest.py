"""Shared fixtures: where the real KITTI development frames are, when they are there at all."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from pass3d_ros.core import pointnet2
from pass3d_ros.core.segmentation import make_checkpoint

REPO_ROOT = Path(__file__).resolve().parents[1]


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
