"""`threads` means busy cores: limit_threads sets torch, OpenMP / MKL variables and numpy's OpenBLAS pool."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from pass3d_ros.core.threads import DEFAULT_THREADS, THREAD_ENV_VARS, set_thread_env
from pass3d_ros.tools.evaluate import build_parser as evaluate_parser
from pass3d_ros.tools.segment import build_parser as segment_parser

# A fresh interpreter (torch's inter-op pool is per process, settable once): import as the tools do, limit,
# then report what the libraries say.
_PROBE = """
import ctypes, json, os, sys
import numpy as np
import torch
from pass3d_ros.core.threads import _OPENBLAS_SETTERS, THREAD_ENV_VARS, _loaded_openblas, limit_threads

limits = limit_threads(int(sys.argv[1]))
blas = []
for path in _loaded_openblas():
    lib = ctypes.CDLL(path)
    for name in _OPENBLAS_SETTERS:
        getter = getattr(lib, name.replace("set_num", "get_num"), None)
        if getter is not None:
            blas.append(getter())
            break
print(json.dumps({"intra": torch.get_num_threads(), "interop": torch.get_num_interop_threads(),
                  "interop_set": limits.interop, "openblas": blas, "libraries": limits.openblas_libraries,
                  "env": {k: os.environ.get(k) for k in THREAD_ENV_VARS}}))
"""


def _probe(threads: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_ENV_VARS}
    out = subprocess.run([sys.executable, "-c", _PROBE, str(threads)], capture_output=True, text=True, env=env,
                         timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("threads", [1, 2])
def test_limit_threads_sets_every_pool(threads: int) -> None:
    got = _probe(threads)
    assert got["intra"] == threads
    assert got["interop"] == threads and got["interop_set"]
    assert got["env"] == {k: str(threads) for k in THREAD_ENV_VARS}
    # numpy's OpenBLAS starts with one thread per core unless told: its spinning pool was the second busy core.
    assert got["libraries"] == len(got["openblas"])
    assert all(n == threads for n in got["openblas"])


def test_set_thread_env_and_bad_count() -> None:
    environ: dict[str, str] = {"OMP_NUM_THREADS": "8"}
    set_thread_env(3, environ)
    assert environ == {k: "3" for k in THREAD_ENV_VARS}
    from pass3d_ros.core.threads import limit_threads

    with pytest.raises(ValueError, match="threads must be >= 1"):
        limit_threads(0)


def test_tools_share_the_default() -> None:
    assert DEFAULT_THREADS == 1
    segment = segment_parser().parse_args(["--data", "synthetic:frames=1", "--out", "x"])
    evaluate = evaluate_parser().parse_args(["--data", "synthetic:frames=1"])
    assert segment.threads == evaluate.threads == DEFAULT_THREADS


def test_benchmark_one_thread_keeps_one_core_busy() -> None:
    """CPU time / wall time of `pass3d_benchmark stage2 --threads 1` (was ~1.7-2.0 with OpenBLAS spinning).
    Other load on the machine only lowers the ratio (it stretches wall time, not this process's CPU time)."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_ENV_VARS}
    out = subprocess.run(
        [sys.executable, "-m", "pass3d_ros.bench.benchmark", "stage2", "--config", "lite", "--threads", "1",
         "--repeats", "8", "--proposals", "20", "--max-points", "1000"],
        capture_output=True, text=True, env=env, timeout=300, check=True,
    )
    match = re.search(r"= ([0-9.]+) cores busy \(--threads 1\)", out.stdout)
    assert match, out.stdout
    assert float(match.group(1)) < 1.3, out.stdout
