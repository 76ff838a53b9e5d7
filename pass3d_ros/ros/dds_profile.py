"""The shipped Fast DDS profile for large clouds between processes: where it is, and putting it in this process's
environment before rclpy starts DDS, unless the user chose a profile (or another RMW)."""

from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping
from pathlib import Path

PROFILE_NAME = "fastdds_large_clouds.xml"
PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"  # what Fast DDS 2.x (Jazzy) reads
USER_VARIABLES = (PROFILE_VARIABLE, "FASTDDS_DEFAULT_PROFILES_FILE")  # either one set (even empty) is the user's
CWD_PROFILE = "DEFAULT_FASTRTPS_PROFILES.xml"  # Fast DDS also loads this file from the working directory
PACKAGE = "pass3d_ros"


def shipped_profile() -> Path | None:
    """The first that exists of: `share/pass3d_ros/config/` in the ament index, the source tree's `launch_configs/`
    (a checkout or editable install), `share/pass3d_ros/config/` of the prefix this module is installed in
    (`<prefix>/lib/pythonX.Y/site-packages/pass3d_ros/ros/`: colcon, unsourced) or of this Python's (pip)."""
    ament = _ament_share()
    here = Path(__file__).resolve().parents
    candidates = [
        *([ament / "config" / PROFILE_NAME] if ament else []),
        here[2] / "launch_configs" / PROFILE_NAME,
        *([here[5] / "share" / PACKAGE / "config" / PROFILE_NAME] if len(here) > 5 else []),
        Path(sys.prefix) / "share" / PACKAGE / "config" / PROFILE_NAME,
    ]
    return next((path for path in candidates if path.is_file()), None)


def _ament_share() -> Path | None:
    """This package's share directory in the ament index (AMENT_PREFIX_PATH), if there is one."""
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except (ImportError, LookupError, OSError, ValueError):  # PackageNotFoundError is a KeyError
        return None


def uses_fastdds(environ: MutableMapping[str, str]) -> bool:
    """Whether the RMW is Fast DDS (Jazzy's default when RMW_IMPLEMENTATION is unset)."""
    return "fastrtps" in (environ.get("RMW_IMPLEMENTATION") or "rmw_fastrtps_cpp")


def apply_shipped_profile(environ: MutableMapping[str, str] | None = None, cwd: Path | None = None) -> str | None:
    """Set FASTRTPS_DEFAULT_PROFILES_FILE to the shipped profile unless the user set a profile (one set empty is
    removed: Fast DDS defaults); call before rclpy.init. Returns the one line to log about it (None under another
    RMW)."""
    environ = os.environ if environ is None else environ
    if not uses_fastdds(environ):
        return None
    for name in USER_VARIABLES:
        if name in environ:
            if not environ[name]:
                del environ[name]  # Fast DDS would complain about an empty path
                return (f"Fast DDS: {name} is empty, so Fast DDS defaults: best-effort clouds of ~2 MB between "
                        "processes will mostly be lost")
            return f"Fast DDS: your profile {name}={environ[name]}"
    if (cwd or Path.cwd()).joinpath(CWD_PROFILE).is_file():
        return f"Fast DDS: your profile ./{CWD_PROFILE}"
    path = shipped_profile()
    if path is None:
        return (f"Fast DDS: the shipped {PROFILE_NAME} was not found (incomplete install?): Fast DDS defaults, "
                "best-effort clouds of ~2 MB between processes will mostly be lost")
    environ[PROFILE_VARIABLE] = str(path)
    return (f"Fast DDS: large-cloud profile {PROFILE_VARIABLE}={path} (64 MB shared memory; set "
            f"{PROFILE_VARIABLE} to use your own, empty for Fast DDS defaults)")
