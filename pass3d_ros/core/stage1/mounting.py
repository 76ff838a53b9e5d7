"""The sensor's mounting, learned from a stream's ground: its height above the road and its tilt.

`Stage1Config.sensor_height` bounds the ground seeds from below (pass3d_ros.core.stage1.ground: points more than
below_ground_margin under -sensor_height never seed). Its default, `auto`, learns the height from the stream instead of
assuming KITTI's 1.73 m: on each of a stream's first scans the ground plane of the segment under the sensor (the one
holding x = 0, which the ground fit lets stand alone) and its ground mask start the search for the plane of the ground
near the sensor (`near_ground_plane`: within NEAR_RANGE_M, the densest plane through stage 1's ground points no
steeper than ground_max_slope_deg), which gives a
reading (`scan_mounting`): the height is the sensor origin's distance from that plane, the tilt the angle between its
normal and the sensor's z axis (as roll about x and pitch about y, REP-103 signs: a positive pitch points x down). A
scan whose near ground plane has fewer than MIN_GROUND_POINTS points (a scan of a wall) gives none. The median of the
first MOUNTING_SCANS readings is held (`MountingHolder`), like the laser lines (pass3d_ros.core.stream.lines),
and a new stream starts over (pass3d_ros.core.stream.ScanStream holds one holder per stream).

Until the mounting is held, an auto stream's seeds are bounded as before, from AUTO_START_HEIGHT_M (1.73 m: a mount
up to 2.73 m seeds, KITTI's scans run as they did); once held, from the held height (`MountingHolder.config_for`),
so a 0.6 m robot's seeds stop 1.6 m under it, not 2.73 m (a mount above 2.73 m is not learned: its first scans find
no ground above the start bound; set its height by hand). A held height
within SEED_DEADBAND_M of AUTO_START_HEIGHT_M keeps the start height: the bound is a coarse guard a metre under the
road, and moving it by centimetres only shifts the LPR's height bins (which start at the bound), so KITTI-like mounts
(1.6-2.0 m) get exactly the stage-1 output of the fixed 1.73 m, and two streams of one car the same.

A numeric sensor_height is used as it is, and the estimate is still made: `problems` says when the two differ by more
than HEIGHT_DISAGREE_M, or the sensor is tilted more than TILT_WARN_DEG from the ground's normal (the ground fit's
segments along x and the boxes' gates read heights along the sensor's z; a slope of the road under the sensor reads as
tilt too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.core.stage1.config import AUTO, Stage1Config

MOUNTING_SCANS = 5  # readings whose median is held
MIN_GROUND_POINTS = 100  # points of the near ground plane a reading needs
NEAR_MIN_RANGE_M = 1.0  # the near ground: points from this horizontal range (nearer: the vehicle, the mount) ...
NEAR_RANGE_M = 10.0  # ... to this, or as far as NEAR_GROUND_POINTS of stage 1's ground points reach ...
NEAR_GROUND_POINTS = 500
FAR_RANGE_M = 30.0  # ... but no further
MAX_NEAR_POINTS = 2000  # the near ground plane reads at most this many points (evenly strided)
RANSAC_TRIALS = 150  # planes through three near points tried
INLIER_M = 0.1  # a point this close to a plane is on it
BELOW_M = 0.3  # ... and this far under it, beneath it (the ground has points on it and next to none beneath it)
HEIGHT_DISAGREE_M = 0.3  # a hand-set sensor_height further than this from the estimate is worth a warning
TILT_WARN_DEG = 5.0  # a sensor tilted more than this from the ground's normal is worth a warning
SEED_DEADBAND_M = 0.3  # a held height this close to AUTO_START_HEIGHT_M bounds the seeds from AUTO_START_HEIGHT_M
_HEIGHT_RANGE = (0.0, 10.0)  # Stage1Config.sensor_height's range: a held height is clipped into it


@dataclass(frozen=True)
class Mounting:
    """The sensor's height above the ground plane under it (m) and its roll and pitch from the plane (degrees)."""

    height_m: float
    roll_deg: float
    pitch_deg: float

    @property
    def tilt_deg(self) -> float:
        """The angle between the ground's normal and the sensor's z axis (degrees)."""
        tx, ty = math.tan(math.radians(self.pitch_deg)), math.tan(math.radians(self.roll_deg))
        return math.degrees(math.acos(1.0 / math.sqrt(1.0 + tx * tx + ty * ty)))

    def __str__(self) -> str:
        return (f"sensor {self.height_m:.2f} m above the ground, tilted {self.tilt_deg:.1f} deg "
                f"(roll {self.roll_deg:.1f}, pitch {self.pitch_deg:.1f})")

    def to_dict(self) -> dict[str, float]:
        """Plain numbers for reports (JSON, diagnostics)."""
        return {"height_m": round(self.height_m, 3), "tilt_deg": round(self.tilt_deg, 2),
                "roll_deg": round(self.roll_deg, 2), "pitch_deg": round(self.pitch_deg, 2)}


def centre_segment(config: Stage1Config) -> int:
    """The ground segment holding x = 0 (the one the ground fit lets stand alone: ground._planes_from_sums)."""
    width = 2.0 * config.ground_x_extent / config.n_seg
    edges = -config.ground_x_extent + width * np.arange(config.n_seg + 1)
    centre = 0
    while centre < config.n_seg - 1 and edges[centre + 1] <= 0.0:
        centre += 1
    return centre


def scan_mounting(points: np.ndarray, ground: np.ndarray, planes: np.ndarray,
                  config: Stage1Config) -> Mounting | None:
    """One scan's reading of the mounting: the plane of the ground near the sensor (`near_ground_plane`, from the
    scan's ground mask and the segment plane under the sensor, `Stage1Result.ground` and `.ground_planes`); None when
    it has fewer than MIN_GROUND_POINTS points or lies above the sensor."""
    if len(planes) != config.n_seg or len(points) == 0 or len(ground) != len(points):
        return None
    plane = near_ground_plane(points, ground, planes[centre_segment(config)], config.ground_max_slope_deg)
    if plane is None or plane[3] <= 0.0:
        return None
    a, b, c, d = plane
    return Mounting(d, math.degrees(math.atan2(b, c)), math.degrees(math.atan2(-a, c)))


def _fit(xyz: np.ndarray) -> np.ndarray:
    """Least-squares plane (a, b, c, d; unit normal, c >= 0) of points: the smallest principal axis."""
    centre = xyz.mean(axis=0)
    normal = np.linalg.svd(xyz - centre, full_matrices=False)[2][2]
    normal = -normal if normal[2] < 0.0 else normal
    return np.append(normal, -normal @ centre)


def _strided(index: np.ndarray, most: int) -> np.ndarray:
    """At most about `most` of `index`, evenly strided."""
    return index[::max(1, -(-len(index) // most))]


def near_ground_plane(points: np.ndarray, ground: np.ndarray, start: np.ndarray,
                      max_slope_deg: float) -> np.ndarray | None:
    """The plane (a, b, c, d; unit normal up) of the ground near the sensor: of `start` (the ground fit's plane) and
    RANSAC_TRIALS planes through three of stage 1's ground points (`ground`) near the sensor (a fixed seed), those no
    steeper than `max_slope_deg`, the one with the most points near the sensor within INLIER_M less those more than
    BELOW_M beneath it (car roofs and bonnets near a sensor can outnumber the road: the road has nothing beneath it),
    refitted on the points within INLIER_M by least squares twice. Near: from NEAR_MIN_RANGE_M to NEAR_RANGE_M
    (horizontal, in the sensor's frame), or as far as the NEAR_GROUND_POINTS nearest ground points reach, up to
    FAR_RANGE_M (a narrow sensor's first ring meets the road 10 m out); at most MAX_NEAR_POINTS of them, evenly
    strided. None with fewer than MIN_GROUND_POINTS points within INLIER_M.

    The ground fit's own plane is fitted over tens of metres (kerbs and pavements included; it sat 5-10 cm above a
    synthetic road under the sensor) from seeds that assume a level sensor (a sensor pitched 4 deg read 1.5); its
    ground mask still holds a strip of the true ground, which the candidates are drawn from, and all near points (not
    only the mask) score them."""
    r2 = points[:, 0] ** 2 + points[:, 1] ** 2
    on_ground = np.flatnonzero(ground & (r2 >= NEAR_MIN_RANGE_M ** 2) & (r2 < FAR_RANGE_M ** 2))
    if len(on_ground) < MIN_GROUND_POINTS:
        return None
    ground_r2 = r2[on_ground]
    reach2 = NEAR_RANGE_M ** 2
    if len(ground_r2) > NEAR_GROUND_POINTS:
        reach2 = max(reach2, float(np.partition(ground_r2, NEAR_GROUND_POINTS)[NEAR_GROUND_POINTS]))
    else:
        reach2 = FAR_RANGE_M ** 2
    seeds = np.asarray(points[_strided(on_ground[ground_r2 < reach2], MAX_NEAR_POINTS), :3], dtype=np.float64)
    near = np.flatnonzero((r2 >= NEAR_MIN_RANGE_M ** 2) & (r2 < reach2))
    xyz = np.asarray(points[_strided(near, MAX_NEAR_POINTS), :3], dtype=np.float64)
    if len(seeds) < 3:
        return None
    rng = np.random.default_rng(0)
    pick = seeds[rng.integers(0, len(seeds), size=(RANSAC_TRIALS, 3))]  # (T, 3 points, xyz)
    normals = np.cross(pick[:, 1] - pick[:, 0], pick[:, 2] - pick[:, 0])
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-9
    normals = normals[ok] / length[ok, None]
    normals *= np.where(normals[:, 2] < 0.0, -1.0, 1.0)[:, None]
    candidates = np.column_stack([normals, -np.einsum("ij,ij->i", normals, pick[ok, 0])])
    start = np.asarray(start, dtype=np.float64)
    candidates = np.vstack([start / max(np.linalg.norm(start[:3]), 1e-12), candidates])
    candidates = candidates[candidates[:, 2] >= math.cos(math.radians(max_slope_deg))]
    if len(candidates) == 0:
        return None
    # distances by broadcasting, not a matrix product: BLAS threads on a busy CPU took 10 times as long
    distance = (xyz[:, 0:1] * candidates[:, 0] + xyz[:, 1:2] * candidates[:, 1] + xyz[:, 2:3] * candidates[:, 2]
                + candidates[:, 3])
    score = (np.abs(distance) < INLIER_M).sum(axis=0) - (distance < -BELOW_M).sum(axis=0)
    plane = candidates[int(np.argmax(score))]
    for _ in range(2):
        inliers = xyz[np.abs(xyz[:, 0] * plane[0] + xyz[:, 1] * plane[1] + xyz[:, 2] * plane[2] + plane[3]) < INLIER_M]
        if len(inliers) < MIN_GROUND_POINTS:
            return None
        plane = _fit(inliers)
    return plane


def median_mounting(readings: list[Mounting]) -> Mounting:
    """Height, roll and pitch, each the median of the readings'."""
    return Mounting(float(np.median([m.height_m for m in readings])), float(np.median([m.roll_deg for m in readings])),
                    float(np.median([m.pitch_deg for m in readings])))


def problems(config: Stage1Config, mounting: Mounting | None) -> list[str]:
    """What a held mounting says is wrong: a hand-set sensor_height more than HEIGHT_DISAGREE_M off it, a tilt of
    more than TILT_WARN_DEG."""
    if mounting is None:
        return []
    out = []
    if config.sensor_height != AUTO and abs(float(config.sensor_height) - mounting.height_m) > HEIGHT_DISAGREE_M:
        out.append(f"stage1.sensor_height is {float(config.sensor_height):g} m but the ground under the sensor lies "
                   f"{mounting.height_m:.2f} m below it (more than {HEIGHT_DISAGREE_M:g} m off): set "
                   f"{mounting.height_m:.2f} or auto")
    if mounting.tilt_deg > TILT_WARN_DEG:
        out.append(f"sensor tilted {mounting.tilt_deg:.1f} deg from the ground's normal (roll {mounting.roll_deg:.1f}, "
                   f"pitch {mounting.pitch_deg:.1f}; more than {TILT_WARN_DEG:g} deg): stage 1 reads heights along the "
                   "sensor's z axis")
    return out
