"""One knob for CPU threads: torch's intra- and inter-op pools, OpenMP / MKL, and numpy's OpenBLAS.

`threads=1` must mean one busy core. torch.set_num_threads alone is not enough: numpy's OpenBLAS keeps its
own pool (sized from OPENBLAS_NUM_THREADS / OMP_NUM_THREADS when numpy is imported) whose idle workers
spin after each BLAS call, so a 1-thread stage 2 burned about 1.7x its wall time in CPU on 2 cores.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import MutableMapping
from dataclasses import dataclass
from pathlib import Path

DEFAULT_THREADS = 1  # the --threads default of the tools and benchmarks; 1 was fastest on a busy 2-core CPU

# Read once, when the OpenMP runtime, MKL or OpenBLAS starts; children of this process inherit them.
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")

# Thread setters of the OpenBLAS builds numpy ships with or links against (plain, ILP64, scipy-openblas).
_OPENBLAS_SETTERS = (
    "openblas_set_num_threads", "openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads", "scipy_openblas_set_num_threads64_",
)


@dataclass(frozen=True)
class ThreadLimits:
    """What limit_threads could set: `interop` is False when torch's inter-op pool had already started."""

    threads: int
    interop: bool
    openblas_libraries: int

    def describe(self) -> str:
        """One line for a tool's output."""
        interop = "set" if self.interop else "already started, left as it was"
        return (f"CPU threads {self.threads}: torch intra-op and OpenMP set, inter-op {interop}, "
                f"OpenBLAS libraries set {self.openblas_libraries}")


def set_thread_env(threads: int, environ: MutableMapping[str, str] = os.environ) -> None:
    """Put `threads` in the variables OpenMP, MKL and OpenBLAS read when they load (and children inherit)."""
    for name in THREAD_ENV_VARS:
        environ[name] = str(threads)


def _loaded_openblas(maps: Path = Path("/proc/self/maps")) -> list[str]:
    """Paths of the OpenBLAS libraries loaded in this process (Linux; empty elsewhere)."""
    try:
        lines = maps.read_text().splitlines()
    except OSError:
        return []
    return sorted({line.split(None, 5)[-1] for line in lines if "openblas" in line.rsplit("/", 1)[-1].lower()})


def limit_openblas(threads: int) -> int:
    """Resize every loaded OpenBLAS pool to `threads`; returns how many libraries were set."""
    count = 0
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _OPENBLAS_SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter.argtypes, setter.restype = [ctypes.c_int], None
                setter(threads)
                count += 1
                break
    return count


def limit_threads(threads: int) -> ThreadLimits:
    """Use `threads` CPU threads from now on: environment, torch intra-op (OpenMP, MKL), inter-op if torch
    has not started it yet, and loaded OpenBLAS pools. Raises ValueError for threads < 1."""
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    set_thread_env(threads)
    import torch

    torch.set_num_threads(threads)
    interop = torch.get_num_interop_threads() == threads
    if not interop:
        try:
            torch.set_num_interop_threads(threads)
            interop = True
        except RuntimeError:
            interop = False
    return ThreadLimits(threads, interop, limit_openblas(threads))
