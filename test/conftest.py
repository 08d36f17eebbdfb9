# SPDX-License-Identifier: Apache-2.0
"""
Shared fixtures.

The star catalog and pattern database are built once per test session into a private cache
directory, so a run never depends on a developer's ~/.cache.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


# ROS domains: random private ones come from 100-199 (star_tracker/ros/domain_ids.py),
# split between pytest-xdist workers below; fixed ones, each used by one test file (which
# --dist loadfile keeps in one worker): 201-203 parameter defaults, 206-209 lifecycle, 211-212
# gyro/QoS, 214 an empty domain (test_commands), 216-221 ros2 CLI, 231 bags; 223-226 the
# cold-start benchmark.


def pytest_configure(config):
    """Give each pytest-xdist worker its own share of the random private ROS domains."""
    from star_tracker.ros.domain_ids import DEFAULT_DOMAIN_IDS, DOMAIN_IDS_VARIABLE

    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not worker or not count:
        return
    low, high = DEFAULT_DOMAIN_IDS
    share = (high - low + 1) // int(count)
    first = low + int(worker.removeprefix("gw")) * share
    os.environ[DOMAIN_IDS_VARIABLE] = f"{first}-{first + share - 1}"


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    if "STAR_TRACKER_TEST_CACHE" in os.environ:  # opt-in reuse for quick local iterations
        os.environ["STAR_TRACKER_CACHE"] = os.environ["STAR_TRACKER_TEST_CACHE"]
    else:
        os.environ["STAR_TRACKER_CACHE"] = str(tmp_path_factory.mktemp("star_tracker_cache"))
    yield


@pytest.fixture(autouse=True)
def same_cache_after_each_test(private_cache):
    """
    Restore STAR_TRACKER_CACHE after every test.

    A command run in-process with --cache-dir sets it, and the tests after it (whichever
    subset runs, e.g. -m "not slow") must still find the session's cache.
    """
    before = os.environ["STAR_TRACKER_CACHE"]
    yield
    os.environ["STAR_TRACKER_CACHE"] = before


@pytest.fixture(scope="session")
def hipparcos():
    """Return the Hipparcos catalogue as loaded, at its own epoch J1991.25."""
    from star_tracker.models.catalog import load_hipparcos

    return load_hipparcos()


@pytest.fixture(scope="session")
def catalog(hipparcos):
    """
    Return the sky the tests render: Hipparcos at the pattern database's epoch.

    Rendered at J1991.25 against a 2026 database, every simulated frame's truth carried 35 years
    of proper motion: a (-0.8, -0.1)" attitude bias, ~5 sigma, in each frame at rest.
    """
    from star_tracker.identify import DatabaseConfig

    return hipparcos.at_epoch(DatabaseConfig().epoch_jyear)


@pytest.fixture(scope="session")
def database():
    from star_tracker.identify import DatabaseConfig, load_or_build_database

    return load_or_build_database(DatabaseConfig())


@pytest.fixture(scope="session")
def nominal_camera():
    from star_tracker.models.camera import CameraModel

    return CameraModel.from_fov(1024, 1024, np.radians(15.0))


def join_isolated_ros_domain(monkeypatch, domain_id: int | None = None) -> dict:
    """
    Put this test process on a private ROS domain and initialise rclpy.

    Localhost discovery, the project's Fast DDS profile; `domain_id` a fixed one (None: a
    random one); returns that environment for the node processes.
    """
    import rclpy

    from star_tracker.ros.pipeline import isolated_ros_environment

    env = isolated_ros_environment(domain_id)
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
        monkeypatch.setenv(key, env[key])
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    rclpy.init(args=[])
    return env


def spots_at(sky, camera, rotation):
    """
    Return the spots a perfect centroider measures of the catalog stars `sky` (a Catalog).

    Seen by `camera` at `rotation` (sensor -> ICRS): true positions [px], brightest first, flux
    from the magnitude, SNR 50, 0.01 px^2 variances; stars within 3 px of the border left out.
    """
    from star_tracker.centroid import Spots

    u, v, front = camera.project(sky.unit_vectors() @ rotation)
    keep = front & camera.in_image(u, v, margin=3)
    order = np.argsort(sky.hp[keep])
    n = order.size
    return Spots(u[keep][order], v[keep][order], 1e5 * 10 ** (-0.4 * sky.hp[keep][order]), np.full(n, 50.0),
                 np.tile(np.eye(2) * 0.01, (n, 1, 1)), np.zeros(n, np.uint32), np.ones(n, np.int32), np.ones(n),
                 camera.width, camera.height)


# --- the package built by colcon, shared by test/package/test_colcon_install.py and test_ros2_cli.py ---
COLCON_REPO = Path(os.environ.get("STAR_TRACKER_REPO") or Path(__file__).resolve().parents[1]).resolve()
COLCON_REPO_ARTIFACTS = ("build", "install", "log", "star_tracker.egg-info")  # a build must never make these


@pytest.fixture(scope="session")
def colcon_workspace(tmp_path_factory) -> Path:
    """
    Run `colcon build` of the repository once per session; return the workspace (holds install/).

    The build runs with the interpreter running pytest, into a tmp workspace, and must leave
    nothing in the repository. STAR_TRACKER_REPO builds another checkout.
    """
    ws = tmp_path_factory.mktemp("colcon_ws")
    preexisting = {name for name in COLCON_REPO_ARTIFACTS if (COLCON_REPO / name).exists()}
    env = os.environ.copy()
    # Ignore the user's ~/.colcon/defaults.yaml (e.g. `symlink-install: true` would install
    # only an egg-link, making the node import star_tracker from the source tree).
    env.pop("COLCON_DEFAULTS_FILE", None)
    env["COLCON_HOME"] = str(ws / "colcon_home")
    env["COLCON_LOG_PATH"] = str(ws / "log")
    cmd = [sys.executable, "-m", "colcon", "--log-base", str(ws / "log"), "build",
           "--base-paths", str(COLCON_REPO), "--build-base", str(ws / "build"),
           "--install-base", str(ws / "install"), "--event-handlers", "console_direct+"]
    # 900 s: the build compiles the nodes' numba kernels (star_tracker/install_compile.py).
    result = subprocess.run(cmd, cwd=ws, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, timeout=900, check=False)
    created = sorted(n for n in COLCON_REPO_ARTIFACTS if (COLCON_REPO / n).exists() and n not in preexisting)
    assert not created, f"colcon build created {created} inside the repo {COLCON_REPO}"
    assert result.returncode == 0, (
        f"colcon build failed (exit {result.returncode}):\n{' '.join(cmd)}\n{result.stdout[-8000:]}")
    assert "Finished <<< star_tracker" in result.stdout, (
        f"colcon did not build star_tracker from {COLCON_REPO}:\n{result.stdout[-8000:]}")
    return ws


def sourced_ros_environment(ros2_exe, colcon_workspace) -> dict[str, str]:
    """
    Return the environment after `source install/setup.bash` of a colcon workspace, the venv on PATH.

    As a user's shell has it: this process's ROS variables dropped first, localhost discovery.
    """
    import sys

    install = colcon_workspace / "install"
    setup = install / "setup.bash"
    if not setup.is_file():  # colcon-bash not installed: colcon's POSIX script is the same
        setup = install / "setup.sh"
    base = {k: v for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "ROS_LOCALHOST_ONLY",
                         "FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")}
    base["PATH"] = os.pathsep.join([str(ros2_exe.parent), base.get("PATH", "")])
    base["VIRTUAL_ENV"] = sys.prefix
    out = subprocess.run(["bash", "-c", 'source "$1" >/dev/null && env -0', "bash", str(setup)], env=base,
                         cwd=colcon_workspace, capture_output=True, timeout=60, check=True).stdout
    env = dict(item.split("=", 1) for item in out.decode().split("\0") if "=" in item)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", RCUTILS_COLORIZED_OUTPUT="0", PYTHONUNBUFFERED="1")
    return env
