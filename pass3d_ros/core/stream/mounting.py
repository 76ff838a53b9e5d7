"""The mounting a stream holds: readings of its first scans (pass3d_ros.core.stage1.mounting.scan_mounting), then the
median of MOUNTING_SCANS of them, held; with sensor_height auto the held height bounds the ground seeds."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np

from pass3d_ros.core.stage1.config import AUTO, AUTO_START_HEIGHT_M, Stage1Config
from pass3d_ros.core.stage1.mounting import (
    _HEIGHT_RANGE,
    MOUNTING_SCANS,
    SEED_DEADBAND_M,
    Mounting,
    median_mounting,
    scan_mounting,
)


class MountingHolder:
    """The mounting of one stream: readings of its first scans, then the median of MOUNTING_SCANS of them, held.
    `reset()` starts over (a new stream); a changed stage-1 config keeps it (the mount did not move)."""

    def __init__(self, scans: int = MOUNTING_SCANS) -> None:
        self.scans = scans
        self._lock = threading.Lock()  # the node's diagnostics read while its worker updates
        self._readings: list[Mounting] = []
        self.held: Mounting | None = None
        self._cached: tuple[Stage1Config, Mounting, Stage1Config] | None = None

    def reset(self) -> None:
        """Forget the readings and the held mounting."""
        with self._lock:
            self._readings = []
            self.held = None
            self._cached = None

    @property
    def readings(self) -> int:
        """Scans that gave a reading so far (at most `scans`)."""
        return len(self._readings)

    @property
    def estimate(self) -> Mounting | None:
        """The held mounting, or the median of the readings so far (None: none yet)."""
        with self._lock:
            readings = list(self._readings)
        return self.held or (median_mounting(readings) if readings else None)

    def config_for(self, config: Stage1Config) -> Stage1Config:
        """`config` as the next scan runs it: with sensor_height auto and a mounting held more than SEED_DEADBAND_M from
        AUTO_START_HEIGHT_M, sensor_height is the held height (the same object while neither changes); otherwise
        `config` itself."""
        held = self.held
        if config.sensor_height != AUTO or held is None or abs(held.height_m - AUTO_START_HEIGHT_M) <= SEED_DEADBAND_M:
            return config
        cached = self._cached
        if cached is not None and cached[0] is config and cached[1] is held:
            return cached[2]
        effective = replace(config, sensor_height=float(np.clip(held.height_m, *_HEIGHT_RANGE)))
        self._cached = (config, held, effective)
        return effective

    def update(self, points: np.ndarray, ground: np.ndarray, planes: np.ndarray, config: Stage1Config) -> bool:
        """Take one scan's reading (its points, `Stage1Result.ground` and `.ground_planes`) while none is held; True
        when this scan's reading made the mounting held."""
        if self.held is not None:
            return False
        reading = scan_mounting(points, ground, planes, config)
        if reading is None:
            return False
        with self._lock:
            self._readings.append(reading)
            if len(self._readings) < self.scans:
                return False
            self.held = median_mounting(self._readings)
        return True

    def report(self) -> dict[str, float | bool | int] | None:
        """The estimate as plain values for reports (`held`, `scans`), None without one."""
        estimate = self.estimate
        if estimate is None:
            return None
        return {**estimate.to_dict(), "held": self.held is not None, "scans": self.readings}
