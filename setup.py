"""ament_python package: console scripts double as `ros2 run pass3d_ros <name>` executables.

The one list of dependencies: INSTALL_REQUIRES (what the package needs to run) and the `test` extra (what its tests and
`make lint` add); `make setup` installs `-e .[test]`, package.xml names the same runtime dependencies as rosdep keys and
test/package/test_dependencies.py keeps the two (and the README's Dependencies section) in agreement."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "pass3d_ros"

# What `ros2 run` needs as pip distributions on a real Jazzy too: the launcher scripts setuptools writes check these
# at start-up, so ROS 2 itself (apt's rclpy is no pip distribution) and torch (a user's own CUDA build) are extras.
INSTALL_REQUIRES = [
    "numpy",
    "numba",  # the stage-1 loops and the scan simulator, compiled
    "rosbags>=0.10",  # bags without a ROS install
    "tqdm",  # progress bars
    "pyyaml",  # the live harness's parameter files
    "scipy",  # the tracker's assignment (linear_sum_assignment: the Hungarian method in C)
]
# ROS 2 Jazzy as PyPI wheels, for a machine without a ROS install (`make setup`); without the fastrtps extra rclpy has
# no RMW and fails to import. A Jazzy install brings them through rosdep (package.xml).
ROS_WHEELS_REQUIRES = ["ros-jazzy-rclpy[fastrtps]==7.1.6", "ros-jazzy-common-interfaces==5.3.6"]
# Pinned: an unpinned torch pulls several GB of CUDA wheels; `make setup` installs it first.
TORCH_REQUIRES = ["torch==2.13.0"]
# The tests and `make lint` (rerun-sdk: pass3d_view, optional for users, is tested).
TEST_REQUIRES = ["pytest", "pytest-timeout", "pytest-xdist", "ruff", "pyyaml", "rerun-sdk"]

CONSOLE_SCRIPTS = [
    "cluster_proposal_node = pass3d_ros.ros.cluster_proposal_node:main",
    "segmentation_node = pass3d_ros.ros.segmentation_node:main",
    "pass3d_pipeline = pass3d_ros.ros.pipeline:main",
    "pass3d_kitti2bag = pass3d_ros.tools.kitti2bag:main",
    "pass3d_replay = pass3d_ros.tools.replay:main",
    "pass3d_evaluate = pass3d_ros.tools.evaluate:main",
    "pass3d_train = pass3d_ros.tools.train:main",
    "pass3d_simulate = pass3d_ros.tools.simulate:main",
    "pass3d_benchmark = pass3d_ros.bench.benchmark:main",
    "pass3d_segment = pass3d_ros.tools.segment:main",
    "pass3d_view = pass3d_ros.tools.view:main",
    "pass3d_params_yaml = pass3d_ros.tools.params_yaml:main",
    "pass3d_pseudo_label = pass3d_ros.tools.pseudo_label:main",
    "pass3d_adapt = pass3d_ros.tools.adapt:main",
]

setup(
    name=PACKAGE,
    version="0.2.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["weights/*.pt", "weights/*.md"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch_configs/*.launch.py") + glob("launch_configs/*.launch.yaml")),
        (f"share/{PACKAGE}/config", ["launch_configs/pass3d_params.yaml", "launch_configs/pass3d.rviz",
                                      "launch_configs/fastdds_large_clouds.xml"]),
    ],
    install_requires=INSTALL_REQUIRES,
    zip_safe=True,
    maintainer="pass3d_ros developers",
    maintainer_email="dev@pass3d-ros.invalid",
    description="PASS3D LiDAR point-wise semantic segmentation for ROS 2 Jazzy",
    license="Apache-2.0",
    # `colcon test` runs pytest when the package declares this extra (setuptools ignores tests_require).
    extras_require={"test": TEST_REQUIRES, "ros-wheels": ROS_WHEELS_REQUIRES, "torch": TORCH_REQUIRES,
                    "view": ["rerun-sdk"]},
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
