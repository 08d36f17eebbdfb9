# SPDX-License-Identifier: Apache-2.0
"""
Compile the numba kernels once (written to numba's on-disk cache).

So the first node start after an install does not spend a minute compiling. `make venv` runs
it on the source tree; `pip install .` and `colcon build` run it on the built copy
(install_compile.py), whose cache is installed with the package. Running it again only loads
the cache.

    python -m star_tracker.warm_up                 # every kernel: nodes, CLI, every algorithm
    python -m star_tracker.warm_up --only nodes    # what the three nodes' warm-ups compile
    python -m star_tracker.warm_up --only centroider   (or identifier): one node's share
"""
from __future__ import annotations

import argparse
import time

import numpy as np

PARTS = ("all", "nodes", "centroider", "identifier")


def warm_centroider() -> None:
    """Compile the kernels CentroiderNode needs before its first frame (centroid.warm_up)."""
    from .centroid.warm_up import warm_up

    warm_up()


def warm_identifier() -> None:
    """
    Compile and load what IdentifierNode needs before its first frame.

    The default database (built and cached when missing) and its deep catalog, the default
    algorithm inside a Tracker (Tracker.warm_up), the camera calibration's kernel.
    """
    from .identify import DEFAULT_ALGORITHM, DatabaseConfig, load_or_build_database, make_identifier
    from .models.calibration_kernel import warm_up as calibration_warm_up
    from .models.camera import CameraModel
    from .track.tracking import Tracker

    identifier = make_identifier(DEFAULT_ALGORITHM, load_or_build_database(DatabaseConfig()))
    identifier.deep_catalog()  # built at the first solve otherwise
    Tracker(identifier).warm_up(CameraModel.from_fov(1024, 1024, np.radians(15.0)))
    calibration_warm_up()  # the online camera refinement (and solve --fov's)


def warm_everything() -> None:
    """
    Compile every kernel: the nodes', then one solve with each algorithm (the CLI's and the benchmarks').

    The solves run without a time budget so that every kernel compiles.
    """
    from .identify import ALGORITHMS, DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
    from .models.catalog import load_hipparcos
    from .sim.scenes import SETUPS, make_scene

    warm_centroider()
    warm_identifier()
    database = load_or_build_database(DatabaseConfig())
    setup = SETUPS["nominal"]
    scene = make_scene(setup, load_hipparcos().at_epoch(database.config.epoch_jyear), np.random.default_rng(0))
    for name in ALGORITHMS:
        identifier = make_identifier(name, database, IdentifyConfig(max_time_s=60.0))
        if hasattr(identifier, "warm_up"):
            identifier.warm_up(setup.camera)
        identifier.identify(scene.spots, setup.camera)


def warm(part: str) -> None:
    """Compile (or load) the kernels of `part` (one of PARTS)."""
    if part == "all":
        warm_everything()
    if part in ("nodes", "centroider"):
        warm_centroider()
    if part in ("nodes", "identifier"):
        warm_identifier()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m star_tracker.warm_up", description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=PARTS, default="all", help="which kernels (default: all)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    warm(args.only)
    print(f"numba kernels ({args.only}) ready in {time.perf_counter() - started:.1f} s", flush=True)


if __name__ == "__main__":
    main()
