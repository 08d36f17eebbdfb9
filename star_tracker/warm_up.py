"""Compile every numba kernel once (written to numba's on-disk cache), so the first node start
after an install does not spend a minute compiling. `make venv` runs it; running it again
only loads the cache.

    python -m star_tracker.warm_up
"""
from __future__ import annotations

import time

import numpy as np


def main() -> None:
    from .camera import CameraModel
    from .centroid.kernels import warm_up as warm_centroid
    from .identify import DatabaseConfig, load_or_build_database, make_identifier

    started = time.perf_counter()
    warm_centroid()
    identifier = make_identifier("hybrid", load_or_build_database(DatabaseConfig()))
    identifier.warm_up(CameraModel.from_fov(1024, 1024, np.radians(15.0)))
    print(f"numba kernels ready in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()
