"""Which scans of a recording adaptation may learn from and which it holds out for its own check.

Neighbouring scans of a drive see the same objects, so a check on scans next to those it learned from would
flatter it: the held-out scans are whole stretches of time spread over the recording, and the scans just around
each stretch (`gap`) are used by neither side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pass3d_ros.msgs.errors import UserError

DEFAULT_SHARE = 0.25  # of the scans held out for the check
DEFAULT_STRETCHES = 2  # held-out stretches, spread over the recording
DEFAULT_GAP = 1  # scans left out on either side of a held-out stretch
MIN_SCANS_EACH = 2  # scans each side needs at least


@dataclass(frozen=True)
class Split:
    """Positions (in time order) of the scans to adapt on, to check on, and left out between them."""

    adapt: np.ndarray
    check: np.ndarray
    left_out: np.ndarray

    def describe(self) -> str:
        """One line: how many scans each side got and the held-out stretches as first-last positions."""
        runs = np.split(self.check, np.flatnonzero(np.diff(self.check) > 1) + 1) if len(self.check) else []
        stretches = ", ".join(f"{r[0]}-{r[-1]}" for r in runs)
        return (f"{len(self.adapt)} scans to adapt on, {len(self.check)} held out (scans {stretches}), "
                f"{len(self.left_out)} between them left out")


def fewest_scans(share: float = DEFAULT_SHARE, stretches: int = DEFAULT_STRETCHES, gap: int = DEFAULT_GAP) -> int:
    """The fewest scans `split_scans` can split with these settings."""
    count = 1
    while True:
        try:
            split_scans(count, share, stretches, gap)
            return count
        except UserError:
            count += 1


def split_scans(count: int, share: float = DEFAULT_SHARE, stretches: int = DEFAULT_STRETCHES,
                gap: int = DEFAULT_GAP) -> Split:
    """`count` scans in time order split into `stretches` held-out stretches of about `share` of them in all,
    centred in equal parts of the recording, `gap` scans around each left out, the rest to adapt on. A recording
    too short for that (fewer than MIN_SCANS_EACH on a side) raises UserError saying how many scans it needs."""
    if not 0.0 < share < 1.0:
        raise ValueError(f"share must lie in (0, 1), got {share}")
    if stretches < 1 or gap < 0:
        raise ValueError(f"need stretches >= 1 and gap >= 0, got {stretches}, {gap}")
    held = max(MIN_SCANS_EACH, round(share * count))
    stretches = min(stretches, held)
    needed = held + 2 * gap * stretches + MIN_SCANS_EACH
    if count < needed:
        raise UserError(f"the recording has {count} scans; adapting needs at least {needed} "
                        f"({held} held out for the check in {stretches} stretches, {gap} around each left out, "
                        f"{MIN_SCANS_EACH} to adapt on): record longer or give more scans")
    role = np.zeros(count, dtype=np.int8)  # 0 adapt, 1 check, 2 left out
    sizes = [held // stretches + (k < held % stretches) for k in range(stretches)]
    part = count / stretches
    starts = [min(max(round(part * (k + 0.5) - size / 2), 0), count - size) for k, size in enumerate(sizes)]
    for start, size in zip(starts, sizes, strict=True):
        role[start:start + size] = 1
    for start, size in zip(starts, sizes, strict=True):
        around = np.r_[max(start - gap, 0):start, start + size:min(start + size + gap, count)]
        role[around[role[around] == 0]] = 2
    return Split(np.flatnonzero(role == 0), np.flatnonzero(role == 1), np.flatnonzero(role == 2))
