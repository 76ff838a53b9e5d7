"""Spinning LiDAR models: laser tables, firing and driver point order, ego-vehicle shadow, range noise, returns.

The default model is KITTI's Velodyne HDL-64E; `sensor_model(name)` gives the others of
pass3d_ros.core.stage1.lasers (VLP-16, VLP-32C, HDL-32E, OS1-32, OS1-64, OS1-128, Pandar40, Pandar40P, Pandar64,
PandarXT-32, RoboSense RS-LiDAR-32), see SENSOR_SPECS.

KITTI geometry measured on KITTI object scans (which lie exactly on 64 cones): laser k fires from (0, 0, v_k)
at elevation e_k, so its points satisfy z = v_k + r_xy * tan(e_k). The upper block (lasers 0-31) is about
1/3 degree apart, the lower block about 1/2 degree. Points come out ring after ring, top laser first, each
ring sweeping azimuth upwards from just above 0 (the +x axis) to just below 360 degrees, like a KITTI .bin.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from pass3d_ros.core.stage1.lasers import LASER_TABLES

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


def _laser_gains(n_lasers: int = N_LASERS) -> np.ndarray:
    """Fixed per-laser intensity gains: KITTI's rings differ in brightness (about 15%, a few lasers weak)."""
    rng = np.random.default_rng(6464 if n_lasers == N_LASERS else 6464 + n_lasers)
    gain = np.exp(rng.normal(0.0, 0.1, n_lasers))
    weak = max(n_lasers * 6 // 64, 1)
    gain[rng.choice(n_lasers, weak, replace=False)] *= rng.uniform(0.4, 0.75, weak)
    return gain


@dataclass(frozen=True)
class LidarModel:
    """Sensor parameters; the defaults are KITTI's HDL-64E at 10 Hz (`sensor_model` gives the others)."""

    name: str = "hdl64e"
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
    # Point order: "kitti" (ring after ring, each from just above 0 degrees upwards, as a KITTI .bin), "row" (ring
    # after ring, each sweeping clockwise from start_azimuth_deg: an organized Ouster cloud) or "column" (firing
    # order: one column after the other, its lasers in `firing_order`: Velodyne and Hesai drivers).
    point_order: str = "kitti"
    firing_order: tuple[int, ...] = ()  # rings in the order a column fires them (empty: top to bottom)
    start_azimuth_deg: float | None = None  # where the scan is cut (None: anywhere, as a packet-count cut)
    # Each laser's azimuth offset from its column's (degrees, one per ring; empty: none): lasers that fire together
    # point apart, so a column's points spread over this range of azimuths (a RoboSense RS-32's over 16 degrees)
    azimuth_offset_deg: tuple[float, ...] = ()
    ego_shadow: bool = True  # leave out KITTI's ego-car shadow (EGO_SHADOW: only for KITTI's HDL-64E)
    ray_drop: float = 0.0  # share of returns lost at random on top of the signal model
    driver: str = "kitti"  # "kitti" (float .bin), "velodyne", "ouster", "hesai" or "robosense": a driver's conventions
    intensity_max: int = 255  # the driver's intensity scale: Frame intensity 1.0 reads this much
    # Mount attitude (degrees, REP-103: roll about x, then pitch about y; positive pitch points the sensor's x axis
    # down, roll 180 is upside down): the rays are cast rotated by it, the points come back in the sensor's frame.
    mount_roll_deg: float = 0.0
    mount_pitch_deg: float = 0.0

    @property
    def n_lasers(self) -> int:
        """Number of lasers (rings)."""
        return len(self.elevation_deg)

    def mount_rotation(self) -> np.ndarray | None:
        """Rotation (3 x 3) taking sensor-frame vectors into the level frame (z up), R = Ry(pitch) Rx(roll); None
        for a level mount."""
        if not (self.mount_roll_deg or self.mount_pitch_deg):
            return None
        roll, pitch = np.deg2rad(self.mount_roll_deg), np.deg2rad(self.mount_pitch_deg)
        cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        return ry @ rx

    def azimuth_steps_deg(self) -> np.ndarray:
        """Azimuth advance (degrees) before each firing of a revolution; they sum to 360."""
        half = np.isin(np.arange(self.columns) % 20, self.half_step_every)
        full = 360.0 / (self.columns - 0.5 * half.sum())
        return np.where(half, 0.5 * full, full)


HDL64E = LidarModel  # KITTI's sensor: the defaults

# Velodyne laser ids in firing order (ring numbers, 0 = top). VLP-16 manual table 9-1: ids alternate -15, +1, -13,
# +3, ... degrees; HDL-32E manual: -30.67, -9.33, -29.33, -8.0, ...; VLP-32C manual table 9-2 (from the table's
# id -> angle column).
_VLP16_FIRING = tuple(int(r) for pair in zip(range(15, 7, -1), range(7, -1, -1), strict=True) for r in pair)
_HDL32E_FIRING = tuple(int(r) for pair in zip(range(31, 15, -1), range(15, -1, -1), strict=True) for r in pair)
_VLP32C_ID_DEG = (
    -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333, 1.333, 0.667,
    -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0, 4.667, -2.333, -2.0, 15.0, 10.333,
    -1.333,
)
_VLP32C_FIRING = tuple(LASER_TABLES["vlp32c"].index(e) for e in _VLP32C_ID_DEG)
# RoboSense RS-LiDAR-32 channels in the order a block lists them: the rows of the driver's calibration file
# (pass3d_ros.core.stage1.lasers, _RS32), channel id -> vertical angle.
_RS32_ID_DEG = (
    -10.333, 0.333, -6.477, 0.0, 2.3151, -0.333, 3.2795, -0.667, 4.6492, 1.667, 6.9824, 1.333, 10.3503, 1.0, 14.9833,
    0.667, -25.0294, -2.333, -14.6883, -2.667, -7.9627, -3.0, -5.4425, -3.333, -3.7027, -0.9463, -3.9822, -1.3509,
    -4.333, -1.667, -4.667, -1.9642,
)
_RS32_FIRING = tuple(LASER_TABLES["rs32"].index(e) for e in _RS32_ID_DEG)
# ... and each channel's horizontal offset (degrees), the file's second column, listed here by ring (0 = top laser)
_RS32_ID_AZIMUTH = (
    8.19315, -8.11089, 8.34127, -2.96772, 8.2448, 2.25193, -7.4969, 7.77112, 8.18069, -8.14859, -7.18652, -2.92932,
    8.3907, 2.24215, -7.04646, 7.70063, -7.2965, -7.91697, -7.25315, -2.89333, -6.89033, 2.45534, -6.90189, 7.73504,
    -8.00103, -8.12256, -2.75319, -2.97813, 2.56952, 2.38522, 7.94491, 7.65473,
)
_RS32_AZIMUTH = tuple(_RS32_ID_AZIMUTH[_RS32_FIRING.index(ring)] for ring in range(32))
# Hesai Pandar40: each channel's azimuth offset (degrees; channel 1 = ring 0, the top laser), the Azimuth column of the
# angle correction file whose elevations pass3d_ros.core.stage1.lasers uses (HesaiLidar_General_ROS config/Pandar40.csv)
_PANDAR40_AZIMUTH = (
    -0.025, -0.025, -0.026, -0.026, -2.54, -2.541, 2.49, -5.042, -2.541, 2.49, -5.042, -2.541, 2.49, -5.042, -0.026,
    2.49, -5.042, -0.026, 4.998, -2.541, -0.026, 4.998, -2.54, -0.026, 4.997, -2.54, 2.49, 4.997, -2.539, 2.49, 2.49,
    2.49, -0.024, -0.023, -0.023, -0.022, -2.528, -2.526, -2.523, -2.521,
)

# Per-sensor parameters at 10 Hz, all mounted at KITTI's 1.73 m (sensor_model(name, mount_height_m=...) moves it).
# columns: firings per revolution (VLP-16 / VLP-32C 55.296 us firing cycle -> ~0.2 deg, HDL-32E 46.08 us -> ~0.166
# deg, OS1 512, 1024 or 2048 columns: 1024, Pandar64 / Pandar40 / Pandar40P 0.2 deg, PandarXT-32 0.18 deg, RS-LiDAR-32
# 55.52 us for all 32 lasers (its user manual, Appendix A) -> ~0.2 deg);
# range_noise_m: 1 sigma = the data sheet's typical accuracy (VLP-16 +-3 cm, VLP-32C +-3 cm, HDL-32E +-2 cm, OS1
# +-3..5 cm: 4 cm, Pandar64 / Pandar40 / Pandar40P +-2 cm beyond 0.5 m, PandarXT-32 +-1 cm; RS-LiDAR-32: 3 cm, taken
# from the VLP-32C, no data sheet figure read); max_range_m from the data sheets (Pandar40 / 40P: 200 m at 20 %
# reflectivity, PandarXT-32: 120 m instrument range, OS1: 120 m, RS-LiDAR-32: 200 m); fade_range_m
# (where returns thin out) scaled from KITTI's 75 of 120 m; ray_drop is a guess (Ouster's dark/far dropouts more than
# Velodyne's). Approximate throughout: no per-unit calibration, no per-laser azimuth offsets but the RS-32's and the
# Pandar40's (the VLP-32C's and Pandar64's are missing), no per-point time. Vertical offsets: VLP-16
# manual's vertical correction (+-11.2 mm, proportional to the elevation); the others: none modelled (beam origin
# offsets of a few mm to cm, radial).
# Driver conventions: Hesai (HesaiLidar_General_ROS, and the UDP layout of the Pandar40 / 40P / 64 / XT-32 manuals:
# each block one azimuth, channels 1..N from the top laser down) publish column after column, each column's lasers
# top down, ring = the channel index, 0 the top laser, intensity the 1-byte reflectivity 0..255; Ouster (ouster-ros)
# an organized cloud, row (beam, 0 the top one) after row, intensity 16-bit; RoboSense (rslidar_sdk, XYZIRT points)
# block after block, each block's 32 channels in the calibration file's channel order (not sorted by angle), float32
# intensity 0..255, a uint16 ring and a float64 timestamp. The Frame carries ring 0 = the top laser
# for every sensor (the Hesai and Ouster drivers' numbering; velodyne_pointcloud numbers bottom-up).
SENSOR_SPECS: dict[str, dict] = {
    "hdl64e": {},
    "vlp16": dict(columns=1800, max_range_m=100.0, fade_range_m=62.0, range_noise_m=0.03, firing_order=_VLP16_FIRING,
                  point_order="column", driver="velodyne", ray_drop=0.005),
    "vlp32c": dict(columns=1800, max_range_m=200.0, fade_range_m=110.0, range_noise_m=0.03,
                   firing_order=_VLP32C_FIRING, point_order="column", driver="velodyne", ray_drop=0.005),
    "hdl32e": dict(columns=2170, max_range_m=100.0, fade_range_m=62.0, range_noise_m=0.02,
                   firing_order=_HDL32E_FIRING, point_order="column", driver="velodyne", ray_drop=0.005),
    "os1-32": dict(columns=1024, max_range_m=120.0, fade_range_m=75.0, range_noise_m=0.04, point_order="row",
                   start_azimuth_deg=180.0, driver="ouster", intensity_max=65535, ray_drop=0.02),
    "os1-64": dict(columns=1024, max_range_m=120.0, fade_range_m=75.0, range_noise_m=0.04, point_order="row",
                   start_azimuth_deg=180.0, driver="ouster", intensity_max=65535, ray_drop=0.02),
    "os1-128": dict(columns=1024, max_range_m=120.0, fade_range_m=75.0, range_noise_m=0.04, point_order="row",
                    start_azimuth_deg=180.0, driver="ouster", intensity_max=65535, ray_drop=0.02),
    "pandar40": dict(columns=1800, max_range_m=200.0, fade_range_m=110.0, range_noise_m=0.02, point_order="column",
                     start_azimuth_deg=0.0, driver="hesai", ray_drop=0.01, azimuth_offset_deg=_PANDAR40_AZIMUTH),
    "pandar40p": dict(columns=1800, max_range_m=200.0, fade_range_m=110.0, range_noise_m=0.02, point_order="column",
                      start_azimuth_deg=0.0, driver="hesai", ray_drop=0.01),
    "pandar64": dict(columns=1800, max_range_m=200.0, fade_range_m=110.0, range_noise_m=0.02, point_order="column",
                     start_azimuth_deg=0.0, driver="hesai", ray_drop=0.01),
    "pandarxt32": dict(columns=2000, max_range_m=120.0, fade_range_m=75.0, range_noise_m=0.01, point_order="column",
                       start_azimuth_deg=0.0, driver="hesai", ray_drop=0.01),
    "rs32": dict(columns=1800, max_range_m=200.0, fade_range_m=110.0, range_noise_m=0.03, firing_order=_RS32_FIRING,
                 point_order="column", driver="robosense", ray_drop=0.01, azimuth_offset_deg=_RS32_AZIMUTH),
}
SENSOR_NAMES: tuple[str, ...] = tuple(SENSOR_SPECS)


def sensor_model(name: str = "hdl64e", **overrides) -> LidarModel:
    """The model of a named sensor (SENSOR_NAMES), with any field overridden (columns=2048, mount_height_m=...)."""
    key = name.lower()
    if key not in SENSOR_SPECS:
        raise ValueError(f"unknown sensor {name!r}; known: {', '.join(SENSOR_NAMES)}")
    if key == "hdl64e":
        return replace(LidarModel(), **overrides) if overrides else LidarModel()
    elev = np.asarray(LASER_TABLES[key], dtype=np.float64)
    offset = -elev * 0.0112 / 15.0 if key == "vlp16" else np.zeros(len(elev))
    spec = dict(SENSOR_SPECS[key], name=key, elevation_deg=elev, vertical_offset_m=offset,
                intensity_gain=_laser_gains(len(elev)), half_step_every=(), ego_shadow=False)
    spec.update(overrides)
    return LidarModel(**spec)


def driver_intensity(sensor: LidarModel, intensity: np.ndarray) -> np.ndarray:
    """Intensity in [0, 1] on the driver's scale (velodyne, hesai and robosense 0..255, ouster 16-bit reflectivity)."""
    return np.round(np.clip(intensity, 0.0, 1.0) * sensor.intensity_max).astype(np.float32)


def firing_azimuths(sensor: LidarModel, rng: np.random.Generator) -> np.ndarray:
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


def _sweep_azimuths(sensor: LidarModel, rng: np.random.Generator) -> np.ndarray:
    """Azimuths (radians, lasers x columns) of a clockwise sweep, column 0 at the cut, as real drivers turn, each
    laser's moved by its azimuth offset."""
    start = sensor.start_azimuth_deg
    start = rng.uniform(0.0, 360.0) if start is None else start
    az = start - 360.0 / sensor.columns * np.arange(sensor.columns)
    if sensor.azimuth_offset_deg:
        return np.mod(np.deg2rad(az[None, :] + np.asarray(sensor.azimuth_offset_deg)[:, None]), 2.0 * np.pi)
    return np.broadcast_to(np.mod(np.deg2rad(az), 2.0 * np.pi), (sensor.n_lasers, sensor.columns))


def ray_grid(sensor: LidarModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rays of one revolution, ring after ring in sweep order: origins (N, 3), unit directions (N, 3),
    ring (N,) uint16 and column (N,) int32 (the firing's place in the revolution).

    KITTI order: firings past 360 degrees or into the ego car's shadow are left out. Origins and directions are in
    the level frame: a tilted or inverted mount (mount_rotation) turns the lasers before they are cast.
    """
    if sensor.point_order == "kitti":
        az = firing_azimuths(sensor, rng)
        keep = ~np.isnan(az)
        if sensor.ego_shadow:
            keep &= ~ego_shadow_mask(sensor.n_lasers, az)
    else:
        az = _sweep_azimuths(sensor, rng)
        keep = np.ones(az.shape, dtype=bool)
    column = np.broadcast_to(np.arange(sensor.columns, dtype=np.int32)[None, :], az.shape)[keep]
    origins, dirs, ring = _rays(sensor, az, keep)
    rotation = sensor.mount_rotation()
    if rotation is not None:
        origins, dirs = origins @ rotation.T, dirs @ rotation.T
    return origins, dirs, ring, column


def ray_bundle(sensor: LidarModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of one revolution, ring after ring: origins (N, 3), unit directions (N, 3), ring (N,) uint16."""
    return ray_grid(sensor, rng)[:3]


def driver_order(sensor: LidarModel, ring: np.ndarray, column: np.ndarray) -> np.ndarray | None:
    """Permutation from ring-after-ring order to the order the sensor's driver publishes (None: already in it).

    "column": one column (firing) after the other, each listing its lasers in the order they fire.
    """
    if sensor.point_order != "column":
        return None
    rank = np.empty(sensor.n_lasers, dtype=np.int64)
    rank[list(sensor.firing_order or range(sensor.n_lasers))] = np.arange(sensor.n_lasers)
    return np.lexsort((rank[ring], column))


def _rays(sensor: LidarModel, az: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origins, directions and rings of the kept firings of an azimuth grid (lasers x columns)."""
    ring = np.broadcast_to(np.arange(sensor.n_lasers, dtype=np.uint16)[:, None], az.shape)[keep]
    elev = np.deg2rad(sensor.elevation_deg)[ring]
    azk = az[keep]
    cos_e = np.cos(elev)
    dirs = np.stack([cos_e * np.cos(azk), cos_e * np.sin(azk), np.sin(elev)], axis=1)
    origins = np.zeros_like(dirs)
    origins[:, 2] = sensor.vertical_offset_m[ring]
    return origins, dirs, np.ascontiguousarray(ring)


def signal_to_noise(sensor: LidarModel, reflectivity: np.ndarray, cos_incidence: np.ndarray,
                    distance: np.ndarray) -> np.ndarray:
    """Strength of a return: brighter, more frontal and nearer surfaces give more; fades past fade_range_m."""
    d = np.maximum(distance, 1.0)
    fade = 1.0 / (1.0 + (d / sensor.fade_range_m) ** 8)
    return sensor.snr_scale * reflectivity * np.clip(cos_incidence, 0.0, 1.0) / d**2 * fade


def return_probability(sensor: LidarModel, snr: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """Chance that a hit gives a return at all (none beyond max_range_m)."""
    return np.where(distance <= sensor.max_range_m, -np.expm1(-snr), 0.0)


def measured_intensity(sensor: LidarModel, reflectivity: np.ndarray, cos_incidence: np.ndarray, ring: np.ndarray,
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
