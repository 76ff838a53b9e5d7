"""Launch both PASS3D nodes (and optionally rviz2) in a real ROS 2 Jazzy install.

    ros2 launch pass3d_ros pass3d.launch.py input_topic:=/velodyne_points rviz:=true
    ros2 launch pass3d_ros pass3d.launch.py namespace:=car1 use_sim_time:=true   # a bag played with --clock

The parameter file comes after the input_topic and weights arguments: a file that sets them (pass3d_adapt's does)
wins over the arguments; the shipped file leaves them to the arguments.

Every process it starts gets the shipped Fast DDS large-cloud profile unless FASTRTPS_DEFAULT_PROFILES_FILE is set
(or fastdds_profile:=... names another; fastdds_profile:='' means Fast DDS defaults).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import EnvironmentVariable, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"


def generate_launch_description() -> LaunchDescription:
    config_dir = PathJoinSubstitution([FindPackageShare("pass3d_ros"), "config"])
    params_file = LaunchConfiguration("params_file")
    sim_time = {"use_sim_time": LaunchConfiguration("use_sim_time")}
    shipped_profile = PathJoinSubstitution([config_dir, "fastdds_large_clouds.xml"])
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "fastdds_profile",
                default_value=EnvironmentVariable(PROFILE_VARIABLE, default_value=shipped_profile),
                description="Fast DDS profile of every process; default: yours if set, else the shipped one "
                "for large clouds between processes",
            ),
            SetEnvironmentVariable(PROFILE_VARIABLE, LaunchConfiguration("fastdds_profile")),
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution([config_dir, "pass3d_params.yaml"]),
                description="parameter YAML for both nodes (its input_topic and weights, if set, win over the "
                "arguments)",
            ),
            DeclareLaunchArgument("input_topic", default_value="/velodyne_points", description="LiDAR topic"),
            DeclareLaunchArgument("weights", default_value="", description="stage-2 checkpoint; empty = shipped"),
            DeclareLaunchArgument("rviz", default_value="false", description="also start rviz2"),
            DeclareLaunchArgument("namespace", default_value="", description="nodes and pass3d topics"),
            DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock (bag replay)"),
            Node(
                package="pass3d_ros",
                executable="cluster_proposal_node",
                name="cluster_proposal_node",
                namespace=LaunchConfiguration("namespace"),
                output="screen",
                parameters=[{"input_topic": LaunchConfiguration("input_topic")}, params_file, sim_time],
            ),
            Node(
                package="pass3d_ros",
                executable="segmentation_node",
                name="segmentation_node",
                namespace=LaunchConfiguration("namespace"),
                output="screen",
                parameters=[{"weights": LaunchConfiguration("weights")}, params_file, sim_time],
            ),
            Node(
                package="rviz2",
                executable="rviz2",
                name="rviz2",
                arguments=["-d", PathJoinSubstitution([config_dir, "pass3d.rviz"])],
                parameters=[sim_time],
                condition=IfCondition(LaunchConfiguration("rviz")),
            ),
        ]
    )
