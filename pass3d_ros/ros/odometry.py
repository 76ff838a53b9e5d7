"""The sensor's pose at each scan from a robot's odometry (nav_msgs/Odometry), for the tracker's world frame.

With a pose per scan the tracker keeps its tracks in the world frame and the ego's own motion is no object's
(pass3d_ros.core.stream.tracks). A robot's odometry is the cheap source of that pose: KISS-ICP run on the scans gave
the same id switches as the true poses on synthetic drives, at 19-60 ms a scan on a 2-core machine
(docs/experiments/tracks.md), so no odometry is computed here. Messages are held for `hold_s`; a scan takes the pose
interpolated at its stamp between the two messages around it (position linearly, orientation by slerp), or the
nearest message's within `max_gap_s`, else none (counted). `sensor_in_base` places the sensor in the odometry's child
frame (x y z roll pitch yaw, as a URDF joint's origin states it): world from sensor = world from base @ base from
sensor.
"""

from __future__ import annotations

import bisect
import math
import threading

import numpy as np

NO_MOUNT = "0 0 0 0 0 0"  # the sensor at the odometry child frame's origin, axes aligned
MAX_POSITION_M = 1e9  # a position farther from the odometry's origin is no robot's (Earth-centred frames reach 6.4e6 m;
# at 1e16 m a double's step is 2 m, and tracks kept there break apart)


def transform_from_xyzrpy(values: tuple[float, ...]) -> np.ndarray:
    """4 x 4 transform of a URDF origin (x, y, z, roll, pitch, yaw; m and rad): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    x, y, z, roll, pitch, yaw = values
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    out = np.eye(4)
    out[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                   [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                   [-sp, cp * sr, cp * cr]]
    out[:3, 3] = (x, y, z)
    return out


def sensor_in_base(text: str) -> np.ndarray:
    """The `sensor_in_base` parameter (x y z roll pitch yaw, spaces or commas) as a 4 x 4 transform; ValueError names
    what is wrong."""
    try:
        values = tuple(float(p) for p in text.replace(",", " ").split())
    except ValueError:
        values = ()
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"sensor_in_base={text!r} must be six numbers: x y z roll pitch yaw (m, rad; a URDF "
                         "joint's origin)")
    return transform_from_xyzrpy(values)


def _rotation(q: np.ndarray) -> np.ndarray:
    """3 x 3 rotation of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical interpolation between unit quaternions (the shorter way round)."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly equal: linear, normalised
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(dot)
    return (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)


class OdometryPoses:
    """The odometry messages of the last `hold_s` seconds and the sensor's pose at a scan's stamp (thread-safe: the
    subscription adds on the executor's thread, stage 2 asks on its own)."""

    def __init__(self, base_from_sensor: np.ndarray | None = None, max_gap_s: float = 0.2,
                 hold_s: float = 2.0) -> None:
        self.base_from_sensor = np.eye(4) if base_from_sensor is None else np.asarray(base_from_sensor, float)
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.hold_ns = int(hold_s * 1e9)
        self._stamps: list[int] = []
        self._poses: list[tuple[np.ndarray, np.ndarray]] = []  # (position, unit quaternion x y z w)
        self._lock = threading.Lock()
        self.rejected = 0  # messages with a non-finite or implausible (MAX_POSITION_M) position or a zero quaternion
        self.missing = 0  # scans that asked and got no pose
        self.frames: tuple[str, str] | None = None  # the messages' frame_id and child_frame_id
        self.frame_changes = 0  # messages whose frames differed from those before (the held poses then dropped)

    def add(self, stamp_ns: int, position: tuple[float, float, float], orientation: tuple[float, ...]) -> bool:
        """Hold one odometry pose (world from base); False (and counted) for a non-finite, implausibly far
        (MAX_POSITION_M) or degenerate one. A stamp already held takes the newer pose: a source whose stamp does not
        move (left unset, a stalled clock) would otherwise pile up every message, none older than hold_s. A stamp more
        than hold_s before the newest held (a bag played again from its start, a restarted source) starts the buffer
        over: else every pose of the new pass would be dropped as too old until its stamps passed the old ones."""
        p = np.asarray(position, dtype=float)
        q = np.asarray(orientation, dtype=float)
        scale = float(np.max(np.abs(q))) if np.all(np.isfinite(q)) else 0.0
        q = q / scale if scale > 0.0 else q  # scaled first: components near 1e308 would overflow the norm
        length = float(np.linalg.norm(q))
        if not np.all(np.abs(p) <= MAX_POSITION_M) or scale * length < 1e-6:  # NaN fails the bound too
            self.rejected += 1
            return False
        with self._lock:
            if self._stamps and stamp_ns < self._stamps[-1] - self.hold_ns:
                self._drop_held()
            k = bisect.bisect_left(self._stamps, stamp_ns)
            if k < len(self._stamps) and self._stamps[k] == stamp_ns:
                self._poses[k] = (p, q / length)
            else:
                self._stamps.insert(k, stamp_ns)
                self._poses.insert(k, (p, q / length))
            cut = bisect.bisect_left(self._stamps, self._stamps[-1] - self.hold_ns)
            del self._stamps[:cut], self._poses[:cut]
        return True

    def add_message(self, msg: object) -> bool:
        """Hold a nav_msgs/Odometry's pose at its header stamp. A message in other frames than those before (odom ->
        map, another robot's base) drops the held poses, counted in frame_changes: a scan's pose is never
        interpolated between two frames."""
        frames = (msg.header.frame_id, msg.child_frame_id)
        if frames != self.frames:
            if self.frames is not None:
                self.frame_changes += 1
                with self._lock:
                    self._drop_held()
            self.frames = frames
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        pose = msg.pose.pose
        return self.add(stamp, (pose.position.x, pose.position.y, pose.position.z),
                        (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w))

    def _drop_held(self) -> None:
        """Forget every held pose (under the lock): the stream started over, or its frames changed."""
        self._stamps.clear()
        self._poses.clear()

    def pose_at(self, stamp_ns: int) -> np.ndarray | None:
        """World from sensor (4 x 4) at `stamp_ns`: interpolated between the held messages around it, else the
        nearest one within max_gap_s; None (and counted) when none is near enough."""
        with self._lock:
            k = bisect.bisect_left(self._stamps, stamp_ns)
            near = [j for j in (k - 1, k) if 0 <= j < len(self._stamps)]
            near = [j for j in near if abs(self._stamps[j] - stamp_ns) <= self.max_gap_ns]
            if not near:
                self.missing += 1
                return None
            if len(near) == 2 and self._stamps[near[1]] > self._stamps[near[0]]:
                (t0, (p0, q0)), (t1, (p1, q1)) = ((self._stamps[j], self._poses[j]) for j in near)
                t = (stamp_ns - t0) / (t1 - t0)
                position, quaternion = p0 + t * (p1 - p0), _slerp(q0, q1, t)
            else:
                j = min(near, key=lambda i: abs(self._stamps[i] - stamp_ns))
                position, quaternion = self._poses[j]
        world_from_base = np.eye(4)
        world_from_base[:3, :3] = _rotation(quaternion)
        world_from_base[:3, 3] = position
        return world_from_base @ self.base_from_sensor
