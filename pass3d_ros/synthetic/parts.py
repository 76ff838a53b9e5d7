"""Ray-castable parts (box, ellipsoid, cylinder) that object models are built from, in the object's own frame.

An object is a list of parts; the scene builder moves them to the object's pose and hands them to the ray caster.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pass3d_ros.synthetic import raycast as rc


@dataclass
class Part:
    """One primitive in its object's frame: rows of `rot` are the primitive's axes."""

    ptype: int
    center: np.ndarray
    rot: np.ndarray
    size: np.ndarray  # 6 values, see raycast
    material: int
    rho: float


def rot_z(yaw: float) -> np.ndarray:
    """Rotation matrix about z (object -> world)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation matrix about y."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def axis_frame(axis: np.ndarray) -> np.ndarray:
    """Rows: an orthonormal frame whose third row is `axis` (the local z of a cylinder)."""
    z = np.asarray(axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = _cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, _cross(z, x), z])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ~20x more per call; scenes build thousands of cylinders)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def box(center, half, material: int, rho: float, rot: np.ndarray | None = None,
        rounding: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Part:
    """Oriented box; `rounding` > 0 intersects it with an ellipsoid that many half-extents wide."""
    return Part(rc.BOX, np.asarray(center, float), np.eye(3) if rot is None else rot,
                np.array([*half, *rounding], dtype=float), material, rho)


def ellipsoid(center, semi, material: int, rho: float, rot: np.ndarray | None = None) -> Part:
    """Ellipsoid with semi-axes `semi` along its rows of `rot`."""
    return Part(rc.ELLIPSOID, np.asarray(center, float), np.eye(3) if rot is None else rot,
                np.array([*semi, 0.0, 0.0, 0.0], dtype=float), material, rho)


def cylinder(p: np.ndarray, q: np.ndarray, radius: float, material: int, rho: float, inner: float = 0.0) -> Part:
    """Cylinder (tube if `inner` > 0) from point p to point q."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    half = 0.5 * float(np.linalg.norm(q - p))
    return Part(rc.CYLINDER, 0.5 * (p + q), axis_frame(q - p),
                np.array([radius, radius, half, inner, 0.0, 0.0]), material, rho)


def disc(center, axis, radius: float, half_width: float, material: int, rho: float, inner: float = 0.0) -> Part:
    """Short cylinder (wheel, round sign) centred at `center` around `axis`."""
    return Part(rc.CYLINDER, np.asarray(center, float), axis_frame(np.asarray(axis, float)),
                np.array([radius, radius, half_width, inner, 0.0, 0.0]), material, rho)


def part_extent(part: Part) -> np.ndarray:
    """Half extent of a part along the axes of the frame it is given in."""
    m = part.rot
    a, b, c = part.size[:3]
    if part.ptype == rc.BOX:
        return np.abs(m.T) @ np.array([a, b, c])
    if part.ptype == rc.ELLIPSOID:
        return np.sqrt((m.T ** 2) @ np.array([a * a, b * b, c * c]))
    axis = m[2]
    return np.abs(axis) * c + a * np.sqrt(np.clip(1.0 - axis * axis, 0.0, 1.0))
