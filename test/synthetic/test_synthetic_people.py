"""Issue 37's people in the synthetic world: groups a hand's breadth apart, pedestrians beside riders, lone
pedestrians far away and with loads (`synthetic.crowds`, world changes "groups" and "lone_people")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pass3d_ros.classes import CYCLIST, PEDESTRIAN
from pass3d_ros.synthetic.builder import TOUCH_CLEARANCE_M, SceneObject
from pass3d_ros.synthetic.dataset import generate_frame
from pass3d_ros.synthetic.objects.people import LOADS, pedestrian
from pass3d_ros.synthetic.parts import part_extent
from pass3d_ros.synthetic.scene import generate_scene

SEEDS = range(12)  # generate_frame(seed, 0)'s scenes
NEW_MODELS = {"group_member", "beside_rider", "waiting_cyclist", "lone_pedestrian"}


def _scene(seed: int, without: frozenset[str] = frozenset()):
    return generate_scene(np.random.default_rng(np.random.SeedSequence([seed, 0])), without)


@pytest.fixture(scope="module")
def scenes() -> dict[int, tuple]:
    """(full scene, scene without both changes) per seed."""
    return {seed: (_scene(seed), _scene(seed, frozenset({"groups", "lone_people"}))) for seed in SEEDS}


def _footprint(o: SceneObject) -> np.ndarray:
    """Corners (4 x 2) of an object's footprint in the sensor frame."""
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    local = [(o.local_min[0], o.local_min[1]), (o.local_max[0], o.local_min[1]), (o.local_max[0], o.local_max[1]),
             (o.local_min[0], o.local_max[1])]
    return np.array([(o.x + c * x - s * y, o.y + s * x + c * y) for x, y in local])


def _gap(a: SceneObject, b: SceneObject) -> float:
    """Distance between two footprints (rectangles that do not overlap): the closest of their edge samples."""

    def edge_points(o: SceneObject) -> np.ndarray:
        corners = _footprint(o)
        t = np.linspace(0.0, 1.0, 60)[:, None]
        return np.concatenate([corners[k] + t * (corners[(k + 1) % 4] - corners[k]) for k in range(4)])

    pa, pb = edge_points(a), edge_points(b)
    return float(np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)).min())


def test_without_the_changes_the_scene_is_the_one_before(scenes):
    """Both changes come last, from streams of their own: left out, the scene is the rest object for object (the
    world before issue 37), and with them it only gains people."""
    for full, plain in scenes.values():
        assert not NEW_MODELS & {o.model for o in plain.objects}
        assert [(o.model, o.x, o.y) for o in full.objects[:len(plain.objects)]] == [
            (o.model, o.x, o.y) for o in plain.objects]
        assert {o.model for o in full.objects[len(plain.objects):]} <= NEW_MODELS
    only_groups = _scene(0, frozenset({"lone_people"}))
    assert "lone_pedestrian" not in {o.model for o in only_groups.objects}
    assert "group_member" in {o.model for o in only_groups.objects}
    assert [o.model for o in _scene(0, frozenset({"groups"})).objects] != [o.model for o in scenes[0][0].objects]


def test_groups_stand_a_hand_apart_and_people_beside_riders(scenes):
    """Groups hold 2-4 pedestrians, each 0.15-0.5 m (footprint to footprint) from another member, in some scenes but
    not all; pedestrians beside riders stand 0.2-0.8 m from a cyclist; everyone keeps a pedestrian's label."""
    with_group = 0
    for full, plain in scenes.values():
        new = full.objects[len(plain.objects):]
        members = [o for o in new if o.model == "group_member"]
        with_group += bool(members)
        for o in members:
            assert o.label == PEDESTRIAN and o.kind == "Pedestrian"
            others = [m for m in members if m is not o]
            assert others, "a group has two members at least"
            assert TOUCH_CLEARANCE_M - 0.01 < min(_gap(o, m) for m in others) < 0.5
        cyclists = [o for o in full.objects if o.label == CYCLIST]
        for o in new:
            if o.model == "beside_rider":
                assert o.label == PEDESTRIAN
                assert 0.15 < min(_gap(o, c) for c in cyclists) < 0.85
            if o.model == "waiting_cyclist":
                assert o.label == CYCLIST and o.kind == "Cyclist"
    assert 2 <= with_group <= 9, with_group  # about 37 % of scenes


def test_lone_pedestrians_stand_far_in_two_bands(scenes):
    """0-2 lone pedestrians a scene, at 30-58 m (few HDL-64E rings) or 9-25 m (few VLP-16 / HDL-32E rings)."""
    lone = [o for full, _ in scenes.values() for o in full.objects if o.model == "lone_pedestrian"]
    assert 0.4 * len(SEEDS) <= len(lone) <= 2 * len(SEEDS)
    ranges = np.array([math.hypot(o.x, o.y) for o in lone])
    assert np.all(((ranges > 8.5) & (ranges < 25.5)) | ((ranges > 29.5) & (ranges < 58.5))), ranges
    assert (ranges > 29.5).any() and (ranges < 25.5).any()


def test_loads_make_long_pedestrians_and_leave_the_others_alone():
    """A pulled suitcase makes a pedestrian as long as a short cyclist; without a load the draws are as before."""
    def length(load: str, seed: int) -> float:
        parts, _, _ = pedestrian(np.random.default_rng(seed), "walk", load=load)
        lo = np.min([p.center - part_extent(p) for p in parts], axis=0)
        hi = np.max([p.center + part_extent(p) for p in parts], axis=0)
        assert lo[2] > -0.01  # nothing below the ground
        return float(hi[0] - lo[0])

    suitcase = np.mean([length("suitcase", seed) for seed in range(40)])
    plain = np.mean([length("", seed) for seed in range(40)])
    assert suitcase > plain + 0.3 and 1.0 < suitcase < 1.6
    for load in LOADS:
        length(load, 0)
    a, b = pedestrian(np.random.default_rng(9)), pedestrian(np.random.default_rng(9), load="")
    assert [p.center.tobytes() for p in a[0]] == [p.center.tobytes() for p in b[0]]
    with pytest.raises(ValueError, match="unknown load"):
        pedestrian(np.random.default_rng(0), load="dog")


def test_stage1_proposes_group_members_together_each_with_its_own_label(scenes):
    """In some scene of seeds 0..11 a stage-1 proposal holds two or more group members, each labelled pedestrian
    with an instance of its own; some lone far pedestrian shows with 3-6 HDL-64E rings."""
    from pass3d_ros.core.stage1 import proposal_members, propose

    together = few_rings = False
    for seed, (full, _) in scenes.items():
        models = {o.model for o in full.objects}
        if together and few_rings:
            break
        if not models & {"group_member", "lone_pedestrian"}:
            continue
        frame = generate_frame(seed, 0)
        members = {b.instance for b in frame.boxes
                   if b.label == PEDESTRIAN and any(o.model == "group_member" and math.hypot(
                       o.x - b.center[0], o.y - b.center[1]) < 0.6 for o in full.objects)}
        lone = {b.instance for b in frame.boxes
                if any(o.model == "lone_pedestrian" and math.hypot(o.x - b.center[0], o.y - b.center[1]) < 0.6
                       and math.hypot(o.x, o.y) > 29.5 for o in full.objects)}
        for i in lone:
            rings = len(np.unique(frame.ring[frame.instance == i]))
            few_rings |= 3 <= rings <= 6
        res = propose(frame.points, frame.ring)
        for idx in proposal_members(res.cluster_id, res.cluster_id2, res.n_proposals):
            inst, count = np.unique(frame.instance[idx], return_counts=True)
            held = [int(i) for i, c in zip(inst, count, strict=True) if int(i) in members and c >= 5]
            if len(held) >= 2:
                together = True
                for i in held:
                    assert np.all(frame.labels[frame.instance == i] == PEDESTRIAN)
    assert together, "no stage-1 proposal holds two group members"
    assert few_rings, "no far lone pedestrian shows with 3-6 rings"
