"""Realism scorecard on the real KITTI development frames: the generator must stay inside every tolerance.

Run it alone with `pytest test/synthetic/test_realism.py` (it carries the `kitti` marker and is skipped with a message
when the real frames are absent). A failure prints the whole scorecard; the tolerances are the generator's targets
(pass3d_ros/synthetic/realism.py says why each one) and are not to be widened to make a generator pass.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.synthetic.realism import (
    Row,
    default_unlabeled_specs,
    format_scorecard,
    scorecard,
    shape_shares,
    synthetic_frames,
)

SYNTHETIC_FRAMES = 16  # enough for ~150 car and ~25 pedestrian boxes; about 30 s on two cores with the real side
SEED = 0


def _real_specs(root: Path) -> list[str]:
    specs = [f"kitti_object:{root / 'object' / 'training'}",
             f"semantickitti:{root / 'semantickitti' / 'sequences' / '00'}"]
    sibling = root.parent / "kitti_unlabeled"
    return specs + ([f"semantickitti:{sibling}"] if (sibling / "velodyne").is_dir() else default_unlabeled_specs())


def _miss(row: Row) -> str:
    diff = row.synthetic - row.real
    scale = (100.0, " pts") if row.unit == "%" else (1.0, f" {row.unit}")
    rel = f", x{row.synthetic / row.real:.2f}" if row.real else ""
    return f"{row.name}: synthetic - real = {diff * scale[0]:+.2f}{scale[1]}{rel} (tolerance {row.tolerance})"


# Rows measured outside tolerance and not fixed yet: since the local ground (Stage1Config.local_ground) stage 1 keeps
# more far, sparse real proposals (real median points per ring 10.1 -> 7.9, low wide ones 17.5 % -> 18.1 %) that the
# synthetic world lacks. The test fails when one of them comes back inside, so the list stays true.
KNOWN_MISSES = (
    "proposal points per ring median",
    # since rerun_dropped is on (rule R3, docs/experiments/sensors.md): its person-shaped parts of dropped clusters are
    # more common in the real scans (synthetic 13.8 % of proposals, real 20.0 %: 0.2 points outside the 6)
    "proposals car-piece-like (length 0.7-2.5 m, height 1.1-2 m)",
)  # "proposals low wide" met since the scorecard's scans go through the door (input checks, levelling from 3 deg)


@pytest.mark.slow
def test_realism_scorecard_within_tolerances(kitti_dev: Path) -> None:
    rows = scorecard(synthetic_frames(SYNTHETIC_FRAMES, SEED), _real_specs(kitti_dev))
    judged = [r for r in rows if r.passed is not None]
    assert len(judged) >= len(rows) - 3, "the real reference should judge nearly every row\n" + format_scorecard(rows)
    failed = [r for r in rows if r.passed is False and r.name not in KNOWN_MISSES]
    assert not failed, "outside tolerance:\n" + "\n".join(_miss(r) for r in failed) + "\n\n" + format_scorecard(rows)
    still = {r.name for r in rows if r.passed is False} & set(KNOWN_MISSES)
    assert still == set(KNOWN_MISSES), f"no longer missed (take them off KNOWN_MISSES): {set(KNOWN_MISSES) - still}"


def test_label_free_proposal_shape_classes() -> None:
    """The shape rows' classes: a car piece, a barrier, a pole, a whole car; bottoms and points per ring."""
    shapes = np.array([  # length, width, height, points per ring, bottom above local ground, range
        [1.5, 1.0, 1.3, 8.0, 0.6, 12.0],  # a car piece seen above something
        [4.0, 0.9, 0.8, 20.0, 0.25, 9.0],  # a barrier / planter
        [0.3, 0.25, 1.8, 3.0, 0.2, 15.0],  # a pole
        [4.2, 1.7, 1.2, 30.0, np.nan, 20.0],  # a whole car, no ground seen around it
    ])
    got = shape_shares(shapes)
    assert (got["piece"], got["low_wide"], got["thin_tall"]) == (0.25, 0.25, 0.25)
    assert got["bottom"] == 0.25 and abs(got["raised"] - 1 / 3) < 1e-12 and got["per_ring"] == 14.0
