"""What every command-line tool shares: one line on stderr and exit 2 for the project's errors, 130 for
Ctrl-C, 143 for SIGTERM, and a cleanup step that removes what an unfinished run would leave behind.

A tool's `main` parses its arguments and hands the work to `run_tool`; nothing here knows any tool.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable
from types import FrameType

from rosbags.rosbag2 import ReaderError, WriterError

from pass3d_ros.core.segmentation import CheckpointError
from pass3d_ros.core.stage2 import ClassifierError
from pass3d_ros.data.bag import BagError
from pass3d_ros.data.spec import DatasetError
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error

EXIT_OK = 0
EXIT_USAGE = 2
EXIT_SIGINT = 130
EXIT_SIGTERM = 143

# The project's error types, plus what a bad path or value raises: each is the user's to fix, not a bug.
USER_ERRORS: tuple[type[BaseException], ...] = (
    DatasetError, BagError, PointCloud2Error, CheckpointError, ClassifierError, ReaderError, WriterError,
    ValueError, OSError,
)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM, carrying the exit status the shell convention gives it (128 + signal number)."""

    def __init__(self, status: int) -> None:
        super().__init__(status)
        self.status = status


def _raise_interrupted(signum: int, _frame: FrameType | None) -> None:
    raise Interrupted(EXIT_SIGTERM if signum == signal.SIGTERM else EXIT_SIGINT)


def run_tool(
    prog: str,
    work: Callable[[], int],
    *,
    cleanup: Callable[[], None] | None = None,
    interrupted: str = "interrupted",
    errors: tuple[type[BaseException], ...] = USER_ERRORS,
) -> int:
    """Run `work` with the shared signal handling and exit-status mapping; returns the exit status.

    A user error prints `prog: error: MESSAGE` and gives 2; Ctrl-C gives 130 and SIGTERM 143 with
    `prog: INTERRUPTED`. `cleanup` runs after an error or an interruption (never after success), so an
    unfinished output never looks complete. Other exceptions are bugs and keep their traceback.
    """
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
    except KeyboardInterrupt as exc:
        print(f"{prog}: {interrupted}", file=sys.stderr)
        return exc.status if isinstance(exc, Interrupted) else EXIT_SIGINT
    except errors as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
