# SPDX-License-Identifier: Apache-2.0
"""
The nodes' warm-ups compile every numba variant their first frames use.

A variant missed there is compiled on the first frame instead: on a fresh install that took
> 8 s in the centroider (a read-only image from a ROS message is its own numba type), so the
first frames of `star-tracker demo --gyro` were dropped for overload.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("rclpy")

# A fresh process (numba dispatchers are per process): the node warm-ups, then frames as the
# nodes see them (decoded from messages), aided and unaided, lost-in-space then tracking.
# Prints the dispatchers that gained a compiled variant after the warm-up.
SCRIPT = textwrap.dedent("""
    import importlib, pkgutil, sys
    import numpy as np
    from numba.core.registry import CPUDispatcher
    import star_tracker
    from star_tracker.models.attitude import attitude_error
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.centroid.warm_up import warm_up
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
    from star_tracker.track.tracking import Tracker
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel
    from star_tracker.ros import convert
    from star_tracker.sim.scenes import NOMINAL_CAMERA as camera

    modules = [importlib.import_module(m.name) for m in pkgutil.walk_packages(star_tracker.__path__, "star_tracker.")
               if ".ros" not in m.name and "commands" not in m.name and not m.name.endswith("__main__")]
    dispatchers = {f"{f.py_func.__module__}.{f.py_func.__name__}": f
                   for m in modules for f in vars(m).values() if isinstance(f, CPUDispatcher)}

    database = load_or_build_database(DatabaseConfig())
    tracker = Tracker(make_identifier("hybrid", database))
    warm_up()  # CentroiderNode.__init__
    tracker.warm_up(camera)  # IdentifierNode.__init__
    before = {name: len(f.signatures) for name, f in dispatchers.items()}

    ARCSEC = np.radians(1 / 3600)
    rate = np.radians([0.8, 1.2, 0.1])
    renderer = StarFieldRenderer(camera, SensorModel(), load_hipparcos().at_epoch(2026.0), magnitude_limit=7.0)
    motion = ConstantRateMotion(np.eye(3), rate)
    identified = 0
    for k in range(4):
        frame = renderer.render(motion, 0.2 * k, frame_seed(0, k))
        stamp = 1_000_000_000 + 200_000_000 * k
        image = convert.image_to_array(convert.array_to_image(frame.image, stamp, "f"))
        smear = SmearModel(camera, rate, SensorModel().exposure_s) if k % 2 else None
        spots = extract_spots(image, CentroidConfig(), smear)
        spots = convert.cloud_to_spots(convert.spots_to_cloud(spots, stamp, "f"), camera.width, camera.height)
        result = tracker.process(stamp, spots, camera).identification
        # Identified means the true attitude (within 60 arcsec), not merely a solution.
        identified += bool(result.solved
                           and attitude_error(result.attitude.rotation, frame.truth.rotation)[2] < 60 * ARCSEC)
    print("identified", identified)
    print("compiled after the warm-up:", sorted(n for n, f in dispatchers.items() if len(f.signatures) > before[n]))
""")


@pytest.mark.timeout(900)
@pytest.mark.slow  # compiles the kernels in a fresh process
def test_the_first_frames_compile_nothing_after_the_node_warm_ups():
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "identified 4" in result.stdout, result.stdout  # every stage ran, and right
    assert "compiled after the warm-up: []" in result.stdout, result.stdout
