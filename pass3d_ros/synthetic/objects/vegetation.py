"""Vegetation models: trees, bushes and hedges (foliage is porous: rays reach some way into it)."""

from __future__ import annotations

import math

import numpy as np

from pass3d_ros.synthetic.materials import M_POLE, M_TRUNK, M_VEGETATION
from pass3d_ros.synthetic.parts import Part, box, cylinder, ellipsoid, rot_z


def tree_parts(rng: np.random.Generator, min_base: float = 1.8) -> tuple[list[Part], list[tuple[float, ...]]]:
    """Tree: trunk and an irregular crown of ellipsoids; returns (parts, footprint).

    The footprint (rows cx, cy, hx, hy, zlo, zhi, see SceneBuilder.place) holds the trunk near the ground and the
    crown above its base, so people and cars may stand under a tree.
    """
    trunk_r = rng.uniform(0.1, 0.35)
    base = rng.uniform(min_base, max(min_base + 0.5, 4.5))
    crown_r = rng.uniform(1.3, 3.6)
    top = base + rng.uniform(2.0, 7.0)
    rho_leaf = float(rng.uniform(0.35, 0.6))
    parts = [cylinder([0.0, 0.0, -0.2], [0.0, 0.0, base + 0.6], trunk_r, M_TRUNK, float(rng.uniform(0.25, 0.5)))]
    conifer = rng.random() < 0.2
    n = int(rng.integers(4, 9))
    for i in range(n):
        if conifer:
            f = i / max(n - 1, 1)
            cz = base + (top - base) * (0.15 + 0.7 * f)
            radius = crown_r * (1.0 - 0.75 * f)
            cx = cy = 0.0
            semi = np.array([radius, radius, (top - base) / n + 0.3])
        else:
            ang, rad = rng.uniform(0, 2 * math.pi), crown_r * 0.55 * math.sqrt(rng.random())
            cx, cy = rad * math.cos(ang), rad * math.sin(ang)
            cz = base + (top - base) * rng.uniform(0.35, 0.65)
            semi = crown_r * rng.uniform(0.4, 0.75, size=3)
        semi[2] = min(semi[2], cz - base, top - cz) if semi[2] > 0.3 else semi[2]
        semi[2] = max(semi[2], 0.3)
        cz = max(cz, base + semi[2])
        semi[0] = min(semi[0], crown_r - math.hypot(cx, cy))
        semi[1] = min(semi[1], crown_r - math.hypot(cx, cy))
        semi[:2] = np.maximum(semi[:2], 0.3)
        parts.append(ellipsoid([cx, cy, cz], semi, M_VEGETATION, rho_leaf, rot_z(rng.uniform(0, math.pi)).T))
    footprint = [(0.0, 0.0, trunk_r, trunk_r, -0.2, base), (0.0, 0.0, crown_r, crown_r, base, base + 8.0)]
    return parts, footprint


def bush_parts(rng: np.random.Generator) -> list[Part]:
    """Bush: a few overlapping low ellipsoids."""
    radius, height = rng.uniform(0.5, 1.6), rng.uniform(0.5, 1.6)
    rho = float(rng.uniform(0.35, 0.6))
    parts = []
    for _ in range(int(rng.integers(2, 6))):
        ang, rad = rng.uniform(0, 2 * math.pi), radius * 0.5 * math.sqrt(rng.random())
        semi = np.array([*(rng.uniform(0.35, 0.6, size=2) * radius), height * rng.uniform(0.35, 0.5)])
        semi[:2] = np.minimum(semi[:2], radius - rad)
        semi[:2] = np.maximum(semi[:2], 0.2)
        parts.append(ellipsoid([rad * math.cos(ang), rad * math.sin(ang), semi[2]], semi, M_VEGETATION, rho))
    return parts


def hedge_parts(rng: np.random.Generator, length: float) -> list[Part]:
    """Hedge `length` long along x: a rounded block of foliage."""
    height, thick = rng.uniform(0.8, 2.2), rng.uniform(0.6, 1.3)
    return [box([0, 0, height / 2 - 0.1], [length / 2, thick / 2, height / 2 + 0.1], M_VEGETATION,
                float(rng.uniform(0.35, 0.6)), rounding=(1.05, 1.5, 1.5))]


def trunk_parts(rng: np.random.Generator) -> list[Part]:
    """Tree trunk seen without its crown (pollarded, dead, or the crown out of the beams): 1-2.3 m, pedestrian-like.

    Sometimes with a protective cage of thin posts around it, as street trees have.
    """
    height, radius = rng.uniform(1.0, 2.3), rng.uniform(0.08, 0.35)
    rho = float(rng.uniform(0.25, 0.5))
    parts = [cylinder([0, 0, -0.2], [0, 0, height], radius, M_TRUNK, rho)]
    if rng.random() < 0.4:  # a stub branch or two
        for _ in range(int(rng.integers(1, 3))):
            ang = rng.uniform(0, 2 * math.pi)
            z = height * rng.uniform(0.6, 0.95)
            reach = rng.uniform(0.3, 0.8)
            parts.append(cylinder([0, 0, z], [reach * math.cos(ang), reach * math.sin(ang), z + reach * 0.6],
                                  radius * 0.4, M_TRUNK, rho))
    if rng.random() < 0.25:
        cage = radius + rng.uniform(0.2, 0.4)
        for ang in np.linspace(0, 2 * math.pi, 4, endpoint=False):
            parts.append(cylinder([cage * math.cos(ang), cage * math.sin(ang), -0.1],
                                  [cage * math.cos(ang), cage * math.sin(ang), 1.4], 0.02, M_POLE, 0.3))
    return parts


def hedge_fragment_parts(rng: np.random.Generator) -> list[Part]:
    """Short hedge piece or shrub block 1-4 m long, 0.9-2 m high: a foliage proposal of car or pedestrian size."""
    length, height, thick = rng.uniform(1.0, 4.0), rng.uniform(0.9, 2.0), rng.uniform(0.5, 1.2)
    return [box([0, 0, height / 2 - 0.1], [length / 2, thick / 2, height / 2 + 0.1], M_VEGETATION,
                float(rng.uniform(0.35, 0.6)), rounding=(1.1, 1.4, 1.4))]


def car_bush_parts(rng: np.random.Generator, length: float | None = None, height: float | None = None) -> list[Part]:
    """Bush or shrub clump of car size: 2.2-5 m long, 1.1-2.2 m deep, 0.9-1.9 m high (or as given), a few
    overlapping ellipsoids along x."""
    length = rng.uniform(2.2, 5.0) if length is None else length
    height = rng.uniform(0.9, 1.9) if height is None else height
    depth = rng.uniform(1.1, 2.2)
    rho = float(rng.uniform(0.35, 0.6))
    n = max(2, int(length / 1.2))
    parts = []
    for x in np.linspace(-length / 2 + depth / 3, length / 2 - depth / 3, n):
        semi = np.array([max(length / n * rng.uniform(0.6, 0.8), 0.4), depth / 2 * rng.uniform(0.8, 1.0),
                         height / 2 * rng.uniform(0.85, 1.0)])
        parts.append(ellipsoid([x + rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), semi[2]], semi, M_VEGETATION, rho))
    return parts


def low_hedge_parts(rng: np.random.Generator, length: float | None = None, height: float | None = None) -> list[Part]:
    """Low hedge or box shrub row 2.5-6 m long (or as given), 0.9-1.3 m high (or as given), 0.6-1.2 m thick."""
    length = rng.uniform(2.5, 6.0) if length is None else length
    height = rng.uniform(0.9, 1.3) if height is None else height
    thick = rng.uniform(0.6, 1.2)
    return [box([0, 0, height / 2 - 0.1], [length / 2, thick / 2, height / 2 + 0.1], M_VEGETATION,
                float(rng.uniform(0.35, 0.6)), rounding=(1.05, 1.4, 1.5))]
