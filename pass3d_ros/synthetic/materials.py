"""Surface materials of the synthetic scene, their reflectivity draws, and the real intensity they are fitted to.

The material of a hit decides its intensity and dropout in the dataset's sensor model (glass, foliage, fences).
On KITTI's HDL-64E a reading of exactly 0 comes from dark (low-reflectivity) surfaces, from glancing hits and
from range; no class owns it. So every material has a share of dark surfaces (`DARK_SHARE`, drawn per object
and material: a whole pole; car paint and clothes also in patches), and the sensor model adds the weak-return
zeros of far and grazing hits.

Measured on the real frames (share of points reading exactly 0, %; n = points), with
  `.venv/bin/python -c "from pass3d_ros.synthetic.materials import print_real_table; print_real_table()"`:

  SemanticKITTI 00 (3 frames), per SemanticKITTI class: car 45.0 (13346), road 12.8 (99691), parking 1.8,
  sidewalk 1.6, lane-marking 2.2, terrain 4.3, building 2.4 (57571), fence 4.1, other-structure 8.7,
  vegetation 3.6 (81226), trunk 6.3, pole 27.3 (1782), traffic-sign 6.8, other-object 16.4, unlabelled 76.4;
  by range (0-10 / 10-20 / 20-30 / 30-50 / 50+ m): car 51 / 38 / 29 / 43 / -, ground 6 / 7 / 8 / 51 / -,
  non-ground background 2 / 2 / 3 / 23 / 77.
  KITTI object (3 frames, front view, box labels): pedestrian 3.4 (377 points, one person at 9 m), cyclist 66.7
  (18 points at 46 m: too few to stand for the class), car 75.0 (76 points at 34 m), background 8.1.
  13 unlabelled HDL-64E scans (stage-1 ground): all 11.1, ground 5.9, non-ground 16.7 (cars included); by range
  ground 5 / 4 / 10 / 58 / 89, non-ground 20 / 5 / 4 / 33 / 88.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN

(M_BUILDING, M_WALL, M_FENCE, M_VEGETATION, M_TRUNK, M_POLE, M_SIGN, M_PAINT, M_CABIN, M_TIRE, M_CLOTH,
 M_SKIN, M_METAL, M_OTHER) = range(14)
N_MATERIALS = 14
POROUS_MATERIALS = (M_VEGETATION,)  # rays reach some way into foliage before they return

# Real zero-reading shares (%) per class, the targets of the generator (see the module docstring). Pedestrian and
# cyclist: the dev frames hold one person and 18 cyclist points, so the figures over more real scans
# (pedestrian 8, cyclist 24, non-ground background 12, car 48) bound them too; the targets lie between.
REAL_ZERO_SHARE: dict[str, float] = {
    "car": 45.0,  # SemanticKITTI 00, 13346 points (issue: 48)
    "pedestrian": 5.5,  # KITTI object 3.4 (377 points); issue: 8
    "cyclist": 24.0,  # issue's figure; KITTI object dev frames: 18 points
    "background": 9.0,  # non-ground background: SemanticKITTI 00 6.9 (160177 points); issue: 12
    "ground": 7.3,  # SemanticKITTI 00, 200228 points; unlabelled scans (stage-1 ground) 5.9
}

# Share of surfaces of each material that are dark (reflectivity below the sensor's first step: reads 0). Small
# things are dark as a whole (DARK_SHARE per object and material; clothes, tyres and bike frames per part), large
# surfaces in patches (DARK_CELL_SHARE of DARK_CELL_M cells), so one dark wall cannot swing a frame.
DARK_SHARE = np.zeros(N_MATERIALS)
DARK_SHARE[[M_TRUNK, M_POLE, M_SIGN, M_TIRE, M_CLOTH, M_SKIN, M_METAL, M_OTHER]] = [0.04, 0.38, 0.04, 0.9, 0.03, 0.1,
                                                                                  0.7, 0.25]
PER_PART = (M_TIRE, M_CLOTH, M_SKIN, M_METAL)
DARK_CELL_SHARE = np.zeros(N_MATERIALS)
DARK_CELL_SHARE[[M_WALL, M_FENCE]] = 0.05
# Clothes: dark garments as a whole (DARK_SHARE per part) and dark patches (CLOTH_CELL_M cells: trousers, bags,
# hair); mostly patches, so that one near person in black does not swing the pedestrian share of a frame.
CLOTH_CELL_M = 0.25
DARK_CELL_SHARE[M_CLOTH] = 0.03
# Car paint (and the painted cabin roof): KITTI's car points read 0 in 45 % of cases, from black cars and from the
# dark parts and patches of any car (dark trim, bumpers and grilles, glossy panels that mirror the beam away). A
# PAINT_BLACK_SHARE of bodies are dark as a whole (`paint_rho`); on the others a DARK_CELL_SHARE of PAINT_CELL_M
# cells is dark. Most of the darkness thus sits in small patches on every car rather than in whole cars, so the
# share of a frame, where a few near cars hold most car points, does not swing with one car's colour.
PAINT_BLACK_SHARE = 0.2
PAINT_CELL_M = 0.4
DARK_CELL_SHARE[[M_PAINT, M_CABIN]] = 0.42
DARK_CELL_M = 1.5  # edge of the dark-patch cells (ground: in x-y; other surfaces: in 3D)
DARK_CELL_EDGE_M = np.full(N_MATERIALS, DARK_CELL_M)  # dark-patch cell edge per material
DARK_CELL_EDGE_M[[M_PAINT, M_CABIN]] = PAINT_CELL_M
DARK_CELL_EDGE_M[M_CLOTH] = CLOTH_CELL_M
DARK_RHO = 0.008  # dark surfaces draw their reflectivity from [0, DARK_RHO)
# Share of ground cells (patches, tar, wet spots) that are dark, per ground region (none, road, sidewalk, terrain):
# asphalt is the dark ground (SemanticKITTI road 12.8 % zero), paving stones and grass rarely read 0 (1.6, 4.3 %).
GROUND_DARK_SHARE = np.array([0.0, 0.13, 0.02, 0.01])


def paint_rho(rng: np.random.Generator) -> float:
    """Car paint reflectivity: PAINT_BLACK_SHARE black cars, the others mid to bright (dark patches on every car:
    DARK_CELL_SHARE of paint)."""
    kind = rng.random()
    if kind < PAINT_BLACK_SHARE:
        return float(rng.uniform(0.0, 0.01))
    if kind < PAINT_BLACK_SHARE + 0.7 * (1.0 - PAINT_BLACK_SHARE):
        return float(rng.uniform(0.15, 0.5))
    return float(rng.uniform(0.4, 0.7))


def cloth_rho(rng: np.random.Generator) -> float:
    """Clothing reflectivity: anything from dark to bright."""
    return float(rng.uniform(0.05, 0.55))


def darken(prho: np.ndarray, pmaterial: np.ndarray, pobject: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Per-primitive reflectivity with dark surfaces: each (object, material) pair, or each part of a PER_PART
    material, is dark with DARK_SHARE of its material."""
    part = np.isin(pmaterial, PER_PART)
    owner = np.where(part, len(pobject) + np.arange(len(pobject)), pobject).astype(np.int64)
    key = owner * N_MATERIALS + pmaterial
    uniq, inverse = np.unique(key, return_inverse=True)
    dark = rng.random(len(uniq)) < DARK_SHARE[uniq % N_MATERIALS]
    level = rng.uniform(0.0, DARK_RHO, len(uniq))
    return np.where(dark[inverse], level[inverse], prho)


def dark_cells(xyz: np.ndarray, share: np.ndarray | float, salt: int,
               edge: np.ndarray | float = DARK_CELL_M) -> np.ndarray:
    """True for points in dark cells of a grid of `edge` metres (per point; DARK_CELL_M by default): a `share`
    (per point) of cells, by `salt`."""
    cell = np.floor(np.asarray(xyz) / np.reshape(edge, (-1, 1) if np.ndim(edge) else ())).astype(np.int64)
    h = (cell[:, 0] * 73856093) ^ (cell[:, 1] * 19349663) ^ (cell[:, 2] * 83492791) ^ salt
    h = (h * 2654435761) & 0xFFFFFFFF
    return h < (np.asarray(share) * 2**32).astype(np.int64)


def zero_shares(frames: Iterable) -> dict[str, float]:
    """Share (%) of points reading intensity exactly 0 per class (car, pedestrian, cyclist, non-ground
    background, ground) over frames with labels; ground needs the frame's ground mask."""
    zeros, totals = np.zeros(5), np.zeros(5)
    for frame in frames:
        value, labels = frame.points[:, 3], frame.labels
        ground = frame.ground if frame.ground is not None else np.zeros(len(labels), dtype=bool)
        masks = [labels == CAR, labels == PEDESTRIAN, labels == CYCLIST, (labels == BACKGROUND) & ~ground,
                 (labels == BACKGROUND) & ground]
        for k, mask in enumerate(masks):
            zeros[k] += np.count_nonzero(value[mask] == 0)
            totals[k] += np.count_nonzero(mask)
    names = ("car", "pedestrian", "cyclist", "background", "ground")
    return {n: float(100.0 * z / t) if t else float("nan") for n, z, t in zip(names, zeros, totals, strict=True)}


def print_real_table(root: str = "../shared/data") -> None:
    """Print the real zero-reading shares of the module docstring (dev frames and unlabelled scans under `root`)."""
    from pathlib import Path

    from pass3d_ros.core.pipeline import ScanPipeline
    from pass3d_ros.data.semantickitti import read_label_file
    from pass3d_ros.data.spec import open_dataset

    seq = Path(root) / "kitti_dev" / "semantickitti" / "sequences" / "00"
    frames = list(open_dataset(f"semantickitti:{seq}"))
    print("semantickitti 00 per class:", zero_shares(frames))
    raw = np.concatenate([read_label_file(seq / "labels" / f"{f.name}.label", len(f.points)) & 0xFFFF
                          for f in frames])
    value = np.concatenate([f.points[:, 3] for f in frames])
    for semantic in np.unique(raw):
        part = value[raw == semantic]
        print(f"  semantic {semantic}: {100.0 * np.mean(part == 0):.1f} % of {len(part)}")
    print("kitti_object:", zero_shares(open_dataset(f"kitti_object:{Path(root) / 'kitti_dev/object/training'}")))
    zeros, ground = [], []
    pipeline = ScanPipeline(intensity_match=False)
    for frame in open_dataset(f"semantickitti:{Path(root) / 'kitti_unlabeled'}"):
        proposed = pipeline.propose(frame.points)
        zeros.append(frame.points[:, 3] == 0)
        ground.append(proposed.in_input(proposed.result.ground, len(frame.points), False))
    z, g = np.concatenate(zeros), np.concatenate(ground)
    print(f"unlabelled: all {100 * z.mean():.1f}, ground {100 * z[g].mean():.1f}, non-ground {100 * z[~g].mean():.1f}")
