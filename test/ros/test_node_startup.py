"""Node start-up with bad ROS arguments: a missing or garbage --params-file and unknown flags end in one line and exit
2 (no traceback); a misspelt parameter is named once, with the nearest declared one."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
from helpers.ros import domain
from rclpy.context import Context
from rclpy.parameter import Parameter

from pass3d_ros.ros import params
from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.run import params_file_problem, ros_message

pytestmark = pytest.mark.ros

NODE = "import sys; from pass3d_ros.ros.cluster_proposal_node import main; sys.exit(main(sys.argv))"


def start(*ros_args: str) -> subprocess.Popen:
    """cluster_proposal_node in a child process on a private domain, with `ros_args` after --ros-args."""
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain())}
    return subprocess.Popen([sys.executable, "-c", NODE, "--ros-args", *ros_args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.parametrize(("content", "says"), [
    (None, "no such file"),
    ("garbage: [unbalanced\n", "Couldn't parse params file"),
    ("\x00\x01binary", "Couldn't parse params file"),
])
def test_bad_params_file_is_one_line(tmp_path: Path, content: str | None, says: str) -> None:
    path = tmp_path / "params.yaml"
    if content is not None:
        path.write_text(content)
    _out, err = start("--params-file", str(path)).communicate(timeout=60)
    lines = [line for line in err.splitlines() if line.startswith("cluster_proposal_node: ")]
    assert len(lines) == 1 and says in lines[0] and str(path) in lines[0], err
    assert "Traceback" not in err and "/project/src" not in err, err


def test_unknown_ros_argument_is_one_line() -> None:
    proc = start("--bogus-flag")
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and err.strip() == "cluster_proposal_node: unknown ROS arguments ['--bogus-flag']"


def test_params_file_problem_and_ros_message(tmp_path: Path) -> None:
    assert params_file_problem(["prog", "--ros-args", "--params-file", str(tmp_path)]).endswith("is a folder")
    assert params_file_problem(["prog", "--params-file", "not/ros/args"]) == ""
    assert ros_message(RuntimeError("bad, at /project/src/parse.c:841, at /x/y.c:1\n")) == "bad"


def test_misspelt_parameters_are_named_once(capfd: pytest.CaptureFixture[str]) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=domain())
    overrides = [Parameter("stage1.th_dsit", value=0.2), Parameter("input_topik", value="/x"),
                 Parameter("stage1.th_ring", value=0.4), Parameter("qos_overrides./x.subscription.depth", value=5)]
    node = ClusterProposalNode(context=context, parameter_overrides=overrides)
    try:
        assert [name for _, name in params.unknown_overrides([node, node])] == ["input_topik", "stage1.th_dsit"]
        capfd.readouterr()
        params.warn_unknown_overrides([node])
        err = capfd.readouterr().err
        assert "parameter 'stage1.th_dsit' is declared by no node here and is ignored (did you mean " \
               "'stage1.th_dist'?)" in err
        assert "'input_topik'" in err and "'input_topic'" in err and "th_ring" not in err and "qos" not in err
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_node_warns_about_a_misspelt_parameter_at_start_up() -> None:
    proc = start("-p", "stage1.th_dsit:=0.2")
    selector = selectors.DefaultSelector()
    selector.register(proc.stderr, selectors.EVENT_READ)
    seen, deadline = "", time.monotonic() + 60
    try:
        while "stage1.th_dsit" not in seen and time.monotonic() < deadline and proc.poll() is None:
            if selector.select(timeout=1):  # read the pipe itself: a buffered readline would keep lines from
                seen += os.read(proc.stderr.fileno(), 65536).decode(errors="replace")  # select and communicate
    finally:
        proc.send_signal(signal.SIGINT)
        seen += proc.communicate(timeout=30)[1] or ""  # what the loop had not read yet (a busy machine is slow)
    assert "(did you mean 'stage1.th_dist'?)" in seen, seen


def test_segmentation_node_bad_device_is_one_line() -> None:
    code = "import sys; from pass3d_ros.ros.segmentation_node import main; sys.exit(main(sys.argv))"
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain())}
    for device in ("cuda:99", "bogus"):
        proc = subprocess.run([sys.executable, "-c", code, "--ros-args", "-p", f"device:={device}"], env=env,
                              capture_output=True, text=True, timeout=120)
        lines = [line for line in proc.stderr.splitlines() if line.startswith("segmentation_node: ")]
        assert proc.returncode == 2 and len(lines) == 1 and f"device {device!r}" in lines[0], proc.stderr
        assert "Traceback" not in proc.stderr


def test_run_time_max_top_below_min_top_is_refused() -> None:
    context = Context()
    rclpy.init(context=context, domain_id=domain())
    node = ClusterProposalNode(context=context)
    try:
        result = node.set_parameters([Parameter("stage1.max_top", value=0.5)])[0]
        assert not result.successful and "max_top=0.5 is below min_top=0.9" in result.reason
        assert node.config.max_top == 2.3
        assert node.set_parameters([Parameter("stage1.max_top", value=1.5)])[0].successful
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("topic", ["''", "bad topic!"])
def test_bad_input_topic_is_one_line(topic: str) -> None:
    proc = start("-p", f"input_topic:={topic}")
    _out, err = proc.communicate(timeout=120)
    lines = [line for line in err.splitlines() if line.startswith("cluster_proposal_node: ")]
    assert proc.returncode == 2 and len(lines) == 1 and "is invalid" in lines[0], err
    assert "Traceback" not in err and "/project/src" not in err, err


def test_ctrl_c_racing_the_executor_is_a_clean_exit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C shuts the context down; when that lands between the executor's check and its wait set, rclpy raises
    RCLError ("the given context is not valid"). That is the same shutdown: exit 0, no traceback (a real
    pass3d_pipeline once exited 1 with it). An RCLError while the context is still up is a bug and propagates."""
    from rclpy._rclpy_pybind11 import RCLError

    from pass3d_ros.ros import run

    def interrupted(self) -> None:
        rclpy.shutdown()
        raise RCLError("failed to initialize wait set: the given context is not valid")

    monkeypatch.setattr(run, "apply_shipped_profile", lambda: None)  # this process's environment stays as it is
    monkeypatch.setattr(run.SingleThreadedExecutor, "spin", interrupted)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain()))
    assert run.run_nodes("pass3d_test", [], ["pass3d_test"]) == 0

    def broken(self) -> None:
        raise RCLError("something else")

    monkeypatch.setattr(run.SingleThreadedExecutor, "spin", broken)
    with pytest.raises(RCLError):
        run.run_nodes("pass3d_test", [], ["pass3d_test"])
