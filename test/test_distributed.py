"""Data-parallel pass3d_train: two CPU processes under torch.distributed.run (gloo) train a few steps, write each
file once, give a plain checkpoint that loads like a single-process one (offline and in the segmentation node),
resume, and reach about the loss of a one-process run from the same seed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from pass3d_ros.core.stage2 import load_classifier
from pass3d_ros.training.distributed import strip_module_prefix
from pass3d_ros.training.samples import SampleSet

ARGS = ["--data", "synthetic:frames=4,seed=3", "--batch-size", "8", "--max-steps", "3", "--seed", "5", "--quiet"]


def torchrun(out: Path, *extra: str) -> subprocess.CompletedProcess:
    """pass3d_train in 2 processes; fails the test with the output when it fails."""
    command = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--standalone",
               "-m", "pass3d_ros.tools.train", *ARGS, "--out", str(out), *extra]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done


@pytest.fixture(scope="module")
def ddp_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A 2-process run of 1 epoch: its output folder and its stdout."""
    out = tmp_path_factory.mktemp("ddp")
    return out, torchrun(out, "--epochs", "1").stdout


def test_two_processes_write_one_plain_checkpoint(ddp_run: tuple[Path, str]) -> None:
    out, stdout = ddp_run
    assert stdout.count("data-parallel: 2 processes (cpu)") == 1  # rank 0 alone logs
    assert stdout.count("epoch 1: loss") == 1 and stdout.count("checkpoints:") == 1
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith("samples_")) == [
        "best.pt", "history.json", "last.pt"]
    assert len(json.loads((out / "history.json").read_text())) == 1
    state = torch.load(out / "last.pt", weights_only=True)
    assert not any(k.startswith("module.") for k in state["state_dict"]) and state["epoch"] == 0
    cache = SampleSet.load(next(out.glob("samples_*.npz")))
    assert len(cache.frame_names) == 4  # both shards gathered

    classifier = load_classifier("network", out / "best.pt")
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(0, 2, (400, 3)), rng.uniform(0, 1, 400)]).astype(np.float32)
    result = classifier.segment(points, [np.arange(150), np.arange(150, 400)])
    assert result.labels.shape == (400,) and result.labels.max() < 4


def test_resume_under_two_processes(ddp_run: tuple[Path, str], tmp_path: Path) -> None:
    out, _ = ddp_run
    for name in ("last.pt", "best.pt", "history.json"):
        (tmp_path / name).write_bytes((out / name).read_bytes())
    for cache in out.glob("samples_*.npz"):
        (tmp_path / cache.name).write_bytes(cache.read_bytes())
    stdout = torchrun(tmp_path, "--epochs", "2", "--resume").stdout
    assert stdout.count("resumed from") == 1 and "epoch 2: loss" in stdout and "epoch 1: loss" not in stdout
    assert [h["epoch"] for h in json.loads((tmp_path / "history.json").read_text())] == [0, 1]


def test_two_processes_reach_the_loss_of_one(ddp_run: tuple[Path, str], tmp_path: Path) -> None:
    """Same seed, same global batch of 8: the first epoch's mean loss (3 steps from the same initial weights) of
    2 processes is within 0.3 of 1 process's (about 1.6 at that point; the gap measured was under 0.1; the runs
    differ only in augmentation draws, background sampling and BatchNorm statistics per half batch)."""
    from pass3d_ros.tools import train

    out, _ = ddp_run
    threads = torch.get_num_threads()
    try:
        assert train.main([*ARGS, "--epochs", "1", "--out", str(tmp_path), "--threads", "2"]) == 0
    finally:
        torch.set_num_threads(threads)
    one = json.loads((tmp_path / "history.json").read_text())[0]["train_loss"]
    two = json.loads((out / "history.json").read_text())[0]["train_loss"]
    assert abs(one - two) < 0.3, (one, two)


def test_strip_module_prefix() -> None:
    plain = {"a.weight": 1, "b.bias": 2}
    assert strip_module_prefix({f"module.{k}": v for k, v in plain.items()}) == plain
    assert strip_module_prefix(plain) == plain


@pytest.mark.ros
def test_segmentation_node_loads_the_ddp_checkpoint(ddp_run: tuple[Path, str]) -> None:
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from pass3d_ros.ros.segmentation_node import SegmentationNode

    out, _ = ddp_run
    context = Context()
    rclpy.init(context=context, domain_id=int(np.random.default_rng().integers(100, 200)))
    try:
        node = SegmentationNode(context=context, parameter_overrides=[
            Parameter("classifier", value="network"), Parameter("weights", value=str(out / "best.pt"))])
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
