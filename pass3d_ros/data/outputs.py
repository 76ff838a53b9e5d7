"""The one rule every output writer follows, so that no flag can destroy what this package did not make.

- An empty `--out` (an unset shell variable) is an error, never the working folder.
- `--force` replaces (or writes into) an existing output only when this package wrote it: a bag it can open, or a
  folder holding the `MARKER` file written when the output was made (an empty folder holds nothing to lose). It
  never touches the working folder, a folder above it, the file-system root, the home folder, an input, or a folder
  holding an input (symlinks resolved).
- A full disk is one line naming the output (`PATH: disk full (no space left on device)`), never a traceback; a
  file is written beside its destination and renamed into place, so a failed write leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import sqlite3
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from pass3d_ros.msgs.errors import UserError

MARKER = ".pass3d_output"  # in a folder this package wrote: the tool that wrote it
DISK_FULL: frozenset[int] = frozenset({errno.ENOSPC, errno.EDQUOT})


class OutputError(UserError):
    """An output path that cannot be created, written or replaced; the message names it and says why."""


class DiskFullError(OutputError):
    """The disk (or the user's quota) filled up while an output was written."""


def out_path(text: str | Path, what: str = "--out") -> Path:
    """`text` as a path; OutputError when it is empty, as an unset `$OUT` gives (it would mean the working folder)."""
    if not str(text).strip():
        raise OutputError(f"{what} is empty; name the output to write")
    return Path(text)


def _home() -> Path | None:
    try:
        return Path.home().resolve()
    except (RuntimeError, KeyError, OSError):  # no HOME and no passwd entry
        return None


def protected_reason(out: str | Path, inputs: Iterable[str | Path] = ()) -> str | None:
    """Why `out` must never be replaced or written into (the working folder or one above it, the root, the home
    folder, an input or a folder holding one; symlinks resolved), or None when it may be."""
    target = Path(out).resolve()
    cwd = Path.cwd().resolve()
    if target == Path(target.anchor):
        return "it is the file-system root"
    if target == cwd:
        return "it is the working folder"
    if target in cwd.parents:
        return "it holds the working folder"
    if target == _home():
        return "it is the home folder"
    for item in inputs:
        source = Path(item).resolve()
        if target == source:
            return f"it is an input ({item})"
        if target in source.parents:
            return f"it holds an input ({item})"
    return None


def refuse_protected(out: str | Path, inputs: Iterable[str | Path] = (), what: str = "--out") -> None:
    """OutputError when `protected_reason` names a reason to keep away from `out`."""
    reason = protected_reason(out, inputs)
    if reason is not None:
        raise OutputError(f"{what} {out}: {reason}; refusing to write there, choose another {what}")


def is_empty_folder(path: Path) -> bool:
    """Whether `path` is a real folder (not a symlink) with nothing in it."""
    return path.is_dir() and not path.is_symlink() and not any(path.iterdir())


def has_marker(path: Path) -> bool:
    """Whether `path` is a folder this package wrote (it holds the `MARKER` file)."""
    return path.is_dir() and not path.is_symlink() and (path / MARKER).is_file()


def write_marker(folder: Path, prog: str) -> None:
    """Mark `folder` as written by `prog`, so a later --force may replace it."""
    (folder / MARKER).write_text(f"written by {prog}; --force may replace this folder\n")


def check_force(out: Path, *, ours: Callable[[Path], bool], kind: str, inputs: Iterable[str | Path] = (),
                what: str = "--out") -> None:
    """Before --force replaces or writes into an existing `out`: refuse a protected path, and anything that is
    neither an empty folder nor what `ours` recognises as this package's (`kind` names that in the message)."""
    refuse_protected(out, inputs, what)
    if not (out.exists() or out.is_symlink()) or is_empty_folder(out) or ours(out):
        return
    raise OutputError(f"{what} {out} exists and is not {kind} this package wrote; --force replaces only those: "
                      f"remove it yourself or choose another {what}")


def marked_folder_out(text: str | Path, datasets: Iterable[object], force: bool, kind: str) -> Path:
    """The resolved `--out` folder of a tool that writes a marked folder from `datasets`: refused when empty,
    protected or an input (`refuse_protected`); an existing one only with `force`, and only one this package wrote
    (`check_force`: it holds the MARKER, or it is empty). `kind` names the folder in the error."""
    given = out_path(text)
    inputs = dataset_paths(datasets)
    refuse_protected(given, inputs)
    out = given.resolve()
    if out.exists() or out.is_symlink():
        if not force:
            raise UserError(f"--out {text} exists; --force replaces it")
        check_force(out, ours=has_marker, kind=kind, inputs=inputs)
    return out


def dataset_paths(datasets: Iterable[object]) -> list[Path]:
    """The paths on disk the datasets read (each one's `path` that exists), for `protected_reason`'s inputs."""
    paths = []
    for dataset in datasets:
        path = str(getattr(dataset, "path", "")).partition("#")[0]
        if path and Path(path).exists():
            paths.append(Path(path))
    return paths


def is_disk_full(exc: BaseException) -> bool:
    """Whether `exc`, or an exception it wraps, says the disk or the quota is full (sqlite3's wording too)."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, OSError) and link.errno in DISK_FULL:
            return True
        if isinstance(link, sqlite3.Error) and "disk is full" in str(link):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def plain_os_error(exc: OSError) -> str:
    """What went wrong in plain words, without the `[Errno N]` prefix: `disk full (no space left on device)` for a
    full disk or quota, else the system's text in lower case (`permission denied`)."""
    text = exc.strerror or (os.strerror(exc.errno) if exc.errno else str(exc))
    text = text[:1].lower() + text[1:]
    return f"disk full ({text})" if exc.errno in DISK_FULL else text


def describe_os_error(exc: OSError) -> str:
    """`PATH: problem in plain words` (both paths of a rename), or the problem alone when no path is known."""
    names = [str(name) for name in (exc.filename, exc.filename2) if name is not None]
    return f"{' -> '.join(names)}: {plain_os_error(exc)}" if names else plain_os_error(exc)


def disk_full_error(path: str | Path | None, exc: BaseException) -> DiskFullError:
    """The one-line error for a full disk while writing `path` (None: not known)."""
    link: BaseException | None = exc
    while link is not None and not (isinstance(link, OSError) and link.errno in DISK_FULL):
        link = link.__cause__ or link.__context__
    detail = plain_os_error(link) if isinstance(link, OSError) else "disk full (no space left on device)"
    return DiskFullError(detail if path is None else f"{path}: {detail}")



def error_text(exc: BaseException) -> str:
    """A user error in plain words: a full disk as `PATH: disk full (...)`, a system error as `PATH: problem` without
    its `[Errno N]`, anything else as its message."""
    if is_disk_full(exc) and not isinstance(exc, OutputError):
        return str(disk_full_error(getattr(exc, "filename", None), exc))
    if isinstance(exc, OSError) and exc.strerror:
        return describe_os_error(exc)
    return str(exc)

@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn a full disk met inside the block into DiskFullError naming `path`; other errors pass unchanged."""
    try:
        yield
    except DiskFullError:
        raise
    except Exception as exc:
        if is_disk_full(exc):
            raise disk_full_error(path, exc) from None
        raise


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write `text` to a hidden sibling of `path` and rename it into place: a failure (a full disk: DiskFullError)
    leaves neither a partial file nor the sibling, and an old `path` as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
    temporary = Path(name)
    try:
        with writing(path):
            with os.fdopen(handle, "w", encoding="utf-8") as stream:
                stream.write(text)
            os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def swap_into_place(build: Path, out: Path) -> None:
    """Move the finished folder `build` to `out`; an old `out` is set aside first and removed only once the new one
    is in place (restored if the move fails)."""
    old = None
    if out.exists() or out.is_symlink():
        old = build.with_name(build.name + ".replaced")
        out.rename(old)
    try:
        build.rename(out)
    except BaseException:
        if old is not None:
            old.rename(out)
        raise
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


def merge_into(build: Path, out: Path) -> None:
    """Move every file of the finished folder `build` to the same place under `out` (replacing a file of that name,
    keeping the others), then remove `build`; a missing or empty `out` simply becomes `build`."""
    if not out.exists() or is_empty_folder(out):
        if out.exists():
            out.rmdir()
        out.parent.mkdir(parents=True, exist_ok=True)
        build.rename(out)
        return
    for path in sorted(build.rglob("*")):
        if path.is_dir():
            continue
        target = out / path.relative_to(build)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path, target)
    shutil.rmtree(build, ignore_errors=True)
