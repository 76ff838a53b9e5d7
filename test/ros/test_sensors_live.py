"""A simulated drive of every supported LiDAR through both live nodes (shipped weights): each frame comes back
labeled, point for point, whatever the sensor's ring count and its driver's point order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.classes import FOREGROUND
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.evaluation.live import run_live
from pass3d_ros.synthetic.sensor import SENSOR_NAMES

pytestmark = pytest.mark.ros


def test_every_sensor_is_labeled_live(tmp_path: Path) -> None:
    specs = [f"synthetic:sensor={name},frames=1,seed=3" for name in SENSOR_NAMES]
    bag = tmp_path / "sensors"
    stats = convert(specs, bag, with_labels=True, progress=False, log=lambda _: None)
    assert stats.frames == len(SENSOR_NAMES)
    result = run_live(bag, lockstep=True, timeout_s=120.0, log_level="warn")
    assert result.frames_in == result.frames_out == len(SENSOR_NAMES), result.node_counters
    assert result.mismatched == 0 and result.timeouts == 0
    foreground = 0
    for frame in result.frames:
        assert frame.predicted is not None and len(frame.predicted) == frame.points == len(frame.truth)
        foreground += int(np.isin(frame.predicted, FOREGROUND).sum())
    truth = sum(int(np.isin(f.truth, FOREGROUND).sum()) for f in result.frames)
    assert truth > 0 and foreground > 0.5 * truth, (foreground, truth)
