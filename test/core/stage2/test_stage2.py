"""Stage 2: canonical frames, sampling, the PointNet++ model, inference, checkpoints, size rules."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, NUM_CLASSES, PEDESTRIAN
from pass3d_ros.core import stage2
from pass3d_ros.core.stage2 import ClassifierError, canonical, open_classifier
from pass3d_ros.core.stage2.pointnet2 import (
    ModelConfig,
    PointNet2Seg,
    ball_query,
    count_parameters,
    farthest_point_sample,
    flush_subnormals,
    fuse_batchnorm,
    make_config,
    pairwise_sq_dist,
)
from pass3d_ros.core.stage2.segmentation import (
    CheckpointError,
    Segmenter,
    SegmentResult,
    make_checkpoint,
    people_only,
    predict_probabilities,
    prepare_proposals,
    scatter_predictions,
)
from pass3d_ros.core.stage2.size_rules import SizeRuleClassifier


def box_points(size, yaw, centre, count, rng, zmin=-1.7):
    """Points uniformly inside a box (length, width, height) turned by yaw about z, with intensity."""
    local = rng.uniform([-size[0] / 2, -size[1] / 2, 0.0], [size[0] / 2, size[1] / 2, size[2]], (count, 3))
    c, s = np.cos(yaw), np.sin(yaw)
    x = local[:, 0] * c - local[:, 1] * s + centre[0]
    y = local[:, 0] * s + local[:, 1] * c + centre[1]
    xyz = np.stack([x, y, local[:, 2] + zmin], axis=1)
    return np.column_stack([xyz, rng.uniform(0, 1, count)]).astype(np.float32)


def asymmetric_cloud(rng):
    """A box-filling cloud with an extra lump near one vertex, so no view equals another."""
    pts = box_points((4.0, 1.8, 1.5), 0.7, (10.0, 5.0), 400, rng)
    lump = box_points((0.5, 0.4, 0.3), 0.7, (10.0 + 1.5 * np.cos(0.7), 5.0 + 1.5 * np.sin(0.7)), 100, rng)
    return np.concatenate([pts, lump])




# ------------------------------------------------------------------------------------------- canonical


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2, np.pi / 2, 2.5])
def test_fit_box_recovers_rotated_rectangle(yaw):
    rng = np.random.default_rng(1)
    corners = box_points((4.0, 1.6, 1.5), yaw, (5.0, -3.0), 4, rng)
    pts = np.concatenate([box_points((4.0, 1.6, 1.5), yaw, (5.0, -3.0), 800, rng), corners])
    boxes = canonical.fit_boxes(pts[:, :3], np.array([0, len(pts)]))
    assert boxes.size[0, 0] == pytest.approx(4.0, abs=0.08)
    assert boxes.size[0, 1] == pytest.approx(1.6, abs=0.08)
    assert boxes.center[0] == pytest.approx([5.0, -3.0], abs=0.05)
    assert -np.pi / 2 < boxes.yaw[0] <= np.pi / 2
    assert np.mod(boxes.yaw[0] - yaw + np.pi / 2, np.pi) - np.pi / 2 == pytest.approx(0.0, abs=0.02)


def test_fit_boxes_is_near_minimal_area_for_many_groups():
    rng = np.random.default_rng(2)
    groups = [rng.normal(size=(int(rng.integers(3, 300)), 3)) * rng.uniform(0.2, 3, 3) for _ in range(25)]
    offsets = np.concatenate([[0], np.cumsum([len(g) for g in groups])])
    boxes = canonical.fit_boxes(np.concatenate(groups), offsets)
    alone = [canonical.fit_boxes(g, np.array([0, len(g)])) for g in groups]  # a box ignores the other groups
    for field in ("center", "size", "yaw", "zmin"):
        assert np.allclose(np.concatenate([getattr(a, field) for a in alone]), getattr(boxes, field))
    fine = np.deg2rad(np.arange(0, 90, 0.05))
    for g, size in zip(groups, boxes.size, strict=True):
        pu = g[:, 0:1] * np.cos(fine) + g[:, 1:2] * np.sin(fine)
        pv = g[:, 1:2] * np.cos(fine) - g[:, 0:1] * np.sin(fine)
        brute = np.min(np.ptp(pu, axis=0) * np.ptp(pv, axis=0))
        assert size[0] * size[1] <= brute * 1.002 + 1e-9
        assert size[0] >= size[1]
        assert size[2] == pytest.approx(np.ptp(g[:, 2]))


def test_canonical_frame_first_octant_and_box_on_axes():
    rng = np.random.default_rng(3)
    pts = asymmetric_cloud(rng)
    boxes = canonical.fit_boxes(pts[:, :3], np.array([0, len(pts)]))
    length, width, height = boxes.size[0]
    corners = np.column_stack([canonical.vertices(boxes)[0], np.full(4, boxes.zmin[0])])
    for view in range(canonical.NUM_VIEWS):
        local = canonical.to_canonical(pts[:, :3], boxes, np.zeros(len(pts), int), np.array([view]))
        assert local.min(axis=0) == pytest.approx([0, 0, 0], abs=1e-6)
        extent = local.max(axis=0)
        assert sorted(extent[:2]) == pytest.approx(sorted([length, width]), abs=1e-6)
        assert extent[2] == pytest.approx(height, abs=1e-6)
        # The box's own vertices land on the corners of [0, a] x [0, b]: its edges lie on the axes.
        mapped = canonical.to_canonical(corners, boxes, np.zeros(4, int), np.array([view]))
        expected = {(0.0, 0.0), (extent[0], 0.0), (0.0, extent[1]), (extent[0], extent[1])}
        got = {(round(x, 5), round(y, 5)) for x, y in mapped[:, :2]}
        assert got == {(round(x, 5), round(y, 5)) for x, y in expected}
        # The view's origin is its vertex.
        assert mapped[view % 4, :2] == pytest.approx([0, 0], abs=1e-6)


def test_eight_views_distinct_with_right_and_left_handed_frames():
    rng = np.random.default_rng(4)
    pts = asymmetric_cloud(rng)
    boxes = canonical.fit_boxes(pts[:, :3], np.array([0, len(pts)]))
    probe = np.array([[10.0, 5.0, 0.0], [11.0, 5.0, 0.0], [10.0, 6.0, 0.0], [10.0, 5.0, 1.0]])
    clouds = []
    for view in range(8):
        local = canonical.to_canonical(np.concatenate([pts[:, :3], probe]), boxes, np.zeros(len(pts) + 4, int), [view])
        clouds.append(local[: len(pts)])
        p = local[len(pts) :]
        basis = np.stack([p[1] - p[0], p[2] - p[0], p[3] - p[0]], axis=1)
        assert np.linalg.det(basis) == pytest.approx(1.0 if view < 4 else -1.0, abs=1e-6)
    for i in range(8):
        for j in range(i + 1, 8):
            assert not np.allclose(clouds[i], clouds[j], atol=1e-3), (i, j)


def test_inference_view_uses_vertex_nearest_sensor():
    rng = np.random.default_rng(5)
    pts = box_points((4.0, 1.8, 1.5), 0.4, (-12.0, 7.0), 300, rng)
    boxes = canonical.fit_boxes(pts[:, :3], np.array([0, len(pts)]))
    view = canonical.inference_views(boxes)
    corners = canonical.vertices(boxes)[0]
    assert view[0] == np.argmin(np.hypot(corners[:, 0], corners[:, 1]))
    assert view[0] < 4


def test_inference_sample_is_the_seeded_draw_and_read_only():
    for count in (40, 1000):
        drawn = canonical.sample_indices(count, 256, canonical.inference_rng(count))
        cached = canonical.inference_sample(count, 256)
        np.testing.assert_array_equal(cached, drawn)
        assert canonical.inference_sample(count, 256) is cached and not cached.flags.writeable


def test_sampling_exact_count_and_n_feature():
    rng = np.random.default_rng(6)
    many = canonical.sample_indices(1000, 256, rng)
    assert len(many) == 256 and len(np.unique(many)) == 256 and many.max() < 1000
    few = canonical.sample_indices(40, 256, rng)
    assert len(few) == 256 and set(few.tolist()) == set(range(40))
    assert canonical.n_feature(40, 256) == pytest.approx((40 - 256) / 256)
    assert canonical.n_feature(512, 256, "log") == pytest.approx(np.log(2))
    with pytest.raises(ValueError):
        canonical.n_feature(40, 256, "cube")
    config = make_config("lite")
    big, small = box_points((4, 2, 1.5), 0.0, (8, 0), 700, rng), box_points((1, 1, 1.7), 0.0, (-5, 3), 40, rng)
    pts = np.concatenate([big, small])
    batch = prepare_proposals(pts, [np.arange(700), np.arange(700, 740)], config)
    assert batch.sample_xyz.shape == (2, config.num_points, 3)
    assert config.n_mode == "log"
    assert batch.sample_feat[0, :, 1] == pytest.approx(np.full(256, np.log(700 / 256)))
    assert batch.sample_feat[1, :, 1] == pytest.approx(np.full(256, np.log(40 / 256)))
    config.n_mode = "ratio"
    batch = prepare_proposals(pts, [np.arange(700), np.arange(700, 740)], config)
    assert batch.sample_feat[0, :, 1] == pytest.approx(np.full(256, (700 - 256) / 256))
    assert batch.sample_feat[1, :, 1] == pytest.approx(np.full(256, (40 - 256) / 256))
    assert np.all(batch.sample_xyz >= 0)
    assert len(batch.query_xyz) == 740
    config.n_feature = False
    assert np.all(prepare_proposals(pts, [np.arange(700)], config).sample_feat[..., 1] == 0)


# ------------------------------------------------------------------------------------------------- model


def test_ops_fps_and_ball_query():
    xyz = torch.tensor([[[0.0, 0, 0], [0.1, 0, 0], [5, 0, 0], [5, 5, 0], [0, 5, 0]]])
    d2 = pairwise_sq_dist(xyz, xyz)
    assert torch.allclose(d2, ((xyz[:, :, None] - xyz[:, None]) ** 2).sum(-1), atol=1e-5)
    assert farthest_point_sample(d2, 3)[0].tolist() == [0, 3, 2]  # p2 and p4 tie; the first wins
    idx = ball_query(d2[:, :1], 0.5, 4)
    assert idx[0, 0].tolist() == [0, 1, 0, 0]


@pytest.mark.parametrize("name", ["lite", "paper"])
def test_model_forward_shapes(name):
    torch.manual_seed(0)
    config = make_config(name)
    model = PointNet2Seg(config)
    n = config.num_points
    xyz, feat = torch.rand(2, n, 3) * torch.tensor([4.0, 2.0, 1.5]), torch.rand(2, n, 2)
    logits = model(xyz, feat)
    assert logits.shape == (2, n, NUM_CLASSES)
    logits.sum().backward()
    assert all(p.grad is not None for p in model.parameters())
    model.eval()
    with torch.no_grad():
        coarse_xyz, coarse_feat = model.encode(xyz, feat)
        assert coarse_xyz.shape == (2, config.sa[0].centres, 3)
        assert model.decode(coarse_xyz, coarse_feat, xyz[:1, :10], feat[:1, :10], torch.tensor([1])).shape == (
            1,
            10,
            NUM_CLASSES,
        )
    assert count_parameters(model) > 0


def test_config_round_trip_and_check():
    config = make_config("paper")
    assert ModelConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="unknown model config keys"):
        ModelConfig.from_dict({**config.to_dict(), "bogus": 1})
    with pytest.raises(ValueError):
        make_config("huge")


def test_fused_batchnorm_matches_eval_model():
    torch.manual_seed(1)
    model = PointNet2Seg(make_config("lite"))
    xyz, feat = torch.rand(3, 256, 3) * 2, torch.rand(3, 256, 2)
    model.train()
    model(xyz, feat)  # move the BN running statistics away from their defaults
    model.eval()
    clone = PointNet2Seg(model.config)
    clone.load_state_dict(model.state_dict())
    fused = fuse_batchnorm(clone)
    assert not any(isinstance(m, torch.nn.BatchNorm1d) for m in fused.modules())
    with torch.no_grad():
        assert torch.allclose(fused(xyz, feat), model(xyz, feat), atol=1e-4)


def test_subnormal_weights_are_flushed_for_inference():
    """Subnormal weights (slow on x86) become 0 and nothing else changes; the inference model holds none."""
    torch.manual_seed(2)
    model = PointNet2Seg(make_config("lite")).eval()
    weight = model.sa[0].mlps[0].layers[0].weight
    before = {k: v.clone() for k, v in model.state_dict().items()}
    with torch.no_grad():
        weight[0, :3] = torch.tensor([1e-39, -3e-40, 2e-38])  # two subnormals and the smallest-but-normal kind
    segmenter = Segmenter(make_checkpoint(model))
    flush_subnormals(model)
    assert weight[0, 0].item() == 0.0 and weight[0, 1].item() == 0.0 and weight[0, 2].item() == pytest.approx(2e-38)
    for key, value in model.state_dict().items():
        if key.endswith("sa.0.mlps.0.layers.0.weight"):
            torch.testing.assert_close(value[1:], before[key][1:])
            torch.testing.assert_close(value[0, 3:], before[key][0, 3:])
        else:
            torch.testing.assert_close(value, before[key])
    tiny = torch.finfo(torch.float32).tiny
    for value in segmenter.model.state_dict().values():
        if value.dtype.is_floating_point:
            assert not ((value.abs() < tiny) & (value != 0)).any()


# --------------------------------------------------------------------------------------------- inference


def frame_with_proposals(rng):
    """A frame: a car-sized box, a person-sized box overlapping it, background clutter."""
    car = box_points((4.2, 1.8, 1.5), 0.3, (9.0, 2.0), 900, rng)
    person = box_points((0.6, 0.6, 1.7), 0.0, (11.2, 2.9), 120, rng)
    clutter = rng.uniform([-30, -30, -2, 0], [30, 30, 0, 1], (3000, 4)).astype(np.float32)
    points = np.concatenate([car, person, clutter])
    members = [np.arange(900), np.arange(900, 1020), np.concatenate([np.arange(850, 900), np.arange(900, 1020)])]
    return points, members


@pytest.fixture(scope="module")
def lite_checkpoint():
    torch.manual_seed(3)
    return make_checkpoint(PointNet2Seg(make_config("lite")), data={"train": ["constructed"]}, epoch=0)


def test_segment_shapes_and_determinism(lite_checkpoint):
    points, members = frame_with_proposals(np.random.default_rng(7))
    segmenter = Segmenter(lite_checkpoint)
    segmenter.warm_up()
    first = segmenter.segment(points, [*members, np.zeros(0, dtype=np.int64)])
    second = segmenter.segment(points.copy(), [m.copy() for m in members] + [np.zeros(0, dtype=np.int64)])
    third = Segmenter(lite_checkpoint, fuse=False).segment(points, members)
    assert first.labels.shape == (len(points),) and first.labels.dtype == np.uint8
    assert first.confidence.dtype == np.float32 and first.proposal_class.shape == (4,)
    assert np.array_equal(first.labels, second.labels)
    assert np.array_equal(first.confidence, second.confidence)
    assert np.array_equal(first.labels[:1020], third.labels[:1020])
    assert first.proposal_class[3] == -1
    outside = np.setdiff1d(np.arange(len(points)), np.concatenate(members))
    assert np.all(first.labels[outside] == BACKGROUND) and np.all(first.confidence[outside] == 1.0)
    assert np.all((first.confidence[:1020] > 0) & (first.confidence[:1020] <= 1))
    share = first.people_share  # pedestrian over pedestrian and background, of the winning prediction
    assert share.shape == (len(points),) and np.all(np.isnan(share[outside]))
    inside = np.concatenate(members)
    assert np.all((share[inside] >= 0) & (share[inside] <= 1))
    batch = prepare_proposals(points, members, segmenter.config, draw=next(iter(segmenter.draw_set())),
                              sampling=segmenter.sampling)
    probs = predict_probabilities(segmenter.model, batch, "cpu")
    once = np.bincount(batch.query_index, minlength=len(points)) == 1  # one prediction: no other wins
    rows = np.flatnonzero(once[batch.query_index])
    expected = probs[rows, PEDESTRIAN] / (probs[rows, PEDESTRIAN] + probs[rows, BACKGROUND])
    np.testing.assert_allclose(share[batch.query_index[rows]], expected, rtol=1e-5)


def test_all_point_decoding_matches_sampled_forward(lite_checkpoint):
    points, members = frame_with_proposals(np.random.default_rng(8))
    segmenter = Segmenter(lite_checkpoint, fuse=False)
    batch = prepare_proposals(points, members, segmenter.config)
    probs = predict_probabilities(segmenter.model, batch, "cpu")
    with torch.no_grad():
        ref = torch.softmax(
            segmenter.model(torch.from_numpy(batch.sample_xyz), torch.from_numpy(batch.sample_feat)), -1
        ).numpy()
    offsets = np.concatenate([[0], np.cumsum([len(m) for m in members])])
    for p, member in enumerate(members):  # members are sorted: find each sampled point among the queries
        pos = offsets[p] + np.searchsorted(member, batch.sample_index[p])
        assert np.array_equal(batch.query_index[pos], batch.sample_index[p])
        assert np.allclose(probs[pos], ref[p], atol=1e-5)


class StubModel(torch.nn.Module):
    """Proposals with n > 0 (many points) say car with logit `car`, the others pedestrian with logit `ped`."""

    def __init__(self, car: float, ped: float) -> None:
        super().__init__()
        self.car, self.ped = car, ped

    def encode(self, xyz, feat):
        big = feat[:, :1, 1:2] > 0
        logits = torch.zeros(len(xyz), 1, NUM_CLASSES)
        logits[..., CAR] = torch.where(big[..., 0], self.car, 0.0)
        logits[..., PEDESTRIAN] = torch.where(big[..., 0], 0.0, self.ped)
        return xyz[:, :1], logits

    def decode(self, coarse_xyz, coarse_feat, xyz, feat, proposal):
        return coarse_feat[proposal].expand(-1, xyz.shape[1], -1)


@pytest.mark.parametrize(("car", "ped", "winner"), [(3.0, 1.0, CAR), (1.0, 6.0, PEDESTRIAN)])
def test_overlap_takes_more_confident_prediction(lite_checkpoint, car, ped, winner):
    rng = np.random.default_rng(9)
    big, small = box_points((4, 2, 1.5), 0, (8, 0), 400, rng), box_points((1, 1, 1.7), 0, (10, 1), 60, rng)
    points = np.concatenate([big, small])
    members = [np.arange(0, 400), np.arange(380, 460)]  # points 380..399 are in both
    segmenter = Segmenter(lite_checkpoint)
    segmenter.model = StubModel(car, ped)
    result = segmenter.segment(points, members)
    assert np.all(result.labels[:380] == CAR)
    assert np.all(result.labels[400:] == PEDESTRIAN)
    assert np.all(result.labels[380:400] == winner)
    assert result.proposal_class.tolist() == [CAR, PEDESTRIAN]


def test_scatter_predictions_overlap_rule():
    labels, conf = scatter_predictions(
        5, np.array([1, 1, 2, 3, 3, 3]), np.array([1, 2, 3, 1, 2, 3]), np.array([0.4, 0.9, 0.5, 0.7, 0.2, 0.6])
    )
    assert labels.tolist() == [0, 2, 3, 1, 0]
    assert conf == pytest.approx([1.0, 0.9, 0.5, 0.7, 1.0])


def test_max_proposals_keeps_nearest(lite_checkpoint):
    rng = np.random.default_rng(10)
    far = box_points((1, 1, 1.7), 0, (40, 0), 50, rng)
    near = box_points((1, 1, 1.7), 0, (5, 0), 50, rng)
    result = Segmenter(lite_checkpoint, max_proposals=1).segment(
        np.concatenate([far, near]), [np.arange(50), np.arange(50, 100)]
    )
    assert result.proposal_class[0] == -1 and result.proposal_class[1] >= 0
    assert np.all(result.confidence[:50] == 1.0) and np.all(result.labels[:50] == BACKGROUND)


# ------------------------------------------------------------------------------------------- checkpoints


def test_checkpoint_file_round_trip(tmp_path, lite_checkpoint):
    path = tmp_path / "w.pt"
    torch.save(lite_checkpoint, path)
    segmenter = Segmenter(path)
    assert segmenter.config.name == "lite" and segmenter.data_description == {"train": ["constructed"]}


def test_incompatible_or_corrupt_checkpoints_fail_clearly(tmp_path, lite_checkpoint):
    missing = tmp_path / "none.pt"
    with pytest.raises(CheckpointError, match=r"none\.pt: no such checkpoint file"):
        Segmenter(missing)
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match=r"not a pass3d checkpoint: .*corrupt\.pt"):
        Segmenter(corrupt)
    foreign = tmp_path / "foreign.pt"
    torch.save({"model": {}}, foreign)
    with pytest.raises(CheckpointError, match=r"foreign\.pt: not a pass3d stage-2 checkpoint"):
        Segmenter(foreign)
    mismatched = tmp_path / "mismatched.pt"
    torch.save({**lite_checkpoint, "config": make_config("paper").to_dict()}, mismatched)
    with pytest.raises(CheckpointError, match=r"mismatched\.pt: weights do not fit the 'paper' model config"):
        Segmenter(mismatched)
    with pytest.raises(CheckpointError, match="trained for classes"):
        Segmenter({**lite_checkpoint, "classes": ["background", "vehicle"]})
    with pytest.raises(CheckpointError, match="bad model config"):
        Segmenter({**lite_checkpoint, "config": {"name": "x"}})
    with pytest.raises(CheckpointError, match="version 99"):
        Segmenter({**lite_checkpoint, "version": 99})


# -------------------------------------------------------------------------------------------- size rules


def test_size_rules_classify_by_box_and_segment():
    rng = np.random.default_rng(11)
    ground = rng.uniform([-20, -20, -1.75, 0], [20, 20, -1.65, 1], (500, 4)).astype(np.float32)
    car = box_points((4.2, 1.7, 1.5), 0.5, (10, -4), 600, rng)
    person = box_points((0.6, 0.5, 1.75), 0.0, (6, 3), 100, rng)
    bike = box_points((1.8, 0.6, 1.7), 1.0, (-8, 2), 150, rng)
    wall = box_points((12.0, 0.4, 3.0), 0.2, (0, -15), 800, rng)
    points = np.concatenate([ground, car, person, bike, wall])
    starts = np.cumsum([0, 500, 600, 100, 150, 800])
    members = [np.arange(starts[i], starts[i + 1]) for i in range(1, 5)]
    members[0] = np.concatenate([members[0], np.arange(0, 20)])  # a few ground points in the car's box
    classifier = open_classifier(None, "size_rules")
    assert isinstance(classifier, SizeRuleClassifier)
    result = classifier.segment(points, [*members, np.zeros(0, np.int64)])
    assert result.proposal_class.tolist() == [CAR, PEDESTRIAN, CYCLIST, BACKGROUND, -1]
    upper_car = members[0][points[members[0], 2] > points[members[0], 2].min() + 0.2]
    assert np.all(result.labels[upper_car] == CAR)
    assert np.all(result.labels[:20] == BACKGROUND)  # low (ground) points stay background
    assert np.all(result.labels[starts[4] :] == BACKGROUND)
    assert result.labels.dtype == np.uint8 and result.confidence.shape == (len(points),)


def test_open_classifier_checks_once_and_names_the_file(tmp_path, lite_checkpoint, monkeypatch):
    with pytest.raises(ClassifierError, match="unknown classifier"):
        open_classifier(None, "magic")
    with pytest.raises(ClassifierError, match="--weights applies to the network classifier"):
        open_classifier("w.pt", "size_rules")
    with pytest.raises(ClassifierError, match=r"none\.pt: no such checkpoint file"):
        open_classifier(tmp_path / "none.pt")
    run = tmp_path / "run"  # a training's --out named instead of the checkpoint in it
    run.mkdir()
    with pytest.raises(ClassifierError, match=r"run: a folder, not a checkpoint file"):
        open_classifier(run)
    with pytest.raises(CheckpointError, match=r"run: a folder, not a checkpoint file"):
        Segmenter(run)
    with pytest.raises(ClassifierError, match=r"device 'gpu' is not a torch device \(cpu, cuda or cuda:N\)"):
        open_classifier(lite_checkpoint, device="gpu")
    with pytest.raises(ClassifierError, match=r"device 'cuda:\d+': no such CUDA device here"):
        open_classifier(lite_checkpoint, device=f"cuda:{torch.cuda.device_count()}")
    for device in ("meta", "hip"):  # a device type this build lacks, and one that holds no data
        with pytest.raises(ClassifierError, match=rf"device '{device}': torch .* cannot run on it here; use cpu"):
            open_classifier(lite_checkpoint, device=device)
    monkeypatch.setattr(stage2, "DEFAULT_WEIGHTS", tmp_path / "pass3d_lite.pt")
    for default in (None, ""):
        with pytest.raises(ClassifierError, match=r"shipped stage-2 weights missing: .*pass3d_lite\.pt.*--classifier "
                                                  r"size_rules"):
            open_classifier(default)
    path = tmp_path / "pass3d_lite.pt"
    torch.save(lite_checkpoint, path)
    checks = []
    real_is_file = Path.is_file
    monkeypatch.setattr(Path, "is_file", lambda self: checks.append(self) or real_is_file(self))
    classifier = open_classifier(None, device="cpu", max_proposals=5)
    assert (classifier.kind, classifier.weights, classifier.max_proposals) == ("network", str(path), 5)
    assert checks == [path], "the file is checked once, by open_classifier"
    rules = open_classifier("", "size_rules")
    assert (rules.kind, rules.weights) == ("size_rules", None)
    assert open_classifier(lite_checkpoint).weights is None  # a checkpoint dict has no file


def test_people_only_points_are_pedestrian_or_background() -> None:
    """Flagged points (rerun_dropped's parts) lose a car or cyclist label to background, with the rest of the
    probability as confidence; pedestrian and background stay, unflagged points and proposals are untouched; a
    proposal of flagged points only loses a car or cyclist class."""
    labels = np.array([CAR, CYCLIST, PEDESTRIAN, BACKGROUND, CAR, CAR], dtype=np.uint8)
    confidence = np.array([0.9, 0.6, 0.8, 1.0, 0.7, 0.7], dtype=np.float32)
    result = SegmentResult(labels, confidence, np.array([CAR, CAR], dtype=np.int16))
    members = [np.array([0, 1, 2, 3]), np.array([3, 4, 5])]
    mask = np.array([True, True, True, True, False, False])
    out = people_only(result, members, mask)
    assert out.labels.tolist() == [BACKGROUND, BACKGROUND, PEDESTRIAN, BACKGROUND, CAR, CAR]
    np.testing.assert_allclose(out.confidence, [0.1, 0.4, 0.8, 1.0, 0.7, 0.7], rtol=1e-6)
    assert out.proposal_class.tolist() == [BACKGROUND, CAR]
    assert labels[0] == CAR  # the input result is not changed
    assert people_only(result, members, None) is result


def test_people_only_decides_by_the_network_s_pedestrian_and_background_odds() -> None:
    """With the network's share of pedestrian over pedestrian and background (rule F), a flagged point is pedestrian
    when that share is above one half, else background, whatever class won the four-class argmax; its confidence is
    the chosen class's share; a proposal of flagged points only takes their majority (ties: background)."""
    labels = np.array([CAR, CYCLIST, PEDESTRIAN, BACKGROUND, CAR, CAR, PEDESTRIAN, CAR], dtype=np.uint8)
    confidence = np.array([0.4, 0.5, 0.8, 0.9, 0.7, 0.7, 0.6, 0.5], dtype=np.float32)
    share = np.array([0.6, 0.3, 0.9, 0.2, 0.7, 0.7, 0.8, 0.55], dtype=np.float32)
    result = SegmentResult(labels, confidence, np.array([CAR, CAR, CAR], dtype=np.int16), share)
    members = [np.array([0, 1, 2, 3]), np.array([3, 4, 5]), np.array([6, 7])]
    mask = np.array([True, True, True, True, False, False, True, True])
    out = people_only(result, members, mask)
    assert out.labels.tolist() == [PEDESTRIAN, BACKGROUND, PEDESTRIAN, BACKGROUND, CAR, CAR, PEDESTRIAN, PEDESTRIAN]
    np.testing.assert_allclose(out.confidence, [0.6, 0.7, 0.9, 0.8, 0.7, 0.7, 0.8, 0.55], rtol=1e-6)
    assert out.proposal_class.tolist() == [BACKGROUND, CAR, PEDESTRIAN]  # 2 of 4 is no majority; 2 of 2 is
