"""`synthetic:` dataset specs: `frames=N,seed=S[,...]` (independent scans, pass3d_ros.synthetic.dataset) and
`drive=N,seed=S[,...]` (one street seen over a drive, pass3d_ros.synthetic.drive), parsed once and read as frames."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import DatasetError
from pass3d_ros.synthetic.dataset import (
    DEFAULT_SENSOR,
    HEIGHT_RANGE_M,
    MOUNT_ANGLE_RANGE_DEG,
    generate_frame,
    unknown_changes,
)
from pass3d_ros.synthetic.drive import drive_scan, plan_drive
from pass3d_ros.synthetic.motion import MAX_DRIVE_SCANS
from pass3d_ros.synthetic.sensor import SENSOR_NAMES, LidarModel, sensor_model


def _number_in(text: str, key: str, value: str, bounds: tuple[float, float], unit: str) -> float:
    """A spec item's number within `bounds`; DatasetError naming the spec, the key and the bounds otherwise."""
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not bounds[0] <= number <= bounds[1]:
        raise DatasetError(f"synthetic spec {text!r}: {key} must be a number of {unit} in "
                           f"{bounds[0]:g}..{bounds[1]:g}, got {value.strip()!r}")
    return number


def parse_synthetic_spec(text: str) -> dict[str, Any]:
    """`frames=N,seed=S[,start=K][,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG][,without=CHANGE+CHANGE]` ->
    {'frames': N, 'seed': S, 'start': K, 'sensor': NAME, 'height': H or None, 'roll': DEG, 'pitch': DEG,
    'without': frozenset}; DatasetError on anything else (sensor defaults to hdl64e, KITTI's; height to the model's
    mount, HEIGHT_RANGE_M; roll and pitch to 0, each within MOUNT_ANGLE_RANGE_DEG; `without` names WORLD_CHANGES to
    leave out, for an ablation).

    A drive, `drive=N,seed=S[,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG]` (N scans of one street,
    1..MAX_DRIVE_SCANS, see `synthetic.drive`), gives the same keys with 'frames': N and 'drive': N added; it takes
    no frames, start or without."""
    values: dict[str, Any] = {"frames": 10, "seed": 0, "start": 0}
    given: set[str] = set()
    sensor = "hdl64e"
    height: float | None = None
    angles = {"roll": 0.0, "pitch": 0.0}
    without: frozenset[str] = frozenset()
    named: set[str] = set()
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = item.partition("=")
        key = key.strip()
        if sep and key in named:  # the last would silently win
            raise DatasetError(f"synthetic spec {text!r}: {key}= given twice")
        named.add(key)
        if sep and key in angles:
            angles[key] = _number_in(text, key, value, MOUNT_ANGLE_RANGE_DEG, "degrees") + 0.0  # -0.0 -> 0.0
            continue
        if sep and key == "height":
            height = _number_in(text, key, value, HEIGHT_RANGE_M, "metres")
            continue
        if sep and key == "sensor":
            sensor = value.strip().lower()
            if sensor not in SENSOR_NAMES:
                raise DatasetError(f"synthetic spec {text!r}: unknown sensor {value.strip()!r}, "
                                   f"known: {', '.join(SENSOR_NAMES)}")
            continue
        if sep and key == "without":
            given.add(key)
            without = frozenset(filter(None, (name.strip() for name in value.split("+"))))
            problem = unknown_changes(without)
            if problem:
                raise DatasetError(f"synthetic spec {text!r}, without=: {problem}")
            continue
        if sep and key == "drive":
            key = "frames"
            given.add("drive")
        elif sep:
            given.add(key)
        if not sep or key not in values:
            raise DatasetError(f"synthetic spec {text!r}: expected frames=N,seed=S[,start=K][,sensor=NAME]"
                               f"[,height=H][,roll=DEG][,pitch=DEG][,without=CHANGE+CHANGE] or drive=N,seed=S"
                               f"[,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG], got {item!r}")
        try:
            values[key] = int(value)
        except ValueError as exc:
            name = "drive" if key == "frames" and "drive" in given else key
            raise DatasetError(f"synthetic spec {text!r}: {name} must be an integer, got {value.strip()!r}") from exc
    negative = [key for key, number in values.items() if number < 0 and not (key == "frames" and "drive" in given)]
    if negative:  # a drive's count is checked below, against its range
        raise DatasetError(f"synthetic spec {text!r}: {' and '.join(negative)} must not be negative, got "
                           f"{', '.join(str(values[key]) for key in negative)}")
    if "drive" in given:
        mixed = sorted(given & {"frames", "start", "without"})
        if mixed:
            raise DatasetError(f"synthetic spec {text!r}: a drive takes no {', '.join(mixed)} "
                               f"(drive=N,seed=S[,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG])")
        if not 1 <= values["frames"] <= MAX_DRIVE_SCANS:
            raise DatasetError(f"synthetic spec {text!r}: drive must be 1..{MAX_DRIVE_SCANS} scans, "
                               f"got {values['frames']}")
    values["sensor"] = sensor
    values["height"] = height
    values.update(angles)
    values["without"] = without
    if "drive" in given:
        values["drive"] = values["frames"]
    return values


def _spec_sensor(spec: dict[str, Any]) -> LidarModel:
    overrides: dict[str, float] = {}
    if spec["height"] is not None:
        overrides["mount_height_m"] = spec["height"]
    if spec.get("roll", 0.0):
        overrides["mount_roll_deg"] = spec["roll"]
    if spec.get("pitch", 0.0):
        overrides["mount_pitch_deg"] = spec["pitch"]
    if overrides:
        return sensor_model(str(spec["sensor"]), **overrides)
    return DEFAULT_SENSOR if spec["sensor"] == "hdl64e" else sensor_model(str(spec["sensor"]))


def read_synthetic(path: str) -> Iterator[Frame]:
    """Frames of the spec `synthetic:frames=N,seed=S[,start=K][,sensor=NAME][,height=H][,roll=DEG][,pitch=DEG]
    [,without=...]`, or the scans of `synthetic:drive=N,seed=S[,sensor=...]` (`synthetic.drive`), generated as they
    are read (boxes in the level frame, see the module's notes)."""
    spec = parse_synthetic_spec(path)
    sensor = _spec_sensor(spec)
    if "drive" in spec:
        return _drive_scans(spec, sensor, None)  # type: ignore[return-value]

    def frames() -> Iterator[Frame]:
        for index in range(spec["start"], spec["start"] + spec["frames"]):
            yield generate_frame(spec["seed"], index, sensor, spec["without"])

    return frames()


def _drive_scans(spec: dict[str, Any], sensor: LidarModel,
                 keep: Callable[[int], bool] | None) -> Iterator[Frame | None]:
    """A drive's scans (None where `keep` refuses one), the drive planned when the first is asked for."""

    drive = plan_drive(spec["seed"], spec["drive"], sensor)
    for k in range(spec["drive"]):
        yield drive_scan(drive, k) if keep is None or keep(k) else None


def read_shard(path: str, keep: Callable[[int], bool]) -> Iterator[Frame | None]:
    """`read_synthetic`, but only the frames whose position k in the spec passes `keep` are generated; the
    others are None (see `pass3d_ros.data.spec.open_datasets_shard`)."""
    spec = parse_synthetic_spec(path)
    sensor = _spec_sensor(spec)
    if "drive" in spec:
        yield from _drive_scans(spec, sensor, keep)
        return
    for k in range(spec["frames"]):
        yield generate_frame(spec["seed"], spec["start"] + k, sensor, spec["without"]) if keep(k) else None


def count_frames(path: str) -> int:
    """Number of frames a synthetic spec yields."""
    return parse_synthetic_spec(path)["frames"]
