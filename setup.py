"""Build script of the ament_python package clutch_ros (colcon, or pip for development)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "clutch_ros"

# Node executables: `ros2 run clutch_ros <name>` runs lib/clutch_ros/<name> (see setup.cfg).
NODES = {
    "can_bridge": "clutch_ros.nodes.can_bridge:main",
    "rig_sim": "clutch_ros.nodes.rig_sim:main",
    "estimator": "clutch_ros.nodes.estimator:main",
    "controller": "clutch_ros.nodes.controller:main",
    "recorder": "clutch_ros.nodes.recorder:main",
    "bag_player": "clutch_ros.nodes.bag_player:main",
    "dashboard": "clutch_ros.nodes.dashboard:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["tests", "tests.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/params",
         sorted(glob("params/*.yaml") + glob("params/*.dbc") + glob("params/*.json"))),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.xml"))),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="clutch_ros developers",
    maintainer_email="clutch-ros@example.com",
    description="Live torque estimation and pressure control for a wet lamella clutch.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [f"{name} = {target}" for name, target in NODES.items()]
        + ["clutch = clutch_ros.cli:main"],
    },
)
