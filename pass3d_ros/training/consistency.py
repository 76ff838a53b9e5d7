"""View consistency on unlabelled real scans: adaptation without their labels, which a user's sensor does not have.

Stage 2 reads a proposal in one canonical view; on real scans 20-25 % of car proposals change class across the 8
views, on synthetic ones 1-3 %. Each training step adds a few proposals of unlabelled real scans: the network's own
answer in the inference view (eval mode, no gradient) is the target for a random view of the same sampled points
with augmented intensity, on the points it is sure of (FixMatch, Sohn et al., NeurIPS 2020, with the canonical views
and the intensity augmentation as the strong augmentation). No label of those scans is read; their intensities are
put on the training scale per stream, as the segmentation node does.

With `draws` (because stage 2's answer moved with the 256 points it drew), the student reads another random draw
of the proposal's points than the teacher, so two draws must agree as well as two views: the teacher labels every
point of the proposal (its inference pass, sample and queries) and the student's sampled points take those labels.
With `teacher_draws` K > 1 the teacher's probabilities are the mean of K independent draws (a one-draw teacher teaches
whichever answer its draw gave; the mean over draws is the answer that depends least on the draw, and with 8 draws the
shipped weights read 19 KITTI frames' cars 10 points better; measured: docs/experiments/trials-issue-37-sampling.md).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch
from torch.nn import functional

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage2 import canonical
from pass3d_ros.core.stage2.pointnet2 import ModelConfig, PointNet2Seg
from pass3d_ros.core.stage2.segmentation import predict_probabilities, prepare_proposals, uses_intensity
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import open_dataset
from pass3d_ros.training.real_scans import proposed_scans
from pass3d_ros.training.samples import SampleSet, augment_intensity

DEFAULT_WEIGHT = 1.0  # the consistency term against the labelled loss
DEFAULT_THRESHOLD = 0.9  # a point's target counts when its inference-view probability is at least this
DEFAULT_BATCH = 8  # unlabelled proposals per optimizer step, over all processes


def unlabelled_samples(specs: Iterable[str], stage1: Stage1Config | None = None) -> SampleSet:
    """Every non-empty stage-1 proposal of the frames of `specs` (laser lines and the intensity map held per spec,
    intensities on the training scale); labels are all background placeholders and are never read."""
    return unlabelled_samples_of(((spec, frame) for spec in specs for frame in open_dataset(spec)), stage1)


def unlabelled_samples_of(frames: Iterable[tuple[str, Frame]], stage1: Stage1Config | None = None) -> SampleSet:
    """`unlabelled_samples` of (spec, frame) pairs already read (a recording's scans chosen by the caller)."""
    points, index, counts, frame_ids, names, sizes = [], [], [], [], [], []
    for scan in proposed_scans(frames, stage1):
        for member in scan.members:
            points.append(scan.points[member])
            index.append(scan.kept[member].astype(np.int32))
            counts.append(len(member))
            frame_ids.append(len(names))
        names.append(scan.frame.name)
        sizes.append(len(scan.frame.points))
    total = int(sum(counts))
    return SampleSet(
        points=np.concatenate(points).astype(np.float32) if points else np.zeros((0, 4), np.float32),
        labels=np.zeros(total, dtype=np.uint8),
        offsets=np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64),
        frame=np.asarray(frame_ids, dtype=np.int32),
        point_index=np.concatenate(index) if index else np.zeros(0, np.int32),
        frame_names=names,
        frame_sizes=np.asarray(sizes, dtype=np.int64),
    )


def view_pair(samples: SampleSet, ids: np.ndarray, config: ModelConfig, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The same random point sample of proposals `ids` twice: (xyz, features) in the inference view (the vertex
    nearest the sensor, intensity as given), then in a random one of the 8 views with augmented intensity.
    Point i of one is point i of the other."""
    ids = np.asarray(ids, dtype=np.int64)
    every = samples.boxes
    boxes = canonical.Boxes(every.center[ids], every.size[ids], every.yaw[ids], every.zmin[ids])
    members = samples.members(ids)
    seed = int(rng.integers(2**63))
    weak = prepare_proposals(samples.points, members, config, rng=np.random.default_rng(seed), boxes=boxes,
                             queries=False)
    views = rng.integers(0, canonical.NUM_VIEWS, len(ids))
    strong = prepare_proposals(samples.points, members, config, views=views, rng=np.random.default_rng(seed),
                               boxes=boxes, queries=False)
    feat = strong.sample_feat
    if uses_intensity(config):
        feat[:, :, 0] = augment_intensity(feat[:, :, 0], rng)
    return weak.sample_xyz, weak.sample_feat, strong.sample_xyz, feat


def draw_pair(samples: SampleSet, ids: np.ndarray, config: ModelConfig, rng: np.random.Generator,
              teacher: PointNet2Seg, device: torch.device | str, teacher_draws: int = 1
              ) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
    """Independent random draws of proposals `ids`: the teacher's `teacher_draws` (the inference view, intensity as
    given, every member point labelled through the network's queries, eval mode, no gradient; their probabilities
    averaged) and the student's (a random view, augmented intensity). Returns the student's (xyz, features) and the
    teacher's probabilities at each of the student's sampled points (P, N, K)."""
    ids = np.asarray(ids, dtype=np.int64)
    every = samples.boxes
    boxes = canonical.Boxes(every.center[ids], every.size[ids], every.yaw[ids], every.zmin[ids])
    members = samples.members(ids)
    seeds = rng.integers(2**63, size=1 + teacher_draws)
    training = teacher.training
    teacher.eval()
    try:
        probabilities, whole = None, None
        for seed in seeds[1:]:  # every draw queries all member points, in the same order
            whole = prepare_proposals(samples.points, members, config, rng=np.random.default_rng(int(seed)),
                                      boxes=boxes)
            draw = predict_probabilities(teacher, whole, device).astype(np.float64)  # (M, K), whole.query_index order
            probabilities = draw if probabilities is None else probabilities + draw
        probabilities = (probabilities / teacher_draws).astype(np.float32)
    finally:
        teacher.train(training)
    views = rng.integers(0, canonical.NUM_VIEWS, len(ids))
    student = prepare_proposals(samples.points, members, config, views=views, rng=np.random.default_rng(int(seeds[0])),
                                boxes=boxes, queries=False)
    order = np.argsort(whole.query_index, kind="stable")
    rows = order[np.searchsorted(whole.query_index[order], student.sample_index)]  # members are distinct points
    feat = student.sample_feat
    if uses_intensity(config):
        feat[:, :, 0] = augment_intensity(feat[:, :, 0], rng)
    return student.sample_xyz, feat, torch.from_numpy(probabilities[rows])


def consistency_loss(student_logits: torch.Tensor, teacher_probs: torch.Tensor, threshold: float
                     ) -> tuple[torch.Tensor, float]:
    """Cross entropy of the student's logits (..., K) against the teacher's most likely class, on the points whose
    teacher probability reaches `threshold`, averaged over all points (unsure ones add 0); and that sure share."""
    confidence, target = teacher_probs.reshape(-1, teacher_probs.shape[-1]).max(dim=-1)
    sure = (confidence >= threshold).float()
    loss = functional.cross_entropy(student_logits.reshape(-1, student_logits.shape[-1]).float(), target,
                                    reduction="none")
    return (loss * sure).mean(), float(sure.mean())
