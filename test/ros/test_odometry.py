"""The sensor's pose at a scan from odometry messages (pass3d_ros.ros.odometry): interpolated between the messages
around the stamp, the nearest within the gap, none beyond it, the sensor placed on the robot by sensor_in_base."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from pass3d_ros.ros.odometry import OdometryPoses, sensor_in_base, transform_from_xyzrpy

S = 1_000_000_000


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def test_a_scan_between_two_messages_takes_the_interpolated_pose() -> None:
    poses = OdometryPoses(max_gap_s=0.2)
    poses.add(10 * S, (0.0, 0.0, 0.0), yaw_quaternion(0.0))
    poses.add(10 * S + S // 10, (1.0, 2.0, 0.0), yaw_quaternion(math.pi / 2))
    pose = poses.pose_at(10 * S + S // 20)
    np.testing.assert_allclose(pose[:3, 3], (0.5, 1.0, 0.0), atol=1e-9)
    np.testing.assert_allclose(pose[:3, :3], transform_from_xyzrpy((0, 0, 0, 0, 0, math.pi / 4))[:3, :3], atol=1e-9)


def test_the_nearest_message_within_the_gap_else_none_and_counted() -> None:
    poses = OdometryPoses(max_gap_s=0.2)
    poses.add(10 * S, (3.0, 0.0, 0.0), yaw_quaternion(0.0))
    np.testing.assert_allclose(poses.pose_at(10 * S + S // 10)[:3, 3], (3.0, 0.0, 0.0))
    assert poses.pose_at(10 * S + S // 2) is None
    assert poses.pose_at(9 * S) is None
    assert poses.missing == 2


def test_the_sensor_is_placed_on_the_robot() -> None:
    """A sensor 1 m ahead of the base and 2 m up, the robot turned 90 degrees: the sensor sits at y = 1 in the
    world, z = 2, and its x axis points along the world's y."""
    poses = OdometryPoses(sensor_in_base("1 0 2 0 0 0"))
    poses.add(S, (0.0, 0.0, 0.0), yaw_quaternion(math.pi / 2))
    pose = poses.pose_at(S)
    np.testing.assert_allclose(pose[:3, 3], (0.0, 1.0, 2.0), atol=1e-9)
    np.testing.assert_allclose(pose[:3, 0], (0.0, 1.0, 0.0), atol=1e-9)


def test_bad_messages_are_counted_and_never_held() -> None:
    poses = OdometryPoses()
    assert not poses.add(S, (float("nan"), 0.0, 0.0), yaw_quaternion(0.0))
    assert not poses.add(S, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
    assert not poses.add(S, (1e16, 0.0, 0.0), yaw_quaternion(0.0))  # no robot's: a double's step there is 2 m
    assert poses.add(S, (6.4e6, 0.0, 0.0), yaw_quaternion(0.0))  # an Earth-centred frame's is one
    assert poses.rejected == 3
    poses = OdometryPoses()
    assert poses.pose_at(S) is None


def test_a_quaternion_with_huge_components_is_normalised_not_zeroed() -> None:
    poses = OdometryPoses()
    assert poses.add(S, (0.0, 0.0, 0.0), (0.0, 0.0, 1e200, 1e200))  # 90 degrees about z, its norm overflows
    np.testing.assert_allclose(poses.pose_at(S)[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-9)
    assert not poses.add(S, (0.0, 0.0, 0.0), (0.0, 0.0, 1e-200, 1e-200))  # too small to be a rotation
    assert poses.rejected == 1


def test_only_the_last_seconds_are_held() -> None:
    poses = OdometryPoses(hold_s=2.0)
    for k in range(50):
        poses.add(k * S // 10, (float(k), 0.0, 0.0), yaw_quaternion(0.0))
    assert poses.pose_at(S // 10) is None  # 4.8 s before the last message: let go
    assert poses.pose_at(49 * S // 10) is not None


def test_a_stamp_that_does_not_move_holds_one_pose_the_newest() -> None:
    """A source that leaves its stamps unset sends every message at one stamp: no message is ever hold_s older than
    the newest, so each one was held (3,000 after 30 s at 100 Hz); the newest pose at a stamp replaces the one held."""
    poses = OdometryPoses(hold_s=2.0)
    for k in range(3000):
        poses.add(0, (float(k), 0.0, 0.0), yaw_quaternion(0.0))
    assert len(poses._stamps) == len(poses._poses) == 1
    np.testing.assert_allclose(poses.pose_at(0)[:3, 3], [2999.0, 0.0, 0.0])


def test_a_bag_played_again_from_its_start_gets_its_poses() -> None:
    """Stamps that jump back by more than hold_s (a looped bag, a restarted source) start the buffer over; the new
    pass's scans get their poses at once, not after its stamps pass the old ones."""
    poses = OdometryPoses(hold_s=2.0)
    for k in range(1000):  # the first pass: 10 s at 100 Hz
        poses.add(k * 10_000_000, (float(k), 0.0, 0.0), yaw_quaternion(0.0))
    for k in range(50):  # the second pass, from the start
        poses.add(k * 10_000_000, (100.0 + k, 0.0, 0.0), yaw_quaternion(0.0))
    pose = poses.pose_at(250_000_000)
    assert pose is not None and pose[0, 3] == pytest.approx(125.0)
    assert len(poses._stamps) == 50


@pytest.mark.parametrize("text", ["1 2 3", "a b c d e f", "0 0 0 0 0 nan"])
def test_a_bad_sensor_in_base_names_itself(text: str) -> None:
    with pytest.raises(ValueError, match="sensor_in_base"):
        sensor_in_base(text)


def test_a_change_of_frames_drops_the_held_poses_and_is_counted() -> None:
    """Poses in `odom` and then in `map` are never interpolated between: the change drops the held ones."""
    def message(stamp_s: float, x: float, frame: str) -> SimpleNamespace:
        return SimpleNamespace(header=SimpleNamespace(frame_id=frame, stamp=SimpleNamespace(
            sec=int(stamp_s), nanosec=round((stamp_s % 1) * 1e9))), child_frame_id="base_link",
            pose=SimpleNamespace(pose=SimpleNamespace(position=SimpleNamespace(x=x, y=0.0, z=0.0),
                                                      orientation=SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0))))
    poses = OdometryPoses(max_gap_s=0.5)
    assert poses.add_message(message(100.0, 0.0, "odom")) and poses.add_message(message(100.1, 1.0, "odom"))
    assert poses.frame_changes == 0 and poses.pose_at(int(100.05e9))[0, 3] == pytest.approx(0.5)
    assert poses.add_message(message(100.2, 50.0, "map"))
    assert poses.frame_changes == 1 and poses.frames == ("map", "base_link")
    assert poses.pose_at(int(100.15e9))[0, 3] == pytest.approx(50.0)  # not halfway between odom's 1 and map's 50
