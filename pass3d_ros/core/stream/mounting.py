"""The mounting a stream runs with: `stage1.mount` when given, else readings of its first scans
(pass3d_ros.core.stage1.mounting.read_mounting, made before stage 1 runs), their median held after MOUNTING_SCANS of
them. Until it is held each scan runs with the median so far, so a clearly tilted, upside-down or high sensor is
levelled from its first scan. With sensor_height auto the mounting's height bounds the ground seeds (`config_for`)."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np

from pass3d_ros.core.stage1.config import AUTO, AUTO_START_HEIGHT_M, Stage1Config
from pass3d_ros.core.stage1.mounting import (
    _HEIGHT_RANGE,
    MAX_HEIGHT_M,
    MOUNTING_SCANS,
    NO_GROUND_SCANS,
    SEED_DEADBAND_M,
    SPREAD_WARN_DEG,
    Mounting,
    level_rotation,
    median_mounting,
    parse_mount,
    read_mounting,
    spread_deg,
)


class MountingHolder:
    """The mounting of one stream. `reset()` starts over (a new stream); a changed stage-1 config keeps what was read
    (the mount did not move)."""

    def __init__(self, scans: int = MOUNTING_SCANS) -> None:
        self.scans = scans
        self._lock = threading.Lock()  # the node's diagnostics read while its worker updates
        self._readings: list[Mounting] = []
        self._observed = 0  # scans offered for a reading
        self.held: Mounting | None = None
        self._given: tuple[str, Mounting | None] = (AUTO, None)  # stage1.mount as last parsed
        self._cached: tuple[Stage1Config, Mounting, Stage1Config] | None = None

    def reset(self) -> None:
        """Forget the readings and the held mounting."""
        with self._lock:
            self._readings = []
            self._observed = 0
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

    def given(self, config: Stage1Config) -> Mounting | None:
        """`config.mount` read (None: auto)."""
        if self._given[0] != config.mount:
            self._given = (config.mount, parse_mount(config.mount))
        return self._given[1]

    def observe(self, points: np.ndarray, config: Stage1Config) -> tuple[Mounting | None, np.ndarray | None]:
        """The mounting the scan `points` runs with and the rotation that levels it (None: run as it comes): the given
        mount, else the held one, else this scan's reading folded into the estimate."""
        given = self.given(config)
        if given is not None:
            return given, level_rotation(given, given=True)
        if self.held is None:
            self._observed += 1
            reading = read_mounting(points)
            if reading is not None:
                with self._lock:
                    self._readings.append(reading)
                    if len(self._readings) >= self.scans:
                        self.held = median_mounting(self._readings)
        mounting = self.estimate
        return mounting, level_rotation(mounting, held=self.held is not None)

    def unsure(self) -> list[str]:
        """Why the mounting read is not to be trusted, if it is not: readings more than SPREAD_WARN_DEG apart (a
        changing road, a loose mount), or no ground read in NO_GROUND_SCANS scans (the mount is higher than
        MAX_HEIGHT_M, the sensor sees no road, or sits indoors)."""
        with self._lock:
            readings, held, observed = list(self._readings), self.held, self._observed
        spread = 0.0 if held is None else spread_deg(readings, held)
        if spread > SPREAD_WARN_DEG:
            return [f"mounting readings of the first {len(readings)} scans disagree by up to {spread:.1f} deg (a "
                    "changing road or a loose mount): the median is held; set stage1.mount if it is known"]
        if not readings and observed >= NO_GROUND_SCANS:
            return [f"no ground read in {observed} scans (a mount over {MAX_HEIGHT_M:g} m, a sensor that sees no "
                    "road, or indoors): the scans run as they come; set stage1.mount"]
        return []

    def config_for(self, config: Stage1Config) -> Stage1Config:
        """`config` as the next scan runs it: with sensor_height auto and a mounting (given, held, or estimated so far)
        more than SEED_DEADBAND_M from AUTO_START_HEIGHT_M, sensor_height is its height (the same object while
        neither changes); otherwise `config` itself."""
        mounting = self.given(config) or self.estimate
        if config.sensor_height != AUTO or mounting is None \
                or abs(mounting.height_m - AUTO_START_HEIGHT_M) <= SEED_DEADBAND_M:
            return config
        cached = self._cached
        if cached is not None and cached[0] is config and cached[1] == mounting:
            return cached[2]
        effective = replace(config, sensor_height=float(np.clip(mounting.height_m, *_HEIGHT_RANGE)))
        self._cached = (config, mounting, effective)
        return effective

    def report(self) -> dict[str, float | bool | int] | None:
        """The estimate as plain values for reports (`held`, `scans`), None without one."""
        estimate = self.estimate
        if estimate is None:
            return None
        return {**estimate.to_dict(), "held": self.held is not None, "scans": self.readings}
