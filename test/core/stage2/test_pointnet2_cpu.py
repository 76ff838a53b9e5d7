"""The numba CPU kernels of stage 2 choose exactly what the torch code chooses (FPS centres, ball members,
3 nearest neighbours), so a frame's labels are the same with and without them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pass3d_ros.bench.stage2 import constructed_frame
from pass3d_ros.core.stage2 import pointnet2_cpu
from pass3d_ros.core.stage2.pointnet2 import (
    PointNet2Seg,
    SharedMLP,
    ball_members,
    fuse_batchnorm,
    make_config,
    sample_centres,
    torch_ops_only,
)
from pass3d_ros.core.stage2.segmentation import (
    Segmenter,
    make_checkpoint,
    predict_probabilities,
    prepare_proposals,
    scatter_predictions,
)
from pass3d_ros.weights import DEFAULT_WEIGHTS


def clouds(seed: int) -> torch.Tensor:
    """(6, 256, 3) float32 point sets as stage 2 samples them: random boxes, a small proposal repeated up to
    256 points (exact ties), a 0.5 m grid (distances exactly on the radii), one point repeated."""
    rng = np.random.default_rng(seed)
    sets = [rng.uniform(0, [4.5, 1.8, 1.6], (256, 3)), rng.uniform(0, [0.7, 0.6, 1.8], (256, 3))]
    few = rng.uniform(0, [1.0, 0.8, 1.7], (40, 3))
    sets.append(np.concatenate([few, few[rng.integers(0, 40, 216)]]))
    grid = np.stack(np.meshgrid(np.arange(8), np.arange(4), np.arange(8), indexing="ij"), -1).reshape(-1, 3) * 0.5
    sets += [grid, grid[rng.permutation(256)], np.full((256, 3), 1.25)]
    return torch.tensor(np.stack(sets), dtype=torch.float32)


RADII = [(0.2, 8), (0.4, 16), (0.5, 32), (1.0, 32), (2.0, 16)]
TIE = 1e-5  # squared distances closer than this (m^2) to a tie or a radius may go either way with float rounding


def exact_sq_dist(xyz: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Squared distances in float64 from the points `rows` of one set to all its points."""
    pts = xyz.astype(np.float64)
    return ((pts[rows][:, None, :] - pts[None, :, :]) ** 2).sum(-1)


def assert_valid_fps(xyz: np.ndarray, idx: np.ndarray) -> None:
    """Every centre after the first is a farthest remaining point, up to float rounding (TIE)."""
    nearest = exact_sq_dist(xyz, idx[:1])[0]
    for k in range(1, len(idx)):
        assert nearest[idx[k]] >= nearest.max() - TIE, k
        nearest = np.minimum(nearest, exact_sq_dist(xyz, idx[k:k + 1])[0])


def assert_valid_ball(xyz: np.ndarray, centres: np.ndarray, members: np.ndarray, radius: float) -> None:
    """Each centre's members are the first points (by index) inside the radius, padded with the first one; points
    within TIE of the radius may count either way."""
    d2 = exact_sq_dist(xyz, centres)
    r2 = radius * radius
    for row, got in zip(d2, members, strict=True):
        unique = list(dict.fromkeys(got.tolist()))
        assert all(row[j] < r2 + TIE for j in unique)
        last = unique[-1] if len(unique) == len(got) else len(row) - 1
        inside = [j for j in range(last + 1) if row[j] < r2 - TIE]
        assert set(inside) <= set(unique) and unique == sorted(unique)
        assert all(j == unique[0] for j in got[len(unique):])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sampling_and_ball_query_choose_as_torch(seed):
    """On random point sets the kernels choose exactly as the torch code; on sets full of exact ties (repeated
    points, a grid on the radii) a different float rounding may pick another of the tied points, so there every
    choice is checked against exact distances instead (the rounding differs between CPUs and BLAS builds)."""
    xyz = clouds(seed)
    idx, d2 = sample_centres(xyz, 32)
    with torch_ops_only():
        ref_idx, ref_d2 = sample_centres(xyz, 32)
    random_sets = slice(0, 2)
    assert torch.equal(idx[random_sets], ref_idx[random_sets])
    assert torch.allclose(d2.clamp_min(0.0)[random_sets], ref_d2[random_sets], atol=1e-5)
    for radius, nsample in RADII:
        got = ball_members(d2, radius, nsample)
        with torch_ops_only():
            ref = ball_members(ref_d2, radius, nsample)
        assert torch.equal(got[random_sets], ref[random_sets]), (radius, nsample)
        for k in range(xyz.shape[0]):
            assert_valid_ball(xyz[k].numpy(), idx[k].numpy(), got[k].numpy(), radius)
    for k in range(xyz.shape[0]):
        assert_valid_fps(xyz[k].numpy(), idx[k].numpy())


def test_ball_query_compares_in_float32_as_torch():
    # A radius whose square rounds up in float32: a point at exactly that float32 distance is inside for torch.
    x = next(v for v in np.arange(0.1, 0.2, 1e-4, dtype=np.float32) if float(v * v) > float(v) ** 2)
    xyz = torch.tensor([[[0.0, 0.0, 0.0], [float(x), 0.0, 0.0], [0.0, float(x) * 1.01, 0.0]]])
    d2 = sample_centres(xyz, 1)[1]
    with torch_ops_only():
        ref = ball_members(sample_centres(xyz, 1)[1], float(x), 3)
    assert ref[0, 0].tolist() == [0, 1, 0]
    assert torch.equal(ball_members(d2, float(x), 3), ref)


def test_tie_rules_of_sampling():
    xyz = torch.tensor([[[0.0, 0, 0], [0.1, 0, 0], [5, 0, 0], [5, 5, 0], [0, 5, 0]]])
    idx, d2 = sample_centres(xyz, 3)
    assert idx[0].tolist() == [0, 3, 2]  # p2 and p4 tie; the first wins
    assert ball_members(d2[:, :1], 0.5, 4)[0, 0].tolist() == [0, 1, 0, 0]


@pytest.mark.parametrize("level", [0, 2])  # a wide skip (projected by MKL) and the last level's 5 channels
@pytest.mark.parametrize("fused", [False, True])
@pytest.mark.parametrize("sources", [1, 2, 3, 8, 32])
def test_fused_interpolation_matches_torch(sources, fused, level):
    torch.manual_seed(sources)
    model = PointNet2Seg(make_config("lite")).eval()
    fp = (fuse_batchnorm(model) if fused else model).fp[level]
    coarse, skips = fp.coarse_channels, fp.mlp.layers[0].in_features - fp.coarse_channels
    coarse_xyz, coarse_feat = torch.rand(4, sources, 3) * 3, torch.randn(4, sources, coarse)
    proposal = torch.tensor([0, 1, 2, 3, 0, 2])
    # Queries anywhere, and three on a source point (distance 0 up to rounding: ties).
    query = torch.cat([torch.rand(6, 40, 3) * 3, coarse_xyz[proposal, :1].expand(-1, 3, -1)], 1)
    skip = torch.cat([query, torch.rand(6, 43, skips - 3)], -1)
    with torch.inference_mode():
        out = fp(query, skip, coarse_xyz, coarse_feat, proposal)
        with torch_ops_only():
            ref = fp(query, skip, coarse_xyz, coarse_feat, proposal)
    assert torch.allclose(out, ref, atol=1e-5)


def test_pool_applies_bias_and_relu_after_the_max():
    torch.manual_seed(4)
    mlp = SharedMLP(8, [16, 32])
    mlp.train()
    mlp(torch.randn(64, 8))  # move the BN statistics away from their defaults
    mlp.eval()
    x = torch.randn(3, 5, 7, 8)
    with torch.no_grad():
        plain = mlp(x).amax(dim=-2)
        assert torch.allclose(mlp.pool(x), plain, atol=1e-6)  # unfused: Linear, BN, ReLU at the end
        model = PointNet2Seg(make_config("lite"))
        model.sa[0].mlps[0] = mlp
        fused = fuse_batchnorm(model).sa[0].mlps[0]
        assert torch.allclose(fused.pool(x), plain, atol=1e-5)


@pytest.mark.parametrize("fuse", [True, False])
def test_segmenter_labels_equal_the_torch_reference(fuse):
    segmenter = Segmenter(DEFAULT_WEIGHTS, fuse=fuse)
    for seed in (0, 1):
        points, members = constructed_frame(12, seed, min_points=5, max_points=1500, background=2000)
        result = segmenter.segment(points, members)
        batch = prepare_proposals(points, members, segmenter.config)
        probs = predict_probabilities(segmenter.model, batch, "cpu")
        with torch_ops_only():
            ref = segmenter.segment(points, members)
            ref_probs = predict_probabilities(segmenter.model, batch, "cpu")
        assert np.array_equal(result.labels, ref.labels)
        assert np.array_equal(result.proposal_class, ref.proposal_class)
        assert np.allclose(result.confidence, ref.confidence, atol=1e-5)
        assert np.allclose(probs, ref_probs, atol=1e-5)


def test_training_gradients_equal_with_numba_sampling():
    torch.manual_seed(5)
    model = PointNet2Seg(make_config("lite"))
    xyz, feat = clouds(3)[:3] * torch.tensor([1.0, 1.0, 0.8]), torch.rand(3, 256, 2)
    grads = []
    for reference in (False, True):
        model.zero_grad()
        torch.manual_seed(6)  # the same dropout mask
        if reference:
            with torch_ops_only():
                model(xyz, feat).square().mean().backward()
        else:
            model(xyz, feat).square().mean().backward()
        grads.append([p.grad.clone() for p in model.parameters()])
    for got, ref in zip(*grads, strict=True):
        assert torch.allclose(got, ref, atol=1e-5)


def test_scatter_predictions_matches_a_sort_on_random_overlaps():
    rng = np.random.default_rng(12)
    point_index = rng.integers(0, 300, 2000)
    confidence = rng.choice(np.float32([0.25, 0.5, 0.75, 1.0]), 2000)  # many exact ties
    labels = rng.integers(0, 4, 2000).astype(np.uint8)
    order = np.lexsort((np.arange(2000), confidence, point_index))  # the most confident, ties: the later one
    last = np.append(point_index[order][1:] != point_index[order][:-1], True)
    expected = np.zeros(310, dtype=np.uint8)
    expected[point_index[order[last]]] = labels[order[last]]
    got, conf = scatter_predictions(310, point_index, labels, confidence)
    assert np.array_equal(got, expected)
    assert np.all(conf[300:] == 1.0)


def test_kernels_warm_up():
    pointnet2_cpu.warm_up()
    Segmenter(make_checkpoint(PointNet2Seg(make_config("lite")))).warm_up()
