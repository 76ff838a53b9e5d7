"""Outputs built in a hidden sibling (`.NAME.partial-...`) and renamed into place when complete, and the removal of
the siblings a killed run left behind: the bag writer and the tools that write folders or files share it."""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path


def partial_prefix(out: Path) -> str:
    """The name every build sibling of `out` starts with."""
    return f".{out.name}.partial-"


def process_gone(pid: int) -> bool:
    """Whether process `pid` has ended (False for this process and for one this user may not signal)."""
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        return False
    return False


def remove_stale(out: Path, is_stale: Callable[[Path], bool], log: Callable[[str], None],
                 what: str = "unfinished output(s)") -> list[Path]:
    """Delete the build siblings of `out` (files or folders) that `is_stale` says no running writer owns; one line
    through `log` names them. Returns what it removed."""
    prefix = partial_prefix(out)
    parent = out.parent
    stale = [p for p in (parent.iterdir() if parent.is_dir() else ())
             if p.name.startswith(prefix) and not p.is_symlink() and is_stale(p)]
    for path in stale:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    if stale:
        names = ", ".join(sorted(p.name for p in stale))
        log(f"note: removed {len(stale)} {what} of {out} left by an earlier interrupted run: {names}")
    return stale


def partial_path(out: Path) -> Path:
    """The hidden sibling this process builds `out` in (`.NAME.partial-PID`), renamed into place when complete."""
    return out.with_name(f"{partial_prefix(out)}{os.getpid()}")


def remove_stale_partials(out: Path) -> list[Path]:
    """Delete the `partial_path` siblings of `out` whose process is gone (a killed run), saying so on stderr."""
    prefix = partial_prefix(out)

    def stale(path: Path) -> bool:
        pid = path.name[len(prefix):]
        return pid.isdigit() and process_gone(int(pid))

    return remove_stale(out, stale, lambda text: print(text, file=sys.stderr))
