"""`pass3d_train`: train the stage-2 PointNet++ on stage-1 proposals of labelled scans.

Validation scores whole frames point by point: each validation frame's proposals are segmented as in
inference (one batch per frame, overlap rule, points outside every proposal are background), and the
per-class IoU is counted over every point of every validation frame, so it includes stage 1's misses.
The best checkpoint is the one with the highest mean IoU over car, pedestrian and cyclist.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from pass3d_ros.core.metrics import ConfusionAccumulator
from pass3d_ros.core.pointnet2 import PointNet2Seg, count_parameters, make_config
from pass3d_ros.core.segmentation import make_checkpoint, predict_probabilities, prepare_proposals, scatter_predictions
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError
from pass3d_ros.training.losses import make_loss
from pass3d_ros.training.samples import Proposer, SampleSet, cached_samples, training_batch

FrameSource = Callable[[list[str]], Iterable[Frame]]


def build_parser() -> argparse.ArgumentParser:
    """The command line of pass3d_train."""
    p = argparse.ArgumentParser(prog="pass3d_train", description=__doc__.splitlines()[0])
    p.add_argument("--data", action="append", required=True, metavar="SPEC", help="training data FORMAT:PATH")
    p.add_argument("--val-data", action="append", default=[], metavar="SPEC", help="validation data FORMAT:PATH")
    p.add_argument("--config", choices=["paper", "lite"], default="lite", help="model configuration")
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--out", type=Path, required=True, help="output folder: checkpoints, sample caches, log")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--loss", choices=["ce", "focal"], default="ce")
    p.add_argument("--focal-alpha", type=float, default=0.25, help="focal alpha: foreground weight, background 1-a")
    p.add_argument("--focal-gamma", type=float, default=2.0)
    p.add_argument("--no-augment", action="store_true", help="train on the inference view only (no 8 views)")
    p.add_argument("--no-n-feature", action="store_true", help="set the point-count feature n to 0")
    p.add_argument("--n-mode", choices=["ratio", "log"], default="log",
                   help="n = log(NUM / N) (default: bounded, trains stably) or the paper's (NUM - N) / N")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=32, help="proposals per batch")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--background-keep", type=float, default=0.3, help="share of background proposals kept")
    p.add_argument("--max-steps", type=int, default=0, help="cap on batches per epoch (0: all)")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch default)")
    p.add_argument("--rebuild-cache", action="store_true", help="rerun stage 1 even if a sample cache exists")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def validate(model: PointNet2Seg, samples: SampleSet, device: str, progress: bool = False) -> dict:
    """Point-level scores over whole validation frames (see the module docstring): ConfusionAccumulator's
    summary (per-class precision, recall, IoU; mean IoU over car, pedestrian, cyclist) plus the matrix."""
    if samples.frame_labels is None:
        raise ValueError("validation samples need the frames' full labels")
    model.eval()
    starts = samples.frame_offsets()
    confusion = ConfusionAccumulator()
    order = np.argsort(samples.frame, kind="stable")
    bounds = np.searchsorted(samples.frame[order], np.arange(len(samples.frame_sizes) + 1))
    for f in tqdm(range(len(samples.frame_sizes)), desc="validate", unit="frame", disable=not progress, leave=False):
        ids = order[bounds[f] : bounds[f + 1]]
        size = int(samples.frame_sizes[f])
        labels = np.zeros(size, dtype=np.uint8)
        if len(ids):
            batch = prepare_proposals(samples.points, samples.members(ids), model.config)
            probs = predict_probabilities(model, batch, device)
            pred = probs.argmax(1)
            labels, _ = scatter_predictions(
                size, samples.point_index[batch.query_index], pred.astype(np.uint8), probs[np.arange(len(pred)), pred]
            )
        confusion.update(samples.frame_labels[starts[f] : starts[f] + size], labels)
    return {**confusion.summary(), "confusion": confusion.matrix.tolist()}


def _format_scores(scores: dict) -> str:
    def pct(value: float | None) -> str:
        return "n/a" if value is None else f"{100 * value:.1f}"

    parts = [f"{name} {pct(row['iou'])}" for name, row in scores["per_class"].items()]
    return f"IoU % {', '.join(parts)}; mean(fg) {pct(scores['mean_iou'])}"


def _default_frames(specs: list[str]) -> Iterable[Frame]:
    from pass3d_ros.data.spec import open_datasets

    return open_datasets(specs)


def _total_frames(specs: list[str]) -> int | None:
    from pass3d_ros.data.spec import count_frames

    try:
        counts = [count_frames(s) for s in specs]
    except Exception:
        return None
    return None if any(c is None for c in counts) else sum(counts)


def run(args: argparse.Namespace, proposer: Proposer | None = None, frame_source: FrameSource | None = None) -> int:
    """Train as the arguments say; `proposer` and `frame_source` replace stage 1 and the dataset readers."""
    if args.threads:
        torch.set_num_threads(args.threads)
    frames = frame_source or _default_frames
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    progress = not args.quiet
    torch.manual_seed(args.seed)

    config = make_config(args.config)
    config.n_feature = not args.no_n_feature
    config.n_mode = args.n_mode
    common = {"frames": frames, "seed": args.seed, "proposer": proposer, "rebuild": args.rebuild_cache}
    train_set, train_cache = cached_samples(
        args.data, out, background_keep=args.background_keep, keep_frame_labels=False, progress=progress,
        total=None if frame_source else _total_frames(args.data), **common
    )
    if len(train_set) == 0:
        print(f"pass3d_train: no proposals in {', '.join(args.data)}", file=sys.stderr)
        return 1
    val_set = None
    if args.val_data:
        val_set, _ = cached_samples(
            args.val_data, out, background_keep=1.0, keep_frame_labels=True, progress=progress,
            total=None if frame_source else _total_frames(args.val_data), **common
        )
    print(f"train samples: {train_set.describe()} (cache {train_cache.name})")
    if val_set is not None:
        print(f"val samples: {val_set.describe()}")

    model = PointNet2Seg(config).to(args.device)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=max(args.epochs, 1), eta_min=args.lr / 100)
    loss_fn = make_loss(args.loss, alpha=args.focal_alpha, gamma=args.focal_gamma)
    start_epoch, best_score, history = 0, -1.0, []
    last_path, best_path = out / "last.pt", out / "best.pt"
    if args.resume and last_path.is_file():
        state = torch.load(last_path, map_location="cpu", weights_only=True)
        if state["config"] != config.to_dict():
            print(f"pass3d_train: {last_path} was trained with another config; not resuming", file=sys.stderr)
            return 1
        model.load_state_dict(state["state_dict"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        start_epoch, best_score, history = state["epoch"] + 1, state["best_score"], list(state["history"])
        print(f"resumed from {last_path} at epoch {start_epoch}")
    print(f"model {config.name}: {count_parameters(model)} parameters, {config.num_points} points per sample")

    data_info = {
        "train": list(args.data),
        "val": list(args.val_data),
        "train_samples": train_set.describe(),
        "val_samples": val_set.describe() if val_set is not None else None,
        "background_keep": args.background_keep,
    }
    train_args = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    batch_size = max(1, args.batch_size)
    for epoch in range(start_epoch, args.epochs):
        rng = np.random.default_rng([args.seed, epoch])
        torch.manual_seed(args.seed * 100_003 + epoch)
        model.train()
        order = rng.permutation(len(train_set))
        steps = -(-len(order) // batch_size)
        if args.max_steps:
            steps = min(steps, args.max_steps)
        losses = []
        bar = tqdm(range(steps), desc=f"epoch {epoch + 1}/{args.epochs}", unit="batch", disable=not progress)
        started = time.perf_counter()
        for step in bar:
            ids = order[step * batch_size : (step + 1) * batch_size]
            xyz, feat, labels = training_batch(train_set, ids, config, rng, augment=not args.no_augment)
            logits = model(torch.from_numpy(xyz).to(args.device), torch.from_numpy(feat).to(args.device))
            loss = loss_fn(logits, torch.from_numpy(labels.astype(np.int64)).to(args.device))
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}", refresh=False)
        scheduler.step()
        record = {"epoch": epoch, "train_loss": float(np.mean(losses)), "seconds": time.perf_counter() - started}
        if val_set is not None:
            scores = validate(model, val_set, args.device, progress)
            record["val"] = scores
            score = scores["mean_iou"] if scores["mean_iou"] is not None else float("nan")
            print(f"epoch {epoch + 1}: loss {record['train_loss']:.4f}; val {_format_scores(scores)}")
        else:
            score = -record["train_loss"]
            print(f"epoch {epoch + 1}: loss {record['train_loss']:.4f}")
        history.append(record)
        improved = not np.isnan(score) and score > best_score
        if improved:
            best_score = float(score)
        info = {
            "data": data_info,
            "command": list(sys.argv),
            "train_args": train_args,
            "epoch": epoch,
            "val": record.get("val"),
            "best_score": best_score,
            "history": history,
        }
        checkpoint = make_checkpoint(model, **info)
        if improved or not best_path.is_file():
            torch.save(checkpoint, best_path)
        torch.save({**checkpoint, "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict()}, last_path)
        with open(out / "history.json", "w") as fh:
            json.dump(history, fh, indent=1)
    print(f"checkpoints: {last_path}, {best_path} (best score {best_score:.4f})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the pass3d_train console script; unusable data ends it with the reason, exit code 2."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except DatasetError as exc:
        print(f"pass3d_train: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
