"""Stage 1 parameters in one dataclass: the single place where each default, description and allowed range is
written. Each step of stage 1 (ring, ground, scanline, refinement) reads its values from it, and the ROS layer
declares one parameter per field.
"""

from __future__ import annotations

import ast
import difflib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from pass3d_ros.core.stage1.lasers import SENSORS
from pass3d_ros.msgs.errors import UserError


class ConfigError(UserError):
    """A parameter or option value the user gave is invalid (out of range, unknown, malformed); the message names it."""


def _is_number(value: Any) -> bool:
    """A real number that is not a bool (True is an int to Python, never a length to us)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


# annotation -> (check, what the message says the value must be)
_TYPE_CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "int": (_is_int, "an integer"),
    "float": (_is_number, "a number"),
    "bool": (lambda v: isinstance(v, (bool, np.bool_)), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
}


_NORMAL_TYPES: dict[str, type] = {"int": int, "float": float, "bool": bool}  # numpy scalars become Python's


def closest(name: str, known: Iterable[str]) -> str | None:
    """The known name nearest a misspelt one (difflib), or None when none is close."""
    match = difflib.get_close_matches(name, list(known), n=1)
    return match[0] if match else None


def refuse_problems(config: str, problems: list[str]) -> None:
    """ConfigError naming every problem found in `config` (a config class's name), if there is any."""
    if problems:
        raise ConfigError(f"{config}: " + "; ".join(problems))


def refuse_unknown(config: str, values: Iterable[str], known: Iterable[str]) -> None:
    """ConfigError naming each key of `values` that is no `known` field of `config` (a config class's name), with
    the nearest known name: a misspelt parameter is an error, not silently ignored."""
    known = set(known)
    unknown = sorted(set(values) - known)
    if unknown:
        named = [name + (f" (did you mean {near}?)" if (near := closest(name, known)) else "") for name in unknown]
        raise ConfigError(f"{config}: unknown parameter(s) {', '.join(named)}")


def _param(default: Any, description: str, lo: float, hi: float) -> Any:
    """A config field whose metadata carries its description and allowed closed range (ROS parameters)."""
    return field(default=default, metadata={"description": description, "range": (lo, hi)})


def _auto_param(description: str, lo: float, hi: float, default: Any = None) -> Any:
    """A config field that is either AUTO (learned from the stream's scans) or a number in the closed range; its
    default is AUTO unless given."""
    return field(default=AUTO if default is None else default,
                 metadata={"description": description, "range": (lo, hi), "auto": True})


def _text(default: str, description: str, check: Callable[[str], str]) -> Any:
    """A free-form string config field; `check(value)` says what is wrong with a value ("" when nothing is)."""
    return field(default=default, metadata={"description": description, "range": None, "check": check})


MOUNT_HEIGHT_RANGE_M = (0.1, 10.0)  # a given mount's z (its height above the ground)


def mount_values(text: str) -> tuple[float, ...] | None:
    """`stage1.mount` read: None for auto (read from the scans), else (x, y, z, roll, pitch, yaw) as a URDF's origin
    states the sensor in a frame on the ground under the vehicle (base_footprint): metres and radians, spaces or
    commas. ValueError names what is wrong."""
    if text.strip().lower() == AUTO:
        return None
    parts = [p for p in text.replace(",", " ").split() if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 6 or not all(np.isfinite(values)):
        raise ValueError(f"mount={text!r} must be auto or six numbers: x y z roll pitch yaw (m, rad; URDF's origin)")
    low, high = MOUNT_HEIGHT_RANGE_M
    if not low <= values[2] <= high:
        raise ValueError(f"mount={text!r}: z (the height above the ground) must lie in [{low:g}, {high:g}] m")
    return values


def _mount_problem(text: str) -> str:
    """What is wrong with a `mount` value ("" when nothing is)."""
    try:
        mount_values(text)
    except ValueError as exc:
        return str(exc)
    return ""


def _choice(default: str, description: str, choices: tuple[str, ...]) -> Any:
    """A string config field whose metadata carries its description and allowed values (no range)."""
    return field(default=default, metadata={"description": description, "range": None, "choices": choices})


AUTO = "auto"  # the value of a number-or-auto field (sensor_height, min_range) that the stream learns from its scans
AUTO_START_HEIGHT_M = 1.73  # sensor_height auto: the seed bound's height until the stream holds its mounting (KITTI's
# 1.73 m, the old default: with below_ground_margin 1 m it lets every mount up to 2.73 m seed; see
# pass3d_ros.core.stage1.mounting)


def is_auto_field(f: Any) -> bool:
    """Whether dataclass field `f` takes AUTO or a number (its ROS parameter is dynamically typed)."""
    return bool(f.metadata.get("auto"))


# (lower, upper): parameters whose values must not cross; each pair bounds one quantity from both sides.
ORDERED_PAIRS: tuple[tuple[str, str], ...] = (("min_top", "max_top"), ("th_num_floor", "th_num_near"))


@dataclass
class Stage1Config:
    """Stage 1 parameters (metres, counts). The paper's values: n_seg .. th_prop and the enlargement; the
    rest is what the paper leaves open, chosen on KITTI (see each field's description)."""

    # Ground plane fitting (Zermas et al.; PASS3D's values).
    min_range: float | str = _auto_param(
        "input: returns nearer than this (m; e.g. 0.5 for the vehicle and mount) are left out before stage 1, "
        "as are points at (0, 0, 0), where drivers put a no-return. auto: the vehicle's own returns, read from the "
        "stream's scans while it moves (about 5 s; pass3d_ros.core.self_returns), then held; 0 until read",
        0.0, 10.0, default=0.0,
    )
    n_seg: int = _param(3, "ground: segments along x", 1, 64)
    n_iter: int = _param(3, "ground: plane fits per segment", 1, 20)
    n_lpr: int = _param(20, "ground: lowest points whose mean height (the LPR) sets the seed height", 1, 1000)
    th_seeds: float = _param(0.4, "ground: seeds lie less than this above the LPR (m)", 0.01, 5.0)
    th_dist: float = _param(0.3, "ground: |distance to plane| below this is ground (m, two-sided)", 0.01, 2.0)
    # Scan-line-run clustering (Zermas et al.; PASS3D's values).
    th_ring: float = _param(0.5, "clustering: consecutive ring points closer than this form a run (m)", 0.01, 5.0)
    th_prop: float = _param(1.0, "clustering: a run takes the label of a previous-ring point this close (m)", 0.01, 5.0)
    n_prev_rings: int = _param(2, "clustering: rings searched back when the previous one has no match", 1, 8)
    run_skip: int = _param(
        1, "clustering: a run bridges this many ring points farther away (seen through an arm or a window)", 0, 4
    )
    # Proposal refinement: point count needed, about 30 near the sensor and falling as 1/range.
    th_num_near: float = _param(30.0, "refinement: points a cluster needs up to th_num_range", 1.0, 1e4)
    th_num_range: float = _param(
        20.0, "refinement: beyond this range (m) a cluster needs th_num_near * th_num_range / range points", 0.1, 200.0
    )
    th_num_floor: int = _param(5, "refinement: a cluster never needs fewer points than this", 1, 1000)
    # Size gates: what an (occluded) car, pedestrian or cyclist can look like. A car is up to ~5.5 m long
    # (clutter and mirrors add); cars, riders and pedestrians stay under ~2.2 m, trees do not; occluded objects
    # show only their top, so the bottom may sit well above the ground.
    max_length: float = _param(7.0, "refinement: longest footprint side (m)", 0.1, 100.0)
    max_width: float = _param(3.5, "refinement: longest short footprint side (m)", 0.1, 100.0)
    max_height: float = _param(3.0, "refinement: largest z extent (m)", 0.1, 100.0)
    max_bottom: float = _param(
        1.5, "refinement: lowest point at most this above the ground plane (m; a person behind a car)", -5.0, 10.0
    )
    min_top: float = _param(0.9, "refinement: highest point at least this above the ground plane (m)", -5.0, 10.0)
    max_top: float = _param(2.3, "refinement: highest point at most this above the ground plane (m)", 0.0, 20.0)
    min_extent: float = _param(0.2, "refinement: the larger of length and height reaches this (m)", 0.0, 10.0)
    max_range: float = _param(70.0, "refinement: largest horizontal range of a cluster centre (m)", 1.0, 500.0)
    # Local ground (pass3d_ros.core.stage1.ground): the height gates read heights above the ground around the
    # cluster, not above a segment plane extrapolated tens of metres from the road it was fitted on.
    local_ground: bool = _param(
        True, "refinement: the height gates read heights above the local ground around a cluster (from a coarse grid "
        "of height histograms built once per frame) instead of above the segment plane alone; kept boxes take in "
        "the ground band under them", 0, 1,
    )
    local_ground_radius: float = _param(
        4.0, "refinement: half-width of the square around a cluster that the local ground is read from (m; grows by "
        "5 % of the range)", 0.5, 50.0,
    )
    # Split instead of drop (pass3d_ros.core.stage1.split): cars parked end to end 0.5-1 m apart chain into one cluster.
    split_merged: bool = _param(
        True, "refinement: cut a cluster failing only the footprint gate at the gaps along its long axis, and "
        "gate each part again", 0, 1,
    )
    split_gap: float = _param(
        0.4, "refinement: an empty stretch of the long axis this long between dense surfaces is a gap to cut at (m; "
        "below the 0.5 m between cars parked end to end)", 0.05, 5.0,
    )
    split_rerun: bool = _param(
        True, "refinement: cluster a cluster failing the footprint gate by its width alone (a road user with clutter "
        "close beside it), and not cut at a gap, again by scan-line runs with th_ring and th_prop times rerun_scale, "
        "and gate each part again", 0, 1,
    )
    rerun_scale: float = _param(
        0.5, "refinement: split_rerun's th_ring and th_prop are the clustering's times this", 0.05, 1.0,
    )
    rerun_dropped: bool = _param(
        True, "refinement: split_rerun also clusters again every other dropped cluster of 2 x th_num to "
        "rerun_max_points points within max_range (people in a crowd, beside parked motorbikes, against a hedge), "
        "and keeps each part that passes the gates and is shaped like a person standing there (footprint 2.0 x 1.2 m "
        "at most and 0.1 m deep at least, rising 0.88 m or more, its top within max_top); a part takes no point "
        "another proposal holds, and stage 2 may call its points pedestrian or background only: people in crowds "
        "found on 32-laser sensors (docs/experiments/sensors.md, rules R3 and R4)", 0, 1,
    )
    split_groups: bool = _param(
        True, "refinement: a part of rerun_dropped of a person's height but too big for one person is a group of "
        "people: each head found in it (the highest points, 0.45 m or more apart, nothing as high 0.3-0.45 m around) "
        "takes the points within 0.6 m, and each such part is kept as rerun_dropped's are "
        "(pass3d_ros.core.stage1.crowd; docs/experiments/sensors.md, rules C1 and C4)", 0, 1,
    )
    cut_canopies: bool = _param(
        True, "refinement: a part of rerun_dropped centred within 15 m whose points above max_top form a canopy "
        "(2 m or more across, at most 1 m deep: an awning, a shelter's roof, a covered walkway) loses them before its "
        "gates: people walking under it (pass3d_ros.core.stage1.canopy; docs/experiments/sensors.md, rule C3)", 0, 1,
    )
    rerun_max_points: int = _param(
        3000, "refinement: rerun_dropped leaves larger clusters (buildings, long walls) dropped whole", 1, 10_000_000,
    )
    split_protruding: bool = _param(
        False, "refinement: cut what protrudes below max_top from a dropped thin taller structure (a person against a "
        "mast or a wall) out of it as clusters of their own, and gate each again; off by default: on real KITTI scans "
        "it nearly doubles the proposals (all background) and stage 1's time", 0, 1,
    )
    join_fragments: bool = _param(
        False, "refinement: a dropped low fragment in front of a kept proposal joins it (a car's boot or bonnet cut "
        "off its windows and roof a laser step away; pass3d_ros.core.stage1.fragments); off by default: car IoU "
        "+0.8 / +1.5 on the nuScenes parking lot with / without its ring field and +0.1 to +0.7 on synthetic scans, "
        "but pedestrians -0.1 there without the ring field (docs/experiments/sensors.md, rules J and J2)", 0, 1,
    )
    # Enlargement of kept boxes, added on each side (paper: 0.1, 0.1, 0.4 m).
    enlarge: tuple[float, float, float] = _param(
        (0.1, 0.1, 0.4), "refinement: kept boxes grow by this on each side in x, y, z (m)", 0.0, 5.0
    )
    # Sensor and robustness details the paper leaves open.
    n_rings: int = _param(64, "rings: lasers of the sensor (HDL-64E); ring recovery checks for this many", 1, 256)
    sensor: str = _choice(
        "auto", "rings: laser table when points have no ring field (" + ", ".join(SENSORS) + "); auto: from the scan",
        SENSORS,
    )
    sensor_scaling: bool = _param(
        True, "refinement: scale th_num to the scan's angular resolution (pass3d_ros.core.stage1.sensor_params); the "
        "HDL-64E keeps the paper's values", 0, 1,
    )
    range_scaling: bool = _param(
        True, "refinement: with sensor_scaling and lasers, th_num's vertical factor per range (and azimuth, tilted): "
        "the lasers that cross a person-tall object there, from the sensor's height above the fitted ground, over "
        "KITTI's HDL-64E's, where under half the median-gap factor (a high or tilted mount sees road users with its "
        "sparse lasers; pass3d_ros.core.stage1.sensor_params; on by rule G3, docs/experiments/sensors.md)", 0, 1,
    )
    sensor_height: float | str = _auto_param(
        "ground: sensor height above the road (m; 1.73 on KITTI's car); it bounds the ground seeds from below. auto: "
        "the height above the ground near the sensor, the median over a stream's first 5 scans, then held "
        "(pass3d_ros.core.stage1.mounting; 1.73 until held, and while the estimate is within 0.3 m of it). With a "
        "number the estimate is still made: the cluster node warns when it differs by more than 0.3 m", 0.0, 10.0,
    )
    mount: str = _text(
        AUTO, "the sensor's mounting: auto (read from the stream's ground: height, roll, pitch; upright or upside "
        "down; a scan tilted 2 deg or more is levelled before stage 1), or x y z roll pitch yaw as a URDF's origin "
        "states the sensor above the ground frame (base_footprint; m and rad): z is the height, the scan is levelled "
        "by the rotation. Labels always come back in the input's frame", _mount_problem,
    )
    below_ground_margin: float = _param(1.0, "ground: points lower than sensor_height + this never seed (m)", 0.0, 10.0)
    ground_x_extent: float = _param(80.0, "ground: segments split x in [-extent, extent] evenly (m)", 1.0, 500.0)
    ground_seed_band: float = _param(20.0, "ground: only points with |y| below this seed and fit planes (m)", 0.5, 1e3)
    ground_lpr_outlier_share: float = _param(
        0.05, "ground: 0.1 m height bins holding less than this share of the fullest cannot set the LPR", 0.0, 1.0
    )
    ground_max_step: float = _param(
        0.5, "ground: an outer plane stepping more than this at its inner edge takes its neighbour's (m)", 0.0, 10.0
    )
    ground_max_slope_deg: float = _param(25.0, "ground: a steeper plane is rejected (degrees)", 0.0, 90.0)
    fit_stride: int = _param(
        4, "ground: the LPR and the plane fits read about one point in fit_stride (the final ground test reads all)",
        1, 64,
    )
    ground_thread: bool = _param(
        True, "ground: fit the ground planes on a second thread while rings are recovered, then cluster the upper "
        "rings of a scan there beside the lower ones (the same result)", 0, 1,
    )
    local_ground_as_ground: bool = _param(
        False, "ground: points within th_dist of the local ground (the height gates' surface) are ground too, so a "
        "road the segment planes miss (a tilted sensor, a sloping road) is never clustered (needs local_ground)",
        0, 1,
    )

    def __post_init__(self) -> None:
        refuse_problems("Stage1Config", self._type_problems())
        for f in fields(self):
            if f.type in _NORMAL_TYPES:
                setattr(self, f.name, _NORMAL_TYPES[f.type](getattr(self, f.name)))
            elif is_auto_field(f):
                value = getattr(self, f.name)
                setattr(self, f.name, AUTO if isinstance(value, str) else float(value))
        self.enlarge = tuple(float(v) for v in self.enlarge)
        self.validate()

    def _type_problems(self) -> list[str]:
        """One line per field whose value has the wrong type (an int field given 3.5, a tuple given a number)."""
        problems = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type.startswith("tuple") and not (
                isinstance(value, (tuple, list)) and all(_is_number(v) for v in value)
            ):
                problems.append(f"{f.name}={value!r} must be a list of numbers")
            elif f.type in _TYPE_CHECKS and not _TYPE_CHECKS[f.type][0](value):
                problems.append(f"{f.name}={value!r} must be {_TYPE_CHECKS[f.type][1]}")
            elif is_auto_field(f) and not (_is_number(value) or (isinstance(value, str)
                                                                 and value.strip().lower() == AUTO)):
                lo, hi = f.metadata["range"]
                problems.append(f"{f.name}={value!r} must be {AUTO} or a number in [{lo:g}, {hi:g}]")
        return problems

    def validate(self) -> None:
        """Raise ConfigError naming every parameter of the wrong type, outside its allowed range, or out of order
        with its pair (max_top below min_top)."""
        problems = self._type_problems()
        refuse_problems("Stage1Config", problems)
        if len(self.enlarge) != 3:
            problems.append(f"enlarge needs 3 values (x, y, z), got {len(self.enlarge)}")
        for f in fields(self):
            if "check" in f.metadata:
                problem = f.metadata["check"](getattr(self, f.name))
                if problem:
                    problems.append(problem)
                continue
            if "choices" in f.metadata:
                if getattr(self, f.name) not in f.metadata["choices"]:
                    problems.append(f"{f.name}={getattr(self, f.name)!r} not one of {', '.join(f.metadata['choices'])}")
                continue
            lo, hi = f.metadata["range"]
            values = getattr(self, f.name)
            if is_auto_field(f) and isinstance(values, str):
                continue
            for v in values if isinstance(values, (tuple, list)) else (values,):
                if not lo <= v <= hi:
                    problems.append(f"{f.name}={v:g} outside [{lo:g}, {hi:g}]")
        for low, high in ORDERED_PAIRS:
            if getattr(self, low) > getattr(self, high):
                problems.append(f"{high}={getattr(self, high):g} is below {low}={getattr(self, low):g}")
        refuse_problems("Stage1Config", problems)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> Stage1Config:
        """Config from a dict (YAML, ROS parameters); unknown keys are an error, not silently ignored."""
        refuse_unknown("Stage1Config", values, (f.name for f in fields(cls)))
        return cls(**dict(values))

    @property
    def seed_height(self) -> float:
        """The sensor height the ground seeds are bounded from (m): sensor_height, or AUTO_START_HEIGHT_M while it
        is auto and no stream has put its held estimate in (pass3d_ros.core.stage1.mounting.MountingHolder)."""
        return AUTO_START_HEIGHT_M if self.sensor_height == AUTO else float(self.sensor_height)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of all parameters (for logs and JSON)."""
        return asdict(self)


# ------------------------------------------------------------------------------ KEY=VALUE text (tools' --param)

STAGE1_PREFIX = "stage1."  # the ROS parameters' namespace of these fields; `--param` takes a key with or without it

_TRUE, _FALSE = ("true", "yes", "on"), ("false", "no", "off")


def field_name(key: str) -> str:
    """A Stage1Config field name from a `--param` key: `th_dist` or, as the node names it, `stage1.th_dist`;
    ConfigError naming the nearest known key when there is no such field."""
    key = key.strip()
    name = key[len(STAGE1_PREFIX):] if key.startswith(STAGE1_PREFIX) else key
    known = {f.name: f for f in fields(Stage1Config)}
    if name not in known:
        near = closest(name, known)
        prefix = STAGE1_PREFIX if key.startswith(STAGE1_PREFIX) else ""
        raise ConfigError(f"Stage1Config: unknown parameter(s) {key}"
                          + (f" (did you mean {prefix}{near}?)" if near else ""))
    return name


def parse_value(name: str, text: str) -> Any:
    """The value of Stage1Config's field `name` written as `text` (`parse_field`)."""
    return parse_field(Stage1Config, name, text)


def parse_field(config: type, name: str, text: str) -> Any:
    """The value of field `name` of the dataclass `config` written as `text`, read by the field's type: a number,
    true / false, a string without quotes (`pandar64`), three numbers for a tuple (`0.1,0.1,0.4`, `[0.1, 0.1, 0.4]`
    or `0.1 0.1 0.4`). Python literals ('pandar64', (0.1, 0.1, 0.4), True) are read as before. A value that is no
    value of the type is returned as written for the config to name; text that is not one at all is a ConfigError
    naming it. One parser for every config read from KEY=VALUE text (Stage1Config, Stage2Config's track_*)."""
    kind = next(f.type for f in fields(config) if f.name == name)
    owner = config.__name__
    text = text.strip()
    try:
        literal: Any = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        literal = _NOT_LITERAL
    if kind == "str":
        return literal if isinstance(literal, str) else text
    if kind == "float | str":  # a number, or auto (any other word is returned for Stage1Config to refuse)
        return literal if literal is not _NOT_LITERAL and not isinstance(literal, bool) else text
    if literal is not _NOT_LITERAL:
        return literal
    if kind == "bool" and text.lower() in _TRUE + _FALSE:
        return text.lower() in _TRUE
    if kind.startswith("tuple"):
        parts = [p for p in text.strip("[]()").replace(",", " ").split() if p]
        try:
            return tuple(float(p) for p in parts)
        except ValueError:
            raise ConfigError(f"{owner}: {name}={text} must be a list of numbers (e.g. {name}=0.1,0.1,0.4)"
                              ) from None
    what = _TYPE_CHECKS[kind][1] if kind in _TYPE_CHECKS else kind
    raise ConfigError(f"{owner}: {name}={text} must be {what}")


_NOT_LITERAL = object()


def config_from_text(items: Iterable[tuple[str, str]]) -> Stage1Config:
    """Stage1Config from (key, text) pairs (`field_name`, `parse_value`; a later key wins); ConfigError names the
    first problem."""
    values: dict[str, Any] = {}
    for key, text in items:
        name = field_name(key)
        values[name] = parse_value(name, text)
    return Stage1Config.from_mapping(values)


def parse_params(items: Iterable[str]) -> Stage1Config:
    """Stage1Config from `--param KEY=VALUE` overrides: KEY as the node names it (`stage1.th_dist`) or bare
    (`th_dist`); VALUE read by the field's type (`parse_value`): 0.25, 3, true, pandar64, 0.1,0.1,0.4, or a Python
    literal as before ('pandar64', (0.1, 0.1, 0.4)). ConfigError names the first problem."""
    pairs = []
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--param {item!r}: expected KEY=VALUE")
        pairs.append((key, text))
    return config_from_text(pairs)
