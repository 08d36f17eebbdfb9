"""ament_python package: installs the same executables for `colcon build` + `ros2 run`
(into lib/star_tracker, see setup.cfg) and for `pip install -e .` (into the venv's bin)."""
import importlib.util
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

PACKAGE = "star_tracker"


class BuildPyAndCompile(build_py):
    """build_py, then the nodes' numba kernels compiled into the built copy, whose cache is
    installed with it: the first start loads them (star_tracker/install_compile.py)."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return  # `pip install -e .` runs the sources in place: `make venv` compiles them there
        path = Path(__file__).resolve().parent / PACKAGE / "install_compile.py"
        spec = importlib.util.spec_from_file_location("star_tracker_install_compile", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        module.compile_into(self.build_lib)


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
    install_requires=["setuptools"],
    cmdclass={"build_py": BuildPyAndCompile},
    zip_safe=False,
    maintainer="star_tracker developers",
    maintainer_email="star-tracker@example.org",
    description="Simulated spacecraft star tracker as ROS 2 nodes",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "camera_simulator = star_tracker.ros.camera_simulator_node:main",
            "centroider = star_tracker.ros.centroider_node:main",
            "identifier = star_tracker.ros.identifier_node:main",
            "star-tracker = star_tracker.cli:main",
        ],
    },
)
