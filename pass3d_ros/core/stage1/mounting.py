"""The sensor's mounting: its height above the road and its orientation to it, read from the scans or given.

Stage 1 works in a level frame (z up, the road about the mounting height below the sensor). A scan from a tilted, high,
low or inverted mount is levelled first (pass3d_ros.core.stage1.proposals: ground, clustering and refinement run on
the levelled points, rings on the sensor's own), so `Mounting.rotation()` takes the sensor's frame to the level one.

A reading (`read_mounting`) needs no stage-1 result: the densest plane through the scan's near returns (RANSAC_TRIALS
planes through three of them, a fixed seed) whose normal lies within MAX_TILT_DEG of the sensor's z axis or of its
reverse (an upside-down mount), oriented so the sensor lies above it, scored by its points within INLIER_M less those
more than BELOW_M beneath it (car roofs and bonnets near a sensor can outnumber the road: the road has nothing beneath
it), refitted by least squares; a best plane with more than MAX_BENEATH_SHARE beneath it is no ground, and the search
looks again among the points beneath it (`_coarse_ground`). The height is the sensor's distance from it, the
orientation the roll about x and the pitch about y (REP-103 signs: a positive pitch points x down; roll 180 is upside
down) that take its normal to z. A stream holds the median of its first MOUNTING_SCANS readings
(pass3d_ros.core.stream.mounting); `stage1.mount` gives it instead, as a URDF states it (`parse_mount`).

A numeric sensor_height is used as it is, and the estimate is still made: `problems` says when the two differ by more
than HEIGHT_DISAGREE_M, or the sensor reads upside down; a steady tilt is levelled (said, not a problem).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.core.stage1.config import AUTO, Stage1Config, mount_values

MOUNTING_SCANS = 5  # readings whose median is held
MIN_GROUND_POINTS = 100  # points of the near ground plane a reading needs
MIN_SEEDS = 10  # points beneath a plane that is no ground the search may look among for one (three make a plane; the
# plane they give must still hold MIN_GROUND_POINTS: an upside-down RS-32's road was 60 of its 3,000 sampled returns)
NEAR_MIN_RANGE_M = 1.0  # the near ground: returns from this range (nearer: the vehicle, the mount) ...
NEAR_RANGE_M = 10.0  # ... to this, or as far as NEAR_GROUND_POINTS of the coarse ground's returns reach ...
NEAR_GROUND_POINTS = 500
FAR_RANGE_M = 40.0  # ... but no further (a narrow sensor 4 m up meets the road 15 m out)
COARSE_INLIER_M = 0.3  # the first pass's ground band over the whole near field
MAX_NEAR_POINTS = 3000  # the near ground plane reads at most this many points (evenly strided)
RANSAC_TRIALS = 300  # planes through three near points tried
MAX_TILT_DEG = 25.0  # a ground candidate's normal lies within this of the sensor's z axis, or of its reverse
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.1, 10.0  # a ground candidate lies this far below the sensor
INLIER_M = 0.1  # a point this close to a plane is on it
BELOW_M = 0.3  # ... and this far under it, beneath it (the ground has points on it and next to none beneath it)
MAX_BENEATH_SHARE = 0.25  # a plane with more points beneath it than this share of those on it is no ground
DESCENTS = 3  # times the coarse search looks again among the points beneath a plane that is no ground
INVERTED_MARGIN = 2.0  # an upside-down reading needs this many times the best upright candidate's score
HEIGHT_DISAGREE_M = 0.3  # a hand-set sensor_height further than this from the estimate is worth a warning
SPREAD_WARN_DEG = 3.0  # readings of one stream further apart than this make the held mounting unsure
NO_GROUND_SCANS = 10  # a stream that read no ground in this many scans says so
LEVEL_MIN_DEG = 2.0  # a stream read as tilted less than this runs unrotated (a level sensor keeps its exact output)
PROVISIONAL_LEVEL_DEG = 3.0  # ... and before its mounting is held, less than this (one scan's reading can be 2-3 deg
# off gravity where the road slopes: levelling to that road is what stage 1 wants; 5 degrees pitched is levelled)
HIGH_MOUNT_M = 2.5  # a sensor this high (a truck, a bus, a mast) hears of stage1.range_scaling while it is off
SEED_DEADBAND_M = 0.3  # a held height this close to AUTO_START_HEIGHT_M bounds the seeds from AUTO_START_HEIGHT_M
_HEIGHT_RANGE = (0.0, 10.0)  # Stage1Config.sensor_height's range: a held height is clipped into it


@dataclass(frozen=True)
class Mounting:
    """The sensor's height above the ground plane under it (m) and its roll, pitch and yaw (degrees, URDF's order:
    the level frame is the sensor's rotated by yaw about z after pitch about y after roll about x)."""

    height_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float = 0.0

    @property
    def tilt_deg(self) -> float:
        """The angle between the ground's normal and the sensor's z axis (degrees; 180 upside down)."""
        cos_tilt = math.cos(math.radians(self.roll_deg)) * math.cos(math.radians(self.pitch_deg))
        return math.degrees(math.acos(max(-1.0, min(1.0, cos_tilt))))

    @property
    def inverted(self) -> bool:
        """The sensor is mounted upside down (its z axis points into the ground's half-space)."""
        return self.tilt_deg > 90.0

    def rotation(self) -> np.ndarray:
        """3 x 3 rotation from the sensor's frame to the level frame: R_z(yaw) R_y(pitch) R_x(roll)."""
        r, p, y = (math.radians(v) for v in (self.roll_deg, self.pitch_deg, self.yaw_deg))
        rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
        ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
        rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
        return rz @ ry @ rx

    def __str__(self) -> str:
        text = (f"sensor {self.height_m:.2f} m above the ground, tilted {self.tilt_deg:.1f} deg "
                f"(roll {self.roll_deg:.1f}, pitch {self.pitch_deg:.1f})")
        return text + (", upside down" if self.inverted else "")

    def to_dict(self) -> dict[str, float]:
        """Plain numbers for reports (JSON, diagnostics)."""
        return {"height_m": round(self.height_m, 3), "tilt_deg": round(self.tilt_deg, 2),
                "roll_deg": round(self.roll_deg, 2), "pitch_deg": round(self.pitch_deg, 2)}


def mounting_from_plane(plane: np.ndarray) -> Mounting:
    """The mounting a ground plane (a, b, c, d; unit normal pointing to the sensor's side, d > 0) says: the roll about
    x, then the pitch about y, that take the normal to z."""
    a, b, c, d = (float(v) for v in plane)
    return Mounting(d, math.degrees(math.atan2(b, c)), math.degrees(math.atan2(-a, math.hypot(b, c))))


def level_rotation(mounting: Mounting | None, given: bool = False, held: bool = True) -> np.ndarray | None:
    """The rotation stage 1 levels a scan with: a given mount's always (unless it is the identity), a read one's when
    it is tilted LEVEL_MIN_DEG or more once `held`, PROVISIONAL_LEVEL_DEG before; None: run the scan as it comes."""
    if mounting is None:
        return None
    if given:
        rotation = mounting.rotation()
        return None if np.allclose(rotation, np.eye(3)) else rotation
    return mounting.rotation() if mounting.tilt_deg >= (LEVEL_MIN_DEG if held else PROVISIONAL_LEVEL_DEG) else None


def _fit(xyz: np.ndarray) -> np.ndarray:
    """Least-squares plane (a, b, c, d; unit normal, the origin on its positive side) of points: the smallest
    principal axis."""
    centre = xyz.mean(axis=0)
    normal = np.linalg.svd(xyz - centre, full_matrices=False)[2][2]
    d = -normal @ centre
    return np.append(normal, d) if d >= 0.0 else np.append(-normal, -d)


def _strided(index: np.ndarray, most: int) -> np.ndarray:
    """At most about `most` of `index`, evenly strided."""
    return index[::max(1, -(-len(index) // most))]


def _best_plane(seeds: np.ndarray, xyz: np.ndarray, inlier_m: float) -> np.ndarray | None:
    """Of RANSAC_TRIALS planes through three `seeds` (a fixed seed), those upright or upside down (normal within
    MAX_TILT_DEG of z or -z) with the sensor MIN_HEIGHT_M..MAX_HEIGHT_M above them, the one with the most `xyz`
    within `inlier_m` less those more than BELOW_M beneath it (a, b, c, d; the sensor on the normal's side)."""
    pick = seeds[np.random.default_rng(0).integers(0, len(seeds), size=(RANSAC_TRIALS, 3))]  # (T, 3 points, xyz)
    normals = np.cross(pick[:, 1] - pick[:, 0], pick[:, 2] - pick[:, 0])
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-9
    normals = normals[ok] / length[ok, None]
    d = -np.einsum("ij,ij->i", normals, pick[ok, 0])
    flip = np.where(d < 0.0, -1.0, 1.0)  # the sensor on the normal's side: d is its height above the plane
    candidates = np.column_stack([normals * flip[:, None], d * flip])
    keep = (np.abs(candidates[:, 2]) >= math.cos(math.radians(MAX_TILT_DEG))) \
        & (candidates[:, 3] >= MIN_HEIGHT_M) & (candidates[:, 3] <= MAX_HEIGHT_M)
    candidates = candidates[keep]
    if len(candidates) == 0:
        return None
    # distances by broadcasting, not a matrix product: BLAS threads on a busy CPU took 10 times as long
    distance = (xyz[:, 0:1] * candidates[:, 0] + xyz[:, 1:2] * candidates[:, 1] + xyz[:, 2:3] * candidates[:, 2]
                + candidates[:, 3])
    score = (np.abs(distance) < inlier_m).sum(axis=0) - (distance < -BELOW_M).sum(axis=0)
    upright = candidates[:, 2] > 0.0
    best_up = int(np.argmax(np.where(upright, score, np.iinfo(np.int64).min))) if upright.any() else -1
    best_down = int(np.argmax(np.where(upright, np.iinfo(np.int64).min, score))) if (~upright).any() else -1
    if best_down < 0 or (best_up >= 0 and score[best_down] <= INVERTED_MARGIN * max(score[best_up], 0)):
        return candidates[best_up]  # upside down only on clear evidence: a ceiling, or the top of clutter, is no road
    return candidates[best_down]


def _coarse_ground(sample: np.ndarray) -> np.ndarray | None:
    """The best plane of the whole near field (`_best_plane`) with at most MAX_BENEATH_SHARE of its points' count
    beneath it; when the best has more, the ground is among the points beneath it, and the search descends to them
    (at most DESCENTS times). An upside-down sensor's few downward lasers see little road, its many horizon lasers a
    band of everything at its own height: three random points rarely all lie on the road, and that band wins."""
    seeds = sample
    for _ in range(DESCENTS):
        plane = _best_plane(seeds, sample, COARSE_INLIER_M)
        if plane is None:
            return None
        distance = sample @ plane[:3] + plane[3]
        beneath = distance < -BELOW_M
        if np.count_nonzero(beneath) <= MAX_BENEATH_SHARE * np.count_nonzero(np.abs(distance) < COARSE_INLIER_M):
            return plane
        seeds = sample[beneath]
        if len(seeds) < MIN_SEEDS:
            return None
    return None


def read_mounting(points: np.ndarray) -> Mounting | None:
    """One scan's reading of the mounting (module docstring), upright or upside down; None when no plane holds
    MIN_GROUND_POINTS points. Two passes: the ground over the whole near field (COARSE_INLIER_M: a crowned or
    sloping road is no plane over 40 m), then the plane of its returns near the sensor, from NEAR_MIN_RANGE_M to
    NEAR_RANGE_M or as far as its NEAR_GROUND_POINTS nearest reach (a narrow sensor's first ring meets the road
    10-15 m out)."""
    xyz = np.asarray(points[:, :3], dtype=np.float64)
    r2 = np.einsum("ij,ij->i", xyz, xyz)
    field = (r2 >= NEAR_MIN_RANGE_M ** 2) & (r2 < FAR_RANGE_M ** 2)
    sample = xyz[_strided(np.flatnonzero(field), MAX_NEAR_POINTS)]
    if len(sample) < MIN_GROUND_POINTS:
        return None
    coarse = _coarse_ground(sample)
    if coarse is None:
        return None
    on_ground = np.flatnonzero(field & (np.abs(xyz @ coarse[:3] + coarse[3]) < COARSE_INLIER_M))
    if len(on_ground) < MIN_GROUND_POINTS:
        return None
    ground_r2 = r2[on_ground]
    reach2 = NEAR_RANGE_M ** 2
    if len(ground_r2) > NEAR_GROUND_POINTS:
        reach2 = max(reach2, float(np.partition(ground_r2, NEAR_GROUND_POINTS)[NEAR_GROUND_POINTS]))
    seeds = xyz[_strided(on_ground[ground_r2 < reach2], MAX_NEAR_POINTS)]
    near = xyz[_strided(np.flatnonzero(field & (r2 < reach2)), MAX_NEAR_POINTS)]
    plane = _best_plane(seeds, near, INLIER_M) if len(seeds) >= 3 else None
    fine = None if plane is None else _refit(near, plane, INLIER_M)
    if fine is not None:
        return mounting_from_plane(fine)
    # the first ring to meet the road runs over kerbs and pavements (a sensor 3.5 m up sees no road nearer than 11
    # m): no near plane holds enough of it, so the coarse ground speaks
    coarse = _refit(sample, coarse, COARSE_INLIER_M)
    return None if coarse is None else mounting_from_plane(coarse)


def _refit(xyz: np.ndarray, plane: np.ndarray, inlier_m: float) -> np.ndarray | None:
    """The plane refitted by least squares twice on the points within `inlier_m` of it; None with fewer than
    MIN_GROUND_POINTS of them, or when the refit leaves the bounds a candidate keeps (`_best_plane`)."""
    for _ in range(2):
        inliers = xyz[np.abs(xyz @ plane[:3] + plane[3]) < inlier_m]
        if len(inliers) < MIN_GROUND_POINTS:
            return None
        plane = _fit(inliers)
    upright = abs(plane[2]) >= math.cos(math.radians(MAX_TILT_DEG))
    distance = xyz @ plane[:3] + plane[3]
    beneath = np.count_nonzero(distance < -BELOW_M)  # a ground has next to nothing beneath it; noise has plenty
    ground = upright and MIN_HEIGHT_M <= plane[3] <= MAX_HEIGHT_M and beneath <= MAX_BENEATH_SHARE * len(inliers)
    return plane if ground else None


def parse_mount(text: str) -> Mounting | None:
    """`stage1.mount` as a mounting (pass3d_ros.core.stage1.config.mount_values; None: auto). x and y are not used:
    stage 1 stays at the sensor; z is the height."""
    values = mount_values(text)
    if values is None:
        return None
    _, _, z, roll, pitch, yaw = values
    return Mounting(z, math.degrees(roll), math.degrees(pitch), math.degrees(yaw))


def median_mounting(readings: list[Mounting]) -> Mounting:
    """Height, roll and pitch, each the median of the readings' (rolls taken about the first one's: an upside-down
    mount reads near +180 and -180)."""
    first = readings[0].roll_deg
    rolls = [first + (m.roll_deg - first + 180.0) % 360.0 - 180.0 for m in readings]
    roll = (float(np.median(rolls)) + 180.0) % 360.0 - 180.0
    return Mounting(float(np.median([m.height_m for m in readings])), roll,
                    float(np.median([m.pitch_deg for m in readings])))


def problems(config: Stage1Config, mounting: Mounting | None) -> list[str]:
    """What a held mounting says is wrong or unsure: a hand-set sensor_height more than HEIGHT_DISAGREE_M off it, a
    sensor read as upside down (a ceiling over an upright one could read so), a sensor HIGH_MOUNT_M or higher while
    `range_scaling` is off (it sees near road users with its sparse lower lasers, and the few-points gate drops them:
    docs/experiments/sensors.md, rule G2). A steady tilt is levelled: no problem."""
    if mounting is None:
        return []
    out = []
    if config.sensor_height != AUTO and abs(float(config.sensor_height) - mounting.height_m) > HEIGHT_DISAGREE_M:
        out.append(f"stage1.sensor_height is {float(config.sensor_height):g} m but the ground under the sensor lies "
                   f"{mounting.height_m:.2f} m below it (more than {HEIGHT_DISAGREE_M:g} m off): set "
                   f"{mounting.height_m:.2f} or auto")
    if mounting.inverted:
        out.append(f"sensor read as upside down (roll {mounting.roll_deg:.1f}, pitch {mounting.pitch_deg:.1f}): stage "
                   "1 levels the scan; if it is not upside down, set stage1.mount")
    if mounting.height_m >= HIGH_MOUNT_M and not config.range_scaling:
        out.append(f"sensor {mounting.height_m:.2f} m above the ground: from so high near road users are crossed by "
                   "few lasers, and stage 1's few-points gate drops some of them; stage1.range_scaling:=true lowers "
                   "the gate where the lasers are sparse (a VLP-32C 3.5 m up: pedestrian IoU 23-34 -> 53-59 % on "
                   "synthetic scans; docs/experiments/sensors.md)")
    return out


def spread_deg(readings: list[Mounting], held: Mounting) -> float:
    """The largest angle (degrees) between a reading's ground normal and the held one's: how far the readings a
    mounting was held from disagree."""
    up = held.rotation()[2]  # the level frame's z in the sensor's frame
    cosines = [float(np.clip(m.rotation()[2] @ up, -1.0, 1.0)) for m in readings]
    return math.degrees(math.acos(min(cosines))) if cosines else 0.0
