"""Synthetic drives: one street scene seen over consecutive scans, as ground truth for time (`synthetic:drive=N,...`).

`plan_drive(seed, n_scans, sensor)` draws the drive from SeedSequence([DRIVE_SEED_TAG, seed]): the scene
(`scene.generate_scene`), the ego car's path and every road user's motion (`synthetic.motion`), and the surfaces'
reflectivities, dark parts and dark cells, fixed for the whole drive. `drive_scan(drive, k)` is scan k, t = 0.1 k s:
the objects moved to their poses at t, the whole world (primitives, ground, boxes) turned into the ego sensor's level
frame there, one revolution cast as a single frame's is (`dataset.simulate_scan`, noise and firing start drawn from
SeedSequence([DRIVE_SEED_TAG, seed, k + 1]), so any scan can be made alone) and the points given in the sensor's own
frame and driver order, as `dataset.generate_frame` gives them (rings, intensity, mount height and tilt alike).

What a scan carries beyond a frame's: `Frame.pose`, world-from-sensor, and instance ids that persist: every car,
van, truck, pedestrian and cyclist of the drive has one id for the whole drive (its rank among the scene's boxed
objects), in `Frame.instance` and on its box, whether or not it has points in a scan (a box only when it has); so ids
need not run 0, 1, 2 in a scan. Boxes lie in the sensor's level frame, as a frame's do. Static things stay put in the
world, movers move at constant velocity (positions advance velocity x 0.1 s per scan), occlusion is recast every scan.
Unlike single frames, a drive's scans are never redrawn: a KITTI-order scan whose rings do not all start on the +x
axis is kept (its `ring` field is exact). Dark cells are keyed in world coordinates, so they stay on the road and
walls but slide over a moving object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pass3d_ros.data.frame import Frame
from pass3d_ros.synthetic import raycast as rc
from pass3d_ros.synthetic.builder import Scene
from pass3d_ros.synthetic.dataset import FRAME_PERIOD_NS, Surfaces, simulate_scan, to_sensor_frame
from pass3d_ros.synthetic.materials import darken
from pass3d_ros.synthetic.motion import (
    MAX_DRIVE_SCANS,
    SCAN_PERIOD_S,
    EgoPath,
    Motions,
    ego_path,
    ego_pose,
    plan_motions,
)
from pass3d_ros.synthetic.scene import generate_scene, set_ground_bounds
from pass3d_ros.synthetic.sensor import MOUNT_HEIGHT_M, LidarModel

DRIVE_SEED_TAG = 0x44524956  # "DRIV": a drive's streams never meet a frame's SeedSequence([seed, index])


@dataclass
class Drive:
    """Everything a drive's scans share (see the module's notes)."""

    seed: int
    n_scans: int
    sensor: LidarModel
    scene: Scene  # the world at t = 0 as the scene placed it, less what the ego car's path cleared
    path: EgoPath
    motions: Motions  # per object of `scene`
    ids: np.ndarray  # instance id per object of `scene` (-1: no box)
    local_center: np.ndarray  # primitives in their object's frame
    local_rot: np.ndarray
    prho: np.ndarray  # reflectivities with the drive's dark parts
    salt: int


def _rot_z(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*np.shape(yaw), 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


def _keep_objects(scene: Scene, keep: np.ndarray) -> Scene:
    """The scene without the objects `keep` leaves out (primitives and object list renumbered)."""
    prim = keep[scene.pobject]
    new_index = np.cumsum(keep) - 1
    objects = []
    pobject = new_index[scene.pobject[prim]].astype(np.int32)
    counts = np.bincount(pobject, minlength=int(keep.sum()))
    firsts = np.cumsum(counts) - counts
    for o, first, count in zip([o for o, k in zip(scene.objects, keep, strict=True) if k], firsts, counts,
                               strict=True):
        objects.append(replace(o, first=int(first), count=int(count)))
    return replace(scene, ptype=scene.ptype[prim], prot=scene.prot[prim], pcenter=scene.pcenter[prim],
                   psize=scene.psize[prim], pmaterial=scene.pmaterial[prim], prho=scene.prho[prim], pobject=pobject,
                   objects=objects)


def plan_drive(seed: int, n_scans: int, sensor: LidarModel) -> Drive:
    """The drive `seed` of `n_scans` scans (1..MAX_DRIVE_SCANS) for `sensor` (see the module's notes)."""
    if seed < 0 or not 1 <= n_scans <= MAX_DRIVE_SCANS:
        raise ValueError(f"a drive needs seed >= 0 and 1..{MAX_DRIVE_SCANS} scans, got seed={seed}, scans={n_scans}")
    rng = np.random.default_rng(np.random.SeedSequence([DRIVE_SEED_TAG, int(seed)]))
    scene = generate_scene(rng)
    path = ego_path(scene, rng, n_scans)
    motions = plan_motions(scene, rng, path, n_scans)
    keep = ~motions.removed
    scene = _keep_objects(scene, keep)
    motions = Motions(motions.x[keep], motions.y[keep], motions.yaw[keep], motions.velocity[keep],
                      motions.removed[keep], [m for m, k in zip(motions.mode, keep, strict=True) if k])
    boxed = np.array([o.boxed for o in scene.objects], dtype=bool)
    ids = np.where(boxed, np.cumsum(boxed) - 1, -1)
    # Primitives in their object's frame (the scene placed them at the objects' poses, yaw about z).
    pos = np.array([[o.x, o.y, o.z] for o in scene.objects]).reshape(-1, 3)
    yaw = np.array([o.yaw for o in scene.objects])
    rot = _rot_z(yaw)[scene.pobject]
    local_center = np.einsum("pji,pj->pi", rot, scene.pcenter - pos[scene.pobject])
    local_rot = scene.prot @ rot
    prho = darken(scene.prho, scene.pmaterial, scene.pobject, rng)
    salt = int(rng.integers(2**31))
    return Drive(int(seed), int(n_scans), sensor, scene, path, motions, ids, local_center, local_rot, prho, salt)


def _ground_from(scene: Scene, u_t: float, v_t: float, z_t: float, yaw_rel: float) -> tuple[np.ndarray, ...]:
    """The world's ground (params, bumps, waves) seen from a level frame at road (u_t, v_t) and height z_t, the
    road heading `yaw_rel` in it: u counted from the frame's origin, so the slope along u takes KU u_t."""
    gp, bumps, waves = scene.ground.copy(), scene.bumps.copy(), scene.waves.copy()
    ku, tu = gp[rc.G_KU], gp[rc.G_TU]
    gp[rc.G_COS], gp[rc.G_SIN] = math.cos(yaw_rel), math.sin(yaw_rel)
    gp[rc.G_VEGO] = v_t
    gp[rc.G_Z0] = gp[rc.G_Z0] + 0.5 * ku * u_t * u_t + tu * u_t - z_t
    gp[rc.G_TU] = tu + ku * u_t
    gp[rc.G_XC] -= u_t
    bumps[:, 0] -= u_t
    waves[:, 2] += waves[:, 0] * u_t
    set_ground_bounds(gp, bumps, waves)
    return gp, bumps, waves


def scene_at(drive: Drive, t: float) -> tuple[Scene, np.ndarray]:
    """(the world at time t in the ego sensor's level frame, the 4 x 4 world-from-that-frame transform)."""
    scene, m = drive.scene, drive.motions
    x = m.x + m.velocity[:, 0] * t
    y = m.y + m.velocity[:, 1] * t
    z = np.array([o.z for o in scene.objects])
    moving = np.any(m.velocity != 0.0, axis=1)
    if moving.any():
        start = np.stack([m.x[moving], m.y[moving]], axis=1)
        now = np.stack([x[moving], y[moving]], axis=1)
        z[moving] += scene.ground_at(now) - scene.ground_at(start)
    ego_yaw, ego = ego_pose(scene, drive.path, t)
    ce, se = math.cos(ego_yaw), math.sin(ego_yaw)
    d = np.stack([x - ego[0], y - ego[1], z - ego[2]], axis=1)
    pos = np.stack([ce * d[:, 0] + se * d[:, 1], -se * d[:, 0] + ce * d[:, 1], d[:, 2]], axis=1)
    yaw = m.yaw - ego_yaw
    rot = _rot_z(yaw)[scene.pobject]
    pcenter = np.einsum("pij,pj->pi", rot, drive.local_center) + pos[scene.pobject]
    prot = drive.local_rot @ np.transpose(rot, (0, 2, 1))
    objects = [replace(o, x=float(pos[k, 0]), y=float(pos[k, 1]), z=float(pos[k, 2]), yaw=float(yaw[k]))
               for k, o in enumerate(scene.objects)]
    u_t = float(scene.to_road(ego[None, :2])[0, 0])
    road_yaw = math.atan2(scene.ground[rc.G_SIN], scene.ground[rc.G_COS])
    gp, bumps, waves = _ground_from(scene, u_t, drive.path.v, float(ego[2]), road_yaw - ego_yaw)
    seen = replace(scene, ground=gp, bumps=bumps, waves=waves, pcenter=pcenter, prot=prot, objects=objects,
                   u_offset=u_t)
    pose = np.eye(4)
    pose[:3, :3] = _rot_z(np.array(ego_yaw))
    pose[:3, 3] = ego
    return seen, pose


def drive_scan(drive: Drive, k: int) -> Frame:
    """Scan k (0-based) of the drive, stamped k x 0.1 s (see the module's notes)."""
    if not 0 <= k < drive.n_scans:
        raise ValueError(f"drive of {drive.n_scans} scans has no scan {k}")
    sensor = drive.sensor
    seen, level_pose = scene_at(drive, k * SCAN_PERIOD_S)
    rng = np.random.default_rng(np.random.SeedSequence([DRIVE_SEED_TAG, drive.seed, k + 1]))
    surfaces = Surfaces(drive.prho, drive.salt, level_pose[:3, :3], level_pose[:3, 3])
    scan = to_sensor_frame(simulate_scan(seen, rng, sensor, surfaces=surfaces, ids=drive.ids), sensor)
    pose = level_pose.copy()
    pose[:3, 3] += pose[:3, :3] @ np.array([0.0, 0.0, sensor.mount_height_m - MOUNT_HEIGHT_M])
    rotation = sensor.mount_rotation()
    if rotation is not None:
        pose[:3, :3] = pose[:3, :3] @ rotation
    return Frame(name=f"{k:06d}", points=scan.points, stamp_ns=k * FRAME_PERIOD_NS, ring=scan.ring,
                 labels=scan.labels, ground=scan.ground, instance=scan.instance, boxes=scan.boxes, pose=pose)
