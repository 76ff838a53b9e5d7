"""Shared fixtures: where the real KITTI development frames are, when they are there at all."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

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
