# SPDX-License-Identifier: Apache-2.0
"""`star-tracker database build|list`: pattern databases in the cache, built ahead of time."""
from __future__ import annotations

import argparse
import math
import os
import threading
import time
from pathlib import Path

import numpy as np

from .common import (DEFAULT_EPOCH_JYEAR, CommandError, HelpFormatter, Progress, database_config_for, guarded,
                     positive_float, positive_int)

NAME = "database"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME, help="build (with progress) or list the cached pattern databases",
        description="Pattern databases (guide stars, star pairs with a k-vector, and for spherical_triangle/"
                    "composite the triangle features) are built on first use and cached as validated .npz "
                    "files in $STAR_TRACKER_CACHE (default ~/.cache/star_tracker). `database build` builds "
                    "them ahead of time for given fields of view, `database list` shows the cache.",
        epilog="example:\n  star-tracker database build --fov 15\n"
               "  star-tracker database build --fov 8 20 --magnitude-limit 7.0 --triangles\n"
               "  star-tracker database list",
        formatter_class=HelpFormatter)
    actions = parser.add_subparsers(dest="database_command", required=True, metavar="{build,list}")
    build = actions.add_parser(
        "build", help="build and cache the databases for fields of view",
        description="Build (or load, when cached and valid) the pattern database of each field of view, "
                    "as `solve` and the identifier use it: star pairs up to the field's diagonal (at least "
                    "the identifier's default 22 deg, so 15 deg gives the nodes' own database), guide stars "
                    "to --magnitude-limit. Progress goes to stderr; then one line per database: cache file, "
                    "size [MB], stars, pairs, build time [s].",
        epilog="example:\n  star-tracker database build --fov 15                 # the nodes' default database\n"
               "  star-tracker database build --fov 5 10 --width 2048 --height 1536 --triangles",
        formatter_class=HelpFormatter)
    build.add_argument("--fov", type=positive_float, nargs="+", default=[15.0], metavar="DEG",
                       help="horizontal field(s) of view [deg] (default 15, the default camera)")
    build.add_argument("--width", type=positive_int, default=1024, metavar="PX",
                       help="image width [px], for the diagonal field (default 1024)")
    build.add_argument("--height", type=positive_int, default=1024, metavar="PX",
                       help="image height [px], for the diagonal field (default 1024)")
    build.add_argument("--magnitude-limit", type=float, default=None, metavar="HP",
                       help="faintest guide star [Hp mag] (default: 6.5, fainter for fields narrower than "
                            "~7 deg, at most 8; what `solve` uses)")
    build.add_argument("--epoch", type=float, default=DEFAULT_EPOCH_JYEAR, metavar="YEAR",
                       help=f"catalog epoch [Julian year] (default {DEFAULT_EPOCH_JYEAR})")
    build.add_argument("--triangles", action="store_true",
                       help="also build the triangle-feature database of the spherical_triangle and composite "
                            "algorithms")
    build.add_argument("--cache-dir", metavar="DIR",
                       help="cache directory (default $STAR_TRACKER_CACHE, else ~/.cache/star_tracker)")
    build.add_argument("--rebuild", action="store_true",
                       help="delete the cached file(s) first and build anew (default: load when valid)")
    build.set_defaults(func=run)
    listing = actions.add_parser("list", help="list the cached databases",
                                 description="List the pattern-database files in the cache with their size "
                                             "and configuration (guide-star magnitude limit, largest pair "
                                             "angle, epoch, stars and pairs); unreadable files are flagged.",
                                 epilog="example:\n  star-tracker database list --cache-dir /tmp/st_cache",
                                 formatter_class=HelpFormatter)
    listing.add_argument("--cache-dir", metavar="DIR",
                         help="cache directory (default $STAR_TRACKER_CACHE, else ~/.cache/star_tracker)")
    listing.set_defaults(func=run)


def _use_cache_dir(directory: str | None) -> Path:
    from ..models.catalog import cache_dir

    if directory:
        os.environ["STAR_TRACKER_CACHE"] = str(Path(directory).resolve())
    return cache_dir()


class _Ticker:
    """Redraws a Progress line every 0.2 s while a build (one opaque call) runs."""

    def __init__(self, progress: Progress, note: str):
        self.progress, self.note = progress, note
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            self.progress._draw(self.note)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    directory = _use_cache_dir(args.cache_dir)
    if args.database_command == "list":
        return list_databases(directory)
    return build_databases(args, directory)


def build_databases(args: argparse.Namespace, directory: Path) -> int:
    from ..models.catalog import load_hipparcos
    from ..identify import load_or_build_database

    configs = []
    for fov in args.fov:
        if not 0.5 <= fov <= 80.0:
            raise CommandError(f"--fov {fov} must be in [0.5, 80] deg")
        configs.append(database_config_for(math.radians(fov), args.width, args.height, args.magnitude_limit,
                                           args.epoch))
    steps = 1 + len(configs) * (2 if args.triangles else 1)
    progress = Progress(steps, "database build")
    with _Ticker(progress, "Hipparcos catalog"):
        load_hipparcos()
    progress.update(note="catalog loaded")
    rows = []
    for fov, config in zip(args.fov, configs):
        path = directory / f"pairs_{config.cache_key()}.npz"
        if args.rebuild and path.exists():
            path.unlink()
        cached = path.exists()
        note = (f"{fov:g} deg: pairs to {math.degrees(config.max_pair_angle_rad):.0f} deg, "
                f"Hp <= {config.magnitude_limit:g}")
        started = time.perf_counter()
        with _Ticker(progress, note + (" (loading)" if cached else " (building)")):
            database = load_or_build_database(config, directory)
        elapsed = time.perf_counter() - started
        progress.update(note=note)
        rows.append((f"{fov:g} deg", path, database.star_count, int(database.pair_a.size), elapsed,
                     "loaded from cache" if database.build_seconds == 0.0 else "built"))
        if args.triangles:
            from ..identify import triangle_database as triangle_module
            from ..identify.triangle_database import TriangleConfig, load_or_build_triangles, triangle_cache_path

            triangle_config = TriangleConfig.for_database(database)
            triangle_path = triangle_cache_path(database, triangle_config, directory)
            if args.rebuild and triangle_path.exists():
                triangle_path.unlink()
            cached = triangle_path.exists()
            triangle_module._MEMO.pop(triangle_path, None)  # report a load from disk, not the memo
            started = time.perf_counter()
            with _Ticker(progress, f"{fov:g} deg: triangle features"):
                triangles = load_or_build_triangles(database, triangle_config, directory)
            elapsed = time.perf_counter() - started
            progress.update(note=f"{fov:g} deg: triangle features")
            rows.append((f"{fov:g} deg triangles", triangle_path, int(triangles.guide_stars.size),
                         int(triangles.spherical.stars.shape[0]), elapsed, "loaded from cache" if cached else "built"))
    print(f"cache: {directory}")
    for label, path, stars, entries, elapsed, how in rows:
        size = path.stat().st_size / 1e6 if path.is_file() else float("nan")
        print(f"{label:>18}: {path.name}  {size:7.1f} MB  {stars:6d} stars  {entries:10,d} entries  "
              f"{elapsed:6.2f} s ({how})")
    return 0


def list_databases(directory: Path) -> int:
    import json

    from ..models.catalog import load_validated_npz

    files = sorted(p for p in directory.glob("*.npz") if not p.name.startswith("hip2_"))
    print(f"cache: {directory}")
    if not files:
        print("no pattern database cached yet (`star-tracker database build` builds one)")
        return 0
    for path in files:
        description = ""
        if path.name.startswith("pairs_"):
            arrays = load_validated_npz(path)
            if arrays is None or "config" not in arrays:
                description = "unreadable or fails its checksum (rebuilt on next use)"
            else:
                config = json.loads(str(arrays["config"]))
                description = (f"star pairs: Hp <= {config['magnitude_limit']:g}, pairs to "
                               f"{np.degrees(config['max_pair_angle_rad']):.1f} deg, epoch {config['epoch_jyear']:g}, "
                               f"{arrays['hip'].size} stars, {arrays['pair_a'].size:,} pairs")
        else:
            description = "triangle features" if "tri" in path.name else ""
        print(f"{path.name}  {path.stat().st_size / 1e6:7.1f} MB  {description}")
    return 0
