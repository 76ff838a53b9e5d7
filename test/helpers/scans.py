"""Constructed scans with known answers, shared by the stage-1 tests: a ray-cast 64-ring scene of boxes on a ground
plane (SENSOR_HEIGHT below the sensor) and a scan with no laser lines at all."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SENSOR_HEIGHT = 1.73
ELEVATIONS = np.deg2rad(np.linspace(2.0, -24.8, 64))  # ring 0 on top, as KITTI's firing order


@dataclass
class Solid:
    """An oriented box obstacle: centre, size (length, width, height), yaw."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0


def raycast(solids: list[Solid], slope: float = 0.0, n_az: int = 1200, backdrop: float = 90.0) -> tuple:
    """A 64-ring scan in KITTI firing order (ring after ring, azimuth rising from the +x axis) of a ground
    z = -SENSOR_HEIGHT + slope * x, some boxes, and a backdrop cylinder (buildings far away) that every ray
    reaches. Returns (points N x 4, ring, hit: -1 ground, -2 backdrop, i = solid i)."""
    az = np.arange(n_az) * (2.0 * np.pi / n_az) + 1e-4
    e, a = np.meshgrid(ELEVATIONS, az, indexing="ij")
    u = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    best = backdrop / np.hypot(u[:, 0], u[:, 1])
    hit = np.full(len(u), -2)
    denom = u[:, 2] - slope * u[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(denom < 0.0, -SENSOR_HEIGHT / denom, np.inf)
    best, hit = np.where(t_ground < best, t_ground, best), np.where(t_ground < best, -1, hit)
    for index, solid in enumerate(solids):
        c, s = np.cos(solid.yaw), np.sin(solid.yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        origin = -rot.T @ np.asarray(solid.center)
        d = u @ rot
        half = np.asarray(solid.size) / 2.0
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - origin) / d
            t2 = (half - origin) / d
        t_near = np.nanmax(np.minimum(t1, t2), axis=1)
        t_far = np.nanmin(np.maximum(t1, t2), axis=1)
        ok = (t_far >= t_near) & (t_near > 0.0) & (t_near < best)
        best, hit = np.where(ok, t_near, best), np.where(ok, index, hit)
    pts = u * best[:, None]
    points = np.concatenate([pts, np.full((len(pts), 1), 0.5)], axis=1).astype(np.float32)
    return points, np.repeat(np.arange(64), n_az).astype(np.uint16), hit


def no_laser_lines_scan(points: int = 20000, seed: int = 0) -> np.ndarray:
    """Points at random elevations in random order: no ring field, no firing order, no laser lines to find."""
    rng = np.random.default_rng(seed)
    r, az, z = rng.uniform(5, 50, points), rng.uniform(-np.pi, np.pi, points), rng.uniform(-2, 3, points)
    return np.stack([r * np.cos(az), r * np.sin(az), z, rng.uniform(0, 1, points)], 1).astype(np.float32)


def person_points(x: float, y: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """Points (x, y, height above ground) of a standing person: legs, a torso 0.45 m broad, a head 0.2 m across."""
    parts = [((0.0, 0.85 * height / 1.75), 0.18, 120), ((0.85 * height / 1.75, height - 0.3), 0.22, 120),
             ((height - 0.25, height), 0.1, 40)]
    out = []
    for (lo, hi), reach, n in parts:
        angle = rng.uniform(0.0, 2.0 * np.pi, n)
        radius = reach * np.sqrt(rng.uniform(0.0, 1.0, n))
        out.append(np.stack([x + radius * np.cos(angle), y + radius * np.sin(angle), rng.uniform(lo, hi, n)], 1))
    return np.concatenate(out)
