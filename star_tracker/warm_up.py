"""Compile every numba kernel once (written to numba's on-disk cache), so the first node start
after an install does not spend a minute compiling. `make venv` runs it; running it again
only loads the cache.

    python -m star_tracker.warm_up
"""
from __future__ import annotations

import time

import numpy as np


def main() -> None:
    from .models.catalog import load_hipparcos
    from .centroid.kernels import warm_up as warm_centroid
    from .identify import ALGORITHMS, DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
    from .sim.scenes import SETUPS, make_scene

    started = time.perf_counter()
    warm_centroid()
    database = load_or_build_database(DatabaseConfig())
    setup = SETUPS["nominal"]
    scene = make_scene(setup, load_hipparcos().at_epoch(database.config.epoch_jyear), np.random.default_rng(0))
    for name in ALGORITHMS:  # one solve each, without a time budget: every kernel compiles
        identifier = make_identifier(name, database, IdentifyConfig(max_time_s=60.0))
        if hasattr(identifier, "warm_up"):
            identifier.warm_up(setup.camera)
        identifier.identify(scene.spots, setup.camera)
    from .track.tracking import Tracker  # the tracking path calls some kernels from Python

    Tracker(make_identifier("hybrid", database)).warm_up(setup.camera)
    print(f"numba kernels ready in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
