"""ament_python package: console scripts double as `ros2 run pass3d_ros <name>` executables."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "pass3d_ros"

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
    install_requires=["setuptools", "numpy", "rosbags", "numba", "tqdm"],
    zip_safe=True,
    maintainer="pass3d_ros developers",
    maintainer_email="dev@pass3d-ros.invalid",
    description="PASS3D LiDAR point-wise semantic segmentation for ROS 2 Jazzy",
    license="Apache-2.0",
    # `colcon test` runs pytest when the package declares this extra (setuptools ignores tests_require).
    extras_require={"test": ["pytest", "pytest-timeout", "pyyaml", "rerun-sdk"], "view": ["rerun-sdk"]},
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
