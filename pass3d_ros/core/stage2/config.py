"""Stage 2 settings in one dataclass, shaped like Stage1Config: the single place where each default, description and
allowed range is written. The segmentation node declares one parameter per field (top level: `weights`,
`max_proposals`, ...) and reads them back through it; the offline tools take their defaults from the same constants.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from pass3d_ros.classes import CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.stage1.config import ConfigError, parse_field, refuse_problems, refuse_unknown
from pass3d_ros.core.stage2.groups import DEFAULT_ENABLED as PEOPLE_IN_GROUPS
from pass3d_ros.core.stage2.segmentation import DEFAULT_MAX_PROPOSALS
from pass3d_ros.core.stream.intensity_match import DEFAULT_ENABLED as INTENSITY_MATCH
from pass3d_ros.core.stream.shapes import VOXEL_M
from pass3d_ros.core.stream.tracks import TrackerConfig
from pass3d_ros.core.threads import DEFAULT_THREADS

CLASSIFIERS: tuple[str, ...] = ("network", "size_rules")
_TRACKER = TrackerConfig()  # the tracker's defaults, read once for the track_* settings below
DEFAULT_CLASSIFIER = "network"

ParameterEntry = tuple[Any, str, "tuple[float, float] | None"]  # (default, description, closed range or None)


def _setting(default: Any, description: str, value_range: tuple[float, float] | None = None,
             choices: tuple[str, ...] | None = None) -> Any:
    """A config field whose metadata carries its description, its allowed closed range (numbers) and its choices."""
    metadata: dict[str, Any] = {"description": description, "range": value_range}
    if choices is not None:
        metadata["choices"] = choices
    return field(default=default, metadata=metadata)


@dataclass(frozen=True)
class Stage2Config:
    """Stage 2 settings: which classifier from which weights on which device, how many proposals a frame, what a
    confidence must reach, and how the classifier runs (threads, a child process and its timeout)."""

    classifier: str = _setting(
        DEFAULT_CLASSIFIER, f"{' or '.join(CLASSIFIERS)}: the PointNet++ or the geometric baseline",
        choices=CLASSIFIERS,
    )
    weights: str = _setting("", "stage-2 checkpoint; empty = the weights shipped with the package")
    device: str = _setting("cpu", "torch device: cpu or cuda")
    threads: int = _setting(
        DEFAULT_THREADS, "CPU threads of the process (torch, OpenMP, numpy's OpenBLAS); 0 = the libraries' defaults (1 "
        "is fastest on a busy 2-core CPU)", (0, 64),
    )
    max_proposals: int = _setting(
        DEFAULT_MAX_PROPOSALS, "at most this many proposals per frame, nearest first", (1, 1024),
    )
    min_confidence: float = _setting(
        0.0, "points predicted below this confidence are labeled background", (0.0, 1.0),
    )
    intensity_match: bool = _setting(
        INTENSITY_MATCH, "map the stream's intensities onto the training scale before the network (a quantile map "
        "fitted on the first scans, then held; a sensor already on that scale is left alone)",
    )
    people_in_groups: bool = _setting(
        PEOPLE_IN_GROUPS, "a proposal stage 2 calls mostly not pedestrian, of a group's height and width, is parted by "
        "heads and each part read again by the classifier; when it calls every part (two at least) pedestrian, their "
        "pedestrian points are pedestrian (pass3d_ros.core.stage2.groups; rule C5 of docs/experiments/sensors.md)",
    )
    process: bool = _setting(
        False, "run the classifier in a child process (with overlap: stage 2 beside stage 1 without sharing the GIL, "
        "and a third thread encodes and publishes; each frame's arrays cross a pipe, a few ms)",
    )
    tracking: bool = _setting(
        True, "objects over time: the stream's tracker (pass3d_ros.core.stream.tracks) gives each object a track id "
        "that persists and a class voted over its recent sightings; the object's points take the voted class in "
        "/pass3d/labeled (and points stage 2 called background on a confirmed track's footprint, its class: "
        "docs/outputs.md), which gains an int32 track_id field (-1: no confirmed track); /pass3d/detections carry the "
        "track id, class and score, the markers the id; /diagnostics tracks alive, born and lost. On by rule K of "
        "docs/experiments/tracks.md",
    )
    track_gate_car: float = _setting(
        _TRACKER.gate(CAR), "tracking: a car detection's centre may lie this far from a track's prediction (m)",
        (0.1, 50.0),
    )
    track_gate_pedestrian: float = _setting(
        _TRACKER.gate(PEDESTRIAN), "tracking: the same for a pedestrian (m)", (0.1, 50.0),
    )
    track_gate_cyclist: float = _setting(
        _TRACKER.gate(CYCLIST), "tracking: the same for a cyclist (m)", (0.1, 50.0),
    )
    track_min_hits: int = _setting(
        _TRACKER.min_hits, "tracking: sightings before a track is confirmed and its id published", (1, 100),
    )
    track_max_misses: int = _setting(
        _TRACKER.max_misses, "tracking: scans a track may go unseen before it ends", (0, 1000),
    )
    track_reid_misses: int = _setting(
        _TRACKER.reid_misses, "tracking: scans after its last sighting an ended track may still be found again, its id "
        "kept, by an object no live track takes", (0, 1000),
    )
    track_vote_window: int = _setting(
        _TRACKER.vote_window, "tracking: recent sightings a track's class is voted over", (1, 1000),
    )
    track_first_score: float = _setting(
        _TRACKER.first_score, "tracking: objects at least this confident are matched to the tracks first, the rest to "
        "the tracks left (ByteTrack's two rounds): a faint fragment beside a person does not take the person's track "
        "from the person's own object; 0: one round. One round by rule W of docs/experiments/tracks.md: on 36 fresh "
        "synthetic drives 0.6 gave 51 id switches, as one round did", (0.0, 1.0),
    )
    track_fill_shapes: bool = _setting(
        _TRACKER.fill_shapes, f"tracking: a confirmed car track's remembered shape (the {VOXEL_M:g} m voxels its "
        f"points filled over its last {_TRACKER.shape_sightings} sightings, moved with it) takes the points stage 2 "
        "left background, in no proposal and off the ground, that fall in it: the rest of a car stage 1 proposed only "
        "in part (docs/outputs.md). Off by rule N of docs/experiments/tracks.md: class changes of cars fewer on "
        "synthetic drives, but the tracker's time over 1 ms at 60 objects and the parking lot's car IoU 1 point lower",
    )
    track_edge_shift: bool = _setting(
        _TRACKER.edge_shift, "tracking: a car's move read from its box edge that moved least: a view whose box centre "
        "jumps while one end stays put (a parked car seen by another side) corrects the track's position, and its "
        "velocity by that move, not by the jump. Off by rule V of docs/experiments/tracks.md: on 36 fresh synthetic "
        "drives id switches 33 -> 37 (one drive), flicker and IoU unchanged",
    )
    stage2_timeout: float = _setting(
        5.0, "seconds a frame may take in stage 2: a child process (process) that answers nothing this long is killed "
        "and restarted, ERROR on /diagnostics; a later result is dropped, never published late (raise it for a "
        "paper-size network on a CPU)", (0.1, 600.0),
    )

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ConfigError naming every setting of the wrong type or outside its allowed range (the classifier's
        name is open_classifier's to check, as it always was)."""
        problems = []
        for f in fields(self):
            value, default = getattr(self, f.name), f.default
            kind = type(default)
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                object.__setattr__(self, f.name, float(value))
                value = float(value)
            if type(value) is not kind:
                problems.append(f"{f.name}={value!r} must be {_WANTED[kind]}")
                continue
            value_range = f.metadata["range"]
            if value_range is not None and not value_range[0] <= value <= value_range[1]:
                problems.append(f"{f.name}={value:g} outside [{value_range[0]:g}, {value_range[1]:g}]")
        refuse_problems("Stage2Config", problems)

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> Stage2Config:
        """Config from a dict (YAML, ROS parameters); unknown keys are an error, not silently ignored."""
        refuse_unknown("Stage2Config", values, (f.name for f in fields(cls)))
        return cls(**values)

    def tracker_config(self) -> TrackerConfig:
        """The tracker's settings with the track_* values (the rest: TrackerConfig's defaults)."""
        return replace(_TRACKER, gate_m=((CAR, self.track_gate_car), (PEDESTRIAN, self.track_gate_pedestrian),
                                         (CYCLIST, self.track_gate_cyclist)),
                       min_hits=self.track_min_hits, max_misses=self.track_max_misses,
                       reid_misses=self.track_reid_misses,
                       vote_window=self.track_vote_window, fill_shapes=self.track_fill_shapes,
                       edge_shift=self.track_edge_shift, first_score=self.track_first_score)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of all settings (for logs and JSON)."""
        return asdict(self)


_WANTED = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
TRACK_PREFIX = "track_"


def tracker_from_params(items: list[str]) -> TrackerConfig:
    """The tracker's settings from `KEY=VALUE` items naming Stage2Config's track_* settings as the segmentation node
    does (`track_fill_shapes=true`, `segmentation_node.track_gate_car=2.5`; the rest its defaults), each value read
    by its field's type as `--param` reads stage 1's (`parse_field`); ConfigError names an item that is no such
    setting or whose value is not of its type or range."""
    values: dict[str, Any] = {}
    known = [f.name for f in fields(Stage2Config) if f.name.startswith(TRACK_PREFIX)]
    for item in items:
        key, sep, text = item.partition("=")
        name = key.strip().removeprefix("segmentation_node.")
        if not sep or name not in known:
            raise ConfigError(f"tracker setting {item!r}: expected KEY=VALUE with KEY one of "
                              f"{', '.join(sorted(known))}")
        values[name] = parse_field(Stage2Config, name, text)
    return Stage2Config(**values).tracker_config()


def parameter_table() -> dict[str, ParameterEntry]:
    """name -> (default, description, range) of every Stage2Config field, in field order: the node's parameter
    table entries (top-level ROS parameters)."""
    return {f.name: (f.default, f.metadata["description"], f.metadata["range"]) for f in fields(Stage2Config)}
