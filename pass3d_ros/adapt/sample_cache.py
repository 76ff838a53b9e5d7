"""The anchor's samples kept between runs of pass3d_adapt, so a second run on the same sensor skips building them.

The fine-tune's Trainer caches its samples as one npz file in its output folder, named by everything that makes them
(the data spec, stage 1's and the synthetic world's source digests, the settings: training/samples.py `cache_path`),
so a stale file is never read, only never matched again. pass3d_adapt's output folder is a temporary one; this module
links the kept files into it before the fine-tune and keeps the new ones after it, newest KEEP of them.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

KEEP = 8  # sample files kept (one per simulated sensor and mount height used lately)
PATTERN = "samples_*.npz"


def default_dir() -> Path:
    """$XDG_CACHE_HOME/pass3d_ros/adapt, else ~/.cache/pass3d_ros/adapt."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pass3d_ros" / "adapt"


def lend(cache: Path, folder: Path, log: Callable[[str], None]) -> None:
    """Link every kept sample file into the Trainer's output `folder` (made if missing). A cache that cannot be read
    costs this run the rebuild it would have had without one: one log line."""
    folder.mkdir(parents=True, exist_ok=True)
    try:
        for kept in cache.glob(PATTERN) if cache.is_dir() else ():
            (folder / kept.name).symlink_to(kept.resolve())
    except OSError as exc:
        log(f"anchor samples of earlier runs not read ({cache}: {exc.strerror or exc})")


def keep(cache: Path, folder: Path, log: Callable[[str], None]) -> None:
    """Copy the sample files the Trainer built in `folder` into `cache` (each whole or not at all), then drop the
    oldest beyond KEEP. A cache that cannot be written costs the next run a rebuild, never this run: one log line."""
    built = [path for path in folder.glob(PATTERN) if not path.is_symlink()]
    if not built:
        return
    try:
        cache.mkdir(parents=True, exist_ok=True)
        for path in built:
            part = cache / f".{path.name}.part"
            shutil.copyfile(path, part)
            os.replace(part, cache / path.name)
        files = sorted(cache.glob(PATTERN), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in files[KEEP:]:
            old.unlink()
    except OSError as exc:
        log(f"anchor samples not kept for the next run ({cache}: {exc.strerror or exc})")
