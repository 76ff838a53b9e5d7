"""Stage 2 without a dice roll (issue 37): an order-free ("set") network with coverage sampling gives the same labels
for the same points, whatever their order."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pass3d_ros.core.stage2.pointnet2 import (
    PointNet2Seg,
    ball_members,
    ball_query,
    make_config,
    sample_centres,
    torch_ops_only,
)
from pass3d_ros.core.stage2.segmentation import Segmenter, default_sampling, make_checkpoint


def _cloud(seed: int, batch: int = 3, n: int = 256) -> torch.Tensor:
    """Random point sets with every fifth point repeated (as a small proposal's sample repeats points)."""
    xyz = np.random.default_rng(seed).normal(size=(batch, n, 3)).astype(np.float32)
    xyz[:, n - n // 5 :] = xyz[:, : n // 5]
    return torch.from_numpy(xyz)


def test_nearest_ball_members_are_the_nearest_inside_nearest_first():
    """The centre, point 0, at the origin; the others 0.3, 0.1, 0.9 (outside a 0.5 m ball) and 0.2 m away: the
    nearest ones listed in index order, padded with the first when the ball holds fewer than asked."""
    xyz = torch.tensor([[[0.0, 0, 0], [0.3, 0, 0], [0.1, 0, 0], [0.9, 0, 0], [0.2, 0, 0]]])
    d2 = (xyz[:, None, :1] - xyz[:, None]).pow(2).sum(-1)  # (1, 1, 5): squared distances to point 0
    assert ball_query(d2, 0.5, 3, nearest=True)[0, 0].tolist() == [0, 2, 4]
    assert ball_query(d2, 0.5, 6, nearest=True)[0, 0].tolist() == [0, 1, 2, 4, 0, 0]
    assert ball_query(d2, 0.5, 3)[0, 0].tolist() == [0, 1, 2]  # "slot": the first ones in index order


@pytest.mark.parametrize("seed", range(4))
def test_set_grouping_kernels_choose_as_torch(seed):
    """The numba kernels pick the same FPS centres (from the point nearest the centroid) and the same nearest ball
    members as the torch code, ties (repeated points) included."""
    xyz = _cloud(seed)
    idx, d2 = sample_centres(xyz, 32, "set")
    with torch_ops_only():
        ref_idx, ref_d2 = sample_centres(xyz, 32, "set")
    assert torch.equal(idx, ref_idx)
    centroid = xyz.double().mean(1, keepdim=True)
    assert torch.equal(idx[:, 0], ((xyz.double() - centroid) ** 2).sum(-1).argmin(-1))
    for radius, nsample in ((0.4, 16), (1.0, 32), (3.0, 8)):
        got = ball_members(d2, radius, nsample, "set")
        with torch_ops_only():
            assert torch.equal(got, ball_members(ref_d2, radius, nsample, "set")), (radius, nsample)


@pytest.mark.parametrize("numba", [True, False])
def test_a_set_network_answers_the_same_for_any_order_of_its_points(numba):
    """Permuting a sample's points permutes the per-point logits and changes nothing else (a "slot" network's
    answer moves: its FPS starts at slot 0)."""
    torch.manual_seed(0)
    config = make_config("lite")
    config.grouping = "set"
    net = PointNet2Seg(config).eval()
    xyz = _cloud(7, batch=2)
    feat = torch.from_numpy(np.random.default_rng(8).random((2, 256, 2)).astype(np.float32))
    feat[:, 256 - 256 // 5 :] = feat[:, : 256 // 5]  # a repeated point repeats its features too
    perm = torch.from_numpy(np.random.default_rng(9).permutation(256))
    with torch.no_grad():
        if numba:
            a, b = net(xyz, feat), net(xyz[:, perm], feat[:, perm])
        else:
            with torch_ops_only():
                a, b = net(xyz, feat), net(xyz[:, perm], feat[:, perm])
    assert torch.allclose(a[:, perm], b, atol=1e-5)
    slot = PointNet2Seg(make_config("lite")).eval()
    slot.load_state_dict(net.state_dict())
    with torch.no_grad():
        assert not torch.allclose(slot(xyz, feat)[:, perm], slot(xyz[:, perm], feat[:, perm]), atol=1e-5)


def _scan(seed: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """A scan of three box-like proposals (40, 300 and 900 points) and some background points."""
    rng = np.random.default_rng(seed)
    parts, members, start = [], [], 0
    for count, centre, size in ((40, (8, 2, -1), (0.6, 0.6, 1.7)), (300, (12, -3, -1), (4.2, 1.8, 1.5)),
                                (900, (6, 5, -1), (4.5, 1.9, 1.6))):
        xyz = np.asarray(centre) + rng.uniform(-0.5, 0.5, (count, 3)) * np.asarray(size)
        parts.append(np.column_stack([xyz, rng.random(count)]))
        members.append(np.arange(start, start + count))
        start += count
    parts.append(np.column_stack([rng.uniform(-30, 30, (500, 3)), rng.random(500)]))
    return np.concatenate(parts).astype(np.float32), members


def test_segmenter_labels_do_not_depend_on_the_order_of_the_points():
    """A "set" network samples by coverage (no draw) and labels every point the same when the scan's points, and
    each proposal's member list, come in another order."""
    torch.manual_seed(3)
    config = make_config("lite")
    config.grouping = "set"
    segmenter = Segmenter(make_checkpoint(PointNet2Seg(config).eval()))
    assert segmenter.sampling == default_sampling(config) == "coverage"
    points, members = _scan(4)
    first = segmenter.segment(points, members)
    rng = np.random.default_rng(5)
    perm = rng.permutation(len(points))  # new position i holds old point perm[i]
    where = np.argsort(perm)  # old point j is now at where[j]
    shuffled = [rng.permutation(where[m]) for m in members]
    second = segmenter.segment(points[perm], shuffled)
    assert np.array_equal(second.labels, first.labels[perm])
    assert np.allclose(second.confidence, first.confidence[perm], atol=1e-5)
    assert np.array_equal(second.proposal_class, first.proposal_class)
    assert default_sampling(make_config("lite")) == "content"  # "slot" weights: the content draw (trial 34)
