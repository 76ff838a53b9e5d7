"""The message between the two nodes, `/pass3d/proposals`: its columns, its in-memory form (`ProposalFrame`), the
checks a received one passes, and the proposal budget (at most `max_proposals`, the nearest) read off its ids.

Both nodes and the in-memory pipeline use this module: the cluster node writes the message (or hands the frame over in
memory), the segmentation node reads it. Nothing here needs rclpy.

Two forms of the message (docs/outputs.md): compact (the default; the points stage 1 read: x, y, z, intensity 0..1,
ring, ground, cluster_id, cluster_id2) and, when the cluster node's `output_layout` is `as_input` or its
`publish_background` is true, the input's own layout (every input point and field, organized as it came, untouched)
plus stage 1's columns under the reserved prefix `__pass3d_` (cluster_id, cluster_id2, ground, ring and intensity,
NaN where stage 1 did not read the point); the reader tells them apart by `__pass3d_intensity` and keeps the input as
the frame's `source` (pass3d_ros.ros.input_layout, which also says why the prefix and why the old unprefixed full
form, marked by `stage1_intensity`, is refused).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from sensor_msgs.msg import PointCloud2

from pass3d_ros.core.stage1 import Stage1Result, proposal_members
from pass3d_ros.core.stage1.proposals import level_points
from pass3d_ros.core.stage2.segmentation import nearest_kept
from pass3d_ros.msgs.pointcloud2 import PointCloud2Error, decode, finite_mask, to_xyzi
from pass3d_ros.ros.input_layout import (
    LEGACY_INTENSITY,
    LEVEL_COLUMNS,
    STAGE1_CLUSTER_ID,
    STAGE1_CLUSTER_ID2,
    STAGE1_COLUMNS,
    STAGE1_GROUND,
    STAGE1_INTENSITY,
    STAGE1_PEOPLE_ONLY,
    STAGE1_RING,
    WIRE_COLUMNS,
    InputSource,
    read_rows,
)

REQUIRED_FIELDS = ("cluster_id",)
ID_FIELDS = ("cluster_id", "cluster_id2")  # the compact message's (and a labelled cloud's, members_from_cloud)
FULL_ID_FIELDS = (STAGE1_CLUSTER_ID, STAGE1_CLUSTER_ID2)  # the full message's


@dataclass(frozen=True)
class ProposalFrame:
    """One frame of stage-1 output in memory: the columns of /pass3d/proposals the segmentation node reads."""

    header: Any  # std_msgs/Header of the input scan (stamp and frame_id)
    points: np.ndarray  # (N, 4) float32 x, y, z, intensity; all finite
    ring: np.ndarray | None  # (N,) ring index, or None
    cluster_id: np.ndarray  # (N,) primary proposal id, -1 = none
    cluster_id2: np.ndarray  # (N,) secondary proposal id (overlapping enlarged boxes), -1 = none
    source: InputSource | None = None  # the input as it came (pipeline, or proposals in the input's layout)
    level: np.ndarray | None = None  # (3, 3) sensor -> level frame when stage 1 levelled the scan (Stage1Result.level)
    ground: np.ndarray | None = None  # (N,) bool stage 1's ground plane when the proposals carry it (for tracking)
    people_only: np.ndarray | None = None  # (N,) bool points stage 2 may call pedestrian or background only
    # (Stage1Result.people_only: rerun_dropped's parts); None: no such point, or the proposals do not say

    @cached_property
    def levelled(self) -> np.ndarray:
        """The points as stage 1 ran them: in the level frame (its canonical boxes stand on the ground); rotated once
        per frame, on first use (the objects and the tracker both read them)."""
        return level_points(self.points, self.level)


ProposalSink = Callable[[ProposalFrame], None]


def proposals_cloud(points: np.ndarray, result: Stage1Result, ring: np.ndarray | None = None
                    ) -> dict[str, np.ndarray]:
    """The columns of /pass3d/proposals: everything the segmentation node needs, point order kept; `ring`: the
    driver's field as it came (its own numbering) when there is one, else stage 1's rings (0 = highest laser)."""
    ring = result.ring if ring is None else ring
    columns = {
        "x": points[:, 0],
        "y": points[:, 1],
        "z": points[:, 2],
        "intensity": points[:, 3],
        "ring": ring.astype(np.uint16),
        "ground": result.ground.astype(np.uint8),
        "cluster_id": result.cluster_id.astype(np.int32),
        "cluster_id2": result.cluster_id2.astype(np.int32),
    }
    if result.level is not None:
        flat = level_points(points, result.level)
        columns.update({name: flat[:, k] for k, name in enumerate(LEVEL_COLUMNS)})
    people_only = result.people_only()
    if people_only is not None:
        columns[STAGE1_PEOPLE_ONLY] = people_only.astype(np.uint8)
    return columns


def proposal_ids(cloud: np.ndarray, rows: np.ndarray | None = None, fields: tuple[str, str] = ID_FIELDS
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The cluster_id and cluster_id2 columns (`fields`: their names) as int64, checked to be integers in -1..N-1
    (N points; `rows`: only those rows count, N = len(rows)).

    Anything else is a malformed message (PointCloud2Error naming the field): work must follow the number of
    points, never the id values a sender chose.
    """
    names = cloud.dtype.names or ()
    n = len(cloud) if rows is None else len(rows)
    ids = []
    for name in fields:
        if name not in names:
            ids.append(np.full(n, -1, np.int64))
            continue
        column = cloud[name] if rows is None else cloud[name][rows]
        if column.dtype.kind not in "iu":
            raise PointCloud2Error(f"field {name!r} has dtype {column.dtype}, expected an integer type (INT8..UINT32)")
        values = column.astype(np.int64)
        if n and (values.min() < -1 or values.max() >= n):
            raise PointCloud2Error(
                f"field {name!r} holds ids {values.min()}..{values.max()}, expected -1 (none) or 0..{n - 1} "
                f"(below the {n} points of the cloud)"
            )
        ids.append(values)
    return ids[0], ids[1]


def proposal_frame(msg: PointCloud2) -> ProposalFrame:
    """A /pass3d/proposals message as arrays (PointCloud2Error when it is not one); NaN points are left out. A message
    in the input's layout (a `__pass3d_intensity` field) gives the rows stage 1 read, and the whole input as `source`;
    one in the old full form (`stage1_intensity`, an older cluster node) is refused (pass3d_ros.ros.input_layout)."""
    cloud = decode(msg)
    names = cloud.dtype.names or ()
    if STAGE1_INTENSITY in names:
        return _full_frame(msg, cloud)
    if LEGACY_INTENSITY in names and "cluster_id" in names:
        raise PointCloud2Error(
            f"a {LEGACY_INTENSITY} field and no {STAGE1_INTENSITY}: /pass3d/proposals in the input's layout from an "
            "older cluster_proposal_node, which drops input fields named like its own columns; refused, restart "
            "cluster_proposal_node from this install")
    keep = finite_mask(cloud)
    cloud = cloud if keep.all() else cloud[keep]
    missing = [name for name in REQUIRED_FIELDS if name not in names]
    if missing:
        raise PointCloud2Error(f"no {', '.join(missing)} field: is this a /pass3d/proposals cloud?")
    _refuse_wide(cloud, ("ring", "ground", *WIRE_COLUMNS))
    first, second = proposal_ids(cloud)
    points = to_xyzi(cloud, with_ring=False).points
    ground = cloud["ground"].astype(bool) if "ground" in names else None
    people_only = cloud[STAGE1_PEOPLE_ONLY] != 0 if STAGE1_PEOPLE_ONLY in names else None
    return ProposalFrame(msg.header, points, cloud["ring"] if "ring" in names else None, first, second,
                         level=_level(cloud, points, None), ground=ground, people_only=people_only)


def _full_frame(msg: PointCloud2, cloud: np.ndarray) -> ProposalFrame:
    """A proposals message in the input's layout as a frame of the rows stage 1 read, the input kept as its source."""
    names = cloud.dtype.names or ()
    missing = [name for name in STAGE1_COLUMNS if name not in names]
    if missing:
        raise PointCloud2Error(f"a {STAGE1_INTENSITY} field without {', '.join(missing)}: is this /pass3d/proposals?")
    _refuse_wide(cloud, WIRE_COLUMNS)
    if cloud[STAGE1_INTENSITY].dtype.kind != "f":
        raise PointCloud2Error(f"field {STAGE1_INTENSITY!r} has dtype {cloud[STAGE1_INTENSITY].dtype}, expected float")
    if cloud[STAGE1_RING].dtype.kind not in "iu":
        raise PointCloud2Error(f"field {STAGE1_RING!r} has dtype {cloud[STAGE1_RING].dtype}, expected an integer type")
    rows = read_rows(cloud)
    first, second = proposal_ids(cloud, rows, FULL_ID_FIELDS)
    points = np.empty((len(rows), 4), np.float32)
    for column, name in enumerate(("x", "y", "z", STAGE1_INTENSITY)):
        points[:, column] = cloud[name][rows]
    ring = cloud[STAGE1_RING][rows]
    # the input's fields untouched, at their offsets (the __pass3d_ bytes stay as padding past them, never copied out)
    source = InputSource(cloud[[name for name in names if name not in WIRE_COLUMNS]], int(msg.height),
                         int(msg.width), bool(msg.is_dense), None if len(rows) == len(cloud) else rows)
    ground = cloud[STAGE1_GROUND][rows].astype(bool)
    people_only = cloud[STAGE1_PEOPLE_ONLY][rows] != 0 if STAGE1_PEOPLE_ONLY in names else None
    return ProposalFrame(msg.header, points, ring, first, second, source, _level(cloud, points, rows), ground,
                         people_only)


def _refuse_wide(cloud: np.ndarray, columns: tuple[str, ...]) -> None:
    """PointCloud2Error naming those of `columns` the cloud has with count > 1: stage 2 reads one value a point."""
    names = cloud.dtype.names or ()
    wide = [name for name in columns if name in names and cloud[name].ndim != 1]
    if wide:
        raise PointCloud2Error(f"field(s) {', '.join(wide)} with count > 1, expected 1")


LEVEL_FIT_POINTS = 2000  # points the level frame's rotation is read back from
LEVEL_TOLERANCE_M = 0.01  # the level coordinates' median distance from the points turned by that rotation (float32
# rounding: a few micrometres; all zeros, or another cloud's columns: metres)


def _level(cloud: np.ndarray, points: np.ndarray, rows: np.ndarray | None) -> np.ndarray | None:
    """The rotation into the level frame a proposals message carries as its points' level coordinates (None without
    LEVEL_COLUMNS): the least-squares rotation (Kabsch) taking the points' xyz onto them; PointCloud2Error when no
    rotation does (all zeros, another cloud's columns), which would turn every box the wrong way."""
    names = cloud.dtype.names or ()
    if not all(name in names for name in LEVEL_COLUMNS):
        return None
    level = np.stack([cloud[name] if rows is None else cloud[name][rows] for name in LEVEL_COLUMNS], axis=1)
    pick = np.arange(0, len(points), max(1, len(points) // LEVEL_FIT_POINTS))
    a, b = points[pick, :3].astype(np.float64), level[pick].astype(np.float64)
    good = np.isfinite(b).all(axis=1)
    if np.count_nonzero(good) < 3:
        raise PointCloud2Error(f"{LEVEL_COLUMNS[0]}..z: fewer than 3 finite rows to read the level frame from")
    u, _, vt = np.linalg.svd(a[good].T @ b[good])
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = (u @ fix @ vt).T
    off = float(np.median(np.linalg.norm(a[good] @ rotation.T - b[good], axis=1)))
    if not off <= LEVEL_TOLERANCE_M:
        raise PointCloud2Error(f"{LEVEL_COLUMNS[0]}..z: no rotation of the points' x, y, z (median {off:.3g} m off)")
    return rotation


def members_from_cloud(cloud: np.ndarray) -> list[np.ndarray]:
    """Point indices of each proposal from the per-point cluster_id (and cluster_id2 when present).

    Ids are renumbered densely in ascending order (unchanged for stage 1's 0..K-1), so the number of proposals is
    the number of distinct ids, never the largest one.
    """
    return members_from_ids(*proposal_ids(cloud))


def members_from_ids(first: np.ndarray, second: np.ndarray) -> list[np.ndarray]:
    """Point indices of each proposal from checked primary and secondary ids (see members_from_cloud)."""
    first, second, count = dense_ids(first, second)
    return proposal_members(first, second, n_proposals=count)


def dense_ids(first: np.ndarray, second: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Checked primary and secondary ids renumbered 0..K-1 in ascending order (unchanged for stage 1's), and K."""
    ids = np.concatenate([first, second])
    present = np.flatnonzero(np.bincount(ids[ids >= 0]))  # ids are checked below N: linear, no sort
    if len(present) and present[-1] != len(present) - 1:
        first = np.where(first >= 0, np.searchsorted(present, first), -1)
        second = np.where(second >= 0, np.searchsorted(present, second), -1)
    return first, second, len(present)


def nearest_proposals(points: np.ndarray, first: np.ndarray, second: np.ndarray, count: int, limit: int
                      ) -> tuple[np.ndarray, np.ndarray, int]:
    """Dense ids (`dense_ids`) cut to the `limit` proposals nearest the sensor (x-y of the mean point, as the
    classifiers choose), renumbered in order; the others' points get -1. Linear in the points, however many ids."""
    if count <= limit:
        return first, second, count
    ids = np.concatenate([first, second])
    inside = ids >= 0
    ids = ids[inside]
    xy = np.concatenate([points[:, :2], points[:, :2]])[inside].astype(np.float64)
    size = np.bincount(ids, minlength=count)
    distance = np.hypot(np.bincount(ids, xy[:, 0], count) / size, np.bincount(ids, xy[:, 1], count) / size)
    kept = nearest_kept(distance, limit)
    renumber = np.full(count + 1, -1, np.int64)  # index -1 (no proposal) reads the last entry: -1
    renumber[kept] = np.arange(limit)
    return renumber[first], renumber[second], limit


def source_ids(raw: tuple[np.ndarray, np.ndarray], dense: tuple[np.ndarray, np.ndarray], count: int) -> np.ndarray:
    """The message's cluster id of each dense proposal 0..count-1; `dense`: the `raw` primary and secondary ids after
    `dense_ids` (and `nearest_proposals` when cut)."""
    ids = np.full(count, -1, np.int64)
    for raw_column, dense_column in zip(raw, dense, strict=True):
        inside = dense_column >= 0
        ids[dense_column[inside]] = raw_column[inside]
    return ids
