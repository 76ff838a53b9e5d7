"""One door per scan (pass3d_ros.core.pipeline): no module outside the core runs stage 1 or stage 2 on its own, and the
pipeline gives what the stages give when called by hand."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.core.pipeline import ScanPipeline, matches_intensity
from pass3d_ros.core.stage1 import Stage1Config, proposal_members, propose, synthetic_scan
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier

PACKAGE = Path(__file__).resolve().parents[2] / "pass3d_ros"

# What running a stage by hand needs: stage 1's entry, the members of its proposals, and a stream's holders.
DOOR_NAMES = {"propose", "proposal_members", "ScanStream", "LineHolder", "MountingHolder", "BodyHolder",
              "StreamIntensityMatch", "StreamIntensityScale"}
# Where those may be imported: the door itself and what it is built of; stage 1's benchmark, which times the kernel
# on fixed inputs; and the ROS layer's proposals codec, which rebuilds a message's members from its cluster ids.
ALLOWED = ("core/pipeline.py", "core/stage1/", "core/stream/", "bench/stage1.py", "ros/proposals.py",
           "ros/segmentation_node.py")
# A classifier's stage 2 is called through the pipeline: stage 2's own modules, the stream's intensity map and stage
# 2's benchmark (it times the classifier on fixed proposals) aside.
SEGMENT_ALLOWED = ("core/pipeline.py", "core/stage2/", "core/stream/", "bench/stage2.py")


def _modules() -> list[tuple[str, ast.Module]]:
    return [(path.relative_to(PACKAGE).as_posix(), ast.parse(path.read_text(), str(path)))
            for path in sorted(PACKAGE.rglob("*.py"))]


def test_no_module_outside_the_door_imports_what_running_a_stage_by_hand_needs() -> None:
    found = []
    for name, tree in _modules():
        if name.startswith(ALLOWED):
            continue
        typing_only = {id(inner) for node in ast.walk(tree) if isinstance(node, ast.If)
                       and ast.unparse(node.test) == "TYPE_CHECKING" for inner in ast.walk(node)}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("pass3d_ros.core") \
                    and id(node) not in typing_only:
                found += [f"{name}: {alias.name}" for alias in node.names if alias.name in DOOR_NAMES]
    assert found == []


def test_no_module_outside_the_door_calls_a_classifier_on_proposals() -> None:
    """`x.segment(points, members)` and `x.on_training_scale(points)` only inside the door (the pipeline's
    `segment`, the segmentation node's ProposalSegmenter `stage2`)."""
    found = []
    for name, tree in _modules():
        if name.startswith(SEGMENT_ALLOWED):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                    and node.func.attr in ("segment", "on_training_scale"):
                receiver = ast.unparse(node.func.value)
                if not receiver.endswith(("pipeline", "stage2")):
                    found.append(f"{name}:{node.lineno}: {ast.unparse(node.func)}")
    assert found == []


def test_the_pipeline_proposes_what_stage_1_proposes_by_hand() -> None:
    scan = synthetic_scan(points_per_ring=900)
    config = Stage1Config(sensor_height=1.73)
    by_hand = propose(scan, None, config)
    proposed = ScanPipeline(config, intensity_match=False).propose(scan)
    assert np.array_equal(proposed.result.cluster_id, by_hand.cluster_id)
    assert np.array_equal(proposed.result.ground, by_hand.ground)
    members = proposal_members(by_hand.cluster_id, by_hand.cluster_id2, by_hand.n_proposals)
    assert len(proposed.members) == len(members) and all(
        np.array_equal(a, b) for a, b in zip(proposed.members, members, strict=True))


def test_points_the_checks_leave_out_are_background_in_no_proposal_at_their_input_positions() -> None:
    scan = synthetic_scan(points_per_ring=900)
    bad = scan.copy()
    bad[::7, 0] = np.nan  # a driver's no-returns
    bad[3::11, :3] = 0.0  # and its zeros
    pipeline = ScanPipeline(classifier=SizeRuleClassifier())
    labelled = pipeline.run(bad)
    proposed = labelled.proposed
    left_out = np.ones(len(bad), bool)
    left_out[proposed.scan.kept] = False
    assert left_out.sum() == np.count_nonzero(~np.isfinite(bad[:, 0]) | (bad[:, :3] == 0).all(axis=1))
    labels = labelled.labels_in_input(len(bad))
    ids = proposed.in_input(proposed.result.cluster_id, len(bad), -1)
    assert labels.shape == ids.shape == (len(bad),)
    assert (labels[left_out] == 0).all() and (ids[left_out] == -1).all()
    assert (labels[~left_out] > 0).any(), "the object 8 m ahead is labelled"
    for members in proposed.input_members():
        assert not left_out[members].any()


def test_an_empty_scan_proposes_nothing_and_teaches_the_stream_nothing() -> None:
    pipeline = ScanPipeline(classifier=SizeRuleClassifier())
    labelled = pipeline.run(np.full((5, 4), np.nan, np.float32))
    assert labelled.proposed.empty and labelled.proposed.members == []
    assert labelled.labels_in_input(5).tolist() == [0] * 5
    assert pipeline.stream.lines.held is None and pipeline.stream.mounting.readings == 0


@pytest.mark.parametrize(("wanted", "kind", "expected"), [(True, "network", True), (True, "size_rules", False),
                                                         (False, "network", False), (True, None, True)])
def test_intensities_are_matched_only_for_the_network(wanted: bool, kind: str | None, expected: bool) -> None:
    classifier = None if kind is None else type("C", (), {"kind": kind})()
    assert matches_intensity(wanted, classifier) is expected
