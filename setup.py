"""ament_python package set-up; also a plain pip package (pip install -e .[ros,test])."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "nrmpc_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Relative pose and gravity for non-rigid multi-perspective cameras (ROS 2 node and tools)",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
    ],
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.24",
        "scipy>=1.10",
        "opencv-python-headless>=4.8",
        "rosbags>=0.11,<0.12",
        "poselib==2.0.5",
        "pyyaml>=6",
        "matplotlib>=3.7",
        "tqdm>=4.60",
    ],
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-common-interfaces"],
        "test": ["pytest>=7", "pytest-xdist>=3.5", "ruff>=0.5", "colcon-core", "colcon-ros",
                 "dask[distributed]>=2024.1", "hypothesis>=6.100", "evo>=1.28"],
        "dask": ["dask[distributed]>=2024.1"],
    },
    zip_safe=True,
    maintainer="nrmpc_ros developers",
    maintainer_email="nrmpc_ros@example.com",
    license="BSD-3-Clause",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "nrmpc = nrmpc_ros.cli.main:main",
            "estimator = nrmpc_ros.node:main",
        ],
    },
)
