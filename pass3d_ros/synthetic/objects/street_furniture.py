"""Street furniture models: street lamps and traffic signs (background clutter near the curb)."""

from __future__ import annotations

import numpy as np

from pass3d_ros.synthetic.materials import M_POLE, M_SIGN
from pass3d_ros.synthetic.parts import Part, box, cylinder, disc


def street_lamp_parts(rng: np.random.Generator, arm_side: float) -> list[Part]:
    """Street lamp: a tall pole whose arm and lamp head reach out along `arm_side` * y (toward the road)."""
    height, radius = rng.uniform(5.0, 9.0), rng.uniform(0.06, 0.12)
    rho = float(rng.uniform(0.1, 0.35))
    arm = rng.uniform(0.8, 2.0)
    return [
        cylinder([0, 0, -0.2], [0, 0, height], radius, M_POLE, rho),
        cylinder([0, 0, height - 0.1], [0, arm_side * arm, height + 0.15], 0.04, M_POLE, rho),
        box([0, arm_side * arm, height + 0.05], [0.3, 0.15, 0.08], M_POLE, rho),
    ]


def sign_parts(rng: np.random.Generator) -> list[Part]:
    """Traffic sign: a thin post with a round or square retro-reflective face toward +x."""
    height = rng.uniform(2.2, 3.2)
    rho_sign = float(rng.uniform(0.6, 0.95))
    parts = [cylinder([0, 0, -0.2], [0, 0, height], 0.035, M_POLE, 0.25)]
    if rng.random() < 0.5:
        parts.append(disc([0.05, 0, height - 0.1], [1, 0, 0], rng.uniform(0.3, 0.45), 0.01, M_SIGN, rho_sign))
    else:
        parts.append(box([0.05, 0, height - 0.2], [0.01, rng.uniform(0.3, 0.45), rng.uniform(0.3, 0.45)],
                         M_SIGN, rho_sign))
    return parts
