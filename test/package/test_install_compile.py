# SPDX-License-Identifier: Apache-2.0
"""
Cold start (issue 18 part 6).

The kernels compiled at install time (install_compile.py, run by setup.py's build_py) are
found by the installed copy, which then compiles nothing, and they give the same results as
the source tree's own kernels (compiled by its first start, or by `make`'s warm-up). Counted
outcomes only, never timing: numba's per-dispatcher cache hits and misses, frames identified,
the attitudes' bytes. (A first start that compiles everything is bench_cold_start's case; a
second cold compile here cost a minute of the suite's 15.)

The "install" is what install_lib does to the built copy: the whole tree (sources and numba's
__pycache__ files) copied to another path, so numba's cache must not depend on the path.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from star_tracker.install_compile import SKIP_ENV, compile_into  # noqa: E402

PACKAGE = Path(__file__).resolve().parents[2] / "star_tracker"

# The node warm-ups, then frames as the nodes see them (decoded from messages), lost-in-space
# then tracking; prints numba's cache misses (compiles) and hits over every star_tracker
# kernel, the frames identified (true attitude within 60") and a hash of the attitudes.
SCRIPT = textwrap.dedent("""
    import hashlib, importlib, pkgutil
    import numpy as np
    from numba.core.registry import CPUDispatcher
    import star_tracker
    from star_tracker.models.attitude import attitude_error
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
    from star_tracker.track.tracking import Tracker
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel
    from star_tracker.ros import convert
    from star_tracker.sim.scenes import NOMINAL_CAMERA as camera
    from star_tracker.warm_up import warm

    print("package", star_tracker.__file__)
    warm("nodes")
    database = load_or_build_database(DatabaseConfig())
    tracker = Tracker(make_identifier("hybrid", database))
    renderer = StarFieldRenderer(camera, SensorModel(), load_hipparcos().at_epoch(2026.0), magnitude_limit=7.0)
    motion = ConstantRateMotion(np.eye(3), np.radians([0.3, 0.2, 0.1]))
    identified, digest = 0, hashlib.sha256()
    for k in range(4):
        frame = renderer.render(motion, 0.2 * k, frame_seed(0, k))
        stamp = 1_000_000_000 + 200_000_000 * k
        image = convert.image_to_array(convert.array_to_image(frame.image, stamp, "f"))
        spots = convert.cloud_to_spots(convert.spots_to_cloud(extract_spots(image, CentroidConfig()), stamp, "f"),
                                       camera.width, camera.height)
        result = tracker.process(stamp, spots, camera).identification
        if result.solved:
            digest.update(np.ascontiguousarray(result.attitude.rotation).tobytes())
            identified += attitude_error(result.attitude.rotation, frame.truth.rotation)[2] < np.radians(60 / 3600)
    modules = [importlib.import_module(m.name) for m in pkgutil.walk_packages(star_tracker.__path__, "star_tracker.")
               if ".ros" not in m.name and "commands" not in m.name and not m.name.endswith("__main__")]
    kernels = {id(f): f for m in modules for f in vars(m).values() if isinstance(f, CPUDispatcher)}.values()
    print("misses", sum(sum(f.stats.cache_misses.values()) for f in kernels))
    print("hits", sum(sum(f.stats.cache_hits.values()) for f in kernels))
    print("identified", identified)
    print("attitudes", digest.hexdigest())
""")


def run_script(package_parent: Path, env: dict[str, str]) -> dict[str, str]:
    result = subprocess.run([sys.executable, "-c", SCRIPT], env=dict(env, PYTHONPATH=str(package_parent)),
                            cwd=package_parent, capture_output=True, text=True, timeout=1200)
    assert result.returncode == 0, result.stdout + result.stderr
    return dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)


def copy_package(source: Path, parent: Path) -> Path:
    """`source` (a star_tracker package dir) copied to parent/star_tracker with its caches."""
    shutil.copytree(source, parent / "star_tracker", ignore=shutil.ignore_patterns("*.pyc"))
    return parent


@pytest.mark.timeout(3600)
@pytest.mark.slow  # compiles every node kernel at "install"
def test_kernels_compiled_at_install_are_loaded_by_the_installed_copy_with_the_same_results(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", SKIP_ENV, "PYTHONPATH")}
    env["STAR_TRACKER_CACHE"] = str(tmp_path / "cache")
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")  # numba's user-wide fallback: empty too

    build = copy_package(PACKAGE, tmp_path / "build" / "lib")
    for stale in (build / "star_tracker").rglob("__pycache__"):
        shutil.rmtree(stale)  # a fresh clone has none
    assert compile_into(build, env)
    assert any((build / "star_tracker").rglob("*.nbi")), "no numba cache written into the built copy"
    installed = run_script(copy_package(build / "star_tracker", tmp_path / "install" / "site-packages"), env)
    assert installed["package"].startswith(str(tmp_path / "install")), installed
    assert installed["misses"] == "0", installed  # nothing compiled after the install
    assert int(installed["hits"]) > 0, installed

    # The source tree itself, with whatever kernels it compiled (or compiles now) on its own.
    tree = run_script(PACKAGE.parent, env)
    assert tree["package"].startswith(str(PACKAGE)), tree
    assert tree["identified"] == installed["identified"] == "4"
    assert tree["attitudes"] == installed["attitudes"]  # bit-identical results


def test_the_install_compile_is_skipped_on_request(tmp_path, capsys):
    assert compile_into(tmp_path, dict(os.environ, **{SKIP_ENV: "1"})) is False  # a note, never a failed install
    assert SKIP_ENV in capsys.readouterr().err
