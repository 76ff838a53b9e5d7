"""`pass3d_adapt`: stage 2 adapted to your own sensor from an unlabelled recording, with its own label-free check.

    pass3d_adapt --data bag:my_drive.mcap[#/ouster/points] --out my_ouster/ [--minutes 20] [--weights W]
    ros2 launch pass3d_ros pass3d.launch.py params_file:=my_ouster/pass3d_params.yaml

Reads at most --max-scans scans of the recording (evenly spaced), learns what the nodes learn from a stream (rings,
mounting, intensity scale), holds out two stretches of time, and checks the starting weights there without labels
(view agreement over point draws, proposals per scan, class shares by range) and on unseen synthetic scenes of the
nearest simulated sensor (the guard). Then it fine-tunes from those weights with view consistency on the other scans
and labelled synthetic scans of that sensor until the --minutes budget (all of it, checks included) runs out,
averages the result with the starting weights, checks again and judges: weights that lose more than 1 mean IoU point
on the guard scenes are refused. Writes OUT/report.md, report.json, view.png and, when accepted, weights.pt and
pass3d_params.yaml (pass3d_ros.adapt.output), all at once. A recording of fewer than 8 scans cannot be held out
from: settings only (the sensor read, the starting weights checked on every scan, pass3d_params.yaml naming them).
Exit status: 0 accepted or settings only, 1 refused (the report says which guard and by how much), 2 user error,
130 / 143 interrupted (a Ctrl-C during the fine-tune writes the last finished epoch's weights marked partial,
unchecked).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from pass3d_ros.adapt import sample_cache
from pass3d_ros.adapt.holdout import fewest_scans
from pass3d_ros.adapt.output import write_folder
from pass3d_ros.adapt.run import Adaptation, AdaptOptions
from pass3d_ros.adapt.sensor import AUTO
from pass3d_ros.core.stage1.config import parse_params
from pass3d_ros.core.threads import limit_threads
from pass3d_ros.data.outputs import marked_folder_out
from pass3d_ros.data.partials import remove_stale_partials
from pass3d_ros.data.spec import resolve_datasets
from pass3d_ros.synthetic.sensor import SENSOR_NAMES
from pass3d_ros.tools.cli import (
    add_data,
    add_param,
    add_threads,
    add_weights,
    check_writable,
    number,
    run_tool,
    torch_device,
)

PROG = "pass3d_adapt"
EXIT_REFUSED = 1
DEFAULTS = AdaptOptions(data=[])


def build_parser() -> argparse.ArgumentParser:
    """The command line of pass3d_adapt."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_data(p, "the unlabelled recording: bag:BAG[#TOPIC], semantickitti:DIR, ... (repeatable)")
    p.add_argument("--out", required=True, metavar="DIR", help="the folder to write")
    add_weights(p, "starting weights (default: the shipped ones)")
    p.add_argument("--minutes", type=number(float, 0.0, low_open=True), default=DEFAULTS.minutes, metavar="M",
                   help=f"wall-time budget of the whole run (default {DEFAULTS.minutes:g})")
    p.add_argument("--max-scans", type=number(int, fewest_scans()), default=DEFAULTS.max_scans, metavar="N",
                   help=f"scans read from the recording, evenly spaced (default {DEFAULTS.max_scans})")
    p.add_argument("--draws", type=number(int, 1), default=DEFAULTS.draws, metavar="D",
                   help=f"point-sample draws of each check (default {DEFAULTS.draws})")
    p.add_argument("--guard-scenes", type=number(int, 1), default=DEFAULTS.guard_scenes, metavar="N",
                   help=f"unseen synthetic scenes of the guard (default {DEFAULTS.guard_scenes})")
    p.add_argument("--anchor-frames", type=number(int, 1), default=DEFAULTS.anchor_frames, metavar="N",
                   help="labelled synthetic scans the fine-tune keeps learning from "
                        f"(default {DEFAULTS.anchor_frames})")
    p.add_argument("--epochs", type=number(int, 1), default=DEFAULTS.epochs,
                   help=f"most fine-tune epochs (default {DEFAULTS.epochs}; the budget left sets how many fit)")
    p.add_argument("--sensor", choices=(AUTO, *SENSOR_NAMES), default=DEFAULTS.sensor,
                   help="the simulated sensor whose labelled scans anchor the fine-tune and whose unseen scenes "
                        f"guard it (default {DEFAULTS.sensor}: the one nearest what the recording shows; name "
                        "yours when the recording hides it, e.g. merged sensors or a frame away from the sensor)")
    p.add_argument("--device", type=torch_device, default=DEFAULTS.device,
                   help=f"torch device of the checks and the fine-tune (default {DEFAULTS.device})")
    p.add_argument("--nproc", type=number(int, 1), default=DEFAULTS.nproc, metavar="N",
                   help="fine-tune in N data-parallel processes of --threads torch threads each (pass3d_train's "
                        f"launcher; the checks run in this one); default {DEFAULTS.nproc}: 2 measured faster but "
                        "slightly worse (docs/adapt.md)")
    p.add_argument("--lr", type=number(float, 0.0, low_open=True), default=DEFAULTS.lr)
    p.add_argument("--seed", type=number(int, 0), default=DEFAULTS.seed)
    add_param(p, "override a stage-1 parameter, repeatable (as in pass3d_evaluate)")
    add_threads(p, "torch CPU threads", low=1)
    p.add_argument("--force", action="store_true", help="replace an existing --out this tool wrote")
    p.add_argument("--no-cache", action="store_true",
                   help=f"neither read nor keep the anchor's samples in {sample_cache.default_dir()} "
                        "($XDG_CACHE_HOME or ~/.cache): a later run on the same sensor skips building them")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return p


def _run(args: argparse.Namespace) -> int:
    datasets = resolve_datasets(args.data)
    out = marked_folder_out(args.out, datasets, args.force, "an adaptation folder")
    check_writable(out, folder=True, what="--out folder")
    options = AdaptOptions(data=list(args.data), weights=args.weights, minutes=args.minutes, max_scans=args.max_scans,
                           draws=args.draws, guard_scenes=args.guard_scenes, anchor_frames=args.anchor_frames,
                           epochs=args.epochs, device=args.device, sensor=args.sensor, nproc=args.nproc,
                           lr=args.lr, seed=args.seed,
                           progress=not args.no_progress, cache=None if args.no_cache else sample_cache.default_dir(),
                           stage1=parse_params(args.param))
    limit_threads(args.threads)
    remove_stale_partials(out)
    out.parent.mkdir(parents=True, exist_ok=True)  # the work folder sits beside the output (checked writable)
    work = Path(tempfile.mkdtemp(prefix=f".{out.name}.work-", dir=out.parent))
    adaptation = Adaptation(options, work, log=lambda line: print(f"{PROG}: {line}", file=sys.stderr))
    try:
        try:
            result = adaptation.run()
        except KeyboardInterrupt:
            if adaptation.result is not None and adaptation.result.weights is not None:
                write_folder(adaptation.result, out, options.data)
                print(f"{PROG}: partial weights of the last finished epoch written to {out} (unchecked)",
                      file=sys.stderr)
            raise
        write_folder(result, out, options.data)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if result.accepted:
        print(f"{PROG}: accepted: {out}/weights.pt; run the nodes with params_file:={out}/pass3d_params.yaml")
        return 0
    if result.settings_only is not None:
        print(f"{PROG}: settings only ({result.settings_only}): run the nodes with "
              f"params_file:={out}/pass3d_params.yaml (the starting weights, not adapted)")
        return 0
    print(f"{PROG}: refused, no weights written: {'; '.join(result.refused)} (see {out}/report.md)", file=sys.stderr)
    return EXIT_REFUSED


def main(argv: list[str] | None = None) -> int:
    """Console entry point."""
    args = build_parser().parse_args(argv)
    return run_tool(PROG, lambda: _run(args))


if __name__ == "__main__":
    sys.exit(main())
