"""`pass3d_benchmark SUITE ...`: speed benchmarks that print what they measured. A suite raises UserError for bad
options or input; `run_tool` prints it as one line, `pass3d_benchmark: error: ...`, on stderr and exits 2."""

from __future__ import annotations

import argparse
import importlib
import sys

from pass3d_ros.tools.cli import run_tool

# suite name -> module with `add_arguments(parser)` and `run(args) -> int`; loaded by name so that a suite missing
# from an install is left out. This entry point lives in bench, the top layer, because it loads the suites.
SUITES: dict[str, str] = {
    "codec": "pass3d_ros.bench.codec",
    "fuzz": "pass3d_ros.bench.codec_fuzz",
    "layout": "pass3d_ros.bench.layout",
    "stage1": "pass3d_ros.bench.stage1",
    "stage2": "pass3d_ros.bench.stage2",
    "simulate": "pass3d_ros.bench.simulate",
    "live": "pass3d_ros.bench.live",
    "sensors": "pass3d_ros.bench.sensors",
    "tracks": "pass3d_ros.bench.tracks",
}


def main(argv: list[str] | None = None) -> int:
    """Console entry point: run the chosen suite and return its exit status (2 on a user error, 130 / 143 when
    interrupted)."""
    parser = argparse.ArgumentParser(prog="pass3d_benchmark", description=__doc__)
    sub = parser.add_subparsers(dest="suite", required=True)
    modules = {}
    for name, module_name in SUITES.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        modules[name] = module
        module.add_arguments(sub.add_parser(name, help=(module.__doc__ or "").strip().splitlines()[0]))
    args = parser.parse_args(argv)
    return run_tool("pass3d_benchmark", lambda: modules[args.suite].run(args))


if __name__ == "__main__":
    sys.exit(main())
