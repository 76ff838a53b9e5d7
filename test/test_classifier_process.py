"""The stage-2 classifier in a child process (pass3d_ros.core.classifier_process): the same results as in this
process, a failed frame reported and survived, and clear errors when the child cannot serve."""

from __future__ import annotations

import numpy as np
import pytest

from pass3d_ros.core.classifier_process import ClassifierProcessError, ProcessClassifier
from pass3d_ros.core.stage1 import proposal_members, propose
from pass3d_ros.core.stage2 import ClassifierError, load_classifier, resolve_weights
from pass3d_ros.synthetic.dataset import generate_frame


@pytest.fixture(scope="module")
def frame_and_members() -> tuple[np.ndarray, list[np.ndarray]]:
    frame = generate_frame(seed=7, index=0)
    result = propose(frame.points, frame.ring)
    return frame.points, proposal_members(result.cluster_id, result.cluster_id2)


def test_child_process_segments_like_this_process(frame_and_members) -> None:
    points, members = frame_and_members
    kind, weights = resolve_weights("network", "")
    here = load_classifier(kind, weights)
    child = ProcessClassifier(kind, weights)
    try:
        assert child.pid > 0
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
        ProcessClassifier("network", str(broken))
