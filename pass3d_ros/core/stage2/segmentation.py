"""Stage 2 inference: per-point labels for a frame's proposals in one batched forward pass.

Every member point of a proposal gets the network's own prediction: the N sampled points go through the
set-abstraction levels, then the last feature-propagation level and the head run at *all* member points
(3-NN interpolation from the finest SA centres plus the point's own features; the same per-point
computation a sampled point gets). This costs one cheap per-point MLP per member point and avoids copying
the label of the nearest sampled neighbour. A point in two proposals takes the more confident prediction;
a point in no proposal is background with confidence 1. Beyond `max_proposals` proposals, the nearest to
the sensor are run; the others count as no proposal (their class is -1).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numba as nb
import numpy as np
import torch

from pass3d_ros.classes import BACKGROUND, CAR, CLASS_NAMES, CYCLIST, PEDESTRIAN
from pass3d_ros.core.stage2 import canonical, pointnet2_cpu
from pass3d_ros.core.stage2.pointnet2 import ModelConfig, PointNet2Seg, flush_subnormals, fuse_batchnorm
from pass3d_ros.msgs.errors import UserError

CHECKPOINT_FORMAT = "pass3d_stage2"
CHECKPOINT_VERSION = 1
# Query points are decoded in blocks of this many points of one proposal (padding wastes < one block each).
BLOCK = 128
# Proposals run per frame at most (the nearest to the sensor); the rest count as no proposal, and the node and the
# offline tools count and report them (`proposals_cut`). A front view has about 30 proposals, a full 360-degree scan
# twice as many and some beyond 64; 128 leaves room for those at about 0.4 ms of CPU per proposal (lite network, one
# thread: 118 proposals of two 360-degree Pandar64 frames took 47 ms at a budget of 64, 68 ms at 128).
DEFAULT_MAX_PROPOSALS = 128


class CheckpointError(UserError):
    """A stage-2 checkpoint is missing, unreadable or does not fit this code; the message names file and problem."""


class SegmentResult(NamedTuple):
    """labels (N,) uint8, confidence (N,) float32, proposal_class (P,) int16 (-1: proposal not classified);
    `people_share` (N,) float32: of each point's winning prediction, its pedestrian probability over its pedestrian
    and background probabilities together (NaN: not predicted), what `people_only` decides by; None from a classifier
    without probabilities."""

    labels: np.ndarray
    confidence: np.ndarray
    proposal_class: np.ndarray
    people_share: np.ndarray | None = None


@dataclass
class ProposalBatch:
    """Network input for P proposals: N sampled points each, plus (for inference) every member point as a
    query, laid out in blocks of BLOCK points of one proposal."""

    sample_xyz: np.ndarray  # (P, N, 3) float32, canonical frame
    sample_feat: np.ndarray  # (P, N, 2) float32: intensity, n
    sample_index: np.ndarray  # (P, N) int64: index of each sampled point in `points`
    query_xyz: np.ndarray | None = None  # (M, 3) float32: every member point, canonical frame
    query_feat: np.ndarray | None = None  # (M, 2) float32
    query_batch: np.ndarray | None = None  # (M,) int64: proposal of each query point
    query_index: np.ndarray | None = None  # (M,) int64: index of each query point in `points`
    block_proposal: np.ndarray | None = None  # (Q,) int64: proposal of each block of BLOCK query slots
    block_slot: np.ndarray | None = None  # (M,) int64: slot of each query point in the flattened blocks

    def blocks(self, values: np.ndarray) -> np.ndarray:
        """Per-query values (M, C) laid out in zero-padded blocks (Q, BLOCK, C)."""
        out = np.zeros((len(self.block_proposal) * BLOCK, values.shape[1]), dtype=values.dtype)
        out[self.block_slot] = values
        return out.reshape(len(self.block_proposal), BLOCK, values.shape[1])


def uses_intensity(config: ModelConfig) -> bool:
    """Whether the network sees intensity; a model trained without it (`extra["intensity"]` False) gets 0."""
    return bool(config.extra.get("intensity", True))


def _canonical_input(
    points: np.ndarray, index: np.ndarray, batch: np.ndarray, boxes: canonical.Boxes, views: np.ndarray, n: np.ndarray,
    intensity: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Canonical xyz (K, 3) and features (K, 2) = (intensity in [0, 1] or 0, n of the proposal) of points[index]."""
    local = canonical.to_canonical(points[index, :3], boxes, batch, views).astype(np.float32)
    feat = np.empty((len(index), 2), dtype=np.float32)
    feat[:, 0] = np.clip(points[index, 3], 0.0, 1.0) if intensity else 0.0
    feat[:, 1] = n[batch]
    return local, feat


def prepare_proposals(
    points: np.ndarray,
    members: list[np.ndarray],
    config: ModelConfig,
    views: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    boxes: canonical.Boxes | None = None,
    queries: bool = True,
    draw: int = 0,
    sampling: str = "draw",
) -> ProposalBatch:
    """Canonical frames and N-point samples of non-empty proposals `members` (indices into points (N, 4)).

    Inference (views None, rng None): the vertex nearest the sensor and, with `sampling` "content", the points of
    canonical.content_sample (draw `draw`), with "draw", a generator seeded from each proposal's point count (and
    `draw`, 0 by default: see canonical.inference_rng), or with "coverage"
    the draw-free sample of canonical.coverage_sample, so the result depends on the input alone. Training passes
    views and rng (and queries=False: only the sampled points are transformed).
    """
    points = np.asarray(points, dtype=np.float32)
    counts = np.array([len(m) for m in members], dtype=np.int64)
    num, count = config.num_points, len(members)
    index = np.concatenate(members).astype(np.int64) if members else np.zeros(0, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    if boxes is None:
        boxes = canonical.fit_boxes(points[index, :3], offsets)
    if views is None:
        views = canonical.inference_views(boxes)
    n = canonical.n_feature(counts, num, config.n_mode) if config.n_feature else np.zeros(count)
    if sampling not in canonical.SAMPLINGS:
        raise ValueError(f"unknown sampling {sampling!r}: {' or '.join(canonical.SAMPLINGS)}")
    if rng is None and sampling == "coverage":
        pos = canonical.coverage_sample(points[index, :3], offsets, num)
    else:
        pos = np.empty((count, num), dtype=np.int64)
        hashes = None
        if rng is None and sampling == "content":  # a network blind to intensity hashes x, y, z only
            hashes = canonical.point_hashes(points[index] if uses_intensity(config) else points[index, :3], draw)
        for p, size in enumerate(counts):
            if hashes is not None:
                pos[p] = offsets[p] + canonical.content_positions(hashes[offsets[p]:offsets[p + 1]], num, draw)
            elif rng is None:
                pos[p] = offsets[p] + canonical.inference_sample(int(size), num, draw)
            else:
                pos[p] = offsets[p] + canonical.sample_indices(int(size), num, rng)
    if not queries:
        local, feat = _canonical_input(points, index[pos.ravel()], np.repeat(np.arange(count), num), boxes, views, n,
                                       uses_intensity(config))
        return ProposalBatch(local.reshape(count, num, 3), feat.reshape(count, num, 2), index[pos])
    batch = np.repeat(np.arange(count), counts)
    local, feat = _canonical_input(points, index, batch, boxes, views, n, uses_intensity(config))
    nblocks = -(-counts // BLOCK)
    block_start = np.concatenate([[0], np.cumsum(nblocks)])
    slot = block_start[batch] * BLOCK + (np.arange(len(index)) - offsets[batch])
    block_proposal = np.repeat(np.arange(count), nblocks)
    return ProposalBatch(local[pos], feat[pos], index[pos], local, feat, batch, index, block_proposal, slot)


def predict_probabilities(model: PointNet2Seg, batch: ProposalBatch, device: torch.device | str) -> np.ndarray:
    """Class probabilities (M, K) of every query point, in one forward pass of the model (eval mode)."""
    with torch.inference_mode():
        coarse_xyz, coarse_feat = model.encode(
            torch.from_numpy(batch.sample_xyz).to(device), torch.from_numpy(batch.sample_feat).to(device)
        )
        logits = model.decode(
            coarse_xyz,
            coarse_feat,
            torch.from_numpy(batch.blocks(batch.query_xyz)).to(device),
            torch.from_numpy(batch.blocks(batch.query_feat)).to(device),
            torch.from_numpy(batch.block_proposal).to(device),
        )
        # Classes first (K, M): the softmax runs across points, ten times faster on CPU than over a last dim of 4.
        logits = logits.reshape(-1, logits.shape[-1]).T[:, torch.from_numpy(batch.block_slot).to(device)]
        return torch.softmax(logits.float(), dim=0).T.contiguous().cpu().numpy()


def scatter_predictions(
    num_points: int, point_index: np.ndarray, labels: np.ndarray, confidence: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-point labels (uint8) and confidences (float32) of a frame from possibly repeated predictions:
    the most confident prediction of a point wins (ties: the later one); unpredicted points are background, 1."""
    out_labels, out_conf, _ = scatter_with_values(num_points, point_index, labels, confidence, None)
    return out_labels, out_conf


def scatter_with_values(num_points: int, point_index: np.ndarray, labels: np.ndarray, confidence: np.ndarray,
                        values: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """`scatter_predictions`, and per point (float32) the `values` of the prediction that wins (NaN for unpredicted
    points; None without `values`), from one pass that finds the winners."""
    out_labels = np.full(num_points, BACKGROUND, dtype=np.uint8)
    out_conf = np.ones(num_points, dtype=np.float32)
    out_values = None if values is None else np.full(num_points, np.nan, dtype=np.float32)
    if len(point_index) == 0:
        return out_labels, out_conf, out_values
    best = _most_confident(num_points, np.asarray(point_index, dtype=np.int64), np.asarray(confidence))
    winners = best[best >= 0]
    at = point_index[winners]
    out_labels[at] = labels[winners]
    out_conf[at] = confidence[winners]
    if out_values is not None:
        out_values[at] = values[winners]
    return out_labels, out_conf, out_values


def people_only(result: SegmentResult, members: list[np.ndarray], mask: np.ndarray | None) -> SegmentResult:
    """`result` with the points flagged in `mask` (one bool per point, or None: none) called pedestrian or
    background only: pedestrian where the network's pedestrian probability is above its background probability
    (`people_share` above one half), else background, with that class's share of the two as confidence (rule F,
    docs/experiments/sensors.md); a proposal (of `members`, as segmented) whose points are all flagged takes the
    majority of their labels (ties: background). From a classifier without probabilities, car and cyclist labels
    become background instead, with confidence 1 less the classifier's. The flagged points are those of stage 1's
    `rerun_dropped` parts (Stage1Result.gives_way): person-shaped pieces kept to find people in crowds. Of their
    points the network called car on the development scans, 230 of 2,027 were cars; of those it called cyclist,
    none of 970 (rule R3)."""
    if mask is None or not mask.any():
        return result
    labels, confidence = result.labels.copy(), result.confidence.copy()
    share = result.people_share
    if share is None:
        veto = mask & ((labels == CAR) | (labels == CYCLIST))
        labels[veto] = BACKGROUND
        confidence[veto] = 1.0 - confidence[veto]
    else:
        told = mask & ~np.isnan(share)
        person = told & (share > 0.5)
        labels[told] = np.where(person[told], PEDESTRIAN, BACKGROUND)
        confidence[told] = np.where(person[told], share[told], 1.0 - share[told])
    proposal_class = result.proposal_class.copy()
    for k, m in enumerate(members):
        if proposal_class[k] >= 0 and len(m) and mask[m].all():
            if share is None:
                proposal_class[k] = BACKGROUND if proposal_class[k] in (CAR, CYCLIST) else proposal_class[k]
            else:
                people = int(np.count_nonzero(labels[m] == PEDESTRIAN))
                proposal_class[k] = PEDESTRIAN if 2 * people > len(m) else BACKGROUND
    return SegmentResult(labels, confidence, proposal_class, share)


@nb.njit(cache=True, nogil=True)
def _most_confident(num_points: int, point_index: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Per point, the position of its most confident prediction (ties: the later one), -1 where none; one pass
    instead of a sort of all predictions."""
    best = np.full(num_points, -1, dtype=np.int64)
    for i in range(len(point_index)):
        p = point_index[i]
        if best[p] < 0 or confidence[i] >= confidence[best[p]]:
            best[p] = i
    return best


def proposal_majority(query_batch: np.ndarray, labels: np.ndarray, num_proposals: int, num_classes: int) -> np.ndarray:
    """The most frequent predicted label of each proposal's points (P,) int16 (ties: the lower class)."""
    votes = np.bincount(query_batch * num_classes + labels, minlength=num_proposals * num_classes)
    return np.argmax(votes.reshape(num_proposals, num_classes), axis=1).astype(np.int16)


def proposals_cut(count: int, limit: int) -> int:
    """How many of a frame's `count` non-empty proposals a budget of `limit` leaves unclassified (their points are
    background): what the segmentation node counts on /diagnostics and the offline tools report."""
    return max(0, int(count) - int(limit))


def nearest_kept(distance: np.ndarray, limit: int) -> np.ndarray:
    """The proposal budget, the one rule every caller applies: the indices (ascending) of the `limit` proposals
    nearest the sensor, given each one's distance (x-y of its mean point); ties keep the lower index."""
    return np.sort(np.argsort(distance, kind="stable")[:limit])


def nearest_first(points: np.ndarray, members: list[np.ndarray], limit: int) -> np.ndarray:
    """Indices of up to `limit` non-empty proposals, the nearest to the sensor (x-y of the mean point) first."""
    valid = np.array([i for i, m in enumerate(members) if len(m) > 0], dtype=np.int64)
    if len(valid) <= limit:
        return valid
    dist = np.array([np.hypot(*points[members[i], :2].mean(axis=0)) for i in valid])
    return valid[nearest_kept(dist, limit)]


# ------------------------------------------------------------------------------------------- checkpoints


def make_checkpoint(model: PointNet2Seg, **info: Any) -> dict:
    """A checkpoint dict: format tag, model config, class list, weights, plus `info` (data, command, epoch, ...)."""
    return {
        "format": CHECKPOINT_FORMAT,
        "version": CHECKPOINT_VERSION,
        "config": model.config.to_dict(),
        "classes": list(CLASS_NAMES),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        **info,
    }


def no_checkpoint_file(path: Path) -> str:
    """Why `path` cannot be read as a checkpoint file: it is missing, or a folder (e.g. a training's --out given
    instead of the .pt file in it)."""
    if path.is_dir():
        return f"{path}: a folder, not a checkpoint file (name the .pt file in it)"
    return f"{path}: no such checkpoint file"


def read_checkpoint(source: str | os.PathLike | dict) -> tuple[dict, str]:
    """The stored dict and a name for messages; CheckpointError for a missing or unreadable file. Only plain
    tensors and containers are loaded (`weights_only`): anything else is not a pass3d checkpoint."""
    if isinstance(source, dict):
        return source, "checkpoint dict"
    path = Path(source)
    where = str(path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except (FileNotFoundError, IsADirectoryError):
        raise CheckpointError(no_checkpoint_file(path)) from None
    except Exception:
        raise CheckpointError(f"not a pass3d checkpoint: {where}") from None
    return data, where


def check_finite(state: dict, where: str) -> None:
    """CheckpointError naming `where` when a floating-point tensor of the state dict holds NaN or infinity (a
    diverged training run wrote it: such a network labels nothing sensibly)."""
    bad = sorted(k for k, v in state.items()
                 if isinstance(v, torch.Tensor) and v.is_floating_point() and not bool(torch.isfinite(v).all()))
    if bad:
        raise CheckpointError(f"{where}: weights are not finite (NaN or infinity) in {len(bad)} of {len(state)} "
                              f"tensors ({', '.join(bad[:3])}{' ...' if len(bad) > 3 else ''}); the training that "
                              "wrote it diverged")


def load_model(source: str | os.PathLike | dict) -> tuple[PointNet2Seg, dict]:
    """The model (eval mode, on CPU) and the checkpoint dict; CheckpointError on any problem."""
    data, where = read_checkpoint(source)
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        keys = sorted(data)[:8] if isinstance(data, dict) else type(data).__name__
        raise CheckpointError(f"{where}: not a pass3d stage-2 checkpoint (format tag missing; found {keys})")
    if data.get("version", 0) > CHECKPOINT_VERSION:
        raise CheckpointError(
            f"{where}: checkpoint format version {data.get('version')}, this code reads up to {CHECKPOINT_VERSION}"
        )
    if list(data.get("classes", [])) != list(CLASS_NAMES):
        raise CheckpointError(
            f"{where}: trained for classes {data.get('classes')}, this package uses {list(CLASS_NAMES)}"
        )
    try:
        config = ModelConfig.from_dict(data["config"])
        model = PointNet2Seg(config)
    except (KeyError, ValueError, TypeError) as exc:
        raise CheckpointError(f"{where}: bad model config ({exc})") from exc
    state = data.get("state_dict")
    if not isinstance(state, dict):
        raise CheckpointError(f"{where}: no state_dict")
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    wrong = sorted(k for k in set(expected) & set(state) if tuple(expected[k].shape) != tuple(state[k].shape))
    if missing or unexpected or wrong:
        problems = []
        for title, keys in (("missing", missing), ("unexpected", unexpected), ("wrong shape", wrong)):
            if keys:
                problems.append(f"{title}: {', '.join(keys[:4])}{' ...' if len(keys) > 4 else ''} ({len(keys)})")
        raise CheckpointError(f"{where}: weights do not fit the '{config.name}' model config; " + "; ".join(problems))
    check_finite(state, where)
    model.load_state_dict(state)
    return model.eval(), data


class ViewProbabilities(NamedTuple):
    """A frame's proposals seen in all 8 views: the point index (M,) of each query, its proposal (M,), the class
    probabilities (8, M, K) per view, and how many proposals."""

    query_index: np.ndarray
    query_batch: np.ndarray
    probs: np.ndarray
    proposals: int


def default_sampling(config: ModelConfig) -> str:
    """How inference samples a network's N points: the draw-free coverage sample for an order-free ("set")
    network, so the same points always get the same labels; for "slot" networks the content draw
    (canonical.content_sample: a large proposal's points picked by their content, so its labels depend on neither
    the input order nor an arbitrary count-seeded roll; a small one read in input order). It replaced the
    count-seeded draw once it matched it, within tolerances fixed beforehand, on real and synthetic scans over five
    draws (docs/experiments/trials-issue-37-sampling.md)."""
    return "coverage" if config.grouping == "set" else "content"


class Segmenter:
    """Stage-2 network classifier loaded from a checkpoint file or dict."""

    kind = "network"

    def __init__(
        self,
        weights: str | os.PathLike | dict,
        device: str = "cpu",
        max_proposals: int = DEFAULT_MAX_PROPOSALS,
        fuse: bool = True,
    ) -> None:
        model, checkpoint = load_model(weights)
        self.weights: str | None = None if isinstance(weights, dict) else str(weights)
        self.device = torch.device(device)
        self.config: ModelConfig = model.config
        self.classes: list[str] = list(checkpoint["classes"])
        self.data_description = checkpoint.get("data")
        self.checkpoint_info = {k: v for k, v in checkpoint.items() if k not in ("state_dict", "optimizer")}
        self.max_proposals = max_proposals
        self.draw = 0  # which seeded N-point sample inference uses (canonical.inference_rng); 0 is the default
        self.average_draws = 1  # draw sample sets of this many seeded draws each, their probabilities averaged
        self.average_below: float | None = None  # average only proposals less sure than this (None: all)
        self.sampling = default_sampling(self.config)  # one of canonical.SAMPLINGS
        self.model = flush_subnormals(fuse_batchnorm(model) if fuse else model).to(self.device).eval()

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        """Labels and confidences of all points, and the class of each proposal (nearest `max_proposals`)."""
        points = np.asarray(points, dtype=np.float32)
        proposal_class = np.full(len(members), -1, dtype=np.int16)
        chosen = nearest_first(points, members, self.max_proposals)
        if len(chosen) == 0:
            labels, conf = scatter_predictions(len(points), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
            return SegmentResult(labels, conf, proposal_class)
        chosen_members = [np.asarray(members[i]) for i in chosen]
        probs, batch = self._averaged_probabilities(points, chosen_members)
        pred = probs.argmax(axis=1)
        conf = probs[np.arange(len(pred)), pred]
        two = probs[:, PEDESTRIAN] + probs[:, BACKGROUND]
        share = np.divide(probs[:, PEDESTRIAN], two, out=np.full(len(two), 0.5), where=two > 0)
        labels, confidence, people_share = scatter_with_values(len(points), batch.query_index, pred.astype(np.uint8),
                                                               conf, share)
        proposal_class[chosen] = proposal_majority(batch.query_batch, pred, len(chosen), self.config.num_classes)
        return SegmentResult(labels, confidence, proposal_class, people_share)

    def _averaged_probabilities(self, points: np.ndarray, members: list[np.ndarray]
                                ) -> tuple[np.ndarray, ProposalBatch]:
        """Class probabilities of every member point from the first draw of `draw_set`, averaged with the set's
        other draws for every proposal (average_below None) or only for those whose points' mean winning
        probability in the first draw is below average_below. A proposal's probabilities do not depend on the
        other proposals of its batch, so the unsure ones are read again on their own."""
        draws = list(self.draw_set())
        batch = prepare_proposals(points, members, self.config, draw=draws[0], sampling=self.sampling)
        probs = predict_probabilities(self.model, batch, self.device)
        if len(draws) == 1:
            return probs, batch
        if self.average_below is None:
            again = np.arange(len(members))
        else:
            sums = np.bincount(batch.query_batch, weights=probs.max(axis=1), minlength=len(members))
            again = np.flatnonzero(sums / np.bincount(batch.query_batch, minlength=len(members)) < self.average_below)
            if len(again) == 0:
                return probs, batch
        rows = np.flatnonzero(np.isin(batch.query_batch, again))  # their points, in proposal order as below
        total = probs[rows].astype(np.float64)
        for draw in draws[1:]:
            subset = prepare_proposals(points, [members[i] for i in again], self.config, draw=draw,
                                       sampling=self.sampling)
            total += predict_probabilities(self.model, subset, self.device)
        probs[rows] = total / len(draws)
        return probs, batch

    def draw_set(self) -> range:
        """The seeded draws (canonical.inference_rng) inference averages: set `draw` of `average_draws` draws, so
        set 0 holds the default draw 0 and the sets are disjoint (seeded and content draws alike); the coverage
        sample has no draw (one pass)."""
        if self.sampling == "coverage":
            return range(1)
        return range(self.draw * self.average_draws, (self.draw + 1) * self.average_draws)

    def view_probabilities(self, points: np.ndarray, members: list[np.ndarray]) -> ViewProbabilities:
        """Class probabilities of every member point of the non-empty `members` in each of the 8 canonical views
        (the same sampled points, the box seen from each bottom vertex and mirrored)."""
        points = np.asarray(points, dtype=np.float32)
        members = [np.asarray(m) for m in members if len(m) > 0]
        if not members:
            empty = np.zeros(0, dtype=np.int64)
            return ViewProbabilities(empty, empty, np.zeros((canonical.NUM_VIEWS, 0, self.config.num_classes)), 0)
        boxes = canonical.fit_box_members(points, members)
        probs, batch = [], None
        for view in range(canonical.NUM_VIEWS):
            batch = prepare_proposals(points, members, self.config, views=np.full(len(members), view), boxes=boxes,
                                      draw=self.draw, sampling=self.sampling)
            probs.append(predict_probabilities(self.model, batch, self.device))
        return ViewProbabilities(batch.query_index, batch.query_batch, np.stack(probs), len(members))

    def view_classes(self, points: np.ndarray, members: list[np.ndarray]) -> np.ndarray:
        """The class of each non-empty proposal (P, 8) int16 in each of the 8 canonical views: a well-learned
        object reads the same in all 8, so their agreement measures how at home the network is on data without
        labels."""
        views = self.view_probabilities(points, members)
        return np.stack([proposal_majority(views.query_batch, p.argmax(axis=1), views.proposals,
                                           self.config.num_classes) for p in views.probs], axis=1) \
            if views.proposals else np.zeros((0, canonical.NUM_VIEWS), dtype=np.int16)

    def warm_up(self) -> None:
        """Compile the numba kernels (on-disk cache after the first time) and run a dummy frame through the
        whole path once (allocations, lazy initialisation)."""
        pointnet2_cpu.warm_up()
        rng = np.random.default_rng(0)
        car = rng.uniform([5, -2, -1.7, 0], [9, 2, 0, 1], (600, 4))
        person = rng.uniform([-8, 3, -1.7, 0], [-7, 4, 0, 1], (60, 4))
        pts = np.concatenate([car, person]).astype(np.float32)
        self.segment(pts, [np.arange(600), np.arange(600, 660)])
