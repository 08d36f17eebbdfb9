# SPDX-License-Identifier: Apache-2.0
"""What a demo needs before its nodes start: the shipped parameter file, the catalog and the pattern database."""
from __future__ import annotations

import time
from pathlib import Path


def default_params_file() -> Path | None:
    """config/star_tracker.yaml from the source tree, or from the colcon install share dir."""
    source = Path(__file__).resolve().parents[2] / "config" / "star_tracker.yaml"
    if source.is_file():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("star_tracker")) / "config" / "star_tracker.yaml"
        return installed if installed.is_file() else None
    except Exception:  # no ament index: the nodes' built-in defaults are the same values
        return None


def prepare_catalog_and_database() -> None:
    """Parse the catalog and build (or load) the pattern database before the nodes start, so they find both cached."""
    from ..identify import DatabaseConfig, load_or_build_database
    from ..models.catalog import load_hipparcos

    started = time.perf_counter()
    load_hipparcos()
    load_or_build_database(DatabaseConfig())
    print(f"catalog and pattern database ready ({time.perf_counter() - started:.1f} s)", flush=True)
