"""Stage-2 training: losses, sample building and caching, a tiny overfit, the trainer learning, and a pass3d_train
smoke run."""

from __future__ import annotations

import dataclasses
import functools
import json

import numpy as np
import pytest
import torch

from pass3d_ros.classes import BACKGROUND, CAR, NUM_CLASSES, PEDESTRIAN
from pass3d_ros.core.stage2.pointnet2 import PointNet2Seg, make_config
from pass3d_ros.core.stage2.segmentation import CheckpointError, Segmenter, load_model, make_checkpoint
from pass3d_ros.data.frame import Frame
from pass3d_ros.tools import train
from pass3d_ros.training import consistency
from pass3d_ros.training.losses import class_alpha, cross_entropy, focal_loss, make_loss
from pass3d_ros.training.samples import SampleSet, build_samples, cached_samples, training_batch
from pass3d_ros.training.trainer import Trainer, TrainingError, TrainOptions
from pass3d_ros.training.validation import validate

# ------------------------------------------------------------------------------------------------ losses


def test_focal_equals_cross_entropy_with_gamma_zero_and_neutral_alpha():
    torch.manual_seed(0)
    logits, target = torch.randn(64, NUM_CLASSES) * 3, torch.randint(0, NUM_CLASSES, (64,))
    ce = cross_entropy(logits, target)
    assert torch.allclose(focal_loss(logits, target, alpha=None, gamma=0.0), ce, atol=1e-6)
    assert torch.allclose(focal_loss(logits, target, alpha=[1.0] * NUM_CLASSES, gamma=0.0), ce, atol=1e-6)
    assert torch.allclose(focal_loss(logits, target, alpha=0.5, gamma=0.0), 0.5 * ce, atol=1e-6)
    assert focal_loss(logits, target, alpha=None, gamma=2.0) < ce


def test_focal_down_weights_easy_points_and_alpha_convention():
    easy = torch.tensor([[8.0, 0, 0, 0]])
    hard = torch.tensor([[0.0, 0, 0, 0]])
    target = torch.tensor([0])
    ratio_focal = focal_loss(easy, target, None, 2.0) / focal_loss(hard, target, None, 2.0)
    ratio_ce = cross_entropy(easy, target) / cross_entropy(hard, target)
    assert ratio_focal < 0.01 * ratio_ce
    assert class_alpha(0.25).tolist() == [0.75, 0.25, 0.25, 0.25]
    assert torch.allclose(
        focal_loss(hard, torch.tensor([CAR]), 0.25, 2.0) / focal_loss(hard, torch.tensor([BACKGROUND]), 0.25, 2.0),
        torch.tensor(1 / 3),
    )
    with pytest.raises(ValueError):
        class_alpha([1.0, 2.0])
    with pytest.raises(ValueError):
        make_loss("hinge")


# --------------------------------------------------------------------------------------- constructed data


def car_points(rng, centre, yaw, count):
    """An L-shaped car-like shell (two visible sides) of 4 x 1.8 x 1.5 m."""
    t = rng.uniform(0, 1, count)
    side = rng.random(count) < 0.6
    x = np.where(side, -2 + 4 * t, -2.0)
    y = np.where(side, -0.9, -0.9 + 1.8 * t)
    z = rng.uniform(0.3, 1.5, count)
    c, s = np.cos(yaw), np.sin(yaw)
    xyz = np.stack([centre[0] + x * c - y * s, centre[1] + x * s + y * c, z - 1.7], axis=1)
    return np.column_stack([xyz, rng.uniform(0.2, 0.6, count)])


def person_points(rng, centre, count):
    """A thin vertical cylinder 1.75 m tall."""
    a = rng.uniform(0, 2 * np.pi, count)
    r = 0.25
    xyz = np.stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), rng.uniform(0, 1.75, count) - 1.7], 1)
    return np.column_stack([xyz, rng.uniform(0.0, 0.3, count)])


def ground_points(rng, centre, half, count):
    xy = rng.uniform(-half, half, (count, 2)) + centre
    return np.column_stack([xy, rng.normal(-1.72, 0.02, count), rng.uniform(0, 0.2, count)])


def constructed_frame(rng, name="f"):
    """A labelled frame: a car and a person (each with some ground in its proposal), a background bush."""
    parts, labels, instance = [], [], []
    objects = [
        (car_points(rng, (rng.uniform(6, 20), rng.uniform(-8, 8)), rng.uniform(-np.pi, np.pi), 300), CAR),
        (person_points(rng, (rng.uniform(-15, -4), rng.uniform(-8, 8)), 80), PEDESTRIAN),
        (rng.normal((rng.uniform(-20, 20), 15.0, -1.0, 0.5), (0.5, 0.5, 0.4, 0.1), (150, 4)), BACKGROUND),
    ]
    for k, (pts, label) in enumerate(objects):
        ground = ground_points(rng, pts[:, :2].mean(0), 1.5, 40)
        parts += [pts, ground]
        labels += [np.full(len(pts), label), np.full(len(ground), BACKGROUND)]
        instance += [np.full(len(pts) + len(ground), k)]
    far = ground_points(rng, np.zeros(2), 40, 500)
    parts.append(far)
    labels.append(np.full(len(far), BACKGROUND))
    instance.append(np.full(len(far), -1))
    return Frame(
        name=name,
        points=np.concatenate(parts).astype(np.float32),
        labels=np.concatenate(labels).astype(np.uint8),
        instance=np.concatenate(instance).astype(np.int32),
    )


def instance_proposer(frame):
    """Stand-in for stage 1: one proposal per instance id."""
    return [np.flatnonzero(frame.instance == k) for k in np.unique(frame.instance) if k >= 0]


# --------------------------------------------------------------------------------------------- samples


def test_build_samples_cache_and_background_discard(tmp_path):
    rng = np.random.default_rng(0)
    frames = [constructed_frame(rng, f"f{i}") for i in range(6)]
    everything = build_samples(frames, background_keep=1.0, proposer=instance_proposer, progress=False)
    assert len(everything) == 18
    assert everything.proposal_class().tolist() == [CAR, PEDESTRIAN, BACKGROUND] * 6
    assert np.array_equal(everything.labels[: everything.offsets[1]], frames[0].labels[everything.point_index[:340]])
    none_bg = build_samples(frames, background_keep=0.0, proposer=instance_proposer, progress=False)
    assert len(none_bg) == 12 and BACKGROUND not in none_bg.proposal_class()

    def source(specs):
        return iter(frames)

    kwargs = {"frames": source, "background_keep": 1.0, "seed": 0, "keep_frame_labels": True}
    first, path = cached_samples(["constructed:a"], tmp_path, proposer=instance_proposer, progress=False, **kwargs)
    assert path.is_file() and first.frame_labels is not None and len(first.frame_labels) == sum(
        len(f.points) for f in frames
    )

    def no_frames(specs):
        raise AssertionError("the cache should have been used")

    again, _ = cached_samples(["constructed:a"], tmp_path, proposer=instance_proposer, progress=False,
                              **{**kwargs, "frames": no_frames})
    assert np.array_equal(again.points, first.points) and again.frame_names == first.frame_names
    assert isinstance(SampleSet.load(path), SampleSet)


def test_a_cut_short_sample_cache_is_rebuilt(tmp_path):
    """A cache file cut short (a copy or sync interrupted) is rebuilt, as any unreadable cache is, not a BadZipFile
    traceback; as --consistency-samples it is the one-line error naming the file."""
    from pass3d_ros.msgs.errors import UserError
    from pass3d_ros.training.trainer import _read_sample_file

    rng = np.random.default_rng(0)
    frames = [constructed_frame(rng, f"f{i}") for i in range(2)]
    kwargs = {"frames": lambda specs: iter(frames), "background_keep": 1.0, "seed": 0, "keep_frame_labels": False,
              "proposer": instance_proposer, "progress": False}
    first, path = cached_samples(["constructed:a"], tmp_path, **kwargs)
    path.write_bytes(path.read_bytes()[:1000])
    again, _ = cached_samples(["constructed:a"], tmp_path, **kwargs)
    assert np.array_equal(again.points, first.points) and isinstance(SampleSet.load(path), SampleSet)
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(UserError, match=r"--consistency-samples .*\.npz: not a readable sample file"):
        _read_sample_file(path)


def test_cache_name_follows_stage1_and_the_synthetic_world(tmp_path, monkeypatch):
    """A changed stage 1 renames every cache; a changed synthetic generator renames the caches of synthetic data only
    (their frames changed; a real dataset's did not)."""
    import pass3d_ros.training.samples as samples

    def names(**identities: str) -> tuple:
        for function, value in identities.items():
            monkeypatch.setattr(samples, function, lambda value=value: value)
        return tuple(samples.cache_path([spec], tmp_path, 0.5, 0, False).name
                     for spec in ("synthetic:frames=4,seed=1", "kitti_object:somewhere"))

    base = names(stage1_identity="a", synthetic_identity="x")
    world = names(stage1_identity="a", synthetic_identity="y")
    stage1 = names(stage1_identity="b", synthetic_identity="x")
    assert world[0] != base[0] and world[1] == base[1]
    assert stage1[0] != base[0] and stage1[1] != base[1]


def test_training_batch_shapes_views_and_labels():
    rng = np.random.default_rng(1)
    samples = build_samples([constructed_frame(rng)], proposer=instance_proposer, progress=False)
    config = make_config("lite")
    xyz, feat, labels = training_batch(samples, np.array([0, 1, 2]), config, np.random.default_rng(0), True)
    assert xyz.shape == (3, config.num_points, 3) and feat.shape == (3, config.num_points, 2)
    assert labels.shape == (3, config.num_points) and set(np.unique(labels[1])) <= {BACKGROUND, PEDESTRIAN}
    assert np.all(xyz >= 0) and CAR in labels[0]
    fixed_a = training_batch(samples, np.array([0]), config, np.random.default_rng(5), False)[0]
    fixed_b = training_batch(samples, np.array([0]), config, np.random.default_rng(5), False)[0]
    assert np.array_equal(fixed_a, fixed_b)


# ----------------------------------------------------------------------------------------------- overfit


def test_lite_model_learns_to_separate_two_shapes():
    torch.manual_seed(0)
    rng = np.random.default_rng(2)
    frames = [constructed_frame(rng, f"f{i}") for i in range(4)]
    samples = build_samples(frames, proposer=instance_proposer, progress=False)
    ids = np.flatnonzero(samples.proposal_class() != BACKGROUND)
    config = make_config("lite")
    model = PointNet2Seg(config)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    batch_rng = np.random.default_rng(3)
    for _ in range(60):  # the BN running statistics need a few dozen steps to settle
        xyz, feat, labels = training_batch(samples, ids, config, batch_rng, augment=True)
        loss = cross_entropy(model(torch.from_numpy(xyz), torch.from_numpy(feat)), torch.from_numpy(labels))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    xyz, feat, labels = training_batch(samples, ids, config, np.random.default_rng(4), augment=True)
    with torch.no_grad():
        pred = model(torch.from_numpy(xyz), torch.from_numpy(feat)).argmax(-1).numpy()
    fg = labels != BACKGROUND
    assert (pred[fg] == labels[fg]).mean() > 0.9, "car and pedestrian points not separated"
    assert (pred == labels).mean() > 0.8


# ------------------------------------------------------------------------------------------------ trainer

LEARNED_IOU_FLOOR = 0.6  # trained here: about 0.97 by the last epoch; untrained weights: 0.0 to 0.1


def test_trainer_brings_loss_down_and_validation_iou_up(tmp_path):
    """Guards the Trainer's learning itself, e.g. a trainer without optimizer.step() (or with a detached loss,
    or a zero learning rate), which every other test here lets through: the library Trainer, on 20 constructed
    frames for 10 short epochs, must bring its training loss down and the validation mean IoU above a floor
    that untrained weights do not reach. About 5 s on one thread."""
    rng = np.random.default_rng(7)
    frames = {"constructed:train": [constructed_frame(rng, f"t{i}") for i in range(20)],
              "constructed:val": [constructed_frame(rng, f"v{i}") for i in range(3)]}

    def source(specs):
        for spec in specs:
            yield from frames[spec]

    options = TrainOptions(data=["constructed:train"], val_data=["constructed:val"], out=tmp_path, config="lite",
                           epochs=10, batch_size=8, lr=3e-3, background_keep=1.0, threads=1, quiet=True, seed=0)
    threads = torch.get_num_threads()
    try:
        trainer = Trainer(options, proposer=instance_proposer, frame_source=source, command=["test"])
        result = trainer.run()
    finally:
        torch.set_num_threads(threads)

    losses = [record["train_loss"] for record in result.history]
    ious = [record["val"]["mean_iou"] for record in result.history]
    assert len(losses) == 10
    assert np.mean(losses[-3:]) < 0.5 * losses[0], f"training loss did not fall: {np.round(losses, 3)}"
    torch.manual_seed(0)
    untrained = validate(PointNet2Seg(trainer.config), trainer.val_set, "cpu")["mean_iou"] or 0.0
    assert untrained < LEARNED_IOU_FLOOR, f"the floor is no test: untrained weights score {untrained:.3f}"
    assert ious[-1] > LEARNED_IOU_FLOOR and ious[-1] > ious[0], (
        f"validation mean IoU did not rise above {LEARNED_IOU_FLOOR}: {np.round(ious, 3)}"
    )
    assert result.best_score == max(ious)


def test_time_budget_stops_at_the_step_that_crosses_it_and_keeps_that_epoch(tmp_path, capsys):
    """--minutes: a budget spent before the first step ends the run after one step, that short epoch validated and
    saved with a record that says so; a budget not reached changes nothing."""
    rng = np.random.default_rng(4)
    frames = {"constructed:train": [constructed_frame(rng, f"t{i}") for i in range(5)],
              "constructed:val": [constructed_frame(rng, f"v{i}") for i in range(2)]}

    def source(specs):
        for spec in specs:
            yield from frames[spec]

    def run(minutes, out):
        options = TrainOptions(data=["constructed:train"], val_data=["constructed:val"], out=out, config="lite",
                               epochs=3, batch_size=4, background_keep=1.0, threads=1, quiet=True, minutes=minutes)
        return Trainer(options, proposer=instance_proposer, frame_source=source, command=["test"]).run()

    threads = torch.get_num_threads()
    try:
        spent = run(1e-9, tmp_path / "spent")
        unspent = run(60.0, tmp_path / "unspent")
    finally:
        torch.set_num_threads(threads)
    assert spent.stopped == "time budget" and len(spent.history) == 1
    record = spent.history[0]
    assert record["stopped"] == "time budget" and record["steps"] == 1 and record["planned"] == 4, record
    assert "val" in record and spent.best_path.is_file() and spent.last_path.is_file()
    saved = torch.load(spent.last_path, weights_only=True)
    assert saved["epoch"] == 0 and saved["history"][0]["stopped"] == "time budget"
    assert "time budget of 1e-09 min reached in epoch 1 after 1 of 4 steps" in capsys.readouterr().out
    assert unspent.stopped is None and len(unspent.history) == 3
    assert not any("stopped" in r for r in unspent.history)


def test_fit_epochs_sets_the_epochs_the_budget_holds_and_the_schedule_ends_on_the_last(tmp_path):
    """fit_epochs: after an epoch of 3 s with about 10 s left, 1 + 3 epochs fit (at most `epochs`); the cosine
    schedule is stretched over them, so the learning rate reaches its floor at the fitted last epoch, not before."""
    import time

    def fitted(cap, left, seconds):
        options = TrainOptions(data=["x"], out=tmp_path, epochs=cap, lr=1e-3, minutes=1.0, fit_epochs=True)
        trainer = Trainer(options, command=["test"])
        trainer.optimizer = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=options.lr)
        trainer.scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(trainer.optimizer, T_max=cap,
                                                                       eta_min=options.lr / 100)
        trainer.optimizer.step()
        trainer.scheduler.step()  # the first epoch's
        trainer.deadline = time.monotonic() + left
        trainer._fit_epochs(0, seconds)
        return trainer

    trainer = fitted(40, 10.0, 3.0)
    assert trainer.epochs == 4 and trainer.scheduler.T_max == 4
    rates = []
    for _ in range(3):
        trainer.optimizer.step()
        trainer.scheduler.step()
        rates.append(trainer.optimizer.param_groups[0]["lr"])
    assert rates[0] > rates[1] > 1e-5 and rates[2] == pytest.approx(1e-5), rates
    assert fitted(2, 100.0, 3.0).epochs == 2  # never more than asked
    assert fitted(40, 1.0, 3.0).epochs == 1  # no time for a second: the first was the last
    options = TrainOptions(data=["x"], out=tmp_path, epochs=7, minutes=1.0)  # not asked to fit: unchanged
    trainer = Trainer(options, command=["test"])
    trainer.deadline = time.monotonic() + 1.0
    trainer._fit_epochs(0, 3.0)
    assert trainer.epochs == 7


# -------------------------------------------------------------------------------------------- pass3d_train


def test_train_smoke_writes_loadable_checkpoints_and_resumes(tmp_path, capsys):
    rng = np.random.default_rng(5)
    frames = {"constructed:train": [constructed_frame(rng, f"t{i}") for i in range(5)],
              "constructed:val": [constructed_frame(rng, f"v{i}") for i in range(2)]}

    def source(specs):
        for spec in specs:
            yield from frames[spec]

    out = tmp_path / "run"
    argv = ["--data", "constructed:train", "--val-data", "constructed:val", "--config", "lite", "--epochs", "2",
            "--out", str(out), "--batch-size", "4", "--max-steps", "2", "--loss", "focal", "--quiet", "--seed", "3"]
    assert train.run(train.build_parser().parse_args(argv), proposer=instance_proposer, frame_source=source) == 0
    for name in ("last.pt", "best.pt", "history.json"):
        assert (out / name).is_file()
    assert len(list(out.glob("samples_*.npz"))) == 2
    _model, checkpoint = load_model(out / "best.pt")
    assert checkpoint["config"]["name"] == "lite" and checkpoint["classes"][1] == "car"
    assert checkpoint["data"]["train"] == ["constructed:train"] and checkpoint["command"]
    assert checkpoint["train_args"]["loss"] == "focal" and checkpoint["epoch"] in (0, 1)
    assert 0.0 <= checkpoint["val"]["per_class"]["background"]["iou"] <= 1.0
    segmenter = Segmenter(out / "best.pt")
    frame = frames["constructed:val"][0]
    result = segmenter.segment(frame.points, instance_proposer(frame))
    assert result.labels.shape == (len(frame.points),)
    history = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in history] == [0, 1]
    assert "val IoU %" in capsys.readouterr().out

    argv_more = [a if a != "2" or i != argv.index("--epochs") + 1 else "3" for i, a in enumerate(argv)]
    assert train.run(train.build_parser().parse_args([*argv_more, "--resume"]), proposer=instance_proposer,
                     frame_source=source) == 0
    history = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in history] == [0, 1, 2]
    assert "resumed from" in capsys.readouterr().out
    last = torch.load(out / "last.pt", weights_only=True)
    assert last["epoch"] == 2 and "optimizer" in last


def test_command_line_defaults_are_the_library_defaults(tmp_path):
    """pass3d_train's flags map one to one onto TrainOptions, with the same defaults."""
    args = train.build_parser().parse_args(["--data", "constructed:a", "--out", str(tmp_path)])
    assert train.options(args) == TrainOptions(data=["constructed:a"], out=tmp_path)
    assert set(vars(args)) == {f.name for f in dataclasses.fields(TrainOptions)} | {"nproc"}


def test_samples_from_synthetic_scan_with_real_stage1():
    pytest.importorskip("pass3d_ros.core.stage1")
    pytest.importorskip("pass3d_ros.synthetic.dataset")
    from pass3d_ros.data.spec import open_datasets

    frames = list(open_datasets(["synthetic:frames=1,seed=7"]))
    samples = build_samples(frames, background_keep=1.0, keep_frame_labels=True, progress=False)
    assert len(samples) > 0 and samples.frame_labels is not None
    assert np.array_equal(samples.labels, frames[0].labels[samples.point_index])
    assert np.array_equal(samples.points, frames[0].points[samples.point_index])
    config = make_config("lite")
    xyz, feat, labels = training_batch(samples, np.arange(min(8, len(samples))), config, np.random.default_rng(0), True)
    assert feat.shape == (len(xyz), config.num_points, 2)
    assert xyz.shape[1:] == (config.num_points, 3) and np.all(xyz >= 0) and labels.max() < NUM_CLASSES


def test_unlabelled_frames_and_bad_specs_fail_clearly(tmp_path, capsys):
    from pass3d_ros.data.spec import DatasetError

    frame = Frame(name="nolabels", points=np.zeros((10, 4), np.float32))
    with pytest.raises(DatasetError, match="nolabels: no per-point labels"):
        build_samples([frame], proposer=instance_proposer, progress=False)
    assert train.main(["--data", "nosuchformat:x", "--out", str(tmp_path), "--quiet"]) == 2
    assert "unknown format 'nosuchformat'" in capsys.readouterr().err


def test_resume_without_a_checkpoint_is_an_error(tmp_path, capsys):
    """--resume with no OUT/last.pt stops before any work (exit 2, naming the file), never trains from scratch."""
    out = tmp_path / "run"
    assert train.main(["--data", "constructed:train", "--out", str(out), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out / "last.pt") in err and "Traceback" not in err
    assert not out.exists()


def test_a_fresh_run_never_overwrites_a_previous_runs_checkpoints(tmp_path, capsys):
    """A run without --resume into an --out holding last.pt or best.pt stops before any work (exit 2, naming the
    folder and the way on), the checkpoint untouched; --force replaces them."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "best.pt").write_bytes(b"an earlier run's weights")
    args = ["--data", "constructed:train", "--out", str(out), "--quiet"]
    assert train.main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out) in err and "best.pt" in err and "--force" in err
    assert (out / "best.pt").read_bytes() == b"an earlier run's weights"
    assert train.main([*args, "--force"]) == 2  # past the check: then no such format here, as without a checkpoint
    assert "previous run" not in capsys.readouterr().err


def test_init_starts_from_a_checkpoints_weights(tmp_path, capsys):
    """--init (fine-tuning) starts from the named weights with a fresh schedule: epoch 0 of the new run, and with a
    zero learning rate and no weight decay its weights stay the initial ones, not random ones."""
    rng = np.random.default_rng(6)
    frames = [constructed_frame(rng, f"t{i}") for i in range(3)]
    first, second = tmp_path / "first", tmp_path / "second"
    common = ["--data", "constructed:train", "--config", "lite", "--epochs", "1", "--batch-size", "4",
              "--max-steps", "1", "--quiet", "--seed", "4"]
    run = functools.partial(train.run, proposer=instance_proposer, frame_source=lambda specs: iter(frames))
    # The first run groups as the shipped weights do; grouping has no weights, so a "set" run may start there, and
    # one that feeds intensity as 0 (--no-intensity: a sensor without it) may start from one that read it.
    assert run(train.build_parser().parse_args([*common, "--out", str(first), "--grouping", "slot"])) == 0
    start = torch.load(first / "best.pt", weights_only=True)["state_dict"]
    argv = [*common, "--out", str(second), "--init", str(first / "best.pt"), "--lr", "0", "--weight-decay", "0",
            "--grouping", "set", "--no-intensity"]
    assert run(train.build_parser().parse_args(argv)) == 0
    assert f"initial weights: {first / 'best.pt'}" in capsys.readouterr().out
    tuned = torch.load(second / "last.pt", weights_only=True)
    assert tuned["epoch"] == 0 and tuned["train_args"]["init"] == str(first / "best.pt")
    assert torch.load(first / "best.pt", weights_only=True)["config"]["grouping"] == "slot"
    assert tuned["config"]["grouping"] == "set" and tuned["config"]["extra"]["intensity"] is False
    for name, value in start.items():
        if not name.endswith(("running_mean", "running_var", "num_batches_tracked")):
            assert torch.equal(value, tuned["state_dict"][name]), name


def test_init_with_a_missing_file_or_with_resume_is_an_error(tmp_path, capsys):
    """A missing --init file is named (exit 2, before any work); --init with --resume is refused (exit 2, one line)."""
    out = tmp_path / "run"
    missing = tmp_path / "nosuch.pt"
    assert train.main(["--data", "constructed:train", "--out", str(out), "--init", str(missing), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "Traceback" not in err
    out.mkdir()
    torch.save({"epoch": 0}, out / "last.pt")
    assert train.main(["--data", "constructed:train", "--out", str(out), "--init", str(missing), "--resume",
                       "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pass3d_train: error: --init and --resume"), err


@pytest.mark.parametrize(("stop_at", "expected"), [(0, "before any checkpoint was written"), (1, "(epoch 1)")])
def test_ctrl_c_names_the_last_checkpoint(tmp_path, capsys, monkeypatch, stop_at, expected):
    """Ctrl-C during training: exit 130 and one line naming the last checkpoint written (or that none was)."""
    rng = np.random.default_rng(2)
    frames = [constructed_frame(rng, f"t{i}") for i in range(3)]
    monkeypatch.setattr(train, "Trainer", functools.partial(Trainer, proposer=instance_proposer,
                                                            frame_source=lambda specs: iter(frames)))
    real_epoch = Trainer._train_epoch

    def interrupted_epoch(self, epoch):
        if epoch == stop_at:
            raise KeyboardInterrupt
        return real_epoch(self, epoch)

    monkeypatch.setattr(Trainer, "_train_epoch", interrupted_epoch)
    out = tmp_path / "run"
    argv = ["--data", "constructed:train", "--epochs", "3", "--out", str(out), "--batch-size", "4",
            "--max-steps", "1", "--quiet", "--threads", "1"]
    threads = torch.get_num_threads()
    try:
        assert train.main(argv) == 130
    finally:
        torch.set_num_threads(threads)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pass3d_train: interrupted") and expected in err, err
    assert (str(out / "last.pt") in err) == (stop_at > 0)
    assert not [p for p in out.iterdir() if ".partial-" in p.name]
    if stop_at:
        assert torch.load(out / "last.pt", weights_only=True)["epoch"] == stop_at - 1


# ------------------------------------------------------------------------------------- refused arguments


@pytest.mark.parametrize(("flag", "value"), [
    ("--epochs", "0"), ("--epochs", "-1"), ("--batch-size", "0"), ("--background-keep", "2"),
    ("--background-keep", "nan"), ("--max-steps", "-1"), ("--threads", "-1"), ("--nproc", "0"), ("--lr", "-1"),
    ("--focal-alpha", "1.5"), ("--epochs", "two"),
])
def test_out_of_range_numbers_are_refused_with_one_line(tmp_path, capsys, flag, value):
    """A count or share outside its range stops before any work: exit 2, one line naming the flag, no output."""
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as stopped:
        train.main(["--data", "constructed:a", "--out", str(out), flag, value])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and err.count("\n") == 1 and f"argument {flag}: " in err, err
    assert not out.exists()


def nan_checkpoint(path):
    """A loadable-looking lite checkpoint whose weights are all NaN, saved at `path`."""
    model = PointNet2Seg(make_config("lite"))
    with torch.no_grad():
        for value in model.state_dict().values():
            if value.is_floating_point():
                value.fill_(float("nan"))
    torch.save(make_checkpoint(model, epoch=0, history=[], best_score=0.0), path)
    return path


def test_nan_weights_are_refused_naming_the_file(tmp_path, capsys):
    """A checkpoint of NaN weights is refused by every loader (load_model: inference and --init) and by --resume."""
    bad = nan_checkpoint(tmp_path / "diverged.pt")
    with pytest.raises(CheckpointError, match=r"diverged\.pt: weights are not finite"):
        load_model(bad)
    assert train.main(["--data", "constructed:a", "--out", str(tmp_path / "a"), "--init", str(bad), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{bad}: weights are not finite" in err, err

    rng = np.random.default_rng(1)
    frames = [constructed_frame(rng, f"t{i}") for i in range(2)]
    out = tmp_path / "b"
    out.mkdir()
    state = torch.load(bad, weights_only=True)
    state.update(optimizer={}, scheduler={})
    torch.save(state, out / "last.pt")
    args = train.build_parser().parse_args(["--data", "constructed:a", "--out", str(out), "--resume", "--quiet",
                                            "--grouping", "slot"])  # as the checkpoint was made
    with pytest.raises(CheckpointError, match=r"last\.pt: weights are not finite"):
        train.run(args, proposer=instance_proposer, frame_source=lambda specs: iter(frames))


# ---------------------------------------------------------------------------------- stage-1 parameters


def test_stage1_parameters_name_their_own_cache(tmp_path):
    """--param values are part of the sample cache name; the defaults (given or not) keep the plain name."""
    from pass3d_ros.core.stage1.config import Stage1Config
    from pass3d_ros.training.samples import cache_path

    def name(stage1):
        return cache_path(["kitti_object:x"], tmp_path, 0.3, 0, False, stage1=stage1).name

    plain = name(None)
    assert name(Stage1Config()) == plain
    assert name(Stage1Config(th_dist=0.25)) != plain
    assert name(Stage1Config(th_dist=0.25)) != name(Stage1Config(th_dist=0.2))


def test_param_reaches_the_stage1_run_that_builds_the_samples(tmp_path, capsys):
    """pass3d_train --param: the stage-1 run that builds the samples uses it (max_range=1 leaves no proposal at
    all: the trainer's error, one line, exit 2); a bad one is one line, exit 2."""
    common = ["--data", "synthetic:frames=1,seed=7", "--epochs", "1", "--batch-size", "4", "--max-steps", "1",
              "--quiet"]
    assert train.main([*common, "--out", str(tmp_path / "a"), "--param", "max_range=1.0"]) == 2
    assert capsys.readouterr().err == "pass3d_train: error: no proposals in synthetic:frames=1,seed=7\n"
    assert train.main([*common, "--out", str(tmp_path / "b"), "--param", "no_such=1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no_such" in err, err


def test_best_without_validation_is_the_lowest_loss_even_above_one(tmp_path):
    """Without validation data the score is minus the training loss: a loss above 1 (4 classes start near ln 4)
    still counts, so best.pt is the epoch of the lowest loss, not whichever epoch came first."""
    rng = np.random.default_rng(3)
    frames = [constructed_frame(rng, f"t{i}") for i in range(3)]
    argv = ["--data", "constructed:a", "--epochs", "3", "--out", str(tmp_path), "--batch-size", "4",
            "--max-steps", "1", "--quiet", "--lr", "0.001", "--seed", "1"]
    assert train.run(train.build_parser().parse_args(argv), proposer=instance_proposer,
                     frame_source=lambda specs: iter(frames)) == 0
    losses = [h["train_loss"] for h in json.loads((tmp_path / "history.json").read_text())]
    best = torch.load(tmp_path / "best.pt", weights_only=True)
    assert best["epoch"] == int(np.argmin(losses)) and best["best_score"] == pytest.approx(-min(losses)), losses


# ------------------------------------------------------------------------------------------ view consistency

UNLABELLED = "synthetic:frames=1,seed=3"  # labelled, so the test can see the labels are not read


def test_unlabelled_samples_read_no_labels_and_pair_the_same_points():
    from pass3d_ros.training.consistency import unlabelled_samples, view_pair

    samples = unlabelled_samples([UNLABELLED])
    assert len(samples) > 5 and not np.any(samples.labels)  # the scan's cars and people are not read
    config = make_config("lite")
    ids = np.arange(len(samples))
    weak_xyz, weak_feat, strong_xyz, strong_feat = view_pair(samples, ids, config, np.random.default_rng(1))
    assert weak_xyz.shape == strong_xyz.shape == (len(ids), config.num_points, 3)
    # One sample seen twice: the same pairwise distances (views are rigid maps, with mirrors), the same point count
    # feature; the views differ for most proposals, and so does the augmented intensity.
    pairwise = [np.linalg.norm(x[:, :, None] - x[:, None], axis=-1) for x in (weak_xyz, strong_xyz)]
    assert np.allclose(*pairwise, atol=1e-4)
    assert np.array_equal(weak_feat[:, :, 1], strong_feat[:, :, 1])
    moved = np.abs(weak_xyz - strong_xyz).max(axis=(1, 2)) > 1e-3
    assert moved.mean() > 0.5
    assert not np.allclose(weak_feat[:, :, 0], strong_feat[:, :, 0])
    # The first one is what inference feeds the network: the view nearest the sensor, the intensity as given.
    from pass3d_ros.core.stage2.segmentation import prepare_proposals

    again = view_pair(samples, ids, config, np.random.default_rng(1))
    assert np.array_equal(again[0], weak_xyz)
    seed = int(np.random.default_rng(1).integers(2**63))
    inference = prepare_proposals(samples.points, samples.members(ids), config, rng=np.random.default_rng(seed),
                                  boxes=samples.boxes, queries=False)
    assert np.array_equal(inference.sample_xyz, weak_xyz) and np.array_equal(inference.sample_feat, weak_feat)


def test_draw_pair_gives_the_student_another_draw_labelled_by_the_teacher_at_its_points():
    from pass3d_ros.core.stage2.segmentation import predict_probabilities, prepare_proposals
    from pass3d_ros.training.consistency import draw_pair, unlabelled_samples

    samples = unlabelled_samples([UNLABELLED])
    config = make_config("lite")
    torch.manual_seed(0)
    model = PointNet2Seg(config).train()
    ids = np.arange(len(samples))
    xyz, _feat, targets = draw_pair(samples, ids, config, np.random.default_rng(2), model, "cpu")
    assert model.training  # the teacher pass leaves the mode as it was
    assert xyz.shape == (len(ids), config.num_points, 3) and targets.shape == (len(ids), config.num_points, NUM_CLASSES)
    # The teacher's pass, redone: the same seeds give its probabilities for every member point; the target of each
    # student point is the teacher's probability at that very point.
    seeds = np.random.default_rng(2).integers(2**63, size=2)
    whole = prepare_proposals(samples.points, samples.members(ids), config, rng=np.random.default_rng(int(seeds[1])),
                              boxes=samples.boxes)
    probabilities = predict_probabilities(model.eval(), whole, "cpu")
    student = prepare_proposals(samples.points, samples.members(ids), config, views=np.zeros(len(ids), np.int64),
                                rng=np.random.default_rng(int(seeds[0])), boxes=samples.boxes, queries=False)
    row_of = {int(point): row for row, point in enumerate(whole.query_index)}
    expected = probabilities[[[row_of[int(p)] for p in draw] for draw in student.sample_index]]
    assert np.allclose(targets.numpy(), expected, atol=1e-6)
    # Another draw than the teacher's: big proposals hold other points.
    big = np.flatnonzero(samples.counts[ids] > 2 * config.num_points)
    assert len(big) and any(set(student.sample_index[p]) != set(whole.sample_index[p]) for p in big)
    # A teacher of three draws: the mean of the three draws' probabilities, the student's draw as before.
    _xyz, _feat, mean_targets = draw_pair(samples, ids, config, np.random.default_rng(2), model, "cpu", 3)
    seeds = np.random.default_rng(2).integers(2**63, size=4)
    draws = [predict_probabilities(model.eval(), prepare_proposals(samples.points, samples.members(ids), config,
                                                                   rng=np.random.default_rng(int(s)),
                                                                   boxes=samples.boxes), "cpu") for s in seeds[1:]]
    model.train()
    student = prepare_proposals(samples.points, samples.members(ids), config, views=np.zeros(len(ids), np.int64),
                                rng=np.random.default_rng(int(seeds[0])), boxes=samples.boxes, queries=False)
    expected = (sum(d.astype(np.float64) for d in draws) / 3)[[[row_of[int(p)] for p in draw] for draw in
                                                                student.sample_index]]
    assert np.allclose(mean_targets.numpy(), expected, atol=1e-6)
    assert np.abs(mean_targets.numpy() - targets.numpy()).max() > 1e-5  # not the one draw (an untrained net: small)


def test_consistency_loss_counts_only_sure_points():
    from pass3d_ros.training.consistency import consistency_loss

    teacher = torch.tensor([[[0.95, 0.05, 0.0, 0.0], [0.4, 0.6, 0.0, 0.0], [0.0, 0.0, 0.1, 0.9]]])
    student = torch.randn(1, 3, NUM_CLASSES)
    loss, sure = consistency_loss(student, teacher, 0.9)
    ce = torch.nn.functional.cross_entropy(student[0], torch.tensor([0, 1, 3]), reduction="none")
    assert sure == pytest.approx(2 / 3)
    assert loss.item() == pytest.approx((ce[0] + ce[2]).item() / 3, rel=1e-5)
    assert consistency_loss(student, teacher, 0.99)[0].item() == 0.0


def test_trainer_with_view_consistency_records_what_it_used(tmp_path):
    rng = np.random.default_rng(9)
    frames = [constructed_frame(rng, f"t{i}") for i in range(4)]
    options = TrainOptions(data=["constructed:train"], out=tmp_path, config="lite", epochs=1, batch_size=4,
                           max_steps=2, background_keep=1.0, threads=1, quiet=True, consistency=[UNLABELLED],
                           consistency_batch=3, consistency_threshold=0.0)
    threads = torch.get_num_threads()
    try:
        result = Trainer(options, proposer=instance_proposer, frame_source=lambda specs: iter(frames),
                         command=["test"]).run()
    finally:
        torch.set_num_threads(threads)
    # threshold 0: every unlabelled point is a target
    assert result.history[0]["consistency_sure"] == 1.0 and np.isfinite(result.history[0]["train_loss"])
    checkpoint = torch.load(result.last_path, weights_only=True)
    assert checkpoint["data"]["consistency"] == [UNLABELLED]
    assert checkpoint["train_args"]["consistency_batch"] == 3


def test_trainer_takes_unlabelled_proposals_built_by_its_caller(tmp_path):
    """pass3d_adapt builds the consistency proposals of the scans it adapts on itself: the Trainer takes them
    (named in the checkpoint as the caller names them), and refuses them beside --consistency specs."""
    from pass3d_ros.data.spec import open_dataset

    rng = np.random.default_rng(9)
    frames = [constructed_frame(rng, f"t{i}") for i in range(4)]
    unlabelled = consistency.unlabelled_samples_of((UNLABELLED, f) for f in open_dataset(UNLABELLED))
    assert len(unlabelled) == len(consistency.unlabelled_samples([UNLABELLED])) > 0
    options = TrainOptions(data=["constructed:train"], out=tmp_path, config="lite", epochs=1, batch_size=4,
                           max_steps=2, background_keep=1.0, threads=1, quiet=True, consistency_batch=3,
                           consistency_threshold=0.0)
    threads = torch.get_num_threads()
    try:
        result = Trainer(options, proposer=instance_proposer, frame_source=lambda specs: iter(frames),
                         command=["test"], unlabelled=unlabelled, unlabelled_name="my drive, scans 0-9").run()
    finally:
        torch.set_num_threads(threads)
    assert result.history[0]["consistency_sure"] == 1.0
    assert torch.load(result.last_path, weights_only=True)["data"]["consistency"] == ["my drive, scans 0-9"]
    with pytest.raises(TrainingError, match="reads one of: the --consistency specs"):
        Trainer(dataclasses.replace(options, consistency=[UNLABELLED]), unlabelled=unlabelled)


def test_trainer_with_draw_consistency_trains(tmp_path):
    rng = np.random.default_rng(9)
    frames = [constructed_frame(rng, f"t{i}") for i in range(4)]
    options = TrainOptions(data=["constructed:train"], out=tmp_path, config="lite", epochs=1, batch_size=4,
                           max_steps=2, background_keep=1.0, threads=1, quiet=True, consistency=[UNLABELLED],
                           consistency_batch=3, consistency_threshold=0.0, consistency_draws=2)
    threads = torch.get_num_threads()
    try:
        result = Trainer(options, proposer=instance_proposer, frame_source=lambda specs: iter(frames),
                         command=["test"]).run()
    finally:
        torch.set_num_threads(threads)
    assert result.history[0]["consistency_sure"] == 1.0 and np.isfinite(result.history[0]["train_loss"])
    assert torch.load(result.last_path, weights_only=True)["train_args"]["consistency_draws"] == 2


def test_consistency_data_without_proposals_is_refused(tmp_path, capsys):
    empty = tmp_path / "seq"
    (empty / "velodyne").mkdir(parents=True)
    np.zeros((0, 4), np.float32).tofile(empty / "velodyne" / "000000.bin")
    rng = np.random.default_rng(2)
    frames = [constructed_frame(rng, "t0")]
    options = TrainOptions(data=["constructed:train"], out=tmp_path / "run", epochs=1, quiet=True,
                           consistency=[f"semantickitti:{empty}"])

    with pytest.raises(TrainingError, match=r"no proposals in semantickitti:.* for view consistency"):
        Trainer(options, proposer=instance_proposer, frame_source=lambda specs: iter(frames), command=["test"]).run()


def test_a_bad_consistency_spec_fails_before_stage_1(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["--data", "synthetic:frames=1,seed=5", "--out", str(out), "--quiet",
            "--consistency", f"semantickitti:{tmp_path / 'missing'}"]
    assert train.main(argv) == 2
    err = capsys.readouterr().err
    assert "missing" in err and "not found" in err and "Traceback" not in err
    assert not list(out.glob("samples_*.npz"))  # no training sample was built first


def test_fit_epochs_without_a_budget_is_an_argument_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        train.main(["--data", "synthetic:frames=1", "--out", str(tmp_path / "run"), "--fit-epochs"])
    assert exc.value.code == 2 and "--fit-epochs fits the epochs to a time budget" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_consistency_samples_name_a_readable_sample_file_and_exclude_consistency_specs(tmp_path, capsys):
    """--consistency-samples (pass3d_adapt --nproc's hand-over): a file that is no sample file is exit 2 naming it,
    before any training sample is built; with --consistency too, an argument error."""
    out = tmp_path / "run"
    bad = tmp_path / "unlabelled.npz"
    bad.write_bytes(b"not an npz")
    assert train.main(["--data", "synthetic:frames=1", "--out", str(out), "--consistency-samples", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"--consistency-samples {bad}: not a readable sample file" in err and "Traceback" not in err
    assert not list(out.glob("samples_*.npz"))
    with pytest.raises(SystemExit) as exc:
        train.main(["--data", "synthetic:frames=1", "--out", str(out), "--consistency", "synthetic:frames=1",
                    "--consistency-samples", str(bad)])
    assert exc.value.code == 2 and "give one" in capsys.readouterr().err
