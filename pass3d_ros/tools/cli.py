"""What every command-line tool shares: one line on stderr and exit 2 for the project's errors, 130 for
Ctrl-C, 143 for SIGTERM, and a cleanup step that removes what an unfinished run would leave behind; the argparse
types (`number`, `torch_device`) and the options many tools take, each declared once here (`add_data`,
`add_weights`, `add_threads`, `add_param`).

A library module, not a command line: a tool's `main` parses its arguments and hands the work to `run_tool`; nothing
here knows any tool.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import signal
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import NoReturn

from rosbags.rosbag2 import ReaderError, WriterError

from pass3d_ros.core.stage2 import ClassifierError, check_device
from pass3d_ros.core.threads import DEFAULT_THREADS
from pass3d_ros.data.outputs import OutputError, error_text, is_disk_full
from pass3d_ros.msgs.errors import Pass3dError
from pass3d_ros.training import distributed, worker

EXIT_USAGE = 2
EXIT_SIGINT = 130
EXIT_SIGTERM = 143


# The project's errors (`Pass3dError`: a user error, or a library that cannot go on, e.g. training with no proposals)
# and rosbags' for unreadable or unwritable bags, plus what the system says about a path the user named: each is one
# line and exit 2. Anything else is a bug and keeps its traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (
    Pass3dError, ReaderError, WriterError,
    FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError, FileExistsError,
)

_received: list[int] = []  # exit statuses of the signals caught while `work` runs


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM, carrying the exit status the shell convention gives it (128 + signal number)."""

    def __init__(self, status: int) -> None:
        super().__init__(status)
        self.status = status


def _raise_interrupted(signum: int, _frame: FrameType | None) -> None:
    status = EXIT_SIGTERM if signum == signal.SIGTERM else EXIT_SIGINT
    _received.append(status)
    raise Interrupted(status)


def _interrupt_status(exc: BaseException) -> int | None:
    """The exit status when `exc` is, wraps or follows a Ctrl-C / SIGTERM (e.g. the SystemError a numba-compiled
    call turns a KeyboardInterrupt into); None for an ordinary exception."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return link.status if isinstance(link, Interrupted) else EXIT_SIGINT
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return _received[-1] if _received else None


class RankParser(argparse.ArgumentParser):
    """argparse with a one-line error (exit 2), silent on ranks that do not report (under torchrun every rank parses
    the same command line)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n" if worker.reports() else None)


def number(kind: type[int] | type[float] = float, low: float | None = None, high: float | None = None, *,
           low_open: bool = False) -> Callable[[str], float]:
    """An argparse type for a finite `kind` (int or float) at least `low` (above it when `low_open`) and at most
    `high`, so nan, inf and out-of-range values are refused with the argument's name rather than misbehaving later."""
    bounds = [f"{'>' if low_open else '>='} {low:g}"] if low is not None else []
    bounds += [f"<= {high:g}"] if high is not None else []
    wanted = f"{'an integer' if kind is int else 'a finite number'}{' ' if bounds else ''}{' and '.join(bounds)}"

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {wanted}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not {wanted}")
        if (low is not None and (value < low or (low_open and value == low))) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text!r} is out of range: must be {' and '.join(bounds)}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse


def torch_device(text: str) -> str:
    """An argparse type for --device: a torch device name this machine has (core.stage2.check_device), so `cuda` on a
    CPU-only torch is one line before any work rather than a traceback once the work started."""
    try:
        check_device(text)
    except ClassifierError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


# --------------------------------------------------------------------------- options many tools take

Options = argparse.ArgumentParser | argparse._ArgumentGroup  # a parser, or a group of one


def add_data(parser: Options, help: str, *, metavar: str = "SPEC", required: bool = True,
             repeatable: bool = True) -> None:
    """`--data SPEC`: a dataset spec (pass3d_ros.data.spec), repeatable unless `repeatable` is False (then one spec,
    default None); not `required`, a repeatable one defaults to no spec."""
    if repeatable:
        parser.add_argument("--data", action="append", required=required, default=None if required else [],
                            metavar=metavar, help=help)
    else:
        parser.add_argument("--data", required=required, default=None, metavar=metavar, help=help)


WEIGHTS_HELP = "stage-2 checkpoint (default: the shipped weights)"


def add_weights(parser: Options, help: str = WEIGHTS_HELP, *, metavar: str | None = "W") -> None:
    """`--weights W`: a stage-2 checkpoint file (None: the tool's default, mostly the shipped weights)."""
    parser.add_argument("--weights", metavar=metavar, help=help)


def add_threads(parser: Options, help: str | None = None, *, default: int = DEFAULT_THREADS, low: int | None = None,
                metavar: str | None = "N") -> None:
    """`--threads N`: CPU threads of the process (an integer at least `low`; any integer when None). The help says
    the default unless `help` is given."""
    parser.add_argument("--threads", type=int if low is None else number(int, low), default=default, metavar=metavar,
                        help=help if help is not None else f"CPU threads: torch, OpenMP, OpenBLAS (default {default})")


PARAM_HELP = "override a Stage1Config parameter, repeatable (e.g. th_dist=0.25, stage1.sensor=pandar64)"


def add_param(parser: Options, help: str = PARAM_HELP) -> None:
    """`--param KEY=VALUE`, repeatable: stage-1 overrides, read by pass3d_ros.core.stage1.config.parse_params."""
    parser.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help=help)


def check_writable(path: str | Path, *, folder: bool, what: str = "output") -> None:
    """OutputError unless `path` (a folder when `folder`, else a file) can be created or written; call it before
    the work starts, so a long run never ends unable to save its result. It tries: an existing file is opened for
    appending (nothing written), elsewhere a probe file is created and removed (root passes every os.access)."""
    path = Path(path)
    if path.exists() and folder != path.is_dir():
        raise OutputError(f"{path}: cannot write {what}, it exists and is not a {'folder' if folder else 'file'}")
    if path.is_file():
        try:
            with path.open("ab"):
                pass
        except OSError as exc:
            raise OutputError(f"{path}: {what} is not writable ({exc.strerror})") from None
        return
    ancestor = path.absolute() if path.exists() else path.absolute().parent
    while not (ancestor.exists() or ancestor == ancestor.parent):
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"{path}: cannot create {what}, {ancestor} is not a folder")
    try:
        handle, probe = tempfile.mkstemp(prefix=".pass3d-write-test-", dir=ancestor)
    except OSError as exc:
        verb = "write" if path.exists() else "create"
        raise OutputError(f"{path}: cannot {verb} {what} in {ancestor} ({exc.strerror})") from None
    os.close(handle)
    os.unlink(probe)


def check_bag_writable(path: str | Path, what: str = "--out bag") -> None:
    """`check_writable` for a bag folder about to be written: the folder it is built in when it exists (a --force
    run replaces it), else the bag itself; so an unwritable place is named before the work, never by the hidden
    build folder's name after it."""
    path = Path(path)
    check_writable(path.parent if path.exists() or path.is_symlink() else path, folder=True, what=what)


def run_tool(
    prog: str,
    work: Callable[[], int],
    *,
    cleanup: Callable[[], None] | None = None,
    interrupted: str | Callable[[], str] = "interrupted",
) -> int:
    """Run `work` with the shared signal handling and exit-status mapping; returns the exit status.

    A user or library error (`USER_ERRORS`) prints `prog: error: MESSAGE` and gives 2; Ctrl-C gives 130 and SIGTERM
    143 with `prog: INTERRUPTED` (a callable is asked for the text then); a full disk is a user error too. `cleanup`
    runs after an error or an interruption (never after success), so an unfinished output never looks complete. Any
    exception raised once a signal came counts as that interruption; other exceptions are bugs and keep their
    traceback.
    """
    _received.clear()
    previous = {sig: signal.signal(sig, _raise_interrupted) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            return work()
        except BaseException:
            if cleanup is not None:
                cleanup()
            raise
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    except BaseException as exc:
        status = _interrupt_status(exc)
        if status is not None:
            print(f"{prog}: {interrupted() if callable(interrupted) else interrupted}", file=sys.stderr)
            return status
        if isinstance(exc, USER_ERRORS) or is_disk_full(exc):
            print(f"{prog}: error: {error_text(exc)}", file=sys.stderr)
            return EXIT_USAGE
        raise



def reported(work: Callable[[], int]) -> int:
    """Run `work` (a tool's `run_tool` call) as this rank reports: as is on a rank that reports; elsewhere (under
    torchrun a rank > 0 says nothing) with its stderr silenced, and a failure's report handed to torchrun's summary
    (pass3d_ros.training.distributed.record_error). Returns its exit status."""
    if worker.reports():
        return work()
    silenced = io.StringIO()
    with contextlib.redirect_stderr(silenced):
        status = work()
    if status not in (0, EXIT_SIGINT, EXIT_SIGTERM):
        distributed.record_error(silenced.getvalue())
    return status


def parse_ranked(parser: argparse.ArgumentParser, argv: list[str] | None,
                 started: str = "processes") -> tuple[argparse.Namespace, list[str]]:
    """(arguments, argv) of a tool that takes `--nproc N`, parsed once a launched worker is tied to its launcher
    (worker.die_with_parent); `argv` None reads sys.argv. Under torchrun --nproc is a parser error: the tool's own
    launcher would start its `started` inside torchrun's."""
    worker.die_with_parent()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if args.nproc > 1 and worker.world_size() > 1 and worker.LAUNCHER_ENV not in os.environ:
        parser.error(f"--nproc starts its own {started}; under torchrun leave it out")
    return args, argv
