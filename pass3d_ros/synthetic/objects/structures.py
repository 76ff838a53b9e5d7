"""Models of built structures along the street: buildings, porches, walls, fences and their fragments (background)."""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic.materials import M_BUILDING, M_FENCE, M_POLE, M_WALL
from pass3d_ros.synthetic.parts import Part, box, cylinder


def building_parts(rng: np.random.Generator, width: float, depth: float, height: float) -> list[Part]:
    """Building `width` along x, `depth` along y (the lot decides them), sunk 0.5 m so slopes leave no gap."""
    return [box([0, 0, height / 2 - 0.5], [width / 2, depth / 2, height / 2 + 0.5], M_BUILDING,
                float(rng.uniform(0.35, 0.6)))]


def porch_parts(rng: np.random.Generator) -> tuple[list[Part], float]:
    """Porch, bay or shop front built out of a building's front; returns (parts, depth along y)."""
    pw, pd, ph = rng.uniform(1.5, 5.0), rng.uniform(0.5, 2.0), rng.uniform(0.8, 3.0)
    return [box([0, 0, ph / 2 - 0.2], [pw / 2, pd / 2, ph / 2 + 0.2], M_BUILDING, float(rng.uniform(0.2, 0.6)))], pd


def wall_parts(rng: np.random.Generator, length: float) -> list[Part]:
    """Garden or boundary wall `length` long along x."""
    height, thick = rng.uniform(0.8, 2.6), rng.uniform(0.2, 0.4)
    return [box([0, 0, height / 2 - 0.2], [length / 2, thick / 2, height / 2 + 0.2], M_WALL,
                float(rng.uniform(0.25, 0.55)))]


def fence_parts(rng: np.random.Generator, length: float) -> list[Part]:
    """Mesh fence `length` long along x on round posts about every 2.5 m (the dataset drops rays through the mesh)."""
    height = rng.uniform(1.0, 2.0)
    rho = float(rng.uniform(0.2, 0.5))
    parts = [box([0, 0, height / 2], [length / 2, 0.02, height / 2], M_FENCE, rho)]
    n_posts = max(int(length / 2.5), 1)
    for x in np.linspace(-length / 2, length / 2, n_posts + 1):
        parts.append(cylinder([x, 0.0, -0.1], [x, 0.0, height + 0.05], 0.04, M_POLE, rho))
    return parts


def wall_fragment_parts(rng: np.random.Generator) -> list[Part]:
    """Short wall piece 0.8-5 m long, 0.9-2.2 m high (gate pier, garden-wall end, retaining step): proposal-sized."""
    length, height, thick = rng.uniform(0.8, 5.0), rng.uniform(0.9, 2.2), rng.uniform(0.2, 0.5)
    return [box([0, 0, height / 2 - 0.2], [length / 2, thick / 2, height / 2 + 0.2], M_WALL,
                float(rng.uniform(0.2, 0.6)))]


def building_corner_parts(rng: np.random.Generator) -> list[Part]:
    """Corner of a low structure (garage, kiosk, shed): two walls meeting at the origin, 1.8-2.6 m high.

    The walls run along +x and +y; seen from the street only a few metres of each show, which stage 1 keeps.
    """
    height = rng.uniform(1.8, 2.6)
    a, c, t = rng.uniform(1.0, 4.0), rng.uniform(1.0, 4.0), rng.uniform(0.15, 0.3)
    rho = float(rng.uniform(0.25, 0.6))
    return [box([a / 2, t / 2, height / 2 - 0.2], [a / 2, t / 2, height / 2 + 0.2], M_BUILDING, rho),
            box([t / 2, c / 2, height / 2 - 0.2], [t / 2, c / 2, height / 2 + 0.2], M_BUILDING, rho)]
