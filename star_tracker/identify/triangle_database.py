# SPDX-License-Identifier: Apache-2.0
"""
The catalog triangle database with k-vectors on area, and its on-disk cache.

The database holds every triangle of guide stars whose three sides are at most
`max_side_rad` (`guide_triangles`). Each feature pair has its own ordering (Cole keeps
pointer arrays sorted by each property): rows by area, in blocks of 64 re-sorted by moment,
so a k-vector over the blocks gives the area window and a binary search per block the moment
window (the "finalists") without a scan. A third invariant, the side product a b c,
completes the shape (with area and moment it fixes the triangle up to reflection); it
screens finalists before their vertices are assigned to the spots by the sides. Guide
stars are thinned, the grid as fine as the triangle budget allows.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..models.catalog import cache_dir, load_validated_npz, save_validated_npz
from .database import StarDatabase
from .guide_triangles import brightest_per_cell, count_triangles, graph_triangles, pair_graph
from .kvector import KVector
from .triangle_features import catalog_features

TRIANGLE_FORMAT_VERSION = 3
DEFAULT_MAX_SIDE_RAD = float(np.radians(8.0))


@dataclass(frozen=True)
class TriangleConfig:
    """
    max_side_rad: longest side of a cataloged triangle (the field of view) [rad].

    moment_depth: subdivision levels of the spherical polar moment (Cole: 3); max_triangles:
    budget; if all guide stars give more triangles, stars are thinned; stars_per_cell:
    brightest stars kept per sky cell when thinning (the cell size is then the finest that
    fits the budget).
    """

    max_side_rad: float = DEFAULT_MAX_SIDE_RAD
    moment_depth: int = 3
    max_triangles: int = 2_000_000
    stars_per_cell: int = 2

    def __post_init__(self) -> None:
        bad = []
        if not (0.0 < self.max_side_rad <= np.radians(60.0)):
            bad.append(f"max_side_rad={self.max_side_rad} must be in (0, 60 deg]")
        if not (0 <= self.moment_depth <= 6):
            bad.append(f"moment_depth={self.moment_depth} must be in [0, 6]")
        if not (1000 <= self.max_triangles <= 50_000_000):
            bad.append(f"max_triangles={self.max_triangles} must be in [1000, 5e7]")
        if not (1 <= self.stars_per_cell <= 1000):
            bad.append(f"stars_per_cell={self.stars_per_cell} must be in [1, 1000]")
        if bad:
            raise ValueError("invalid triangle config: " + "; ".join(bad))

    @staticmethod
    def for_database(database: StarDatabase, max_side_rad: float | None = None, **kwargs) -> "TriangleConfig":
        """
        Return the default for a pair database: sides up to its largest pair angle, at most 8 deg.

        8 deg is DEFAULT_MAX_SIDE_RAD.

        For Cole's 8 deg field that is the field itself; for the 15 deg camera, all Hp <= 6.5
        stars with sides <= 8 deg (1.8 M triangles) beat the brightest stars with sides <= 15
        deg under the same budget: a 15 deg field always holds small triangles of bright stars,
        and with many false stars (Toloei's scenes) the few real ones must all be in the
        catalog.
        """
        if max_side_rad is None:
            max_side_rad = min(database.config.max_pair_angle_rad, DEFAULT_MAX_SIDE_RAD)
        return TriangleConfig(max_side_rad=float(max_side_rad), **kwargs)

    def cache_key(self, database: StarDatabase) -> str:
        text = json.dumps({**asdict(self), "pairs": database.config.cache_key(),
                           "version": TRIANGLE_FORMAT_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


class FeatureIndex(NamedTuple):
    """
    Catalog triangles ordered for one feature pair (area, polar moment).

    Rows are sorted by area and cut into blocks of `block` rows; within a block, rows are
    re-sorted by moment. An area window is then a run of blocks (found with a k-vector over
    the blocks' smallest areas), and in each block a binary search on the moment yields the
    finalists without scanning the window row by row. stars (T, 3): database star indices,
    ascending within a row; area, moment (T,) [sr or rad^2; sr rad^2 or rad^4]; product
    (T,): side product a b c [rad^3]; block_min, block_max (B,) area range of each block.
    A record of arrays, so the compiled matching takes it whole.
    """

    stars: np.ndarray
    area: np.ndarray
    moment: np.ndarray
    product: np.ndarray
    block: int
    block_min: np.ndarray
    block_max: np.ndarray
    kvector: KVector

    @staticmethod
    def build(stars: np.ndarray, area: np.ndarray, moment: np.ndarray, product: np.ndarray,
              block: int = 64) -> "FeatureIndex":
        by_area = np.argsort(area)
        area_sorted = area[by_area]
        # Within each block of `block` rows, by moment (the last block padded with +inf).
        padded = np.full(-(-area.size // block) * block, np.inf)
        padded[:area.size] = moment[by_area]
        within = np.argsort(padded.reshape(-1, block), axis=1, kind="stable")
        positions = (within + np.arange(0, padded.size, block)[:, None]).ravel()
        order = by_area[positions[positions < area.size]]
        starts = np.arange(0, area.size, block)
        block_min = area_sorted[starts]
        block_max = area_sorted[np.minimum(starts + block, area.size) - 1]
        return FeatureIndex(stars[order], area[order].astype(np.float32), moment[order].astype(np.float32),
                            product[order].astype(np.float32), block, block_min, block_max,
                            _compact_kvector(block_min))

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.stars, self.area, self.moment, self.product, self.block_min,
                                          self.block_max, self.kvector.k)))

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}_stars": self.stars, f"{prefix}_area": self.area, f"{prefix}_moment": self.moment,
                f"{prefix}_product": self.product,
                f"{prefix}_block": np.array(self.block), f"{prefix}_block_min": self.block_min,
                f"{prefix}_block_max": self.block_max, f"{prefix}_k": self.kvector.k,
                f"{prefix}_line": np.array([self.kvector.slope, self.kvector.intercept])}

    @staticmethod
    def from_arrays(arrays: dict[str, np.ndarray], prefix: str, star_count: int) -> "FeatureIndex":
        """
        Return the index saved by `arrays`.

        ValueError when the arrays are not one this code wrote for a database of `star_count`
        stars (shapes, dtypes, star indices in range).
        """
        stars, line = arrays[f"{prefix}_stars"], arrays[f"{prefix}_line"]
        rows = stars.shape[0] if stars.ndim == 2 else -1
        columns = [arrays[f"{prefix}_{name}"] for name in ("area", "moment", "product")]
        bounds = [arrays[f"{prefix}_{name}"] for name in ("block_min", "block_max", "k")]
        if (stars.ndim != 2 or stars.shape[1] != 3 or not np.issubdtype(stars.dtype, np.integer)
                or any(c.shape != (rows,) for c in columns) or line.shape != (2,)
                or len({b.shape for b in bounds}) != 1 or bounds[0].ndim != 1
                or (rows and (stars.min() < 0 or stars.max() >= star_count))):
            raise ValueError(f"cached {prefix} triangle index does not match the database")
        return FeatureIndex(arrays[f"{prefix}_stars"], arrays[f"{prefix}_area"], arrays[f"{prefix}_moment"],
                            arrays[f"{prefix}_product"], int(arrays[f"{prefix}_block"]), arrays[f"{prefix}_block_min"],
                            arrays[f"{prefix}_block_max"],
                            KVector(arrays[f"{prefix}_block_min"], arrays[f"{prefix}_k"], float(line[0]),
                                    float(line[1])))


@dataclass(frozen=True)
class TriangleDatabase:
    """
    Catalog triangles with both feature pairs.

    Spherical (Cole: area [sr], polar moment [sr rad^2]) and planar (Toloei: area [rad^2],
    polar moment [rad^4]), each a FeatureIndex. guide_stars: database star indices used
    (after thinning); cells_per_face: thinning grid (0: all stars); build_seconds: time of
    the build [s].
    """

    config: TriangleConfig
    spherical: FeatureIndex
    planar: FeatureIndex
    guide_stars: np.ndarray
    cells_per_face: int
    build_seconds: float = 0.0

    @property
    def triangle_count(self) -> int:
        return int(self.spherical.stars.shape[0])

    @property
    def nbytes(self) -> int:
        """Memory held by the arrays [bytes] (the cache file is about as large)."""
        return self.spherical.nbytes + self.planar.nbytes + int(self.guide_stars.nbytes)


def select_guide_stars(database: StarDatabase, config: TriangleConfig) -> tuple[np.ndarray, int]:
    """
    Return all database stars if their triangles fit the budget.

    Else the brightest `stars_per_cell` per cell of the finest grid that fits: (star indices,
    cells_per_face). The grid is first guessed from triangles ~ stars^3, then stepped to the
    finest that fits.
    """
    everything = np.arange(database.star_count)
    total = count_triangles(database, everything, config.max_side_rad)
    if total <= config.max_triangles:
        return everything, 0

    def thinned(n: int) -> np.ndarray:
        return brightest_per_cell(database.vectors, database.magnitude, n, config.stars_per_cell)

    def fits(n: int) -> bool:
        return count_triangles(database, thinned(n), config.max_side_rad) <= config.max_triangles

    target = everything.size * (config.max_triangles / total) ** (1.0 / 3.0)
    n = 1
    while n < 256 and thinned(n + 1).size <= target:
        n += 1
    while n > 1 and not fits(n):
        n -= 1
    while n < 256 and fits(n + 1):
        n += 1
    return thinned(n), n


def _smallest_uint(limit: int):
    return np.uint16 if limit < 2**16 else np.int32


def build_triangle_database(database: StarDatabase, config: TriangleConfig) -> TriangleDatabase:
    started = time.perf_counter()
    guide, cells = select_guide_stars(database, config)
    indptr, indices = pair_graph(database, guide, config.max_side_rad)
    local = graph_triangles(indptr, indices)
    stars = guide[local].astype(_smallest_uint(database.star_count))  # guide ascending: rows stay ascending
    sph_area, sph_moment, pl_area, pl_moment, product = catalog_features(database.vectors, stars, config.moment_depth)
    return TriangleDatabase(config=config, spherical=FeatureIndex.build(stars, sph_area, sph_moment, product),
                            planar=FeatureIndex.build(stars, pl_area, pl_moment, product),
                            guide_stars=guide.astype(np.int32),
                            cells_per_face=cells, build_seconds=time.perf_counter() - started)


def _compact_kvector(sorted_values: np.ndarray) -> KVector:
    kv = KVector.build(sorted_values)
    return KVector(kv.sorted_values, kv.k.astype(np.int32), kv.slope, kv.intercept)


_MEMO: dict[Path, TriangleDatabase] = {}


def triangle_cache_path(database: StarDatabase, config: TriangleConfig, directory: Path | None = None) -> Path:
    """
    Return the cache file of the triangles of `database` and `config`.

    In `directory`, else where the pair database lives (database.cache_directory), else in
    catalog.cache_dir().
    """
    return (directory or database.cache_directory or cache_dir()) / f"triangles_{config.cache_key(database)}.npz"


def load_or_build_triangles(database: StarDatabase, config: TriangleConfig | None = None,
                            directory: Path | None = None) -> TriangleDatabase:
    """
    Return the triangle database of `database` and `config` (default: for_database).

    Loaded from the checksum-validated cache (triangle_cache_path: by default beside the
    pair database) or built and cached; kept in memory per cache file.
    """
    config = config or TriangleConfig.for_database(database)
    path = triangle_cache_path(database, config, directory)
    if path in _MEMO and path.is_file():
        return _MEMO[path]
    arrays = load_validated_npz(path)
    triangles = None
    if arrays is not None:
        try:
            guide_stars = arrays["guide_stars"]
            if guide_stars.ndim != 1 or (guide_stars.size and (guide_stars.min() < 0
                                                               or guide_stars.max() >= database.star_count)):
                raise ValueError("cached guide stars do not match the database")
            triangles = TriangleDatabase(
                config=config, spherical=FeatureIndex.from_arrays(arrays, "spherical", database.star_count),
                planar=FeatureIndex.from_arrays(arrays, "planar", database.star_count), guide_stars=guide_stars,
                cells_per_face=int(arrays["cells_per_face"]), build_seconds=float(arrays["build_seconds"]))
        except (KeyError, ValueError, TypeError):
            triangles = None  # another layout, or not written for this database: rebuild
    if triangles is None:
        triangles = build_triangle_database(database, config)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_validated_npz(path, {
            **triangles.spherical.arrays("spherical"), **triangles.planar.arrays("planar"),
            "guide_stars": triangles.guide_stars, "cells_per_face": np.array(triangles.cells_per_face),
            "build_seconds": np.array(triangles.build_seconds)})
    _MEMO[path] = triangles
    return triangles
