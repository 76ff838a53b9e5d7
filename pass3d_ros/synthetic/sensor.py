"""KITTI's Velodyne HDL-64E: laser table, firing order, ego-vehicle shadow, range noise and return model.

Geometry measured on KITTI object scans (which lie exactly on 64 cones): laser k fires from (0, 0, v_k)
at elevation e_k, so its points satisfy z = v_k + r_xy * tan(e_k). The upper block (lasers 0-31) is about
1/3 degree apart, the lower block about 1/2 degree. Points come out ring after ring, top laser first, each
ring sweeping azimuth upwards from just above 0 (the +x axis) to just below 360 degrees, like a KITTI .bin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

N_LASERS = 64
MOUNT_HEIGHT_M = 1.73  # sensor origin above the road under the car

# Elevation (degrees) of each laser, ring 0 = highest.
ELEVATION_DEG = np.array([
    1.94, 1.57, 1.30, 0.87, 0.58, 0.18, -0.09, -0.45, -0.80, -1.20, -1.49, -1.83, -2.21, -2.55, -2.87, -3.24,
    -3.54, -3.94, -4.22, -4.59, -4.91, -5.25, -5.61, -5.96, -6.33, -6.68, -7.00, -7.29, -7.68, -8.06, -8.31,
    -8.71, -9.03, -9.57, -10.06, -10.47, -10.96, -11.60, -12.11, -12.56, -13.04, -13.48, -14.05, -14.60,
    -15.19, -15.66, -16.18, -16.55, -17.19, -17.73, -18.32, -18.80, -19.32, -19.74, -20.22, -20.79, -21.32,
    -21.94, -22.44, -22.86, -23.32, -23.97, -24.51, -25.00,
])
# Height of each laser's firing point above the sensor origin (m): upper block ~0.2, lower block ~0.12.
VERTICAL_OFFSET_M = np.concatenate([np.linspace(0.209, 0.198, 32), np.linspace(0.126, 0.116, 32)])

# Azimuth wedges (first ring, last ring, from deg, to deg) where the ego car's roof, rack and mounts hide the
# ground: the azimuth spans that are empty in every KITTI development scan.
EGO_SHADOW: tuple[tuple[int, int, float, float], ...] = (
    (42, 52, 157.0, 165.0), (42, 52, 197.0, 205.0), (52, 52, 170.0, 192.0), (53, 59, 157.0, 205.0),
    (60, 63, 153.0, 210.0), (47, 47, 288.0, 293.0), (48, 59, 283.0, 300.0), (60, 63, 283.0, 292.0),
    (56, 63, 129.0, 134.0), (56, 63, 229.0, 234.0), (57, 57, 0.0, 10.0), (57, 57, 350.0, 360.0),
    (58, 59, 0.0, 12.0), (58, 59, 346.0, 360.0), (60, 60, 0.0, 16.0), (60, 60, 345.0, 360.0),
    (61, 63, 0.0, 19.0), (61, 63, 342.0, 360.0), (61, 63, 26.0, 29.0), (61, 63, 33.0, 37.0),
    (61, 63, 322.0, 326.0), (61, 63, 329.0, 333.0),
)


def _laser_gains() -> np.ndarray:
    """Fixed per-laser intensity gains: KITTI's rings differ in brightness (about 15%, a few lasers weak)."""
    rng = np.random.default_rng(6464)
    gain = np.exp(rng.normal(0.0, 0.1, N_LASERS))
    gain[rng.choice(N_LASERS, 6, replace=False)] *= rng.uniform(0.4, 0.75, 6)
    return gain


@dataclass(frozen=True)
class HDL64E:
    """Sensor parameters; the defaults are KITTI's HDL-64E at 10 Hz."""

    elevation_deg: np.ndarray = field(default_factory=lambda: ELEVATION_DEG.copy())
    vertical_offset_m: np.ndarray = field(default_factory=lambda: VERTICAL_OFFSET_M.copy())
    intensity_gain: np.ndarray = field(default_factory=_laser_gains)
    # 2140 firings per revolution: 18.5 full steps per 20 firings, as the azimuth gaps of KITTI scans show
    # (mostly 0.182 degrees, with a half step about every 6.7 firings).
    columns: int = 2140
    half_step_every: tuple[int, ...] = (3, 10, 16)  # positions mod 20 of the half steps
    max_range_m: float = 120.0
    # KITTI scans hold almost nothing past 80 m: returns fade out around this range.
    fade_range_m: float = 75.0
    range_noise_m: float = 0.02
    rate_hz: float = 10.0
    mount_height_m: float = MOUNT_HEIGHT_M
    # Signal model: snr = snr_scale * reflectivity * cos(incidence) / range^2; p(return) = 1 - exp(-snr),
    # and a weak return reads intensity 0 with probability exp(-(snr' / zero_snr)^zero_power), as far and grazing
    # KITTI points often do, where snr' also fades past zero_fade_m (real zero share by range, 0-10 / 10-20 /
    # 20-30 / 30-50 / 50+ m: ground 5 / 5 / 9 / 55 / 89 %, non-ground background 2 / 3 / 4 / 28 / 82 %).
    snr_scale: float = 40000.0
    zero_snr: float = 1.5
    zero_power: float = 2.0
    zero_fade_m: float = 45.0

    @property
    def n_lasers(self) -> int:
        """Number of lasers (rings)."""
        return len(self.elevation_deg)

    def azimuth_steps_deg(self) -> np.ndarray:
        """Azimuth advance (degrees) before each firing of a revolution; they sum to 360."""
        half = np.isin(np.arange(self.columns) % 20, self.half_step_every)
        full = 360.0 / (self.columns - 0.5 * half.sum())
        return np.where(half, 0.5 * full, full)


def firing_azimuths(sensor: HDL64E, rng: np.random.Generator) -> np.ndarray:
    """Azimuth (radians, in [0, 2 pi)) of every firing: shape (lasers, columns), NaN where past 360 degrees.

    Each laser starts at its own small offset (the revolution's phase plus a per-laser jitter), so the first
    point of every ring lies just above 0 degrees and the last just below 360, as in KITTI.
    """
    steps = sensor.azimuth_steps_deg()
    base = np.concatenate([[0.0], np.cumsum(steps[:-1])])
    start = rng.uniform(0.0, steps[0]) + rng.uniform(0.0, steps[0], size=sensor.n_lasers)
    az = start[:, None] + base[None, :]
    az[az >= 360.0] = np.nan
    return np.deg2rad(az)


def ego_shadow_mask(n_lasers: int, azimuth_rad: np.ndarray) -> np.ndarray:
    """True for firings (lasers x columns) that hit the ego car, which KITTI scans leave out."""
    az = np.rad2deg(azimuth_rad)
    mask = np.zeros(az.shape, dtype=bool)
    for first, last, lo, hi in EGO_SHADOW:
        rows = slice(first, min(last, n_lasers - 1) + 1)
        with np.errstate(invalid="ignore"):
            mask[rows] |= (az[rows] >= lo) & (az[rows] < hi)
    return mask


def ray_bundle(sensor: HDL64E, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of one revolution in firing order: origins (N, 3), unit directions (N, 3), ring (N,) uint16.

    Firings past 360 degrees or into the ego car's shadow are left out.
    """
    az = firing_azimuths(sensor, rng)
    keep = ~np.isnan(az) & ~ego_shadow_mask(sensor.n_lasers, az)
    ring = np.broadcast_to(np.arange(sensor.n_lasers, dtype=np.uint16)[:, None], az.shape)[keep]
    elev = np.deg2rad(sensor.elevation_deg)[ring]
    azk = az[keep]
    cos_e = np.cos(elev)
    dirs = np.stack([cos_e * np.cos(azk), cos_e * np.sin(azk), np.sin(elev)], axis=1)
    origins = np.zeros_like(dirs)
    origins[:, 2] = sensor.vertical_offset_m[ring]
    return origins, dirs, np.ascontiguousarray(ring)


def signal_to_noise(sensor: HDL64E, reflectivity: np.ndarray, cos_incidence: np.ndarray,
                    distance: np.ndarray) -> np.ndarray:
    """Strength of a return: brighter, more frontal and nearer surfaces give more; fades past fade_range_m."""
    d = np.maximum(distance, 1.0)
    fade = 1.0 / (1.0 + (d / sensor.fade_range_m) ** 8)
    return sensor.snr_scale * reflectivity * np.clip(cos_incidence, 0.0, 1.0) / d**2 * fade


def return_probability(sensor: HDL64E, snr: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """Chance that a hit gives a return at all (none beyond max_range_m)."""
    return np.where(distance <= sensor.max_range_m, -np.expm1(-snr), 0.0)


def measured_intensity(sensor: HDL64E, reflectivity: np.ndarray, cos_incidence: np.ndarray, ring: np.ndarray,
                       snr: np.ndarray, noise: np.ndarray, uniform: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """KITTI-like intensity in [0, 0.99], 0.01 steps.

    From reflectivity, incidence and the laser's gain, with noise (standard normal `noise`); weak returns
    read 0 (decided by `uniform` draws in [0, 1)).
    """
    raw = reflectivity * np.clip(cos_incidence, 1e-3, 1.0) ** 0.35 * sensor.intensity_gain[ring]
    raw = raw + noise * (0.01 + 0.12 * reflectivity)
    value = np.clip(np.floor(raw * 100.0) / 100.0, 0.0, 0.99)
    weak = snr / (1.0 + (np.asarray(distance) / sensor.zero_fade_m) ** 6) / sensor.zero_snr
    return np.where(uniform < np.exp(-(weak**sensor.zero_power)), 0.0, value)
