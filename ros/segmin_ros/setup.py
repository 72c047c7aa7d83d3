"""The ament_python build of segmin_ros: the `follow` executable, the launch file and the parameter
files, installed where ROS 2 looks for them (the ament index marker, share/segmin_ros).

segmin is not listed in install_requires: it comes from pip (`pip install 'segmin[ros]'`), and
colcon must not try to fetch it while building the workspace.
"""

from glob import glob

from setuptools import setup

PACKAGE = "segmin_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=[PACKAGE],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="segmin developers",
    maintainer_email="segmin@example.org",
    description="segmin's crop-row follower node, its launch file and the Jackal / D435 parameter file",
    license="MIT",
    entry_points={"console_scripts": [f"follow = {PACKAGE}.follow:main"]},
)
