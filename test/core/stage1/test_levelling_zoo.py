"""Stage 1 on sensors as robots mount them: simulated scans (the lasers cast from the tilted, high or upside-down
sensor, points in its own frame) are levelled by the mounting read from their first scan, and stage 1 finds the
road users it finds on the level mount (stage-1 foreground recall within 0.05)."""

from __future__ import annotations

import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers synthetic:)
from pass3d_ros.core.metrics import Stage1Metrics
from pass3d_ros.core.pipeline import ScanPipeline
from pass3d_ros.data.spec import open_dataset

SENSORS = ("vlp16", "hdl32e", "os1-64", "pandarxt32")
MOUNTS = ("pitch=10", "roll=10", "pitch=-7,roll=4", "height=3.5", "roll=180")


def recall(spec: str) -> float:
    """Stage-1 foreground recall of one stream through the door (stage 1 only)."""
    pipeline = ScanPipeline(intensity_match=False)
    metrics = Stage1Metrics()
    for frame in open_dataset(spec):
        proposed = pipeline.propose(frame.points, frame.ring)
        metrics.update_result(frame.name, proposed.result, proposed.kept_values(frame.labels))
    return metrics.summary()["stage1"]["foreground_recall"]


KNOWN_SHORT = {("vlp16", "height=3.5"): "a VLP-16 3.5 m up meets the road 13 m out and crosses near road users with "
                                        "few lasers: 0.89 against 0.97 level (docs/experiments/sensors.md)"}
CASES = [pytest.param(sensor, mount, marks=pytest.mark.xfail(strict=True, reason=KNOWN_SHORT[sensor, mount]))
         if (sensor, mount) in KNOWN_SHORT else (sensor, mount) for sensor in SENSORS for mount in MOUNTS]


@pytest.fixture(scope="module")
def level() -> dict[str, float]:
    return {sensor: recall(f"synthetic:frames=1,seed=97,sensor={sensor}") for sensor in SENSORS}


def test_the_level_mounts_find_the_road_users(level: dict[str, float]) -> None:
    assert min(level.values()) > 0.9, level


@pytest.mark.parametrize(("sensor", "mount"), CASES)
def test_tilted_high_and_upside_down_mounts_find_what_the_level_one_finds(
        sensor: str, mount: str, level: dict[str, float]) -> None:
    assert recall(f"synthetic:frames=1,seed=97,sensor={sensor},{mount}") >= level[sensor] - 0.05
