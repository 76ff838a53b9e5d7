"""The stage-2 classifier in a child process (pass3d_ros.core.stage2.classifier_process): the same results as in this
process, a failed frame reported and survived, clear errors when the child cannot serve, a killed child restarted
with back-off, and SIGINT (Ctrl-C) left to the parent."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
import time

import numpy as np
import pytest

from pass3d_ros.core.stage1 import proposal_members, propose
from pass3d_ros.core.stage2 import ClassifierError, classifier_process, open_classifier
from pass3d_ros.core.stage2.classifier_process import (
    ClassifierProcessDownError,
    ClassifierProcessError,
    ProcessClassifier,
    describe_exit,
    restart_delay,
)
from pass3d_ros.synthetic.dataset import generate_frame


@pytest.fixture(scope="module")
def frame_and_members() -> tuple[np.ndarray, list[np.ndarray]]:
    frame = generate_frame(seed=7, index=0)
    result = propose(frame.points, frame.ring)
    return frame.points, proposal_members(result.cluster_id, result.cluster_id2)


def test_child_process_segments_like_this_process(frame_and_members) -> None:
    points, members = frame_and_members
    here = open_classifier("")
    child = ProcessClassifier("")
    try:
        assert child.pid > 0 and (child.kind, child.weights) == ("network", here.weights)
        assert here.weights is not None and here.weights.endswith("pass3d_lite.pt")
        for limit in (64, 5):  # max_proposals travels with each frame
            here.max_proposals = child.max_proposals = limit
            expected, got = here.segment(points, members), child.segment(points, members)
            for a, b in zip(expected, got, strict=True):
                np.testing.assert_array_equal(a, b)
        with pytest.raises(ClassifierProcessError, match="failed this frame"):
            child.segment(points, [np.array([len(points) + 10])])  # a member index past the points
        assert len(child.segment(points, members).labels) == len(points)  # the child keeps serving
    finally:
        child.close()
    with pytest.raises(ClassifierProcessError, match="ended"):
        child.segment(points, members)


def test_child_that_cannot_load_says_why(tmp_path) -> None:
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    with pytest.raises(ClassifierError, match="could not load the classifier"):
        ProcessClassifier(str(broken))
    with pytest.raises(ClassifierError, match=r"could not load the classifier: ClassifierError: .*nowhere\.pt: no "):
        ProcessClassifier(str(tmp_path / "nowhere.pt"), "network")


def test_restart_back_off_and_exit_descriptions() -> None:
    assert [restart_delay(k) for k in range(8)] == [1, 2, 4, 8, 16, 30, 30, 30]
    assert restart_delay(10_000) == 30
    assert describe_exit(-signal.SIGKILL) == "killed by SIGKILL, as the out-of-memory killer does"
    assert describe_exit(-signal.SIGSEGV) == "killed by SIGSEGV"
    assert describe_exit(3) == "exit code 3"


def test_a_killed_child_is_restarted_and_sigint_is_left_to_the_parent(
    frame_and_members, capfd: pytest.CaptureFixture[str]
) -> None:
    points, members = frame_and_members
    reports: list[tuple[str, str]] = []
    child = ProcessClassifier("", "size_rules", report=lambda level, message: reports.append((level, message)))
    try:
        expected = child.segment(points, members)
        first = child.pid
        os.kill(first, signal.SIGINT)  # what Ctrl-C sends the whole process group
        time.sleep(1.0)
        assert child.segment(points, members).labels.tobytes() == expected.labels.tobytes()
        assert child.pid == first and child.restarts == 0 and reports == []

        os.kill(first, signal.SIGKILL)  # what the out-of-memory killer sends
        deadline = time.monotonic() + 5.0
        while child.down_for() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert child.down_for() is not None
        with pytest.raises(ClassifierProcessDownError, match="down for"):
            child.segment(points, members)  # at once, not after a wait
        deadline = time.monotonic() + 90.0
        while child.restarts == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        got = child.segment(points, members)
        assert child.restarts == 1 and child.pid != first and child.down_for() is None
        assert got.labels.tobytes() == expected.labels.tobytes()
        assert reports[0] == ("error", f"stage 2 process {first} died (killed by SIGKILL, as the out-of-memory "
                                       "killer does); frames are dropped until it is restarted, in 1 s")
        assert [level for level, _ in reports] == ["error", "info"], reports
        assert reports[1][1].startswith(f"stage 2 restarted in process {child.pid} (restart 1, down ")
    finally:
        child.close()
    assert "KeyboardInterrupt" not in capfd.readouterr().err


def test_closing_during_a_restart_leaves_no_child() -> None:
    child = ProcessClassifier("", "size_rules")
    os.kill(child.pid, signal.SIGKILL)
    deadline = time.monotonic() + 5.0
    while child.down_for() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(1.5)  # past the 1 s back-off: the new child is loading
    started = time.monotonic()
    child.close()
    assert time.monotonic() - started < 2.0, "a loading child is terminated, not asked politely"
    assert child.restarts == 0 and not [p for p in mp.active_children() if p.name == "pass3d-stage2"]
    with pytest.raises(ClassifierProcessDownError, match="closed"):
        child.segment(np.zeros((1, 4), np.float32), [])


def test_closing_ends_a_stopped_idle_child(monkeypatch: pytest.MonkeyPatch) -> None:
    child = ProcessClassifier("", "size_rules", timeout_s=5.0)
    process = next(p for p in mp.active_children() if p.pid == child.pid)
    monkeypatch.setattr(classifier_process, "STOP_TIMEOUT_S", 0.5)
    os.kill(child.pid, signal.SIGSTOP)  # no frame in hand: nothing for the supervisor's timeout to kill
    try:
        child.close()
        assert not process.is_alive(), "a stopped child outlives close, and the interpreter's exit waits for it"
    finally:
        if process.is_alive():
            process.kill()
            process.join()


def test_closing_ends_a_child_stopped_mid_frame(frame_and_members, monkeypatch: pytest.MonkeyPatch) -> None:
    points, members = frame_and_members
    big = np.tile(points, (20, 1))  # megabytes: the pipe fills while the stopped child reads none of it
    child = ProcessClassifier("", "size_rules", timeout_s=600.0)
    monkeypatch.setattr(classifier_process, "STOP_TIMEOUT_S", 0.5)
    os.kill(child.pid, signal.SIGSTOP)
    errors: list[BaseException] = []

    def frame() -> None:
        try:
            child.segment(big, members)
        except ClassifierProcessDownError as exc:
            errors.append(exc)

    worker = threading.Thread(target=frame, daemon=True)
    worker.start()
    time.sleep(0.5)
    closer = threading.Thread(target=child.close, daemon=True)
    closer.start()
    closer.join(10.0)
    worker.join(5.0)
    assert not closer.is_alive(), "close blocks on the stopped child's full pipe"
    assert not worker.is_alive() and len(errors) == 1
