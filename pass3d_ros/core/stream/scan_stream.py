"""One sensor stream's state, held across its scans: the one object both nodes and every offline tool hold.

What a stream's input needs is a property of its sensor, learned from its first scans and then held: the laser lines
and the order of its ring field (pass3d_ros.core.stream.lines), the sensor's height and tilt above the ground
(pass3d_ros.core.stage1.mounting: stage1.sensor_height auto runs on the held height), the full scale of its intensities
(pass3d_ros.core.stream.intensity_scale), the map of its intensities onto stage 2's training scale
(pass3d_ros.core.stream.intensity_match) and, with stage1.min_range auto, the reach of the vehicle's own returns
(pass3d_ros.core.self_returns). `ScanStream.prepare` applies the input checks every path applies
(coordinates a LiDAR could return, intensities read as 0..1, a ring field within the sensor's lasers), so a scan is
treated the same live and offline; what it repaired comes back as notes for the caller to log.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

import numpy as np

from pass3d_ros.core import scan_checks
from pass3d_ros.core.stage1 import Stage1Config, Stage1Result
from pass3d_ros.core.stage1.config import AUTO
from pass3d_ros.core.stage1.lasers import ring_limit
from pass3d_ros.core.stage1.mounting import level_rotation, problems
from pass3d_ros.core.stream.body import BodyHolder
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stream.intensity_match import StreamIntensityMatch
from pass3d_ros.core.stream.intensity_scale import FRAMES_TO_RAISE, StreamIntensityScale
from pass3d_ros.core.stream.lines import LineHolder
from pass3d_ros.core.stream.mounting import MountingHolder

_NO_STREAM = object()  # the key before the first scan: every real key differs from it


@dataclass(frozen=True)
class Note:
    """Something a scan's checks repaired or found odd: `topic` (x/y/z, intensity-scale, intensity-constant, ring)
    groups a caller's throttle;
    `throttle` is False for a change a throttle must not hide (the stream's intensity scale changed)."""

    topic: str
    text: str
    throttle: bool = True


@dataclass
class PreparedScan:
    """A scan after the input checks: what stage 1 reads, and what a node publishes as it came."""

    points: np.ndarray  # (M, 4) float32: coordinates a LiDAR could return, intensities in 0..1
    ring: np.ndarray | None  # the ring field of those points when stage 1 may read it, else None
    field: np.ndarray | None  # the driver's ring field of those points, as it came (None: none)
    kept: np.ndarray | None  # positions in the input of the points kept (None: all of them)
    notes: list[Note] = field(default_factory=list)


class ScanStream:
    """The state of one sensor stream. `clock`: seconds (`time.monotonic` live; None offline, where each scan counts
    as one revolution); `intensity_match`: map intensities onto stage 2's training scale (`on_training_scale`).
    `follow(key)` starts over when the stream changes (another dataset, another sensor)."""

    def __init__(self, clock: Callable[[], float] | None = None, intensity_match: bool = INTENSITY_MATCH) -> None:
        self.lines = LineHolder(clock)
        self.mounting = MountingHolder()
        self.body = BodyHolder(clock)
        self.scale = StreamIntensityScale()
        self.match = StreamIntensityMatch()
        self.intensity_match = intensity_match
        self._key: Hashable = _NO_STREAM
        self._noted: set[str] = set()
        self.maps: dict[str, str] = {}  # the intensity map each stream key got (str of the key), for reports
        self.mountings: dict[str, dict] = {}  # the mounting estimate of each stream key (MountingHolder.report)

    def reset(self) -> None:
        """Forget everything learned: the next scan is the stream's first."""
        self.lines.reset()
        self.mounting.reset()
        self.body.reset()
        self.restart_scale()
        self.match.reset()
        self._noted.clear()

    def restart_scale(self) -> None:
        """Forget the intensities' full scale (the caller's intensity_scale changed): the next scans read it afresh."""
        self.scale = StreamIntensityScale()

    def follow(self, key: Hashable) -> None:
        """The next scan belongs to stream `key` (a dataset spec): a new key starts over."""
        if key != self._key:
            self._key = key
            self.reset()

    def prepare(self, points: np.ndarray, ring: np.ndarray | None = None, config: Stage1Config | None = None, *,
                intensity_scale: float = 1.0, use_ring: bool = True) -> PreparedScan:
        """The input checks on one N x 4 float32 scan (never changed: a repaired scan is a copy): points with non-finite
        or absurd coordinates left out, and no-returns (at (0, 0, 0) or nearer than `config.min_range`, with auto the
        body radius the stream holds), intensities
        times `intensity_scale` and then divided by the stream's full scale, and a ring field with values past
        `config`'s lasers (or with `use_ring` False) not read."""
        points = np.asarray(points)
        if points.ndim != 2 or points.shape[1] < 4:  # the checks read column 3 unchecked (a compiled kernel)
            raise ValueError(f"points must be N x 4 (x, y, z, intensity), got shape {points.shape}")
        # The kernels are compiled (warm_up) for contiguous, writeable float32 points and ring fields: a read-only
        # (np.frombuffer, a memory map), strided or float64 scan compiled them again on first use (28 s for a
        # read-only one); such a scan is copied, a conforming one passes as it is.
        points = np.require(points, np.float32, ("C_CONTIGUOUS", "WRITEABLE"))
        if ring is not None:
            ring = np.require(ring, None, ("C_CONTIGUOUS", "WRITEABLE"))
            if ring.shape != (len(points),):  # a short one was cut silently by the points the checks keep
                raise ValueError(f"ring field has shape {ring.shape} for {len(points)} points")
        notes: list[Note] = []
        kept = None
        config = config or Stage1Config()
        min_range = self.min_range(config)
        summary = scan_checks.scan_summary(points, min_range)
        if not summary.plausible or summary.no_returns:
            keep = scan_checks.plausible_points(points)
            if not summary.plausible:
                notes.append(Note("x/y/z", scan_checks.dropped_points_warning(int(np.count_nonzero(~keep)))))
            keep &= scan_checks.returns(points, min_range)  # no-returns: a driver's convention, not noted
            kept = np.flatnonzero(keep)
            points = np.ascontiguousarray(points[kept])
            ring = None if ring is None else ring[kept]
            summary = scan_checks.scan_summary(points)
        scan = PreparedScan(points, ring if use_ring else None, ring, kept, notes)
        if len(points) == 0:
            return scan
        scan.points, summary = self._unit_intensity(points, summary, intensity_scale, notes)
        points = scan.points
        if summary.constant_intensity():
            notes.append(Note("intensity-constant", f"intensity: every point reads {float(points[0, 3]):g}; stage 2 "
                                                    "will have no intensity information (does the driver or conversion "
                                                    "drop it?)"))
        lasers = ring_limit(config.sensor, config.n_rings)
        if scan.ring is not None and int(scan.ring.max()) >= lasers:
            notes.append(Note("ring", f"ring: values up to {int(scan.ring.max())}, expected 0..{lasers - 1} "
                                      f"(stage1.sensor {config.sensor}); rings recovered from the points for this "
                                      "frame"))
            scan.ring = None
        return scan

    def min_range(self, config: Stage1Config) -> float:
        """The range nearer than which returns are left out: `config.min_range`, or with auto the body radius the
        stream holds (0 until it is read)."""
        return self.body.radius_m if config.min_range == AUTO else float(config.min_range)

    def _unit_intensity(self, points: np.ndarray, summary: scan_checks.ScanSummary, scale: float,
                        notes: list[Note]) -> tuple[np.ndarray, scan_checks.ScanSummary]:
        """The scan with its intensities in 0..1 (`scale`, then the stream's held full scale: a corrupt scan changes
        no later scan's; a copy when anything changes) and its summary after it."""
        if scale != 1.0:
            points = points.copy()
            points[:, 3] *= scale
            summary = summary.scaled(scale)
        problem = summary.intensity_problem()
        reading = self.scale.read(points[:, 3], in_unit_range=not problem)
        advice = "a 0..255 driver wants intensity_scale 1/255, 16-bit reflectivity 1/65535"
        if reading.implausible:
            text = (f"intensity: a corrupt scan ({reading.implausible}): divided by the stream's full scale "
                    f"{reading.divisor:g}, non-finite values read 0; it does not change the scale of later scans")
            notes.append(Note("intensity-scale", text))
        elif reading.change is not None and (reading.change.old is not None or reading.change.new != 1.0):
            text = (f"intensity: {problem or 'values within 0..1'} after intensity_scale {scale:g}, expected 0..1; "
                    f"this stream is divided by {reading.change.new:g} from now on ({reading.change}; {advice})")
            notes.append(Note("intensity-scale", text, throttle=False))
        elif reading.provisional and problem:
            text = (f"intensity: {problem} after intensity_scale {scale:g}, expected 0..1; divided by "
                    f"{reading.divisor:g}, this scan's full scale, until {FRAMES_TO_RAISE} scans in a row agree on the "
                    f"stream's ({advice})")
            notes.append(Note("intensity-scale", text))
        if not problem and reading.divisor == 1.0:
            return points, summary
        points = points.copy() if scale == 1.0 else points
        points[:, 3] = scan_checks.unit_intensity(points[:, 3], reading.divisor)
        return points, scan_checks.scan_summary(points)

    def propose(self, scan: PreparedScan, config: Stage1Config | None = None) -> Stage1Result:
        """Stage 1 on a prepared scan, with the stream's held laser lines and ring-field order, levelled by the
        stream's mounting (given, or read from its first scans: `mounting`), its height bounding the seeds with
        sensor_height auto; with min_range auto the vehicle's own returns are read until their reach is held
        (`body`). Per-point results are in the scan's order; boxes and planes in the level frame
        (`Stage1Result.level`)."""
        config = config or Stage1Config()
        _, level = self.mounting.observe(scan.points, config)
        result = self.lines.propose(scan.points, scan.ring, self.mounting.config_for(config), level=level)
        report = self.mounting.report()
        if report is not None:
            self.mountings[str(self._key)] = report
        if config.min_range == AUTO:  # a no-op once the reading is held
            self.body.observe(scan.points, result.ground)
        return result

    def on_training_scale(self, points: np.ndarray) -> np.ndarray:
        """`points` with intensities mapped onto stage 2's training scale (the map is fitted on the stream's first
        scans, then held); the same array when matching is off or changes nothing."""
        if not self.intensity_match:
            return points
        mapped, _ = self.match.fold(points)
        if self.match.map is not None:
            self.maps[str(self._key)] = str(self.match.map)
        return mapped

    def first_notes(self, notes: list[Note]) -> list[Note]:
        """The notes on topics this stream has not noted yet: what an offline tool prints once a stream."""
        fresh = [note for note in notes if note.topic not in self._noted]
        self._noted.update(note.topic for note in notes)
        return fresh

    def mounting_notes(self, config: Stage1Config) -> list[Note]:
        """Once the mounting is held: what it is when the scans are levelled, and what is wrong or unsure about it
        (pass3d_ros.core.stage1.mounting.problems, MountingHolder.unsure); each its own topic."""
        held = self.mounting.held
        if held is None:
            return []
        notes = [Note("mounting-levelled", f"mounting: {held}; the scans are levelled before stage 1")] \
            if level_rotation(held) is not None else []
        notes += [Note(f"mounting-{k}", f"mounting: {text}")
                  for k, text in enumerate(problems(config, held) + self.mounting.unsure())]
        return notes
