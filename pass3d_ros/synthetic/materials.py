"""Surface materials of the synthetic scene and the reflectivity draws shared by several object models.

The material of a hit decides its intensity and dropout in the dataset's sensor model (glass, foliage, fences).
"""

from __future__ import annotations

import numpy as np

(M_BUILDING, M_WALL, M_FENCE, M_VEGETATION, M_TRUNK, M_POLE, M_SIGN, M_PAINT, M_CABIN, M_TIRE, M_CLOTH,
 M_SKIN, M_METAL, M_OTHER) = range(14)
POROUS_MATERIALS = (M_VEGETATION,)  # rays reach some way into foliage before they return


def paint_rho(rng: np.random.Generator) -> float:
    """Car paint reflectivity: many dark cars (KITTI car points are often intensity 0), some bright."""
    kind = rng.random()
    if kind < 0.45:
        return float(rng.uniform(0.0, 0.01))
    if kind < 0.85:
        return float(rng.uniform(0.15, 0.5))
    return float(rng.uniform(0.4, 0.7))


def cloth_rho(rng: np.random.Generator) -> float:
    """Clothing reflectivity: anything from dark to bright."""
    return float(rng.uniform(0.05, 0.55))
