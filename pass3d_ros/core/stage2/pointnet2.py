"""PointNet++ (multi-scale grouping) for per-point segmentation of one proposal, in PyTorch.

Farthest point sampling, ball query, grouping and 3-NN interpolation are batched torch code that runs on any
device. On CPU, numba kernels (`pointnet2_cpu`) take over: they compute the same float32 distances and pick
the same indices (training uses them too: indices need no gradient), and in inference they also fuse the
grouping, the interpolation and the head's last layer. `torch_ops_only()` turns them off, for reference.
Tensors are channel-last: (batch, points, channels).

Decoding is split from encoding: `encode` runs the set-abstraction levels and the upper feature
propagation levels on the N sampled points of each proposal; `decode` runs the last feature propagation
level and the head at any query points of a proposal (a flat, ragged batch), so every member point of a
proposal gets the network's own prediction, not only the N sampled ones.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields

import numpy as np
import torch
from torch import nn

from pass3d_ros.classes import NUM_CLASSES
from pass3d_ros.core.stage2 import pointnet2_cpu as _cpu

# Per-point input features beside the local xyz: intensity and the point-count feature n.
NUM_POINT_FEATURES = 2

# How a set-abstraction level groups its N points. "slot" (the shipped weights and every older checkpoint): FPS starts
# at slot 0 and a ball keeps its first members in slot order, so the answer depends on the order of the points. "set":
# FPS starts at the point nearest the points' centroid and a ball keeps its nearest members (ties to the lower slot,
# which only identical points share), so the answer is a function of the point set alone.
GROUPINGS = ("slot", "set")
CHECKPOINT_GROUPING = "slot"  # a checkpoint that names no grouping was trained with this one
# A new run's default: the shipped one. "set", trained, lost the held-out VLP-32C's pedestrians by 9-11 IoU points
# (docs/experiments/trials-issue-37-sampling.md).
TRAIN_GROUPING = CHECKPOINT_GROUPING


@dataclass
class SAConfig:
    """One multi-scale set-abstraction level: `centres` sampled by FPS, one (radius, nsample, mlp) per scale."""

    centres: int
    radii: list[float]
    nsamples: list[int]
    mlps: list[list[int]]


@dataclass
class ModelConfig:
    """Everything that defines the network and its input; stored in checkpoints as a plain dict."""

    name: str
    num_points: int
    sa: list[SAConfig]
    global_mlp: list[int]
    fp_mlps: list[list[int]]
    fc: int
    dropout_keep: float = 0.7
    num_classes: int = NUM_CLASSES
    n_feature: bool = True  # False: the point-count feature n is 0 (the paper's ablation baseline)
    n_mode: str = "log"  # "log": log(NUM / N), bounded (trains stably); "ratio": the paper's (NUM - N) / N
    grouping: str = CHECKPOINT_GROUPING  # one of GROUPINGS: how FPS starts and which points a ball keeps
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain dict (lists, numbers, strings) for a checkpoint."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> ModelConfig:
        """Inverse of to_dict; raises ValueError naming unknown or missing keys."""
        names = {f.name for f in fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown model config keys {sorted(unknown)}")
        values = dict(data)
        try:
            values["sa"] = [SAConfig(**level) for level in values["sa"]]
            return cls(**values)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"bad model config: {exc}") from exc

    def check(self) -> None:
        """Raise ValueError when the sizes do not fit together."""
        if len(self.fp_mlps) != len(self.sa) + 1:
            raise ValueError(f"{len(self.sa)} SA levels need {len(self.sa) + 1} FP levels, got {len(self.fp_mlps)}")
        for level in self.sa:
            if not (len(level.radii) == len(level.nsamples) == len(level.mlps)):
                raise ValueError(f"SA level {level}: radii, nsamples and mlps differ in length")
        if self.sa and self.sa[0].centres > self.num_points:
            raise ValueError("SA1 has more centres than points per sample")
        if self.grouping not in GROUPINGS:
            raise ValueError(f"unknown grouping {self.grouping!r}, choose from {', '.join(GROUPINGS)}")


def paper_config() -> ModelConfig:
    """Frustum-PointNets v2 instance-segmentation sizes, as in the PASS3D paper (1024 points per sample)."""
    return ModelConfig(
        name="paper",
        num_points=1024,
        sa=[
            SAConfig(128, [0.2, 0.4, 0.8], [32, 64, 128], [[32, 32, 64], [64, 64, 128], [64, 96, 128]]),
            SAConfig(32, [0.4, 0.8, 1.6], [64, 64, 128], [[64, 64, 128], [128, 128, 256], [128, 128, 256]]),
        ],
        global_mlp=[128, 256, 1024],
        fp_mlps=[[128, 128], [128, 128], [128, 128]],
        fc=128,
    )


def lite_config() -> ModelConfig:
    """Real time on 2 CPU cores for a frame's ~30 proposals: 256 points, 32 / 8 centres, narrow MLPs.

    Chosen among variants trained alike on synthetic scans: 64 / 16 or 48 / 12 centres scored the same
    validation IoU (within epoch-to-epoch noise) at up to twice the cost.
    """
    return ModelConfig(
        name="lite",
        num_points=256,
        sa=[
            SAConfig(32, [0.4, 1.0], [16, 32], [[16, 32], [32, 64]]),
            SAConfig(8, [1.0, 2.0], [8, 16], [[64, 96], [64, 96]]),
        ],
        global_mlp=[128, 256],
        fp_mlps=[[128], [96], [64]],
        fc=64,
    )


CONFIGS = {"paper": paper_config, "lite": lite_config}


def make_config(name: str) -> ModelConfig:
    """A named configuration: 'paper' or 'lite'."""
    if name not in CONFIGS:
        raise ValueError(f"unknown model config {name!r}, choose from {', '.join(CONFIGS)}")
    return CONFIGS[name]()


# ---------------------------------------------------------------------------------------------- ops


def lift_points(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows (a, |a|^2, 1) of a (B, P, 3) and (-2b, 1, |b|^2) of b (B', Q, 3): row dot products are the squared
    distances."""
    ones_a = torch.ones_like(a[..., :1])
    ones_b = torch.ones_like(b[..., :1])
    left = torch.cat([a, (a * a).sum(-1, keepdim=True), ones_a], dim=-1)
    right = torch.cat([-2.0 * b, ones_b, (b * b).sum(-1, keepdim=True)], dim=-1)
    return left, right


def pairwise_sq_dist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distances (B, P, Q) between a (B, P, 3) and b (B, Q, 3): one batched matmul of
    (a, |a|^2, 1) with (-2b, 1, |b|^2), clamped >= 0."""
    left, right = lift_points(a, b)
    return torch.bmm(left, right.transpose(1, 2)).clamp_min_(0.0)


def farthest_point_sample(d2: torch.Tensor, count: int, start: torch.Tensor | None = None) -> torch.Tensor:
    """Indices (B, count) of farthest point sampling given the squared distance matrix d2 (B, N, N) of
    the points, starting at point `start` (B,) or 0 (deterministic)."""
    b = d2.shape[0]
    idx = torch.zeros(b, count, dtype=torch.long, device=d2.device)
    rows = torch.arange(b, device=d2.device)
    if start is not None:
        idx[:, 0] = start
    dist = d2[rows, idx[:, 0]]
    for i in range(1, count):
        last = dist.argmax(-1)
        idx[:, i] = last
        dist = torch.minimum(dist, d2[rows, last])
    return idx


def gather_points(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """values (B, N, C) gathered at idx (B, ...) -> (B, ..., C)."""
    b, n, c = values.shape
    flat = idx.reshape(b, -1) + torch.arange(b, device=idx.device).unsqueeze(1) * n
    return values.reshape(b * n, c)[flat.reshape(-1)].reshape(*idx.shape, c)


def ball_query(d2: torch.Tensor, radius: float, nsample: int, nearest: bool = False) -> torch.Tensor:
    """For squared distances d2 (B, S, N) of centres to points: the first `nsample` point indices within
    `radius` of each centre, in index order (`nearest`: the nearest ones, ties to the lower index, listed in index
    order too), padded with the first one listed (B, S, nsample).

    Every centre must be one of the points (FPS centres are), so each ball holds at least one point.
    """
    b, s, n = d2.shape
    if nearest:
        inside = d2 <= radius * radius
        key = torch.where(inside, d2.clamp_min(0.0), torch.full_like(d2, float("inf")))
        order = torch.sort(key, dim=-1, stable=True).indices[..., :nsample]
        found = torch.gather(inside, -1, order)
        if nsample > n:  # fewer points than members asked for: the rest is padding
            order = torch.cat([order, order[..., :1].expand(b, s, nsample - n)], dim=-1)
            found = torch.cat([found, torch.zeros_like(found[..., :1]).expand(b, s, nsample - n)], dim=-1)
        listed = torch.where(found, order, torch.full_like(order, n)).sort(dim=-1).values  # index order, padding last
        return torch.where(listed == n, listed[..., :1], listed)
    inside = d2 <= radius * radius
    rank = inside.cumsum(-1) - 1
    keep = inside & (rank < nsample)
    out = torch.full((b, s, nsample + 1), n, dtype=torch.long, device=d2.device)
    slot = torch.where(keep, rank, torch.full_like(rank, nsample))
    out.scatter_(2, slot, torch.arange(n, device=d2.device).expand(b, s, n).contiguous())
    out = out[..., :nsample]
    first = out[..., :1]
    return torch.where(out == n, first, out)


def three_nn(query: torch.Tensor, source: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Indices and inverse-distance weights (B, Q, k), k = min(3, S), of the nearest sources (B, S, 3)
    to each query point (B, Q, 3). Repeated argmin: faster than topk on CPU for k = 3."""
    k = min(3, source.shape[1])
    d2 = pairwise_sq_dist(query, source)
    idx = torch.empty(*d2.shape[:2], k, dtype=torch.long, device=d2.device)
    near = torch.empty(*d2.shape[:2], k, dtype=d2.dtype, device=d2.device)
    for j in range(k):
        near[..., j], idx[..., j] = d2.min(dim=-1)
        if j + 1 < k:
            d2.scatter_(-1, idx[..., j : j + 1], float("inf"))
    w = 1.0 / (near + 1e-8)
    return idx, w / w.sum(-1, keepdim=True)


def interpolate(query: torch.Tensor, source: torch.Tensor, source_feat: torch.Tensor) -> torch.Tensor:
    """3-NN inverse-distance interpolation of source_feat (B, S, C) at source (B, S, 3) onto query (B, Q, 3)."""
    b, q, _ = query.shape
    s, c = source_feat.shape[1:]
    if s == 1:
        return source_feat.expand(b, q, c)
    idx, w = three_nn(query, source)
    flat = (idx + torch.arange(b, device=idx.device).view(b, 1, 1) * s).reshape(b * q, -1)
    out = nn.functional.embedding_bag(
        flat, source_feat.reshape(b * s, c), per_sample_weights=w.reshape(b * q, -1), mode="sum"
    )
    return out.reshape(b, q, c)


_numba = {"enabled": True}
# Skip features up to this wide (the last FP level's xyz + point features) are projected inside the numba kernel.
_KERNEL_SKIP_CHANNELS = 8


@contextmanager
def torch_ops_only() -> Iterator[None]:
    """Inside the block, the torch code runs on CPU too, as on a GPU: the reference the numba kernels match."""
    before = _numba["enabled"]
    _numba["enabled"] = False
    try:
        yield
    finally:
        _numba["enabled"] = before


def _numba_ok(*tensors: torch.Tensor) -> bool:
    """Whether the numba kernels of `pointnet2_cpu` take these tensors: float32 on the CPU."""
    return _numba["enabled"] and all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)


def _no_grad_needed(*tensors: torch.Tensor | None) -> bool:
    """Whether autograd needs no graph through an op on these tensors (inference, or none requires grad)."""
    return not torch.is_grad_enabled() or not any(t is not None and t.requires_grad for t in tensors)


def _np(t: torch.Tensor) -> np.ndarray:
    """A contiguous numpy view (or copy) of a CPU tensor, detached."""
    return t.detach().contiguous().numpy()


def _lifted(a: torch.Tensor, b: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """lift_points(a, b) channels first, (B, 5, P) and (B', 5, Q), for the numba kernels (vector loads)."""
    return _cpu.lift_points(_np(a), _np(b))


def centroid_nearest(xyz: torch.Tensor) -> torch.Tensor:
    """Index (B,) of the point of xyz (B, N, 3) nearest the points' centroid (in float64, so the order the points
    are summed in does not show), ties to the lower index: where "set" grouping starts FPS."""
    both = xyz.detach().double()
    return ((both - both.mean(dim=1, keepdim=True)) ** 2).sum(-1).argmin(dim=-1)


def sample_centres(xyz: torch.Tensor, count: int, grouping: str = CHECKPOINT_GROUPING
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Farthest point sampling of xyz (B, N, 3) as `grouping` starts it: centre indices (B, count) and the
    centres' squared distances to all points (B, count, N), as pairwise_sq_dist + farthest_point_sample give
    them. On CPU one numba kernel computes only those rows (unclamped: its ball_query reads them as clamped)."""
    start = centroid_nearest(xyz) if grouping == "set" else None
    if _numba_ok(xyz):
        first = np.zeros(xyz.shape[0], dtype=np.int64) if start is None else _np(start)
        idx, d2 = _cpu.farthest_point_sample(*_lifted(xyz, xyz), count, first)
        return torch.from_numpy(idx), torch.from_numpy(d2)
    d2_all = pairwise_sq_dist(xyz, xyz)
    idx = farthest_point_sample(d2_all, count, start)
    return idx, torch.gather(d2_all, 1, idx.unsqueeze(-1).expand(-1, -1, d2_all.shape[-1]))


def ball_members(d2: torch.Tensor, radius: float, nsample: int, grouping: str = CHECKPOINT_GROUPING) -> torch.Tensor:
    """ball_query as `grouping` keeps members; on CPU a numba kernel (one pass per centre instead of a cumsum and
    a scatter, or a sort)."""
    nearest = grouping == "set"
    if not _numba_ok(d2):
        return ball_query(d2, radius, nsample, nearest)
    # torch compares a float32 tensor with a Python float in float32: so does the kernel.
    kernel = _cpu.ball_query_nearest if nearest else _cpu.ball_query
    return torch.from_numpy(kernel(_np(d2), np.float32(radius * radius), nsample))


# -------------------------------------------------------------------------------------------- layers


class SharedMLP(nn.Module):
    """Per-point Linear + BatchNorm + ReLU layers on the last dimension of any (..., C) tensor."""

    def __init__(self, in_channels: int, widths: list[int]) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for width in widths:
            layers += [nn.Linear(in_channels, width, bias=False), nn.BatchNorm1d(width), nn.ReLU(inplace=True)]
            in_channels = width
        self.layers = nn.ModuleList(layers)
        self.out_channels = in_channels

    def forward(self, x: torch.Tensor, start: int = 0) -> torch.Tensor:
        """Apply layers[start:] (start = 1: the caller has applied the first Linear itself)."""
        return self._run(x, self.layers[start:])

    @staticmethod
    def _run(x: torch.Tensor, layers: nn.ModuleList | list[nn.Module]) -> torch.Tensor:
        shape = x.shape
        x = x.reshape(-1, shape[-1])
        for layer in layers:
            x = layer(x)
        return x.reshape(*shape[:-1], x.shape[-1])

    def pool(self, x: torch.Tensor, start: int = 0) -> torch.Tensor:
        """forward(x, start) max-pooled over dim -2. A trailing Linear + ReLU (a fused model's) adds its bias
        and the ReLU after the max: exact (both are monotonic per channel) and far less work on big groups."""
        layers = list(self.layers[start:])
        if (len(layers) >= 2 and isinstance(layers[-1], nn.ReLU) and isinstance(layers[-2], nn.Linear)
                and layers[-2].bias is not None):
            linear = layers[-2]
            x = self._run(x, layers[:-2])
            x = nn.functional.linear(x, linear.weight).amax(dim=-2) + linear.bias
            return torch.relu_(x)
        return self._run(x, layers).amax(dim=-2)


class SetAbstractionMSG(nn.Module):
    """FPS centres, then per scale: ball query, group (relative xyz + features), shared MLP, max-pool."""

    def __init__(self, cfg: SAConfig, in_features: int, grouping: str = CHECKPOINT_GROUPING) -> None:
        super().__init__()
        self.cfg = cfg
        self.grouping = grouping
        self.mlps = nn.ModuleList(SharedMLP(in_features + 3, widths) for widths in cfg.mlps)
        self.out_channels = sum(m.out_channels for m in self.mlps)

    def forward(self, xyz: torch.Tensor, feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        centres_idx, d2 = sample_centres(xyz, self.cfg.centres, self.grouping)
        centres = gather_points(xyz, centres_idx)
        both = torch.cat([xyz, feat], dim=-1)
        outs = []
        for radius, nsample, mlp in zip(self.cfg.radii, self.cfg.nsamples, self.mlps, strict=True):
            idx = ball_members(d2, radius, nsample, self.grouping)
            # The first Linear acts on (point xyz - centre, features): project every point and centre once,
            # then group the projections (cheaper than projecting every grouped copy).
            first = mlp.layers[0]
            projected, centre_part = first(both), centres @ first.weight[:, :3].T
            start = 1
            if _numba_ok(projected) and _no_grad_needed(projected, centre_part):
                relu = isinstance(mlp.layers[1], nn.ReLU)
                start += relu
                grouped = torch.from_numpy(_cpu.group_relative(_np(projected), _np(idx), _np(centre_part), relu))
            else:
                grouped = gather_points(projected, idx) - centre_part.unsqueeze(2)
            outs.append(mlp.pool(grouped, start=start))
        return centres, torch.cat(outs, dim=-1)


class SetAbstractionAll(nn.Module):
    """Group-all level: shared MLP on (xyz, features) of every point, max-pool to one global feature."""

    def __init__(self, widths: list[int], in_features: int) -> None:
        super().__init__()
        self.mlp = SharedMLP(in_features + 3, widths)
        self.out_channels = self.mlp.out_channels

    def forward(self, xyz: torch.Tensor, feat: torch.Tensor) -> torch.Tensor:
        return self.mlp.pool(torch.cat([xyz, feat], dim=-1)).unsqueeze(1)


class FeaturePropagation(nn.Module):
    """3-NN interpolated coarse features concatenated with the finer points' skip features, then a shared MLP.

    The first Linear is applied to the coarse features before interpolating (interpolation weights sum to
    one, so this is exact) and to the skip features separately: no per-point concatenation of wide features.
    """

    def __init__(self, coarse_channels: int, skip_channels: int, widths: list[int]) -> None:
        super().__init__()
        self.coarse_channels = coarse_channels
        self.mlp = SharedMLP(coarse_channels + skip_channels, widths)
        self.out_channels = self.mlp.out_channels

    def forward(
        self, query: torch.Tensor, skip: torch.Tensor, source: torch.Tensor, source_feat: torch.Tensor,
        source_batch: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """query (B, Q, 3) with skip features (B, Q, Cs); sources (B, S, 3) with features (B, S, C), or
        with `source_batch` (B,) those of proposal source_batch[b] of sources (P, S, 3) and features (P, S, C)."""
        first = self.mlp.layers[0]
        c = self.coarse_channels
        projected = source_feat @ first.weight[:, :c].T  # per proposal, before any copies per query block
        skip_weight = first.weight[:, c:]
        if _numba_ok(query, source, projected, skip) and _no_grad_needed(projected, skip, skip_weight, first.bias):
            # One source feature (the group-all level's) goes to every query, as `interpolate` does.
            left, right = _lifted(query, source if projected.shape[1] > 1 else source[:, :1])
            bias = first.bias if first.bias is not None else torch.zeros(first.out_features)
            if source_batch is None:
                source_batch = torch.arange(len(query))
            relu = isinstance(self.mlp.layers[1], nn.ReLU)
            if skip.shape[-1] > _KERNEL_SKIP_CHANNELS:  # a matmul for MKL; the kernel adds its result
                skip, skip_weight = skip @ skip_weight.T, skip_weight[:, :0]
            x = torch.from_numpy(_cpu.interpolate_project(
                left, right, _np(source_batch), _np(projected), _np(skip), _np(skip_weight.T), _np(bias),
                relu))
            return self.mlp(x, start=1 + relu)
        if source_batch is not None:
            source, projected = source[source_batch], projected[source_batch]
        x = interpolate(query, source, projected) + skip @ skip_weight.T
        if first.bias is not None:
            x = x + first.bias
        return self.mlp(x, start=1)


class PointNet2Seg(nn.Module):
    """PointNet++ MSG segmentation network: SA levels, a group-all level, FP levels back to the points."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        config.check()
        self.config = config
        channels = [NUM_POINT_FEATURES]
        self.sa = nn.ModuleList()
        for level in config.sa:
            self.sa.append(SetAbstractionMSG(level, channels[-1], config.grouping))
            channels.append(self.sa[-1].out_channels)
        self.sa_all = SetAbstractionAll(config.global_mlp, channels[-1])
        coarse = self.sa_all.out_channels
        self.fp = nn.ModuleList()
        # FP levels from coarsest to finest; the finest one's skip features are (xyz, point features).
        skips = [*channels[1:][::-1], 3 + NUM_POINT_FEATURES]
        for skip, widths in zip(skips, config.fp_mlps, strict=True):
            self.fp.append(FeaturePropagation(coarse, skip, widths))
            coarse = self.fp[-1].out_channels
        self.head = nn.Sequential(
            SharedMLP(coarse, [config.fc]),
            nn.Dropout(1.0 - config.dropout_keep),
            nn.Linear(config.fc, config.num_classes),
        )

    def encode(self, xyz: torch.Tensor, feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sampled points xyz (B, N, 3), features (B, N, F) -> finest SA centres (B, S1, 3) with their
        propagated features (B, S1, C)."""
        levels = [(xyz, feat)]
        for sa in self.sa:
            levels.append(sa(*levels[-1]))
        coarse_xyz, coarse_feat = levels[-1][0], self.sa_all(*levels[-1])
        for fp, (level_xyz, level_feat) in zip(self.fp[:-1], levels[1:][::-1], strict=True):
            coarse_feat = fp(level_xyz, level_feat, coarse_xyz, coarse_feat)
            coarse_xyz = level_xyz
        return coarse_xyz, coarse_feat

    def decode(
        self,
        coarse_xyz: torch.Tensor,
        coarse_feat: torch.Tensor,
        xyz: torch.Tensor,
        feat: torch.Tensor,
        proposal: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Logits (Q, L, K) at query blocks xyz (Q, L, 3) with features (Q, L, F); block q belongs to
        proposal `proposal[q]` of the encoded batch (default: block q is proposal q). Without autograd the
        logits are a view of a (K, Q * L) tensor."""
        x = self.fp[-1](xyz, torch.cat([xyz, feat], dim=-1), coarse_xyz, coarse_feat, proposal)
        if not _no_grad_needed(x):
            return self.head(x)
        # Inference: the last Linear with classes first, (K, Q * L), returned as a transposed view; a caller's
        # softmax over classes is ten times faster on CPU in that layout (dim 0) than over a last dim of 4.
        shape = x.shape[:-1]
        hidden, _, last = self.head
        first = hidden.layers[0]
        if (not self.training and _numba_ok(x) and len(hidden.layers) == 2 and isinstance(hidden.layers[1], nn.ReLU)
                and first.bias is not None):
            # A fused model's head: one matmul to channels-first features, then bias, ReLU and the last Linear
            # in one numba pass (no bias copy, no separate ReLU pass over Q * L * C values).
            hidden_t = torch.mm(first.weight, x.reshape(-1, x.shape[-1]).T)
            logits = torch.from_numpy(_cpu.relu_linear_t(_np(hidden_t), _np(first.bias), _np(last.weight),
                                                         _np(last.bias)))
        else:
            for layer in self.head[:-1]:
                x = layer(x)
            logits = torch.addmm(last.bias.unsqueeze(1), last.weight, x.reshape(-1, x.shape[-1]).T)
        return logits.T.reshape(*shape, logits.shape[0])

    def forward(self, xyz: torch.Tensor, feat: torch.Tensor) -> torch.Tensor:
        """Logits (B, N, K) for the sampled points xyz (B, N, 3) with features (B, N, F)."""
        return self.decode(*self.encode(xyz, feat), xyz, feat)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def _fuse_layers(layers: list[nn.Module]) -> list[nn.Module]:
    """The same layers with each Linear directly followed by an eval-mode BatchNorm1d folded into one Linear."""
    out: list[nn.Module] = []
    i = 0
    while i < len(layers):
        layer = layers[i]
        nxt = layers[i + 1] if i + 1 < len(layers) else None
        if isinstance(layer, nn.Linear) and isinstance(nxt, nn.BatchNorm1d):
            scale = nxt.weight / torch.sqrt(nxt.running_var + nxt.eps)
            fused = nn.Linear(layer.in_features, layer.out_features, bias=True)
            bias = layer.bias if layer.bias is not None else torch.zeros_like(nxt.running_mean)
            with torch.no_grad():
                fused.weight.copy_(layer.weight * scale.unsqueeze(1))
                fused.bias.copy_((bias - nxt.running_mean) * scale + nxt.bias)
            out.append(fused.to(layer.weight.device))
            i += 2
        else:
            out.append(layer)
            i += 1
    return out


def fuse_batchnorm(model: PointNet2Seg) -> PointNet2Seg:
    """Fold every BatchNorm into the Linear before it, in place, for faster inference; puts the model in eval mode."""
    model.eval()
    for module in model.modules():
        if isinstance(module, SharedMLP):
            module.layers = nn.ModuleList(_fuse_layers(list(module.layers)))
    return model


def flush_subnormals(model: nn.Module) -> nn.Module:
    """Set every subnormal weight and buffer value (|v| < 1.2e-38, never 0) to 0, in place, for inference.

    Training leaves some (weight decay on dead units; the shipped lite weights hold about 6,300); an x86 CPU takes a
    slow microcode path for each multiply with one, and they add less than 1e-30 to any output. Measured on the
    lite weights (10 synthetic frames, the two models interleaved frame by frame): the same labels and confidences,
    stage 2 7-8 % faster (median per-frame ratio 0.92-0.93).
    """
    tiny = torch.finfo(torch.float32).tiny
    with torch.no_grad():
        for tensor in (*model.parameters(), *model.buffers()):
            if tensor.dtype.is_floating_point:
                tensor[tensor.abs() < tiny] = 0.0
    return model
