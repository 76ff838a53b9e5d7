"""Laser elevation tables of common spinning LiDARs, ring 0 the highest laser (KITTI's order).

Angles are in degrees from the sensor's horizontal plane, as the makers' manuals and driver calibration files give
them, sorted from the top laser down. A table marked approximate is a nominal spread or one unit's calibration, not
the calibration of the unit at hand. Ring recovery refits every laser's line to the scan itself
(pass3d_ros.core.stage1.ring), so the table only has to tell how many lasers there are and roughly where: each laser is
looked for within half the gap to its neighbours, so a table further off than that (another beam configuration, a
nominal spread that real units do not reach) seeds lines on the wrong lasers, and "auto" does better.
"""

from __future__ import annotations

import numpy as np

# Velodyne VLP-16 user manual (63-9243), table 9-1: -15..+15 degrees in 2 degree steps.
_VLP16 = tuple(np.arange(15.0, -15.5, -2.0))
# Velodyne HDL-32E user manual (63-9113), laser angles: -30.67..+10.67 degrees in 1.333 degree steps.
_HDL32E = tuple(np.round(10.67 - 4.0 / 3.0 * np.arange(32), 3))
# Velodyne VLP-32C user manual (63-9325), table 9-2 (non-uniform: dense around the horizon).
_VLP32C = (
    15.0, 10.333, 7.0, 4.667, 3.333, 2.333, 1.667, 1.333, 1.0, 0.667, 0.333, 0.0, -0.333, -0.667, -1.0, -1.333,
    -1.667, -2.0, -2.333, -2.667, -3.0, -3.333, -3.667, -4.0, -4.667, -5.333, -6.148, -7.254, -8.843, -11.31,
    -15.639, -25.0,
)
# Velodyne HDL-64E S2 (KITTI's sensor): upper block +2.0..-8.33 degrees in 1/3 degree steps, lower block
# -8.83..-24.33 degrees in 1/2 degree steps, per the S2 manual. Approximate: each unit's calibration differs by up
# to a few tenths of a degree (KITTI's fitted lines run +1.9..-25.0).
_HDL64E = tuple(np.round(np.concatenate([2.0 - np.arange(32) / 3.0, -8.83 - 0.5 * np.arange(32)]), 3))
# Ouster OS1 gen2 data sheets, "uniform" beam configuration: beams spread evenly. Approximate: OS1-64 over
# +-16.6 degrees (33.2 total); OS1-128 (Rev6) over +-22.5 degrees (45 total).
_OS1_64 = tuple(np.round(np.linspace(16.6, -16.6, 64), 3))
_OS1_128 = tuple(np.round(np.linspace(22.5, -22.5, 128), 3))
# Hesai Pandar64 angle correction file (HesaiLidar_General_ROS, Pandar64 default calibration), elevation column;
# +15..-25 degrees, 0.167 degree steps between +2 and -6. Approximate: per-unit calibrations differ slightly.
_PANDAR64 = (
    14.882, 11.032, 8.059, 5.057, 3.04, 2.028, 1.86, 1.688, 1.522, 1.351, 1.184, 1.013, 0.846, 0.675, 0.508, 0.337,
    0.169, 0.0, -0.169, -0.337, -0.508, -0.675, -0.845, -1.013, -1.184, -1.351, -1.522, -1.688, -1.86, -2.028,
    -2.198, -2.365, -2.536, -2.7, -2.873, -3.04, -3.21, -3.375, -3.548, -3.712, -3.884, -4.05, -4.221, -4.385,
    -4.558, -4.72, -4.892, -5.057, -5.229, -5.391, -5.565, -5.726, -5.898, -6.061, -7.063, -8.059, -9.06, -9.885,
    -11.032, -12.006, -12.974, -13.93, -18.889, -24.897,
)
# Hesai Pandar40P design values (HesaiLidar_General_SDK's default Pandar40P table, src/PandarGeneralRaw/src/
# pandarGeneral_internal.cc): +15..-25 degrees, 1/3 degree steps between +2 and -6. Approximate: unit calibrations
# differ by up to 0.21 degrees (tier4/nebula's Pandar40P.csv, HesaiLidar_SDK_2.0's Pandar40E3X angle correction file).
_PANDAR40P = (15.0, 11.0, 8.0, 5.0, 3.0, *np.round(2.0 - np.arange(25) / 3.0, 3), *np.arange(-7.0, -14.5, -1.0),
              -19.0, -25.0)
# Hesai Pandar40, the original 40-laser model (narrower than the Pandar40P): HesaiLidar_General_ROS's angle
# correction file config/Pandar40.csv, elevation column; +7.25..-15.59 degrees, 0.34 degree steps between +2.2 and
# -5.9. Approximate: one unit's calibration (the same repository's config/correction.csv is 0.107 degrees lower
# throughout; Apollo's hesai driver defaults run +6.96..-15.44 degrees, up to 0.29 degrees off).
_PANDAR40 = (
    7.25, 6.249, 5.243, 4.235, 3.222, 2.209, 1.874, 1.528, 1.194, 0.859, 0.513, 0.178, -0.161, -0.499, -0.838,
    -1.177, -1.514, -1.853, -2.191, -2.529, -2.867, -3.204, -3.541, -3.879, -4.212, -4.554, -4.888, -5.219, -5.56,
    -5.893, -6.894, -7.89, -8.88, -9.864, -10.841, -11.81, -12.767, -13.718, -14.659, -15.589,
)
# Ouster OS1-32, "uniform" beam configuration (gen 2): beam_altitude_angles of the OS-1-32-U0 unit in ouster-sdk's
# test metadata (tests/metadata/2_0_rc2_os-992011000121-32U0_legacy.json, firmware v2.0.0-rc.2); +20.55..-21.48
# degrees, gaps 1.24-1.42 degrees (narrowest at the edges). Approximate: one unit's calibration. Not an even spread
# over the 45 degrees (+-22.5) quoted for gen-2 OS1s: that puts the top beam 2 degrees above this unit's, more than
# half a gap, and seeds the lines on the wrong lasers (a synthetic scan of this unit: 67 % of its points in their
# laser's ring, 100 % with this table). A "gradient" OS1-32 (beams packed near the horizon: +12.75..-15.32 degrees in
# ouster-sdk's OS-1-32-G sample) fits no table here, and no data sheet found gives its angles: use "auto".
_OS1_32 = (
    20.548, 19.292, 18.017, 16.724, 15.414, 14.088, 12.747, 11.391, 10.022, 8.641, 7.249, 5.847, 4.438, 3.022, 1.601,
    0.178, -1.245, -2.667, -4.084, -5.496, -6.899, -8.294, -9.678, -11.05, -12.409, -13.754, -15.084, -16.398,
    -17.696, -18.975, -20.236, -21.476,
)
# Hesai PandarXT-32 design values: HesaiLidar_General_ROS's pandarXT_elev_angle_map (channel 1 = top), in
# src/HesaiLidar_General_SDK/src/PandarGeneralRaw/src/pandarXT.h: +15..-16 degrees in 1 degree steps (the XT-16 takes
# every second one, +15..-15 in 2 degree steps as its user manual's Appendix I lists). Approximate: per-unit
# calibrations differ.
_PANDARXT32 = tuple(np.arange(15.0, -16.5, -1.0))
# RoboSense RS-LiDAR-32: the vertical column of RoboSense's ROS driver calibration file
# (RoboSense-LiDAR/ros_rslidar, rslidar_pointcloud/data/rs_lidar_32/angle.csv), sorted from the top laser down;
# +15..-25 degrees, 1/3 degree steps between +1.67 and -4.67 (the user manual's 40 degree field, 0.33 degree finest
# resolution). Approximate: one unit's calibration. Close to the VLP-32C's layout, but up to a degree away from it
# below -4 degrees, more than half the gap there.
_RS32 = (
    14.9833, 10.3503, 6.9824, 4.6492, 3.2795, 2.3151, 1.667, 1.333, 1.0, 0.667, 0.333, 0.0, -0.333, -0.667, -0.9463,
    -1.3509, -1.667, -1.9642, -2.333, -2.667, -3.0, -3.333, -3.7027, -3.9822, -4.333, -4.667, -5.4425, -6.477,
    -7.9627, -10.333, -14.6883, -25.0294,
)

LASER_TABLES: dict[str, tuple[float, ...]] = {
    "hdl64e": _HDL64E,
    "hdl32e": _HDL32E,
    "vlp16": _VLP16,
    "vlp32c": _VLP32C,
    "os1-32": _OS1_32,
    "os1-64": _OS1_64,
    "os1-128": _OS1_128,
    "pandar40": _PANDAR40,
    "pandar40p": _PANDAR40P,
    "pandar64": _PANDAR64,
    "pandarxt32": _PANDARXT32,
    "rs32": _RS32,
}
SENSORS: tuple[str, ...] = ("auto", *LASER_TABLES)
# Laser counts a line search may end at: Velodyne and Ouster make 16, 32, 64 and 128; Hesai's Pandar40 / 40P / 40M
# have 40 (the tables above), and without 40 here their scans fell back to elevation bins.
STANDARD_RING_COUNTS: tuple[int, ...] = (16, 32, 40, 64, 128)
# How many lines fewer than a standard count a search may find and still be read as that sensor: an eighth (at least
# two), but only two for 40, which sits just above 32: a 32-laser scan's first search can overshoot to 35-37 lines
# (a 64-laser scan with every other ring off read 37 and, refused, 32 on the second search).
MISSING_LINES: dict[int, int] = {count: 2 if count == 40 else max(2, count // 8) for count in STANDARD_RING_COUNTS}


def ring_limit(sensor: str, n_rings: int) -> int:
    """How many lasers a driver's ring field may index: the named sensor's, or with "auto" the most any supported
    sensor has (at least `n_rings`), so a 128-laser driver's field is not mistaken for a broken one."""
    if sensor in LASER_TABLES:
        return len(LASER_TABLES[sensor])
    return max(n_rings, *STANDARD_RING_COUNTS)


def laser_elevations(sensor: str) -> np.ndarray:
    """Elevation angles (radians, descending: ring 0 on top) of a named sensor's lasers."""
    try:
        table = LASER_TABLES[sensor]
    except KeyError:
        raise ValueError(f"unknown sensor {sensor!r}; known: {', '.join(LASER_TABLES)}") from None
    return np.deg2rad(np.asarray(table, dtype=np.float64))
