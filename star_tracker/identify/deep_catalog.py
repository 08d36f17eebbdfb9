# SPDX-License-Identifier: Apache-2.0
"""
The deep verification catalog: every Hipparcos star to a fainter limit than the guide stars.

Identification searches the pattern database (guide stars, database.py); once an attitude is
accepted, the spots left unmatched are matched against this catalog (deep_match.py), so a
real frame's faint stars count in the attitude and the false-positive bound. It holds ICRS
unit vectors at the epoch, HIP ids and Hp magnitudes of every star to `magnitude_limit`
(blended pairs included: the matcher refuses an ambiguous spot); the stars of one field of
view come from a compiled query of a cube-map cell index (CellIndex, cone_stars).

Cached like the databases: a checksum-validated .npz (catalog.save_validated_npz) in the
pattern database's cache directory, keyed by limit, epoch and format version; a file that
fails its checks is rebuilt. Loaded catalogs are shared in memory.
"""
from __future__ import annotations

import functools
import hashlib
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

from ..models.catalog import cache_dir, load_hipparcos, load_validated_npz, save_validated_npz
from .kernel_records import DeepArrays
from .skygrid import cell_centres, cells_of

DEEP_CATALOG_FORMAT_VERSION = 1
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DeepCatalog:
    """
    magnitude_limit.

    Faintest star [Hp mag]; epoch_jyear: epoch of the positions [Julian year]; vectors (N, 3)
    ICRS unit vectors; hip (N,) Hipparcos ids (increasing); magnitude (N,) Hp [mag];
    sorted_magnitudes: `magnitude` sorted (the magnitude CDF of the false-positive bound). Made
    by `of`.
    """

    magnitude_limit: float
    epoch_jyear: float
    vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray
    sorted_magnitudes: np.ndarray = field(repr=False, compare=False)

    @staticmethod
    def of(magnitude_limit: float, epoch_jyear: float, vectors: np.ndarray, hip: np.ndarray,
           magnitude: np.ndarray) -> "DeepCatalog":
        return DeepCatalog(float(magnitude_limit), float(epoch_jyear), vectors, hip, magnitude, np.sort(magnitude))

    @functools.cached_property
    def arrays(self) -> DeepArrays:
        """The catalog as the compiled deep re-match reads it (deep_match_kernel)."""
        as_float = lambda a: np.ascontiguousarray(a, float)  # noqa: E731
        return DeepArrays(as_float(self.vectors), np.ascontiguousarray(self.hip), as_float(self.magnitude),
                          as_float(self.sorted_magnitudes))

    @property
    def star_count(self) -> int:
        return int(self.hip.size)

    @property
    def mean_density(self) -> float:
        """Stars per steradian over the whole sky [1/sr]."""
        return self.star_count / (4.0 * math.pi)

    def cone(self, axis: np.ndarray, chord: float) -> np.ndarray:
        """Return the indices of the stars within `chord` (2 sin(angle / 2)) of the ICRS unit vector `axis`."""
        cells = self.cells
        return cone_stars(self.vectors, cells.cell_start, cells.star_of_cell, cells.centres, cells.reach,
                          np.ascontiguousarray(axis, float), float(chord))

    @functools.cached_property
    def cells(self) -> "CellIndex":
        """The stars by cube-map cell, for cone queries (CellIndex)."""
        return CellIndex.build(self.vectors)


class CellIndex(NamedTuple):
    """
    Stars sorted by cube-map cell (skygrid.cell_of, CELL_GRID cells per face edge).

    cell_start (C + 1,) offsets into star_of_cell; centres (C, 3) unit vectors of the cells'
    centres; reach (C,) chord from each centre to the farthest of its stars (-1: none). A star
    of cell c lies within chord `reach[c]` of its centre, so a cone can hold it only when the
    centre is within the cone's angle + the cell's (cone_stars takes the largest for all).
    """

    cell_start: np.ndarray
    star_of_cell: np.ndarray
    centres: np.ndarray
    reach: np.ndarray

    @staticmethod
    def build(vectors: np.ndarray, grid: int = 16) -> "CellIndex":
        vectors = np.ascontiguousarray(vectors, float)
        cells = cells_of(vectors, grid)
        order = np.argsort(cells, kind="stable").astype(np.int64)
        count = 6 * grid * grid
        cell_start = np.concatenate([[0], np.cumsum(np.bincount(cells, minlength=count))]).astype(np.int64)
        centres = cell_centres(grid)
        reach = np.full(count, -1.0)
        np.maximum.at(reach, cells, np.linalg.norm(vectors - centres[cells], axis=1))
        return CellIndex(cell_start, order, centres, reach)


@njit(cache=True)
def cone_stars(vectors, cell_start, star_of_cell, centres, reach, axis, chord):
    """
    Return the indices of the `vectors` within `chord` (a chord: 2 sin(angle / 2)) of the unit vector `axis`.

    Only the cells whose centre lies within the cone's angle + the largest cell reach are read.
    """
    out = np.empty(vectors.shape[0], np.int64)
    count = 0
    widest = 0.0
    for c in range(reach.size):
        widest = max(widest, reach[c])
    angle = 2.0 * math.asin(min(1.0, 0.5 * chord)) + 2.0 * math.asin(min(1.0, 0.5 * widest))
    least_cos = math.cos(angle) - 1e-12 if angle < math.pi else -2.0
    chord2 = chord * chord
    for c in range(centres.shape[0]):
        if reach[c] < 0.0 or centres[c, 0] * axis[0] + centres[c, 1] * axis[1] + centres[c, 2] * axis[2] < least_cos:
            continue
        for q in range(cell_start[c], cell_start[c + 1]):
            s = star_of_cell[q]
            dx, dy, dz = vectors[s, 0] - axis[0], vectors[s, 1] - axis[1], vectors[s, 2] - axis[2]
            if dx * dx + dy * dy + dz * dz <= chord2:
                out[count] = s
                count += 1
    return out[:count].copy()


def deep_catalog_identity(magnitude_limit: float, epoch_jyear: float) -> str:
    """Return the catalog's parameters and format version as canonical JSON (stored in its cache file)."""
    return json.dumps({"magnitude_limit": round(float(magnitude_limit), 6), "epoch_jyear": round(float(epoch_jyear), 6),
                       "version": DEEP_CATALOG_FORMAT_VERSION}, sort_keys=True)


def build_deep_catalog(magnitude_limit: float, epoch_jyear: float) -> DeepCatalog:
    """Every Hipparcos star to `magnitude_limit` [Hp mag] at `epoch_jyear` [Julian year]."""
    stars = load_hipparcos().at_epoch(epoch_jyear).brighter_than(magnitude_limit)
    order = np.argsort(stars.hip, kind="stable")
    vectors = np.ascontiguousarray(stars.unit_vectors()[order])
    return DeepCatalog.of(magnitude_limit, epoch_jyear, vectors, stars.hip[order].astype(np.int32),
                          stars.hp[order].astype(float))


def deep_catalog_from_cache(arrays: dict[str, np.ndarray], magnitude_limit: float, epoch_jyear: float) -> DeepCatalog:
    """
    Return the catalog stored in `arrays` (a checksum-valid cache file).

    ValueError naming the first problem when it is of another version or configuration or
    malformed.
    """
    for name, dtype in (("vectors", np.float64), ("hip", np.int32), ("magnitude", np.float64)):
        if name not in arrays or arrays[name].dtype != dtype:
            raise ValueError(f"array {name!r} missing or not {np.dtype(dtype)}")
    if "identity" not in arrays or str(arrays["identity"]) != deep_catalog_identity(magnitude_limit, epoch_jyear):
        raise ValueError("built for another configuration")
    vectors, hip, magnitude = arrays["vectors"], arrays["hip"], arrays["magnitude"]
    n = hip.size
    if vectors.shape != (n, 3) or magnitude.shape != (n,) or hip.ndim != 1 or n < 4:
        raise ValueError(f"arrays disagree: vectors {vectors.shape}, hip {hip.shape}, magnitude {magnitude.shape}")
    if not (np.all(np.isfinite(vectors)) and np.all(np.abs(np.linalg.norm(vectors, axis=1) - 1.0) < 1e-9)):
        raise ValueError("star vectors are not finite unit vectors")
    if not (np.all(np.diff(hip) > 0) and hip[0] > 0 and np.all(magnitude <= magnitude_limit)):
        raise ValueError("hip ids not strictly increasing, or magnitudes beyond the limit")
    return DeepCatalog.of(magnitude_limit, epoch_jyear, vectors, hip, magnitude)


def deep_catalog_path(magnitude_limit: float, epoch_jyear: float, directory: Path | None = None) -> Path:
    """Return the cache file of the deep catalog for these parameters in `directory` (None: catalog.cache_dir())."""
    identity = deep_catalog_identity(magnitude_limit, epoch_jyear)
    return (Path(directory) if directory is not None else cache_dir()) / \
        f"deep_{hashlib.sha256(identity.encode()).hexdigest()[:16]}.npz"


_MEMO: dict[tuple, DeepCatalog] = {}


def load_or_build_deep_catalog(magnitude_limit: float, epoch_jyear: float,
                               directory: Path | None = None) -> DeepCatalog:
    """
    Return the deep catalog for (magnitude_limit [Hp mag], epoch_jyear [Julian year]).

    From `directory` (None: catalog.cache_dir()), built and cached there when missing or
    rejected (logged). Shared in memory by every identifier of the process.
    """
    directory = Path(directory) if directory is not None else cache_dir()
    identity = deep_catalog_identity(magnitude_limit, epoch_jyear)
    key = (identity, str(directory))
    if key in _MEMO:
        return _MEMO[key]
    path = deep_catalog_path(magnitude_limit, epoch_jyear, directory)
    arrays = load_validated_npz(path)
    catalog = None
    if arrays is not None:
        try:
            catalog = deep_catalog_from_cache(arrays, magnitude_limit, epoch_jyear)
        except ValueError as exc:
            log.warning("deep catalog cache %s rejected (%s); rebuilding it", path, exc)
    elif path.exists():
        log.warning("deep catalog cache %s is unreadable or fails its checksum; rebuilding it", path)
    if catalog is None:
        catalog = build_deep_catalog(magnitude_limit, epoch_jyear)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_validated_npz(path, {"vectors": catalog.vectors, "hip": catalog.hip, "magnitude": catalog.magnitude,
                                      "identity": np.array(identity)})
        except OSError as exc:
            log.warning("deep catalog cache %s not written (%s); it is rebuilt at every start", path, exc)
    _MEMO[key] = catalog
    return catalog
