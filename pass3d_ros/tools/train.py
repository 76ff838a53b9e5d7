"""`pass3d_train`: train the stage-2 PointNet++ on stage-1 proposals of labelled scans.

Validation scores whole frames point by point: each validation frame's proposals are segmented as in
inference (one batch per frame, overlap rule, points outside every proposal are background), and the
per-class IoU is counted over every point of every validation frame, so it includes stage 1's misses.
The best checkpoint is the one with the highest mean IoU over car, pedestrian and cyclist.
The training itself is pass3d_ros.training.trainer; this module only parses the command line.

Data-parallel: `torchrun --nproc_per_node N -m pass3d_ros.tools.train ...` (or `torchrun ... $(which pass3d_train)`)
trains in N processes (gloo on CPU, nccl with --device cuda); --batch-size stays the global batch per step.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pass3d_ros.tools.cli import check_writable, run_tool
from pass3d_ros.training.samples import Proposer
from pass3d_ros.training.trainer import FrameSource, Trainer, TrainingError, TrainOptions


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
    p.add_argument("--init", type=Path, metavar="CHECKPOINT",
                   help="start from these weights (fine-tuning; fresh optimizer and schedule)")
    p.add_argument("--loss", choices=["ce", "focal"], default="ce")
    p.add_argument("--focal-alpha", type=float, default=0.25, help="focal alpha: foreground weight, background 1-a")
    p.add_argument("--focal-gamma", type=float, default=2.0)
    p.add_argument("--no-augment", action="store_true", help="train on the inference view only (no 8 views)")
    p.add_argument("--no-n-feature", action="store_true", help="set the point-count feature n to 0")
    p.add_argument("--n-mode", choices=["ratio", "log"], default="log",
                   help="n = log(NUM / N) (default: bounded, trains stably) or the paper's (NUM - N) / N")
    p.add_argument("--no-intensity-augment", action="store_true",
                   help="no per-proposal intensity augmentation (gain, offset, gamma, zeroing, constant)")
    p.add_argument("--no-intensity", action="store_true",
                   help="feed intensity as 0 (stored in the checkpoint: inference does the same)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size", type=int, default=32, help="proposals per step (in all, under torchrun)")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--background-keep", type=float, default=0.3, help="share of background proposals kept")
    p.add_argument("--max-steps", type=int, default=0, help="cap on batches per epoch (0: all)")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch default)")
    p.add_argument("--rebuild-cache", action="store_true", help="rerun stage 1 even if a sample cache exists")
    p.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true",
                   help="no progress bars (as in the other tools; --quiet is the old name)")
    return p


def run(args: argparse.Namespace, proposer: Proposer | None = None, frame_source: FrameSource | None = None) -> int:
    """Train as the arguments say; `proposer` and `frame_source` replace stage 1 and the dataset readers."""
    return _train(Trainer(TrainOptions(**vars(args)), proposer, frame_source, command=sys.argv))


def _train(trainer: Trainer) -> int:
    """Run `trainer` once its output folder is known to be writable; exit 1 when it cannot go on."""
    check_writable(trainer.out, folder=True, what="--out folder")
    try:
        trainer.run()
    except TrainingError as exc:
        print(f"pass3d_train: {exc}", file=sys.stderr)
        return 1
    return 0


def _interrupted(trainer: Trainer) -> str:
    """The one line after Ctrl-C: which checkpoint this run wrote last, or that it wrote none."""
    if trainer.saved_epoch is None:
        return "interrupted before any checkpoint was written"
    return f"interrupted; last checkpoint written: {trainer.last_path} (epoch {trainer.saved_epoch})"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the pass3d_train console script: 0 done, 1 nothing to train on, 2 unusable data, output
    or checkpoint, 130 / 143 interrupted."""
    args = build_parser().parse_args(argv)
    trainer = Trainer(TrainOptions(**vars(args)), command=sys.argv)
    return run_tool("pass3d_train", lambda: _train(trainer), interrupted=lambda: _interrupted(trainer))


if __name__ == "__main__":
    sys.exit(main())
