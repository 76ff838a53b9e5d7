"""One adaptation of stage 2 to a user's sensor, from an unlabelled recording (`pass3d_adapt`).

`Adaptation(options).run()` reads the recording (at most `max_scans`, evenly spaced in time), reads its sensor as a
stream would (adapt/sensor.py), holds out stretches of it (adapt/holdout.py), checks the starting weights on them
without labels (adapt/check.py) and on unseen synthetic scenes of the nearest simulated sensor at the measured mount
(the guard), fine-tunes from those weights with view consistency on the scans adapted on and labelled synthetic
scans of the same simulated sensor (the anchor) within the time budget, averages the result with the starting
weights (as the shipped weights were made), checks and guards again, and judges: weights that lose more than
GUARD_DROP mean IoU on the guard scenes are refused. The folder is written by adapt/output.py.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np
import torch

from pass3d_ros.adapt import sample_cache
from pass3d_ros.adapt.check import check_scans
from pass3d_ros.adapt.holdout import Split, fewest_scans, split_scans
from pass3d_ros.adapt.sensor import AUTO, FAR_DISTANCE, SensorReading, read_sensor
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.core.stage1.config import AUTO as AUTO_RANGE
from pass3d_ros.core.stage2 import open_classifier
from pass3d_ros.core.stage2.segmentation import Segmenter, load_model, make_checkpoint
from pass3d_ros.data.bag import parse_bag_spec, select_topic
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import Dataset, open_dataset, refuse_repeated_recordings, resolve_dataset
from pass3d_ros.evaluation.offline import evaluate_draws, proposed_frame
from pass3d_ros.msgs.errors import UserError
from pass3d_ros.synthetic.dataset import HEIGHT_RANGE_M
from pass3d_ros.training import launcher
from pass3d_ros.training.consistency import unlabelled_samples_of
from pass3d_ros.training.samples import SampleSet
from pass3d_ros.training.trainer import Trainer, TrainOptions

GUARD_DROP = 1.0  # mean IoU points the guard scenes may lose (mean over draws): adapting must not unlearn the labels
GUARD_SEED = 97  # unseen synthetic scenes: no shipped training run drew from this seed
ANCHOR_SEED = 51  # labelled synthetic scenes the fine-tune keeps learning from, so the labels are not forgotten
AVERAGE_ALPHA = 0.5  # the adapted weights: this share of the fine-tune, the rest the starting weights
TRAIN_MODULE = "pass3d_ros.tools.train"  # the fine-tune's workers with --nproc: pass3d_train's, as its launcher runs
RESERVE = 1.2  # the time after the fine-tune is budgeted as this many times the checks before it took


@dataclass
class AdaptOptions:
    """What `pass3d_adapt` was asked for (its flags, same names and defaults)."""

    data: list[str]
    weights: str | None = None  # the starting weights (None: the shipped ones)
    minutes: float = 20.0  # the whole run's wall-time budget
    max_scans: int = 120  # scans read from the recording, evenly spaced
    draws: int = 2  # point-sample draws of each check and guard
    guard_scenes: int = 10
    anchor_frames: int = 100
    epochs: int = 40  # the fine-tune's most epochs: as many as fit the budget left (Trainer fit_epochs), at most these
    device: str = "cpu"  # torch device of the checks and the fine-tune
    nproc: int = 1  # fine-tune processes (data-parallel, pass3d_train's launcher); the checks run in this one
    sensor: str = AUTO  # the simulated sensor of the anchor and the guard (AUTO: the nearest to the recording)
    cache: Path | None = None  # where the anchor's samples are kept between runs (None: nowhere)
    lr: float = 3e-4
    seed: int = 0
    progress: bool = True
    stage1: Stage1Config = field(default_factory=Stage1Config)


@dataclass
class AdaptResult:
    """Everything the report and the folder need."""

    sensor: SensorReading
    split: Split
    scan_names: list[str]
    before: dict
    guard_before: dict | None  # None: no guard ran (settings only)
    after: dict | None = None
    guard_after: dict | None = None
    weights: dict | None = None  # the adapted checkpoint (None: none made)
    training: dict = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)  # the guards that failed, each with its numbers
    partial: str | None = None  # why the run ended early ("interrupted"), None when it did not
    seconds: float = 0.0
    view: dict | None = None  # a held-out scan's points and labels before and after, for the picture
    topic: str | None = None  # the recording's PointCloud2 topic when it is bags of one topic: the node's input_topic
    stage1: Stage1Config = field(default_factory=Stage1Config)  # the run's (--param, the body's min_range): the nodes'
    start_weights: str | None = None  # the weights the run started from (None: the shipped ones)
    settings_only: str | None = None  # why no fine-tune was tried (a recording too short to hold out); None: one was

    @property
    def accepted(self) -> bool:
        """Whether the adapted weights passed every guard (and the run finished)."""
        return self.weights is not None and not self.refused and self.partial is None


class Adaptation:
    """One run of `pass3d_adapt`: `run()` lists its steps. `work` is a folder for the fine-tune's files."""

    def __init__(self, options: AdaptOptions, work: Path, log: Callable[[str], None] = print) -> None:
        self.options = options
        self.work = work
        self.log = log
        self.started = time.monotonic()
        self.scans: list[tuple[str, Frame]] = []
        self.topic: str | None = None
        self.start_checkpoint: dict = {}
        self.check_seconds = 0.0
        self.after: dict | None = None
        self.guard_after: dict | None = None
        self.adapted: dict | None = None  # the averaged checkpoint, once the fine-tune made one
        self.training: dict = {}
        self.refused: list[str] = []
        self.result: AdaptResult | None = None  # set by run(), or by a Ctrl-C in the fine-tune (partial)
        self.settings_only: str | None = None  # set when the recording is too short to hold out stretches
        self._guard_frames: list[Frame] | None = None
        self.segmenters: dict[str, Segmenter] = {}  # "before" / "after": built once, read by the checks and the view
        self.printed: set[str] = set()  # input-check topics printed per spec: each once over the run's passes

    def run(self) -> AdaptResult:
        """Read, check, fine-tune, check again and judge; a Ctrl-C during the fine-tune ends the run with the
        weights of the last finished epoch (partial, unchecked) and is raised again once the result is kept. A
        recording too short to hold out stretches gets the sensor's settings and the starting weights' check only."""
        self._read_weights()
        self._read_recording()
        self._read_sensor_and_split()
        self._check_before()
        if self.settings_only is not None:
            return self._finish()
        try:
            self._fine_tune()
        except KeyboardInterrupt:
            self._keep_partial()
            raise
        self._check_after()
        self._judge()
        return self._finish()

    # ------------------------------------------------------------------------------------------------ steps

    def _read_weights(self) -> None:
        """The starting weights, checked before the recording is read: a file that is no checkpoint of this model is
        one error naming it, at once rather than after the reading."""
        _, self.start_checkpoint = load_model(self.options.weights or _shipped())

    def _read_recording(self) -> None:
        """At most max_scans scans of the recording, evenly spaced over each spec, in time order."""
        o = self.options
        # a recording's copies would fall on both sides of the split and flatter the check
        refuse_repeated_recordings(o.data, "its copies would be both adapted on and held out")
        each = max(1, o.max_scans // len(o.data))
        topics = set()
        for spec in o.data:
            dataset = resolve_dataset(spec)
            topics.add(_bag_topic(dataset))
            count = _count(dataset)
            stride = max(1, -(-count // each)) if count else 1
            kept = 0
            for k, frame in enumerate(open_dataset(dataset)):
                if k % stride == 0 and kept < each:
                    self.scans.append((spec, frame))
                    kept += 1
        if not self.scans:
            raise UserError(f"no scans in {', '.join(o.data)}")
        self.topic = topics.pop() if len(topics) == 1 else None
        self.log(f"read {len(self.scans)} scans of {', '.join(o.data)}")

    def _read_sensor_and_split(self) -> None:
        """The sensor as a stream reads it, and the held-out stretches. The vehicle's own returns, when the scans show
        them, are left out of stage 1 from here on (stage1.min_range) and the sensor read again without them: they
        skew its elevation span and hide its laser lines."""
        asked = self.options.stage1.min_range  # auto: this tool reads the body over the whole recording instead
        reading = self.options.stage1
        if asked == AUTO_RANGE:
            reading = dataclasses.replace(reading, min_range=0.0)
        self.sensor = read_sensor(self.scans, reading, printed=self.printed, simulated=self.options.sensor)
        body = self.sensor.self_returns
        if body is not None and body.radius_m > (0.0 if asked == AUTO_RANGE else float(asked)):
            stage1 = dataclasses.replace(self.options.stage1, min_range=body.radius_m)
            self.options = dataclasses.replace(self.options, stage1=stage1)
            self.log(f"self-returns: {body.note}; stage1.min_range {body.radius_m:.1f} m leaves them out")
            again = read_sensor(self.scans, stage1, printed=self.printed, simulated=self.options.sensor)
            self.sensor = dataclasses.replace(again, self_returns=body)
        s = self.sensor
        needed = fewest_scans()
        if len(self.scans) < needed:  # settings only: every scan is checked, none adapted on
            count = len(self.scans)
            self.settings_only = (f"{count} scan(s); a fine-tune needs {needed} or more, to check it on stretches "
                                  "of time it did not learn from")
            self.split = Split(np.zeros(0, np.int64), np.arange(count), np.zeros(0, np.int64))
            self.log(f"sensor: {s.n_rings} rings ({s.ring_source}); settings only ({self.settings_only}): the "
                     "starting weights are checked on every scan")
            return
        self.split = split_scans(len(self.scans))
        far = ("" if s.distance <= FAR_DISTANCE else " (unlike the recording: the guard is only indicative)"
               if s.simulated_named else " (no simulated sensor is close: the guard is only indicative)")
        self.log(f"sensor: {s.n_rings} rings ({s.ring_source}), {s.simulated_how} "
                 f"simulated {s.nearest_simulated}{far}; {self.split.describe()}")

    def _check_before(self) -> None:
        """The starting weights on the held-out scans and on the guard scenes (no guard for settings only: no
        new weights to guard)."""
        t0 = time.monotonic()
        start = self.segmenters["before"] = self._segmenter(self.start_checkpoint)
        self.before = self._check(start)
        self.guard_before = None if self.settings_only is not None else self._guard(start)
        self.check_seconds = time.monotonic() - t0
        guard = "" if self.guard_before is None else f"; guard mean IoU {_guard_mean(self.guard_before):.1f}"
        self.log(f"before: {_agreement_line(self.before)}{guard}")

    def _fine_tune(self) -> None:
        """From the starting weights: the anchor's labelled synthetic scans and view consistency on the scans adapted
        on, until the budget left (minus the checks after it) runs out; then averaged with the starting weights."""
        o = self.options
        spent = (time.monotonic() - self.started) / 60.0
        left = o.minutes - spent - RESERVE * self.check_seconds / 60.0
        if left <= 0.0:
            raise UserError(f"--minutes {o.minutes:g} leaves no time to fine-tune: reading and checking took "
                            f"{spent:.1f} min and the checks after it need about {self.check_seconds / 60:.1f}; "
                            "give more minutes or fewer --max-scans")
        adapt_scans = [self.scans[i] for i in self.split.adapt]
        unlabelled = unlabelled_samples_of(adapt_scans, o.stage1)
        start_path = self.work / "start.pt"
        torch.save(self.start_checkpoint, start_path)
        options = TrainOptions(data=[self._anchor_spec()], out=self.work / "train", init=start_path,
                               epochs=o.epochs, lr=o.lr, seed=o.seed, quiet=not o.progress, minutes=left,
                               fit_epochs=True, device=o.device)
        self.log(f"fine-tune: up to {left:.1f} min, {len(unlabelled)} unlabelled proposals, anchor "
                 f"{self._anchor_spec()}" + (f", {o.nproc} processes" if o.nproc > 1 else ""))
        if o.cache is not None:
            sample_cache.lend(o.cache, options.out, self.log)
        try:
            if o.nproc > 1:
                self._train_in_workers(options, unlabelled)
            else:
                name = f"{len(adapt_scans)} scans of {', '.join(o.data)} (pass3d_adapt)"
                Trainer(options, command=["pass3d_adapt"], unlabelled=unlabelled, unlabelled_name=name).run()
        finally:  # kept after a Ctrl-C too: the anchor's samples are whole once written
            if o.cache is not None:
                sample_cache.keep(o.cache, options.out, self.log)
        last = torch.load(options.out / "last.pt", weights_only=True)  # its history: one record an epoch
        history = last.get("history", [])
        self.training = {"epochs": len(history), "stopped": history[-1].get("stopped") if history else None,
                         "minutes": left, "history": history, "unlabelled_proposals": len(unlabelled),
                         "processes": o.nproc}
        self.adapted = self._averaged(last)

    def _train_in_workers(self, options: TrainOptions, unlabelled: SampleSet) -> None:
        """The fine-tune in `nproc` data-parallel pass3d_train workers (its launcher), the unlabelled proposals handed
        over as a sample file."""
        samples = self.work / "unlabelled.npz"
        unlabelled.save(samples)
        options = dataclasses.replace(options, consistency_samples=str(samples))
        status = launcher.launch(TRAIN_MODULE, train_arguments(options), self.options.nproc, "pass3d_adapt")
        if status in (launcher.EXIT_SIGINT, launcher.EXIT_SIGTERM):
            raise KeyboardInterrupt
        if status != 0:
            raise UserError(f"the fine-tune's {self.options.nproc} processes failed (exit {status}; their report "
                            "is above)")

    def _keep_partial(self) -> None:
        """After a Ctrl-C in the fine-tune: the last finished epoch's weights, averaged, kept as partial."""
        last = self.work / "train" / "last.pt"
        self.adapted = self._averaged(torch.load(last, weights_only=True)) if last.is_file() else None
        self.after = self.guard_after = None
        self.result = self._finish(partial="interrupted")

    def _check_after(self) -> None:
        """The adapted weights on the same held-out scans and guard scenes."""
        adapted = self.segmenters["after"] = self._segmenter(self.adapted)
        self.after = self._check(adapted)
        self.guard_after = self._guard(adapted)
        self.log(f"after: {_agreement_line(self.after)}; guard mean IoU {_guard_mean(self.guard_after):.1f}")

    def _judge(self) -> None:
        """The guard: the unseen synthetic scenes of the nearest simulated sensor may lose at most GUARD_DROP."""
        self.refused = []
        drop = _guard_mean(self.guard_before) - _guard_mean(self.guard_after)
        if drop > GUARD_DROP:
            self.refused.append(f"guard: unseen synthetic {self.sensor.nearest_simulated} scenes lost {drop:.1f} "
                                f"mean IoU points (at most {GUARD_DROP:g})")

    def _finish(self, partial: str | None = None) -> AdaptResult:
        """The result of the run so far (`partial`: why it ended early)."""
        result = AdaptResult(
            sensor=self.sensor, split=self.split, scan_names=[f"{s}#{f.name}" for s, f in self.scans],
            before=self.before, guard_before=self.guard_before, after=self.after, guard_after=self.guard_after,
            weights=self.adapted, training=self.training, refused=list(self.refused), partial=partial,
            seconds=time.monotonic() - self.started, view=self._view() if partial is None else None,
            topic=self.topic, stage1=self.options.stage1, start_weights=self.options.weights,
            settings_only=self.settings_only)
        self.result = result
        return result

    # ---------------------------------------------------------------------------------------------- helpers

    def _segmenter(self, checkpoint: dict) -> Segmenter:
        """A warmed-up classifier of `checkpoint` (a dict: nothing is written to disk)."""
        segmenter = cast(Segmenter, open_classifier(checkpoint, device=self.options.device))  # a network
        segmenter.warm_up()
        return segmenter

    def _check(self, segmenter: Segmenter) -> dict:
        """The label-free check of `segmenter` on the held-out scans."""
        held = [self.scans[i] for i in self.split.check]
        return check_scans(held, self.options.stage1, segmenter, self.options.draws, printed=self.printed)

    def _guard_spec(self) -> str:
        return (f"synthetic:sensor={self.sensor.nearest_simulated},frames={self.options.guard_scenes},"
                f"seed={GUARD_SEED}{self._height()}")

    def _anchor_spec(self) -> str:
        return (f"synthetic:sensor={self.sensor.nearest_simulated},frames={self.options.anchor_frames},"
                f"seed={ANCHOR_SEED}{self._height()}")

    def _height(self) -> str:
        height = (self.sensor.mounting or {}).get("height_m")
        return f",height={min(max(float(height), HEIGHT_RANGE_M[0]), HEIGHT_RANGE_M[1]):.2f}" if height else ""

    def _guard(self, segmenter: Segmenter) -> dict:
        """`segmenter` on the guard scenes (generated once, kept), over the draws."""
        spec = self._guard_spec()
        if self._guard_frames is None:
            self._guard_frames = list(open_dataset(spec))
        scenes = self._guard_frames

        def frames() -> Iterator[tuple[str, Frame]]:
            return ((spec, frame) for frame in scenes)

        summary = evaluate_draws(frames, self.options.stage1, segmenter, self.options.draws)
        return {"spec": spec, "draws": summary["draws"]}

    def _averaged(self, fine_tuned: dict) -> dict:
        """The fine-tune's floating tensors averaged with the starting weights' (AVERAGE_ALPHA), with provenance."""
        start = self.start_checkpoint["state_dict"]
        tuned = fine_tuned["state_dict"]
        state = {k: AVERAGE_ALPHA * tuned[k] + (1 - AVERAGE_ALPHA) * start[k] if tuned[k].is_floating_point()
                 else tuned[k] for k in tuned}
        model, _ = load_model({**self.start_checkpoint, "state_dict": state})
        made = ("format", "version", "config", "classes", "state_dict", "optimizer", "scheduler")  # make_checkpoint's
        info = {k: v for k, v in self.start_checkpoint.items() if k not in made}
        info["adapted"] = {"data": list(self.options.data), "from": self.options.weights or "shipped",
                           "sensor": self.sensor.to_dict(), "anchor": self._anchor_spec(),
                           "epochs": fine_tuned.get("epoch", -1) + 1, "alpha": AVERAGE_ALPHA,
                           "history": fine_tuned.get("history", [])}
        return make_checkpoint(model, **info)

    def _view(self) -> dict | None:
        """A held-out scan (the middle one) labelled by the starting and the adapted weights."""
        if "after" not in self.segmenters or len(self.split.check) == 0:
            return None
        spec, frame = self.scans[self.split.check[len(self.split.check) // 2]]
        labels = []
        for when in ("before", "after"):
            pipeline = ScanPipeline(self.options.stage1, self.segmenters[when])
            proposed = proposed_frame(pipeline, spec, frame, self.printed)
            labels.append(pipeline.segment(proposed, proposed.nonempty_members()).segmented.labels)
        return {"name": f"{spec}#{frame.name}", "points": proposed.scan.points, "before": labels[0],
                "after": labels[1]}


def train_arguments(options: TrainOptions) -> list[str]:
    """pass3d_train's command line for the fine-tune's options (those pass3d_adapt sets; the rest are defaults)."""
    args = ["--data", *options.data[:1], "--out", str(options.out), "--init", str(options.init),
            "--epochs", str(options.epochs), "--lr", repr(options.lr), "--seed", str(options.seed),
            "--minutes", repr(options.minutes), "--device", options.device,
            "--consistency-samples", str(options.consistency_samples)]
    for spec in options.data[1:]:
        args += ["--data", spec]
    return args + (["--fit-epochs"] if options.fit_epochs else []) + (["--no-progress"] if options.quiet else [])


def _bag_topic(dataset: Dataset) -> str | None:
    """The PointCloud2 topic a `bag:` spec reads (as its reader picks it), None for any other format."""
    if dataset.format != "bag":
        return None
    path, topic = parse_bag_spec(dataset.path)
    return select_topic(path, topic)


def _count(dataset: Dataset) -> int | None:
    try:
        return dataset.count()
    except Exception:  # a reader that cannot count: every scan is read, the first max_scans kept
        return None


def _shipped() -> str:
    from pass3d_ros.core.stage2 import DEFAULT_WEIGHTS

    return str(DEFAULT_WEIGHTS)


def _agreement_line(check: dict) -> str:
    parts = []
    for name, row in check["agreement"].items():
        if row["mean"] is not None:
            parts.append(f"{name} agreement {100 * row['mean']:.1f} % ({sum(row['proposals'])} proposals)")
    return ", ".join(parts) or "no proposal called an object"


def _guard_mean(guard: dict) -> float:
    value = guard["draws"]["mean_iou"]["mean"]
    return float("nan") if value is None else 100.0 * float(value)

