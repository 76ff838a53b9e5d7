"""The README's quick flow across real processes, each started as a user would in its own shell (no Fast DDS
variable set by hand): `pass3d_pipeline`, a recorder of /pass3d/labeled and a replay of a 20-frame synthetic bag
of ~2 MB clouds. Every frame must come back labeled: over Fast DDS's defaults most of them never arrived."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers.ros import domain

from pass3d_ros.data.bag import iter_raw
from pass3d_ros.ros.dds_profile import USER_VARIABLES

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.timeout(420)]

ROOT = Path(__file__).resolve().parents[2]
FRAMES = 20
RATE = 0.25  # the bag is 10 Hz: 2.5 Hz leaves a loaded CI machine time for every frame (the README uses 1)
MODULES = {"pass3d_pipeline": "pass3d_ros.ros.pipeline", "pass3d_replay": "pass3d_ros.tools.replay",
           "pass3d_kitti2bag": "pass3d_ros.tools.kitti2bag"}


def command(name: str, *args: str | Path) -> list[str]:
    """The console script beside this Python (as a user runs it), else its module."""
    script = Path(sys.executable).parent / name
    head = [str(script)] if script.exists() else [sys.executable, "-m", MODULES[name]]
    return head + [str(arg) for arg in args]


class Process:
    """A child process whose merged output is collected by a thread."""

    def __init__(self, argv: list[str], env: dict[str, str]) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                     cwd=ROOT)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def wait_for(self, text: str, timeout: float) -> bool:
        """Whether a line with `text` appears within `timeout` s (False early if the process ended)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return True
            if self.proc.poll() is not None:
                self._reader.join(timeout=5)
                return any(text in line for line in self.lines)
            time.sleep(0.1)
        return False

    def stop(self, grace: float = 0.0, timeout: float = 30.0) -> int:
        """Ctrl-C if still running after `grace` s, and the exit status."""
        try:
            self.proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._reader.join(timeout=5)
        return code

    @property
    def output(self) -> str:
        return "\n".join(self.lines)


def test_quick_flow_records_every_frame_across_processes(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in USER_VARIABLES and k != "RMW_IMPLEMENTATION"}
    env["ROS_DOMAIN_ID"] = str(domain())
    bag, out = tmp_path / "input_bag", tmp_path / "labeled_bag"
    subprocess.run(command("pass3d_kitti2bag", "--data", f"synthetic:frames={FRAMES},seed=7", "--out", bag,
                           "--no-progress"), env=env, check=True, capture_output=True, timeout=300)
    sent = [stamp for _, stamp, _ in iter_raw(bag, "/velodyne_points")]
    assert len(sent) == FRAMES

    pipeline = Process(command("pass3d_pipeline", "--ros-args", "--params-file",
                               ROOT / "launch_configs" / "pass3d_params.yaml"), env)
    recorder = None
    try:
        assert pipeline.wait_for("stage 2 ready", 240), pipeline.output
        assert "Fast DDS: large-cloud profile" in pipeline.output
        recorder = Process(command("pass3d_replay", "--record", "/pass3d/labeled", "--out", out,
                                   "--count", str(FRAMES)), env)
        assert recorder.wait_for("recording /pass3d/labeled", 60), recorder.output
        replay = subprocess.run(command("pass3d_replay", bag, "--rate", str(RATE)), env=env, capture_output=True,
                                text=True, timeout=180)
        assert replay.returncode == 0, replay.stderr
        assert f"published {FRAMES} messages" in replay.stdout
        assert "Fast DDS: large-cloud profile" in replay.stderr and "1 subscriber(s) after" in replay.stderr
        recorder.wait_for(f"recorded {FRAMES} messages", 60)
    finally:
        codes = {"recorder": recorder.stop(grace=30) if recorder else None, "pipeline": pipeline.stop()}
    assert codes["recorder"] == 0, recorder.output
    assert "Fast DDS: large-cloud profile" in recorder.output
    labeled = [stamp for _, stamp, _ in iter_raw(out, "/pass3d/labeled")]
    assert labeled == sent, f"{len(labeled)} of {FRAMES} frames labeled and recorded\n{pipeline.output[-3000:]}"
    assert codes["pipeline"] == 0, pipeline.output[-3000:]
