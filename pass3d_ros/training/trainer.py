"""The stage-2 training loop: samples, model, optional resume, then per epoch train, validate, save.

`Trainer.run` reads as the list of its steps; each step is one private method. A run writes into its
output folder the sample caches, `last.pt` (with optimizer and scheduler state, for resuming), `best.pt`
(the highest validation mean IoU over car, pedestrian and cyclist; without validation data, the lowest
training loss) and `history.json`.

Data-parallel (pass3d_train --nproc or torchrun, see pass3d_ros.training.distributed): every process runs stage 1
on its share of the frames (frame i goes to rank i mod N) and the shares are all-gathered, so every rank holds the
whole sample set and every epoch visits each sample once. `batch_size` is global, proposals per optimizer step over
all processes: each rank takes every N-th proposal of the step's batch and DistributedDataParallel averages the
gradients, so a step is the single-process step up to augmentation noise and BatchNorm statistics. BatchNorm stays
per-process (no SyncBatchNorm: it does not run on CPU/gloo, and a process's share of a batch still holds thousands of
points per channel); DDP broadcasts rank 0's running statistics at every forward, and checkpoints hold rank 0's. The
shuffle order is seeded by (seed, epoch) on every rank; augmentation and dropout by seed + rank. Rank 0 alone
validates, logs, draws progress bars and writes checkpoints (plain, without the `module.` prefix) and history; a
sharded sample cache is named apart from the single-process one. In a plain run nothing of this happens.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from pass3d_ros.core.stage1.config import Stage1Config
from pass3d_ros.core.stage2.pointnet2 import (
    TRAIN_GROUPING,
    ModelConfig,
    PointNet2Seg,
    count_parameters,
    make_config,
)
from pass3d_ros.core.stage2.segmentation import (
    CheckpointError,
    check_finite,
    load_model,
    make_checkpoint,
    read_checkpoint,
)
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import Dataset, open_datasets, open_datasets_shard, resolve_datasets
from pass3d_ros.msgs.errors import Pass3dError, UserError
from pass3d_ros.training import consistency as view_consistency  # `consistency` is a TrainOptions field
from pass3d_ros.training import distributed
from pass3d_ros.training.losses import make_loss
from pass3d_ros.training.samples import (
    READ_ERRORS,
    Proposer,
    SampleSet,
    build_samples,
    cache_path,
    cached_samples,
    load_cached,
    stage1_overrides,
    training_batch,
)
from pass3d_ros.training.validation import format_scores, validate

FrameSource = Callable[[list[str]], Iterable[Frame]]


class TrainingError(Pass3dError, RuntimeError):
    """A run that cannot go on: no proposals to train on, or a checkpoint to resume from that does not fit."""


class DivergedError(TrainingError, UserError):
    """The loss or the weights stopped being finite (too high a learning rate, mostly); no checkpoint of it is kept."""


class PeerLostError(TrainingError):
    """Data-parallel: another process of the run stopped (its own report says why), so this one cannot go on."""


@dataclass(kw_only=True)
class TrainOptions:
    """Settings of one run. The fields are pass3d_train's flags (same names, same defaults), and every
    checkpoint stores them as `train_args`, so a run can be traced back to its settings."""

    data: list[str]  # training data specs, FORMAT:PATH
    val_data: list[str] = field(default_factory=list)  # validation data specs; none: best = lowest loss
    config: str = "lite"  # model configuration name
    epochs: int = 40
    out: Path  # output folder: checkpoints, sample caches, history
    device: str = "cpu"
    resume: bool = False  # continue from OUT/last.pt
    init: Path | None = None  # start from these weights (fine-tuning): fresh optimizer, schedule and epochs
    loss: str = "ce"  # "ce" or "focal"
    focal_alpha: float = 0.25
    focal_gamma: float = 2.0
    no_augment: bool = False  # train on the inference view only (no 8 views)
    no_n_feature: bool = False  # point-count feature n set to 0
    n_mode: str = "log"
    grouping: str = TRAIN_GROUPING  # pass3d_ros.core.stage2.pointnet2.GROUPINGS
    no_intensity_augment: bool = False  # no per-proposal intensity augmentation
    no_intensity: bool = False  # intensity fed as 0, in training and (stored in the config) inference
    seed: int = 0
    batch_size: int = 32  # proposals per optimizer step, over all processes when data-parallel
    lr: float = 1e-3
    weight_decay: float = 1e-4
    background_keep: float = 0.3  # share of background proposals kept
    max_steps: int = 0  # cap on batches per epoch (0: all)
    minutes: float = 0.0  # wall-time budget from the start of the run, samples included (0: none): see Trainer
    fit_epochs: bool = False  # with minutes: as many epochs as fit the budget, at most `epochs`: see Trainer
    threads: int = 0  # torch CPU threads (0: torch default)
    rebuild_cache: bool = False  # rerun stage 1 even if a sample cache exists
    force: bool = False  # a fresh run may replace a previous run's checkpoints in `out` (else it is refused)
    quiet: bool = False  # no progress bars
    param: list[str] = field(default_factory=list)  # stage-1 overrides KEY=VALUE as given (the Trainer's `stage1`)
    consistency: list[str] = field(default_factory=list)  # unlabelled real data specs for view consistency
    consistency_samples: str | None = None  # or their proposals, a sample file (SampleSet.save; pass3d_adapt --nproc)
    consistency_weight: float = view_consistency.DEFAULT_WEIGHT
    consistency_threshold: float = view_consistency.DEFAULT_THRESHOLD
    consistency_batch: int = view_consistency.DEFAULT_BATCH  # unlabelled proposals per step, all processes
    consistency_draws: int = 0  # K > 0: the student reads another random draw than the teacher, whose
    # probabilities are the mean of K draws (two draws must agree); 0: the student reads the teacher's draw

    def record(self) -> dict:
        """The options as a checkpoint stores them: plain values, paths as strings."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in values.items()}


def _read_sample_file(path: Path) -> SampleSet:
    """A sample file written by SampleSet.save; UserError naming it when it cannot be read."""
    try:
        return SampleSet.load(path)
    except READ_ERRORS as exc:
        raise UserError(f"--consistency-samples {path}: not a readable sample file ({exc})") from exc


@dataclass
class TrainResult:
    """What a finished run leaves: one record per epoch (loss, seconds, validation scores), the best score
    and the two checkpoint files."""

    history: list[dict]
    best_score: float
    last_path: Path
    best_path: Path
    stopped: str | None = None  # why the run ended before its last epoch ("time budget"); None when it did not


class Trainer:
    """One training run of the stage-2 network. `proposer` and `frame_source` replace stage 1 and the dataset
    readers (tests, constructed data); `command` is the command line a checkpoint records (default sys.argv);
    `stage1` the stage-1 parameters that build the samples (default: Stage1Config()); `unlabelled` the proposals of
    unlabelled scans for view consistency when the caller has built them (pass3d_adapt: the recording's scans to
    adapt on; `unlabelled_name` names them in the checkpoint), instead of `options.consistency`'s specs.

    With a time budget (`minutes`), the step that ends past it is the last: that epoch, however short, is validated
    and saved like a full one, its record says so ("stopped", "steps" of "planned"), and the run ends; validation
    and writing come after the budget (a few seconds to a minute on CPU). Data-parallel, the ranks stop together.
    With `fit_epochs` too, the first epoch's pace sets how many epochs the budget holds (at most `epochs`) and the
    learning-rate schedule is stretched over them (pass3d_adapt: the budget, not an epoch count, ends its fine-tune)."""

    config: ModelConfig
    train_set: SampleSet
    val_set: SampleSet | None
    model: PointNet2Seg
    net: torch.nn.Module  # the model as trained: the model itself, or its DistributedDataParallel wrapper
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]

    def __init__(
        self,
        options: TrainOptions,
        proposer: Proposer | None = None,
        frame_source: FrameSource | None = None,
        command: Sequence[str] | None = None,
        stage1: Stage1Config | None = None,
        unlabelled: SampleSet | None = None,
        unlabelled_name: str = "",
    ) -> None:
        if sum((unlabelled is not None, bool(options.consistency), bool(options.consistency_samples))) > 1:
            raise TrainingError("view consistency reads one of: the --consistency specs, --consistency-samples, "
                                "the given proposals")
        self.options = options
        self.stage1 = stage1
        self.proposer = proposer
        self.frame_source = frame_source
        self.command = list(sys.argv if command is None else command)
        self.out = Path(options.out)
        self.last_path, self.best_path = self.out / "last.pt", self.out / "best.pt"
        self.progress = not options.quiet
        self.start_epoch, self.best_score, self.history = 0, -math.inf, []
        self.data_info: dict = {}
        self.unlabelled: SampleSet | None = unlabelled  # proposals of the `consistency` scans (or the caller's)
        self.unlabelled_names = list(options.consistency) or (
            [unlabelled_name or "given"] if unlabelled is not None
            else [str(options.consistency_samples)] if options.consistency_samples else [])
        self._sure: list[float] = []  # the epoch's shares of unlabelled points sure enough to be a target
        self.init_model: PointNet2Seg | None = None  # the network `init` names, loaded before any work
        self.saved_epoch: int | None = None  # the last epoch this run wrote into last.pt (1-based)
        self.dist = distributed.Dist(device=options.device)
        self.deadline: float | None = None  # time.monotonic() at which the budget runs out (None: no budget)
        self.epochs = options.epochs  # the run's epochs: `fit_epochs` may set them after the first one

    def run(self) -> TrainResult:
        """Train as the options say; raises TrainingError when there is nothing to train on or the
        checkpoint to resume from has another model configuration, CheckpointError when it is missing."""
        if self.options.minutes:
            self.deadline = time.monotonic() + 60.0 * self.options.minutes
        self.dist = distributed.setup(self.options.device)
        try:
            return self._run()
        except RuntimeError as exc:
            if not (self.dist.enabled and distributed.is_peer_loss(exc)):
                raise
            raise PeerLostError(f"another process of this data-parallel run stopped ({type(exc).__name__})") from exc
        finally:
            distributed.shutdown(self.dist)

    def _run(self) -> TrainResult:
        """The steps of `run`, inside the process group when there is one."""
        self._check_checkpoints()
        self._prepare()
        self._load_samples()
        self._build_model()
        self._initialise()
        self._resume()
        self._distribute()
        self._describe_model()
        stopped = None
        epoch = self.start_epoch
        while epoch < self.epochs:
            began = time.monotonic()
            record = self._train_epoch(epoch)
            score = self._validate(record)
            improved = self._keep_record(record, score)
            self._save_checkpoints(record, improved)
            stopped = record.get("stopped")
            if stopped is not None:
                self._log(f"time budget of {self.options.minutes:g} min reached in epoch {epoch + 1} after "
                          f"{record['steps']} of {record['planned']} steps: that epoch was validated and saved")
                break
            if epoch == self.start_epoch:
                self._fit_epochs(epoch, time.monotonic() - began)
            epoch += 1
        self._log(f"checkpoints: {self.last_path}, {self.best_path} (best score {self.best_score:.4f})")
        return TrainResult(self.history, self.best_score, self.last_path, self.best_path, stopped)

    def _log(self, line: str) -> None:
        """Print a log line (rank 0 only)."""
        if self.dist.main:
            print(line)

    # ------------------------------------------------------------------------------------------ steps

    def _check_checkpoints(self) -> None:
        """Before any work: with `resume`, last.pt must be there; without it (or `force`), no earlier run's
        checkpoint may be there to be overwritten (hours of training); with `init`, its checkpoint must load."""
        held = [p.name for p in (self.last_path, self.best_path) if p.exists()]
        if held and not (self.options.resume or self.options.force):
            raise TrainingError(f"{self.out} holds a previous run's checkpoints ({', '.join(held)}): --resume to "
                                "continue it, --force to replace them (its sample caches are reused either way), or "
                                "another --out")
        if self.options.resume and not self.last_path.is_file():
            raise CheckpointError(f"{self.last_path}: no checkpoint to resume from (--resume)")
        if self.options.resume and self.options.init is not None:
            raise TrainingError("--init and --resume exclude each other: a resumed run already has its weights")
        if self.options.init is not None:
            self.init_model, _ = load_model(self.options.init)  # every check a checkpoint gets (format, classes, ...)

    def _prepare(self) -> None:
        """Threads, output folder, the seed, and the model configuration (a bad name fails before stage 1)."""
        o = self.options
        if o.threads:
            torch.set_num_threads(o.threads)
        self.progress = self.progress and self.dist.main
        if self.dist.enabled:
            self._log(f"data-parallel: {self.dist.world} processes ({self.dist.device}), "
                      f"batch {o.batch_size} proposals per step in all")
        self.out.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(o.seed)
        self.config = make_config(o.config)
        self.config.n_feature = not o.no_n_feature
        self.config.n_mode = o.n_mode
        self.config.grouping = o.grouping
        if o.no_intensity:
            self.config.extra["intensity"] = False

    def _load_samples(self) -> None:
        """Unlabelled samples for view consistency (first: a bad spec fails before the long part), then training
        (background partly discarded) and validation samples, from the caches or stage 1."""
        o = self.options
        if o.consistency:  # small: every rank builds it alike
            self.unlabelled = view_consistency.unlabelled_samples(o.consistency, self.stage1)
        elif o.consistency_samples:
            self.unlabelled = _read_sample_file(Path(o.consistency_samples))
        if self.unlabelled is not None:
            if len(self.unlabelled) == 0:
                raise TrainingError(f"no proposals in {', '.join(self.unlabelled_names)} for view consistency")
            draws = (f", teacher ({o.consistency_draws} draws averaged) and student on independent draws"
                     if o.consistency_draws else "")
            self._log(f"view consistency: {len(self.unlabelled)} unlabelled proposals of "
                      f"{len(self.unlabelled.frame_names)} scans, weight {o.consistency_weight}, "
                      f"threshold {o.consistency_threshold}, {o.consistency_batch} a step{draws}")
        common = {
            "frames": self.frame_source or _default_frames,
            "seed": o.seed,
            "proposer": self.proposer,
            "rebuild": o.rebuild_cache,
            "stage1": self.stage1,
        }
        self.train_set, train_cache = self._samples(
            o.data, background_keep=o.background_keep, keep_frame_labels=False, common=common
        )
        if len(self.train_set) == 0:
            raise TrainingError(f"no proposals in {', '.join(o.data)}")
        self.val_set = None
        if o.val_data:
            self.val_set, _ = self._samples(o.val_data, background_keep=1.0, keep_frame_labels=True, common=common)
        self._log(f"train samples: {self.train_set.describe()} (cache {train_cache.name})")
        if self.val_set is not None:
            self._log(f"val samples: {self.val_set.describe()}")
        self.data_info = {
            "train": list(o.data),
            "val": list(o.val_data),
            "train_samples": self.train_set.describe(),
            "val_samples": self.val_set.describe() if self.val_set is not None else None,
            "background_keep": o.background_keep,
            "stage1_params": stage1_overrides(self.stage1),
            "consistency": list(self.unlabelled_names),
        }

    def _samples(
        self, specs: list[str], background_keep: float, keep_frame_labels: bool, common: dict
    ) -> tuple[SampleSet, Path]:
        """The samples of `specs` from the cache or stage 1; data-parallel, each rank builds its share of the
        frames and all ranks gather the whole set, which rank 0 caches."""
        datasets = None if self.frame_source is not None else resolve_datasets(specs)  # each spec parsed once
        data = specs if datasets is None else datasets
        total = None if datasets is None else _total_frames(datasets)  # for the progress bar
        if not self.dist.enabled:
            return cached_samples(data, self.out, background_keep=background_keep,
                                  keep_frame_labels=keep_frame_labels, progress=self.progress, total=total, **common)
        path = cache_path(data, self.out, background_keep, common["seed"], keep_frame_labels, common["proposer"],
                          shards=self.dist.world, stage1=common["stage1"])
        cached = distributed.broadcast(self.dist, path.is_file() and not common["rebuild"])
        if cached:
            loaded = load_cached(path)
            if all(distributed.all_gather(self.dist, loaded is not None)):
                return loaded, path
        frames = (common["frames"](data) if self.frame_source is not None
                  else open_datasets_shard(data, self.dist.rank, self.dist.world))
        part = build_samples(frames, background_keep, common["seed"], keep_frame_labels, common["proposer"],
                             self.progress, total, shard=(self.dist.rank, self.dist.world), stage1=common["stage1"])
        samples = SampleSet.concatenate(distributed.all_gather(self.dist, part))
        if self.dist.main:
            samples.save(path)
        return samples, path

    def _build_model(self) -> None:
        """The network, Adam with a cosine learning-rate schedule over the epochs, and the loss."""
        o = self.options
        self.model = PointNet2Seg(self.config).to(self.dist.device)
        self.net = self.model
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=o.lr, weight_decay=o.weight_decay)
        self.scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
            self.optimizer, T_max=max(o.epochs, 1), eta_min=o.lr / 100
        )
        self.loss_fn = make_loss(o.loss, alpha=o.focal_alpha, gamma=o.focal_gamma)

    def _initialise(self) -> None:
        """With `init`, load its weights into the fresh model (fine-tuning); the model configuration must
        match (the checkpoint's, including the n feature setting; intensity may be turned off)."""
        if self.init_model is None:
            return
        # The grouping has no weights: a network trained with one can start training with the other; and a network
        # that read intensity can start training without it (--no-intensity, a sensor without it: that input is 0).
        init = self.init_model.config.to_dict()
        init["grouping"] = self.config.grouping
        if self.options.no_intensity:
            init["extra"] = {**init["extra"], "intensity": False}
        if init != self.config.to_dict():
            raise TrainingError(f"{self.options.init} was trained with another config "
                                f"({self.init_model.config.name}); cannot start from it")
        self.model.load_state_dict(self.init_model.state_dict())
        self._log(f"initial weights: {self.options.init}")

    def _resume(self) -> None:
        """With `resume`, continue from last.pt: weights, optimizer, scheduler, epoch, best score, history."""
        if not self.options.resume:
            return
        state, _ = read_checkpoint(self.last_path)
        if not isinstance(state, dict) or not {"config", "optimizer", "scheduler", "epoch"} <= state.keys():
            raise CheckpointError(f"{self.last_path}: not a pass3d training checkpoint (last.pt); cannot resume")
        if state["config"] != self.config.to_dict():
            raise TrainingError(f"{self.last_path} was trained with another config; not resuming")
        check_finite(state["state_dict"], str(self.last_path))
        self.model.load_state_dict(distributed.strip_module_prefix(state["state_dict"]))
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.start_epoch, self.best_score = state["epoch"] + 1, state["best_score"]
        self.history = list(state["history"])
        self._log(f"resumed from {self.last_path} at epoch {self.start_epoch}")

    def _distribute(self) -> None:
        """Data-parallel: wrap the model (weights fresh or resumed) in DistributedDataParallel."""
        if self.dist.enabled:
            cuda = self.dist.device.startswith("cuda")
            self.net = torch.nn.parallel.DistributedDataParallel(
                self.model, device_ids=[self.dist.device] if cuda else None
            )

    def _describe_model(self) -> None:
        """Log the network's size, once the weights (fresh or resumed) are in place."""
        self._log(
            f"model {self.config.name}: {count_parameters(self.model)} parameters, "
            f"{self.config.num_points} points per sample"
        )

    def _train_epoch(self, epoch: int) -> dict:
        """One pass over the shuffled training samples (seeded per epoch), then a scheduler step; the
        epoch's record: mean loss (over all processes) and seconds."""
        o = self.options
        rank, world = self.dist.rank, self.dist.world
        rng = np.random.default_rng([o.seed, epoch])
        torch.manual_seed((o.seed + rank) * 100_003 + epoch)
        self.net.train()
        batch_size = max(1, o.batch_size)
        order = rng.permutation(len(self.train_set))
        if world > 1:  # the order is shared; augmentation draws are the rank's own
            rng = np.random.default_rng([o.seed + rank, epoch])
        steps = -(-len(order) // batch_size)
        if o.max_steps:
            steps = min(steps, o.max_steps)
        losses, self._sure = [], []
        bar = tqdm(range(steps), desc=f"epoch {epoch + 1}/{self.epochs}", unit="batch",
                   disable=None if self.progress else True)
        started = time.perf_counter()
        stopped = None
        for step in bar:
            batch = order[step * batch_size : (step + 1) * batch_size]
            if world > 1:  # this rank's share; a batch smaller than the world repeats proposals
                batch = np.resize(batch, max(len(batch), world))[rank::world]
            losses.append(self._train_step(batch, rng))
            if not math.isfinite(losses[-1]):
                raise DivergedError(f"training diverged: the loss is {losses[-1]} at epoch {epoch + 1}, step "
                                    f"{step + 1}; no checkpoint of this epoch written, try a smaller --lr "
                                    f"(this run: {o.lr:g})")
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}", refresh=False)
            if self._out_of_time() and step + 1 < steps:
                stopped = "time budget"
                break
        if not all(torch.isfinite(value).all() for value in self.model.state_dict().values()
                   if value.is_floating_point()):
            raise DivergedError(f"training diverged: the weights are no longer finite after epoch {epoch + 1}, step "
                                f"{steps}; no checkpoint of this epoch written, try a smaller --lr (this run: "
                                f"{o.lr:g})")
        self.scheduler.step()
        loss = distributed.mean(self.dist, float(np.mean(losses)))
        record = {"epoch": epoch, "train_loss": loss, "seconds": time.perf_counter() - started}
        if stopped is not None or (self._out_of_time() and epoch + 1 < self.epochs):
            record.update(stopped="time budget", steps=len(losses), planned=steps)
        if self._sure:
            record["consistency_sure"] = distributed.mean(self.dist, float(np.mean(self._sure)))
        return record

    def _fit_epochs(self, epoch: int, seconds: float) -> None:
        """With `fit_epochs` and a budget, after the run's first epoch: the epochs become as many as fit the time
        left at that epoch's pace (at least this one, at most `epochs`), and the cosine schedule spans them, so a
        budget ends the run at the schedule's end instead of cutting it or leaving time unused. Every rank agrees."""
        if not self.options.fit_epochs or self.deadline is None:
            return
        left = max(self.deadline - time.monotonic(), 0.0)
        fit = distributed.mean(self.dist, float(epoch + 1 + int(left // max(seconds, 1e-3))))
        epochs = max(epoch + 1, min(self.options.epochs, int(fit)))
        capped = " (the most asked for)" if int(fit) > self.options.epochs else ""
        self._log(f"time budget: {epochs} epochs{capped} ({seconds:.0f} s an epoch, {left / 60:.1f} min left)")
        if epochs != self.epochs:
            self.epochs = epochs
            self.scheduler.T_max = epochs

    def _out_of_time(self) -> bool:
        """Whether the time budget has run out, on any rank (a collective when data-parallel: every rank asks
        after every step, so they stop at the same one)."""
        if self.deadline is None:
            return False
        return distributed.mean(self.dist, float(time.monotonic() >= self.deadline)) > 0.0

    def _train_step(self, ids: np.ndarray, rng: np.random.Generator) -> float:
        """One optimizer step on the proposals `ids` (a random view each unless no_augment, intensity augmented
        unless no_intensity_augment); the batch loss."""
        o = self.options
        xyz, feat, labels = training_batch(self.train_set, ids, self.config, rng, augment=not o.no_augment,
                                           intensity_augment=not o.no_intensity_augment)
        device = self.dist.device
        if self.unlabelled is None:
            logits = self.net(torch.from_numpy(xyz).to(device), torch.from_numpy(feat).to(device))
            loss = self.loss_fn(logits, torch.from_numpy(labels.astype(np.int64)).to(device))
        else:
            loss = self._consistency_step(xyz, feat, labels, rng)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.item()

    def _consistency_step(self, xyz: np.ndarray, feat: np.ndarray, labels: np.ndarray, rng: np.random.Generator
                          ) -> torch.Tensor:
        """The labelled loss plus the view-consistency term on this rank's share of `consistency_batch`
        unlabelled proposals (pass3d_ros.training.consistency), in one forward pass through the trained net."""
        o, device = self.options, self.dist.device
        share = max(1, -(-o.consistency_batch // self.dist.world))
        ids = rng.integers(0, len(self.unlabelled), share)
        if o.consistency_draws:
            strong_xyz, strong_feat, teacher = view_consistency.draw_pair(self.unlabelled, ids, self.config, rng,
                                                                          self.model, device, o.consistency_draws)
            teacher = teacher.to(device)
        else:
            weak_xyz, weak_feat, strong_xyz, strong_feat = view_consistency.view_pair(self.unlabelled, ids,
                                                                                      self.config, rng)
            self.model.eval()
            with torch.no_grad():
                teacher = torch.softmax(self.model(torch.from_numpy(weak_xyz).to(device),
                                                   torch.from_numpy(weak_feat).to(device)).float(), dim=-1)
            self.model.train()
        logits = self.net(torch.from_numpy(np.concatenate([xyz, strong_xyz])).to(device),
                          torch.from_numpy(np.concatenate([feat, strong_feat])).to(device))
        labelled = len(xyz)
        loss = self.loss_fn(logits[:labelled], torch.from_numpy(labels.astype(np.int64)).to(device))
        term, sure = view_consistency.consistency_loss(logits[labelled:], teacher, o.consistency_threshold)
        self._sure.append(sure)
        return loss + o.consistency_weight * term

    def _validate(self, record: dict) -> float:
        """Score the epoch and log it: the validation mean IoU (NaN when undefined), or without validation
        data minus the training loss. The validation scores go into `record`. Data-parallel, rank 0 validates
        and the others receive its scores."""
        line = f"epoch {record['epoch'] + 1}: loss {record['train_loss']:.4f}"
        if self.val_set is None:
            self._log(line)
            return -record["train_loss"]
        scores = validate(self.model, self.val_set, self.dist.device, self.progress) if self.dist.main else None
        scores = distributed.broadcast(self.dist, scores)
        record["val"] = scores
        self._log(f"{line}; val {format_scores(scores)}")
        return scores["mean_iou"] if scores["mean_iou"] is not None else float("nan")

    def _keep_record(self, record: dict, score: float) -> bool:
        """Append the epoch to the history; whether its score beats the best so far (then it is the best)."""
        self.history.append(record)
        improved = not np.isnan(score) and score > self.best_score
        if improved:
            self.best_score = float(score)
        return improved

    def _save_checkpoints(self, record: dict, improved: bool) -> None:
        """Write best.pt (when improved, or when missing), last.pt with optimizer and scheduler, history.json;
        data-parallel, rank 0 writes and the others wait for it."""
        if not self.dist.main:
            distributed.barrier(self.dist)
            self.saved_epoch = record["epoch"] + 1
            return
        info = {
            "data": self.data_info,
            "command": self.command,
            "train_args": self.options.record(),
            "epoch": record["epoch"],
            "val": record.get("val"),
            "best_score": self.best_score,
            "history": self.history,
        }
        checkpoint = make_checkpoint(self.model, **info)
        if improved or not self.best_path.is_file():
            _save_atomically(self.best_path, lambda path: torch.save(checkpoint, path))
        state = {**checkpoint, "optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict()}
        _save_atomically(self.last_path, lambda path: torch.save(state, path))
        self.saved_epoch = record["epoch"] + 1
        text = json.dumps(self.history, indent=1)
        _save_atomically(self.out / "history.json", lambda path: path.write_text(text))
        distributed.barrier(self.dist)


def _save_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """Write `path` through a hidden sibling renamed into place, so an interruption never leaves half a file."""
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _default_frames(datasets: Sequence[Dataset]) -> Iterable[Frame]:
    return open_datasets(datasets)


def _total_frames(datasets: Sequence[Dataset]) -> int | None:
    try:
        counts = [dataset.count() for dataset in datasets]
    except Exception:
        return None
    return None if any(c is None for c in counts) else sum(counts)
