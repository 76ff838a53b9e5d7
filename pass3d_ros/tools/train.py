"""`pass3d_train`: train the stage-2 PointNet++ on stage-1 proposals of labelled scans.

Validation scores whole frames point by point: each validation frame's proposals are segmented as in
inference (one batch per frame, overlap rule, points outside every proposal are background), and the
per-class IoU is counted over every point of every validation frame, so it includes stage 1's misses.
The best checkpoint is the one with the highest mean IoU over car, pedestrian and cyclist.
The training itself is pass3d_ros.training.trainer; this module only parses the command line.

Data-parallel: `pass3d_train --nproc N ...` trains in N processes on this machine (gloo on CPU, nccl with --device
cuda); --batch-size stays the global batch per step. The workers stop with it: Ctrl-C gives 130, SIGTERM 143, a
user error 2, each with one line. `torchrun --nproc_per_node N -m pass3d_ros.tools.train ...` does the same training
(multi-node too), with torchrun's own messages and exit statuses around it.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from pass3d_ros.training import worker

PROG = "pass3d_train"

# Before the seconds of imports below: a launched worker ties itself to its launcher, and Ctrl-C meanwhile is the one
# line and status 130 it is later, not a traceback (worker.starting).
with worker.starting(PROG):
    from pass3d_ros.core.stage1.config import parse_params
    from pass3d_ros.core.stage2.pointnet2 import GROUPINGS, TRAIN_GROUPING
    from pass3d_ros.tools.cli import (
        RankParser,
        add_data,
        add_param,
        add_threads,
        check_writable,
        number,
        parse_ranked,
        reported,
        run_tool,
        torch_device,
    )
    from pass3d_ros.training import consistency, launcher
    from pass3d_ros.training.samples import Proposer
    from pass3d_ros.training.trainer import (
        FrameSource,
        PeerLostError,
        Trainer,
        TrainOptions,
    )


def build_parser() -> argparse.ArgumentParser:
    """The command line of pass3d_train."""
    p = RankParser(prog=PROG, description=__doc__.splitlines()[0])
    add_data(p, "training data FORMAT:PATH")
    p.add_argument("--val-data", action="append", default=[], metavar="SPEC", help="validation data FORMAT:PATH")
    p.add_argument("--config", choices=["paper", "lite"], default="lite", help="model configuration")
    p.add_argument("--epochs", type=number(int, 1), default=40)
    p.add_argument("--out", type=Path, required=True, help="output folder: checkpoints, sample caches, log")
    p.add_argument("--device", type=torch_device, default="cpu", help="cpu or cuda")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--init", type=Path, metavar="CHECKPOINT",
                   help="start from these weights (fine-tuning; fresh optimizer and schedule)")
    p.add_argument("--loss", choices=["ce", "focal"], default="ce")
    p.add_argument("--focal-alpha", type=number(float, 0.0, 1.0), default=0.25,
                   help="focal alpha: foreground weight, background 1-a")
    p.add_argument("--focal-gamma", type=number(float, 0.0), default=2.0)
    p.add_argument("--no-augment", action="store_true", help="train on the inference view only (no 8 views)")
    p.add_argument("--no-n-feature", action="store_true", help="set the point-count feature n to 0")
    p.add_argument("--n-mode", choices=["ratio", "log"], default="log",
                   help="n = log(NUM / N) (default: bounded, trains stably) or the paper's (NUM - N) / N")
    p.add_argument("--grouping", choices=GROUPINGS, default=TRAIN_GROUPING,
                   help="slot: FPS from slot 0, first ball members in slot order (the shipped weights); set: FPS "
                        "from the point nearest the centroid, nearest ball members (order-free: such weights sample "
                        "by coverage, no draw)")
    p.add_argument("--no-intensity-augment", action="store_true",
                   help="no per-proposal intensity augmentation (gain, offset, gamma, zeroing, constant)")
    p.add_argument("--no-intensity", action="store_true",
                   help="feed intensity as 0 (stored in the checkpoint: inference does the same)")
    p.add_argument("--seed", type=number(int, 0), default=0)
    p.add_argument("--batch-size", type=number(int, 1), default=32,
                   help="proposals per step (in all, when data-parallel)")
    p.add_argument("--lr", type=number(float, 0.0), default=1e-3)
    p.add_argument("--weight-decay", type=number(float, 0.0), default=1e-4)
    p.add_argument("--background-keep", type=number(float, 0.0, 1.0), default=0.3,
                   help="share of background proposals kept")
    p.add_argument("--max-steps", type=number(int, 0), default=0, help="cap on batches per epoch (0: all)")
    p.add_argument("--minutes", type=number(float, 0.0), default=0.0, metavar="M",
                   help="wall-time budget from the start, samples included (0: none): the epoch it ends in is "
                        "validated and saved, then the run stops")
    p.add_argument("--fit-epochs", action="store_true",
                   help="with --minutes: after the first epoch, as many epochs as fit the budget at its pace (at "
                        "most --epochs), the learning-rate schedule stretched over them")
    add_threads(p, "torch CPU threads (0: torch default)", default=0, low=0, metavar=None)
    add_param(p, "override a Stage1Config parameter for the stage-1 run that builds the samples, repeatable "
                 "(e.g. th_dist=0.25; part of the sample cache name)")
    p.add_argument("--nproc", type=number(int, 1), default=1, metavar="N",
                   help="data-parallel: train in N processes started here (the alternative is torchrun)")
    p.add_argument("--consistency", action="append", default=[], metavar="SPEC",
                   help="unlabelled real scans FORMAT:PATH for view consistency (their labels are not read)")
    p.add_argument("--consistency-samples", metavar="FILE",
                   help="instead of --consistency: their proposals as a sample file, as pass3d_adapt --nproc hands "
                        "its recording's to the workers")
    p.add_argument("--consistency-weight", type=number(float, 0.0), default=consistency.DEFAULT_WEIGHT,
                   help="weight of the view-consistency term")
    p.add_argument("--consistency-threshold", type=number(float, 0.0, 1.0), default=consistency.DEFAULT_THRESHOLD,
                   help="inference-view probability a point's target needs")
    p.add_argument("--consistency-batch", type=number(int, 1), default=consistency.DEFAULT_BATCH,
                   help="unlabelled proposals per optimizer step, over all processes")
    p.add_argument("--consistency-draws", type=number(int, 1, 64), nargs="?", const=1, default=0, metavar="K",
                   help="the consistency term's student reads another random draw of each proposal's points than "
                        "its teacher, whose probabilities are the mean of K draws (default 1), so draws must agree "
                        "as well as views")
    p.add_argument("--rebuild-cache", action="store_true", help="rerun stage 1 even if a sample cache exists")
    p.add_argument("--force", action="store_true",
                   help="replace a previous run's checkpoints in --out (without it, a fresh run there is refused)")
    p.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true",
                   help="no progress bars (as in the other tools; --quiet is the old name)")
    return p


def options(args: argparse.Namespace) -> TrainOptions:
    """The TrainOptions of parsed arguments (all flags but --nproc, which only says how to start)."""
    return TrainOptions(**{k: v for k, v in vars(args).items() if k != "nproc"})


def run(args: argparse.Namespace, proposer: Proposer | None = None, frame_source: FrameSource | None = None) -> int:
    """Train as the arguments say; `proposer` and `frame_source` replace stage 1 and the dataset readers."""
    return _train(Trainer(options(args), proposer, frame_source, command=sys.argv, stage1=parse_params(args.param)))


def _train(trainer: Trainer) -> int:
    """Run `trainer` once its output folder is known to be writable; exit 1 when another worker stopped first
    (silently under pass3d_train's launcher: it shows that worker's report)."""
    check_writable(trainer.out, folder=True, what="--out folder")
    try:
        trainer.run()
    except PeerLostError as exc:
        if worker.LAUNCHER_ENV in os.environ:
            return launcher.EXIT_PEER_LOST
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 1
    return 0  # any other TrainingError (nothing to train on, diverged, ...) is run_tool's one line, exit 2


def _interrupted(trainer: Trainer) -> str:
    """The one line after Ctrl-C: which checkpoint this run wrote last, or that it wrote none."""
    if trainer.saved_epoch is None:
        return "interrupted before any checkpoint was written"
    return f"interrupted; last checkpoint written: {trainer.last_path} (epoch {trainer.saved_epoch})"


def _launch(args: argparse.Namespace, argv: list[str]) -> int:
    """--nproc N: check what can be checked once, then run N workers of this command line (see launcher)."""
    parse_params(args.param)  # a bad --param is reported once, before any worker starts
    check_writable(args.out, folder=True, what="--out folder")
    return launcher.launch("pass3d_ros.tools.train", argv, args.nproc, PROG)


def _work(args: argparse.Namespace, holder: list[Trainer]) -> int:
    """Build the trainer (kept in `holder` for the interruption line) and train."""
    holder.append(Trainer(options(args), command=sys.argv, stage1=parse_params(args.param)))
    return _train(holder[0])


def main(argv: list[str] | None = None) -> int:
    """Entry point of the pass3d_train console script: 0 done, 1 another data-parallel worker stopped, 2 unusable
    data, output, checkpoint or argument, nothing to train on, or a run that diverged, 130 / 143 interrupted.
    Data-parallel, only rank 0 reports (see --nproc)."""
    parser = build_parser()
    args, argv = parse_ranked(parser, argv, "workers")
    if args.fit_epochs and not args.minutes:
        parser.error("--fit-epochs fits the epochs to a time budget: give --minutes too")
    if args.consistency and args.consistency_samples:
        parser.error("--consistency and --consistency-samples both name the unlabelled scans: give one")
    if args.nproc > 1 and worker.world_size() == 1:
        return run_tool(PROG, lambda: _launch(args, argv))
    holder: list[Trainer] = []
    return reported(lambda: run_tool(PROG, lambda: _work(args, holder),
                                     interrupted=lambda: _interrupted(holder[0]) if holder else "interrupted"))


if __name__ == "__main__":
    sys.exit(main())
