"""People in groups (pass3d_ros.core.stage2.groups, `people_in_groups`): a proposal stage 2 calls background that
holds two people or more is read again person by person, and changes only when every person is called pedestrian."""

from __future__ import annotations

import itertools

import numpy as np
from helpers.scans import person_points

from pass3d_ros.classes import BACKGROUND, CAR, PEDESTRIAN
from pass3d_ros.core.pipeline import ProposalSegmenter
from pass3d_ros.core.stage2 import groups
from pass3d_ros.core.stage2.segmentation import SegmentResult


class ByWidth:
    """A stand-in classifier: a proposal no wider than one person (x-y extent under 0.7 m) is pedestrian, anything
    wider background (as the network reads two people side by side); `refuse`: proposals whose centre lies at x above
    this are background whatever their width (one person-like part in clutter). Counts its calls and proposals."""

    def __init__(self, refuse: float = np.inf, max_proposals: int = 128) -> None:
        self.refuse, self.max_proposals = refuse, max_proposals
        self.calls: list[int] = []

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        self.calls.append(len(members))
        labels = np.zeros(len(points), dtype=np.uint8)
        confidence = np.zeros(len(points), dtype=np.float32)
        proposal_class = np.full(len(members), -1, dtype=np.int16)
        for k, member in enumerate(members[:self.max_proposals]):
            xy = points[member, :2]
            narrow = (xy.max(axis=0) - xy.min(axis=0)).max() < 0.7 and xy[:, 0].mean() <= self.refuse
            proposal_class[k] = PEDESTRIAN if narrow else BACKGROUND
            labels[member] = proposal_class[k]
            confidence[member] = 0.9 if narrow else 0.8
        return SegmentResult(labels, confidence, proposal_class)


def scan_of(*proposals: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Points (N x 4 float32) and members of proposals, each a list of people's points (x, y, height)."""
    chunks = [np.concatenate(people) for people in proposals]
    points = np.zeros((sum(len(c) for c in chunks), 4), dtype=np.float32)
    points[:, :3] = np.concatenate(chunks)
    ends = np.cumsum([0] + [len(c) for c in chunks])
    return points, [np.arange(a, b) for a, b in itertools.pairwise(ends)]


def pair(x: float, y: float, spacing: float, rng: np.random.Generator) -> list[np.ndarray]:
    return [person_points(x, y, 1.75, rng), person_points(x, y + spacing, 1.65, rng)]


def test_a_pair_called_background_is_read_person_by_person() -> None:
    rng = np.random.default_rng(0)
    points, members = scan_of(pair(8.0, 0.0, 0.6, rng))
    classifier = ByWidth()
    first = classifier.segment(points, members)
    assert first.proposal_class[0] == BACKGROUND
    result, read = groups.people_in_groups(points, members, first, classifier)
    assert read == 2 and classifier.calls == [1, 2]
    assert (result.labels[members[0]] == PEDESTRIAN).mean() > 0.9
    assert result.proposal_class[0] == PEDESTRIAN
    assert np.allclose(result.confidence[result.labels == PEDESTRIAN], 0.9)


def test_nothing_changes_unless_every_person_is_called_pedestrian() -> None:
    """Two groups; the classifier calls the far one's second part background: that group stays as it was."""
    rng = np.random.default_rng(1)
    near, far = pair(8.0, 0.0, 0.6, rng), [person_points(20.0, 0.0, 1.75, rng), person_points(20.6, 0.0, 1.7, rng)]
    points, members = scan_of(near, far)
    classifier = ByWidth(refuse=20.3)
    first = classifier.segment(points, members)
    result, read = groups.people_in_groups(points, members, first, classifier)
    assert read == 4
    assert (result.labels[members[0]] == PEDESTRIAN).mean() > 0.9
    assert np.array_equal(result.labels[members[1]], first.labels[members[1]])
    assert result.proposal_class.tolist() == [PEDESTRIAN, BACKGROUND]


def test_only_group_shaped_proposals_not_called_pedestrian_are_read() -> None:
    rng = np.random.default_rng(2)
    lone = [person_points(5.0, 0.0, 1.75, rng)]  # called pedestrian already
    tall = pair(10.0, 0.0, 0.6, rng)
    tall[0][:, 2] *= 1.6  # rises 2.8 m: no group of people
    wide = [person_points(15.0, y, 1.7, rng) for y in (0.0, 0.7, 1.4, 2.1, 2.8)]  # 3.2 m wide
    points, members = scan_of(lone, tall, wide)
    assert not any(groups.looks_like_group(points, m, ByWidth().segment(points, members).labels) for m in members)
    classifier = ByWidth()
    first = classifier.segment(points, members)
    result, read = groups.people_in_groups(points, members, first, classifier)
    assert read == 0 and classifier.calls == [3] and result is first


def test_a_flat_top_is_no_group() -> None:
    """A box of a group's size whose top runs on at one height (a car's boot, a bench) shows no heads: not read."""
    rng = np.random.default_rng(3)
    n = 800
    xyz = np.stack([rng.uniform(0, 1.2, n), rng.uniform(0, 0.6, n), rng.uniform(0.0, 1.3, n)], axis=1)
    points, members = scan_of([xyz])
    classifier = ByWidth()
    first = classifier.segment(points, members)
    assert groups.looks_like_group(points, members[0], first.labels)
    assert groups.group_parts(points, members[0]) == []
    assert groups.people_in_groups(points, members, first, classifier)[1] == 0


def test_a_part_left_unread_by_the_budget_keeps_its_group_as_it_was() -> None:
    rng = np.random.default_rng(4)
    points, members = scan_of(pair(8.0, 0.0, 0.6, rng))
    classifier = ByWidth(max_proposals=1)
    first = classifier.segment(points, members)
    result, read = groups.people_in_groups(points, members, first, classifier)
    assert read == 2 and np.array_equal(result.labels, first.labels)


def test_the_segmenter_reads_groups_only_when_asked() -> None:
    rng = np.random.default_rng(5)
    points, members = scan_of(pair(8.0, 0.0, 0.6, rng), [person_points(12.0, 3.0, 1.7, rng)])
    for on, calls in ((False, [2]), (True, [2, 2])):
        classifier = ByWidth()
        segmenter = ProposalSegmenter(classifier, intensity_match=False, people_in_groups=on)
        result = segmenter.segment(points, members)
        assert classifier.calls == calls and segmenter.group_parts_read == (2 if on else 0)
        assert result.proposal_class[0] == (PEDESTRIAN if on else BACKGROUND)
        assert result.proposal_class[1] == PEDESTRIAN


def test_a_car_proposal_is_read_too_and_keeps_its_points_that_are_no_person() -> None:
    """A proposal called car of a group's size is read as one not called pedestrian; points a part leaves out (a bag
    far from every head) keep their label."""
    rng = np.random.default_rng(6)
    people = pair(8.0, 0.0, 0.6, rng)
    bag = np.array([[8.0, 1.6, 0.3]] * 3) + rng.normal(0, 0.02, (3, 3))
    points, members = scan_of([*people, bag])
    first = ByWidth().segment(points, members)
    first = SegmentResult(np.where(first.labels == BACKGROUND, CAR, first.labels).astype(np.uint8), first.confidence,
                          np.array([CAR], dtype=np.int16))
    result, _ = groups.people_in_groups(points, members, first, ByWidth())
    assert (result.labels[members[0][:-3]] == PEDESTRIAN).mean() > 0.9
    assert (result.labels[members[0][-3:]] == CAR).all()
    assert result.proposal_class[0] == PEDESTRIAN
