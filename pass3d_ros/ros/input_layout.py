"""Outputs in the input's own layout: `output_layout: as_input` and the background cloud (`publish_background`).

`compact` (the default) publishes on /pass3d/labeled the points stage 1 read (finite, plausible returns), with x, y,
z, intensity (0..1), ring, cluster_id, label, confidence, rgb. `as_input` publishes every input point in the input's
order and layout (height, width, organized or not; NaN, no-return and implausible points kept with label 0,
confidence 0, cluster_id -1) with every input field as it came (dtype and value: Ouster's `t`, `reflectivity`, a
uint16 `intensity`), plus cluster_id, confidence, rgb and label, so `label[i]` belongs to input point i. An input
field of one of those four names is replaced (one WARN). The background cloud is the input less the points labelled
car, pedestrian or cyclist (after min_confidence), every input field as it came, in input order, unorganized
(height 1): non-returns and NaN points stay as they came, for odometry and SLAM.

Design:
- `InputSource` is the input as decoded (`decode`, a zero-copy view of the message), the positions in it of the points
  stage 1 read, and its height, width and is_dense. Positions compose the cluster node's NaN filter (`to_xyzi`) with
  `ScanStream.prepare`'s `kept`. Holding it costs a reference to the message, no copy.
- In `pass3d_pipeline` the cluster node always attaches it to the `ProposalFrame` (free), and the segmentation node
  decides by its own `output_layout` and `publish_background`.
- Between two processes the source must cross /pass3d/proposals: when the cluster node's `output_layout` is
  `as_input` or its `publish_background` is true, that message carries every input point and field in the input's
  layout, untouched, plus stage 1's columns under the reserved prefix `__pass3d_` (`full_proposals_cloud`, WIRE_PREFIX):
  `__pass3d_cluster_id`, `__pass3d_cluster_id2` (int32, -1 = none), `__pass3d_ground` (uint8), `__pass3d_ring` (uint16:
  the ring the in-memory frame carries, the driver's field as it came when it fits, else stage 1's) and
  `__pass3d_intensity` (float32: the 0..1 intensity stage 1 read, NaN for points it did not read). The segmentation
  node recognises that cloud by `__pass3d_intensity`, rebuilds the frame from the rows where it is a number and keeps
  the whole cloud less the `__pass3d_` columns as the source: the same fields, bytes and offsets the in-memory source
  has, so both paths publish the same messages. One NaN-able column marks both "read" and the value stage 1 read (it
  was scaled into 0..1 by intensity_scale and the stream's scale, which the input's own intensity field is not), so
  no separate flag is needed. The prefix, not bare names: this message used to carry `cluster_id`, `cluster_id2`,
  `ground` and `stage1_intensity`, and an input field of one of those names (a driver's own `ground` or `cluster_id`,
  a cloud already labelled upstream) was dropped from the separate-nodes outputs while pass3d_pipeline kept it. Only
  an input that already carries `__pass3d_` columns (one of these messages fed back in) loses them (WARN once in the
  cluster node). A message in that old form (`stage1_intensity` and `cluster_id`, no `__pass3d_intensity`: an older
  cluster node) is refused as malformed, with a throttled warning naming it, rather than read: both nodes come from
  one install, so a mix is a stale process to restart, and reading it would publish outputs silently short of the
  fields the old form lost. The compact message is unchanged byte for byte.
- Outputs are `Extended` clouds (pass3d_ros.msgs.pointcloud2) that `encode` builds straight into the message's buffer:
  each point's input bytes copied as one void item, the new columns appended (4-byte aligned), the input's height kept.
  A field-by-field copy would cost in proportion to the input's fields, and building an array first then copying it
  into the message a second copy; docs/outputs.md gives the measured cost per frame.
- Asked for `as_input` with compact proposals (a cluster node left at compact), the segmentation node publishes
  compact and warns once; asked for the background without a source, it publishes the compact columns of the
  background points and warns once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND, packed_rgb
from pass3d_ros.core.stage1.proposals import level_points
from pass3d_ros.msgs.pointcloud2 import Extended, finite_mask

COMPACT = "compact"
AS_INPUT = "as_input"
OUTPUT_LAYOUTS: tuple[str, ...] = (COMPACT, AS_INPUT)
OUTPUT_LAYOUT_HELP = ("compact: the points stage 1 read, x y z intensity(0..1) ring + labels; as_input: every input "
                      "point in the input's order and layout (organized too), every input field as it came, + "
                      "cluster_id confidence rgb label (label 0 where not a return)")
# Stage 1's own columns on the full /pass3d/proposals are named with this prefix so that no input field can collide
# with them and every input field crosses untouched. No LiDAR driver (Velodyne, Ouster, Hesai, Livox, RoboSense,
# Autoware's), PCL point type or labelling tool names a field after this package, and the leading double underscore
# marks the columns internal (as Python and C reserve such names), keeping them apart from the input's in
# `ros2 topic echo` and rviz. Letters, digits and underscores only, so numpy dtypes, PCL and rosbag tools take them.
WIRE_PREFIX = "__pass3d_"
STAGE1_INTENSITY = WIRE_PREFIX + "intensity"  # float32 0..1, NaN where stage 1 did not read the point
STAGE1_CLUSTER_ID = WIRE_PREFIX + "cluster_id"
STAGE1_CLUSTER_ID2 = WIRE_PREFIX + "cluster_id2"
STAGE1_GROUND = WIRE_PREFIX + "ground"
STAGE1_RING = WIRE_PREFIX + "ring"
STAGE1_COLUMNS: tuple[str, ...] = (STAGE1_CLUSTER_ID, STAGE1_CLUSTER_ID2, STAGE1_GROUND, STAGE1_RING, STAGE1_INTENSITY)
# With a levelled scan (a tilted, high or upside-down mount: pass3d_ros.core.stage1.mounting), both forms carry each
# point's coordinates in the level frame stage 1 ran in, so stage 2 reads the proposals standing on the ground.
LEVEL_COLUMNS: tuple[str, ...] = (WIRE_PREFIX + "level_x", WIRE_PREFIX + "level_y", WIRE_PREFIX + "level_z")
# Where stage 1 kept rerun_dropped's parts, both forms flag their points (uint8 1), which stage 2 may call pedestrian or
# background only (Stage1Result.people_only); without such points the column is left out.
STAGE1_PEOPLE_ONLY = WIRE_PREFIX + "people_only"
WIRE_COLUMNS: tuple[str, ...] = STAGE1_COLUMNS + LEVEL_COLUMNS + (STAGE1_PEOPLE_ONLY,)  # every column of ours
LEGACY_INTENSITY = "stage1_intensity"  # the old full message's marker (unprefixed columns): refused, see above
LABEL_COLUMNS: tuple[str, ...] = ("cluster_id", "confidence", "rgb", "label")
COMPACT_BACKGROUND: tuple[str, ...] = ("x", "y", "z", "intensity", "ring")  # without a source


def check_layout(value: str) -> str:
    """`value` when it is an output layout, else ValueError naming the choices."""
    if value not in OUTPUT_LAYOUTS:
        raise ValueError(f"output_layout {value!r} unknown, expected {' or '.join(OUTPUT_LAYOUTS)}")
    return value


@dataclass(frozen=True)
class InputSource:
    """The input scan as it came, and where stage 1's points sit in it."""

    cloud: np.ndarray  # (height * width,) structured: the input's fields only, every point, row-major
    height: int
    width: int
    is_dense: bool  # no NaN coordinate among the input's points
    positions: np.ndarray | None  # (N,) row in `cloud` of each point stage 1 read; None: point i is row i

    def scatter(self, values: np.ndarray, fill: float | int) -> np.ndarray:
        """A column over every input row: `values` (one per point stage 1 read) at their rows, `fill` elsewhere."""
        if self.positions is None:
            return values
        column = np.full(len(self.cloud), fill, values.dtype)
        column[self.positions] = values
        return column

    def replaced(self, names: tuple[str, ...]) -> list[str]:
        """The input's fields among `names` (an output replaces them)."""
        return [name for name in names if name in (self.cloud.dtype.names or ())]


def input_source(cloud: np.ndarray, height: int, width: int, read: int, kept: np.ndarray | None) -> InputSource:
    """The source of a decoded input `cloud` from which `to_xyzi(skip_nans=True)` kept `read` points and
    `ScanStream.prepare` then kept the positions `kept` of those (None: all)."""
    finite = None if read == len(cloud) else np.flatnonzero(finite_mask(cloud))
    positions = kept if finite is None else finite if kept is None else finite[kept]
    return InputSource(cloud, height, width, finite is None, positions)


def full_proposals_cloud(source: InputSource, points: np.ndarray, cluster_id: np.ndarray, cluster_id2: np.ndarray,
                         ground: np.ndarray, ring: np.ndarray, level: np.ndarray | None = None,
                         people_only: np.ndarray | None = None) -> Extended:
    """/pass3d/proposals in the input's layout: every input row and field untouched plus stage 1's `__pass3d_` columns
    (module docstring), to `encode` with the input's height. `ring`: the frame's (one per point stage 1 read);
    `level`: the level frame's rotation when stage 1 levelled the scan (adds LEVEL_COLUMNS); `people_only`: the
    points of rerun_dropped's parts when there are some (adds STAGE1_PEOPLE_ONLY)."""
    columns = {
        STAGE1_CLUSTER_ID: source.scatter(cluster_id.astype(np.int32), -1),
        STAGE1_CLUSTER_ID2: source.scatter(cluster_id2.astype(np.int32), -1),
        STAGE1_GROUND: source.scatter(ground.astype(np.uint8), 0),
        STAGE1_RING: source.scatter(ring.astype(np.uint16), 0),
        STAGE1_INTENSITY: source.scatter(points[:, 3].astype(np.float32), np.nan),
    }
    if level is not None:
        flat = level_points(points, level)
        columns.update({name: source.scatter(flat[:, k], np.nan) for k, name in enumerate(LEVEL_COLUMNS)})
    if people_only is not None:
        columns[STAGE1_PEOPLE_ONLY] = source.scatter(people_only.astype(np.uint8), 0)
    return Extended(source.cloud, columns)


def read_rows(cloud: np.ndarray) -> np.ndarray:
    """The rows of a full proposals cloud stage 1 read: `__pass3d_intensity` a number (a row with implausible
    coordinates there all the same is left out by the segmentation node's check of every received frame)."""
    return np.flatnonzero(~np.isnan(cloud[STAGE1_INTENSITY]))


def labeled_as_input(source: InputSource, columns: Mapping[str, np.ndarray]) -> Extended:
    """/pass3d/labeled in the input's layout, from the compact columns (`labeled_cloud`): the input's fields and
    rows, with cluster_id, (with tracking on) track_id, confidence, rgb and label (-1, -1, 0, grey, 0 at points stage
    1 did not read), to `encode` with the input's height."""
    labels = source.scatter(columns["label"], BACKGROUND)
    out = {"cluster_id": source.scatter(columns["cluster_id"], -1)}
    if "track_id" in columns:
        out["track_id"] = source.scatter(columns["track_id"], -1)
    out.update({
        "confidence": source.scatter(columns["confidence"], 0.0),
        "rgb": packed_rgb(labels) if source.positions is not None else columns["rgb"],
        "label": labels,
    })
    return Extended(source.cloud, out)


def background_rows(source: InputSource, labels: np.ndarray) -> np.ndarray:
    """The input rows not labelled an object (`labels`: one per point stage 1 read), in input order."""
    return np.flatnonzero(source.scatter(labels, BACKGROUND) == BACKGROUND)


def background_cloud(source: InputSource, labels: np.ndarray) -> Extended:
    """The input without its points labelled car, pedestrian or cyclist, every field as it came, input order (to
    `encode` as one row)."""
    return Extended(source.cloud, rows=background_rows(source, labels))


def compact_background(columns: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Without a source: the compact x, y, z, intensity (and ring) columns of the background points."""
    keep = columns["label"] == BACKGROUND
    return {name: np.asarray(columns[name])[keep] for name in COMPACT_BACKGROUND if name in columns}
