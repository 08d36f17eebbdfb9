# SPDX-License-Identifier: Apache-2.0
"""
Guide-star catalog and star-pair database with a k-vector on inter-star angle.

Built once per parameter set and cached on disk (validated .npz, no pickle). Angles are
radians; star vectors are ICRS unit vectors at the configured epoch.

A cache file is trusted only after three checks: the CRC-32 of each array (catalog.
load_validated_npz: truncation, bit rot), its format version and configuration, and the
structure the compiled kernels rely on without bounds checks (dtypes, shapes, star indices
in range, sorted angles, unit vectors). A file failing any of them is logged and rebuilt.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from scipy.spatial import cKDTree

from ..models.catalog import StarCatalog, cache_dir, load_hipparcos, load_validated_npz, save_validated_npz
from ..models.file_memo import FileMemo
from ..parameter_spec import parameter, range_problems
from .geometry import chord_angle
from .kvector import KVector

if TYPE_CHECKING:
    from ..models.camera import CameraModel

DATABASE_FORMAT_VERSION = 2
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DatabaseConfig:
    """
    magnitude_limit.

    Faintest guide star [Hp mag]; max_pair_angle_rad: largest star-pair separation stored
    (must cover the camera's full diagonal FOV) [rad]; epoch_jyear: epoch the positions are
    propagated to [Julian year]; min_separation_rad: a guide star with a companion closer
    than this (and less than `blend_magnitude_gap` fainter) is left out, because the camera
    sees the two as one blended spot of ambiguous identity and position [rad].
    """

    # The default largest pair angle [deg]: every camera whose field diagonal fits in it (up to
    # ~15.5 deg square fields) shares the default database and its cache file (for_camera).
    DEFAULT_PAIR_ANGLE_DEG: ClassVar[float] = 22.0
    # Widest field diagonal for_camera accepts [deg]: its pairs (diagonal + 1 deg) stay within 90 deg.
    MAX_FIELD_DIAGONAL_DEG: ClassVar[float] = 89.0
    NARROW_PAIR_MARGIN: ClassVar[float] = 1.1  # a narrow field's pair range over its diagonal (for_camera)

    magnitude_limit: float = parameter(6.5, "faintest guide star", "Hp mag", -2.0, 12.0)
    max_pair_angle_rad: float = float(np.radians(DEFAULT_PAIR_ANGLE_DEG))  # the node's parameter is in degrees
    epoch_jyear: float = parameter(2026.0, "epoch of the guide-star positions", "Julian year", 1900.0, 2200.0)
    min_separation_rad: float = float(np.radians(180.0 / 3600.0))
    blend_magnitude_gap: float = 2.5

    def __post_init__(self) -> None:
        problems = range_problems(self)
        if problems:
            raise ValueError("; ".join(problems))
        if not (0.0 < self.max_pair_angle_rad <= np.radians(90.0)):
            raise ValueError(f"max_pair_angle_rad={self.max_pair_angle_rad} must be in (0, pi/2]")
        if not (0.0 <= self.min_separation_rad < self.max_pair_angle_rad):
            raise ValueError(f"min_separation_rad={self.min_separation_rad} must be in [0, max_pair_angle_rad)")
        if not (0.0 <= self.blend_magnitude_gap <= 10.0):
            raise ValueError(f"blend_magnitude_gap={self.blend_magnitude_gap} must be in [0, 10]")

    @classmethod
    def for_camera(cls, camera: CameraModel, magnitude_limit: float | None = None,
                   epoch_jyear: float | None = None) -> "DatabaseConfig":
        """
        Return the configuration whose pairs cover `camera`'s field (models.camera.CameraModel).

        Star pairs up to DEFAULT_PAIR_ANGLE_DEG (the default) when the field diagonal
        (field_diagonal_rad) fits in it, else up to the diagonal plus 1 deg rounded up to a
        whole degree (any two stars in view are a stored pair). A field so narrow that
        NARROW_PAIR_MARGIN x its diagonal + 1 deg is under half the default range gets that
        range (whole degrees): the default would store over 4x the pairs ever in view (a 6
        deg field's database at Hp 7.9: 21 M pairs, 0.5 GB, most of them never looked up;
        the margin covers a field up to 10 % wider than the nominal one). magnitude_limit
        [Hp mag] and epoch_jyear [Julian year]: None keeps the defaults. ValueError for a
        field diagonal over MAX_FIELD_DIAGONAL_DEG.
        """
        diagonal_deg = math.degrees(cls.field_diagonal_rad(camera))
        if diagonal_deg > cls.MAX_FIELD_DIAGONAL_DEG:
            raise ValueError(f"a {camera.width}x{camera.height} px camera of fx={camera.fx:.1f} px has a "
                             f"{diagonal_deg:.0f} deg field diagonal: at most ~{cls.MAX_FIELD_DIAGONAL_DEG:.0f} deg is "
                             f"supported")
        default_deg = cls.DEFAULT_PAIR_ANGLE_DEG
        pair_deg = default_deg if diagonal_deg <= default_deg else math.ceil(diagonal_deg + 1.0)
        narrow_deg = math.ceil(cls.NARROW_PAIR_MARGIN * diagonal_deg + 1.0)
        if narrow_deg <= 0.5 * default_deg:
            pair_deg = narrow_deg
        optional = dict(magnitude_limit=magnitude_limit, epoch_jyear=epoch_jyear)
        return cls(max_pair_angle_rad=float(np.radians(pair_deg)),
                   **{name: float(value) for name, value in optional.items() if value is not None})

    @staticmethod
    def field_diagonal_rad(camera: CameraModel) -> float:
        """
        Return the largest angle between two points of `camera`'s image [rad].

        The widest separation of any two of its four outer corners (pixel edges, (-0.5,
        -0.5) to (width - 0.5, height - 0.5)), distortion included; for a pinhole with a
        centred principal point, 2 atan(half diagonal / f).
        """
        u = np.array([-0.5, camera.width - 0.5, -0.5, camera.width - 0.5])
        v = np.array([-0.5, -0.5, camera.height - 0.5, camera.height - 0.5])
        corners = camera.pixel_to_ray(u, v)
        chord = np.linalg.norm(corners[:, None, :] - corners[None, :, :], axis=-1)
        return float(2.0 * np.arcsin(min(1.0, 0.5 * float(chord.max()))))

    def cache_key(self) -> str:
        return hashlib.sha256(self.identity().encode()).hexdigest()[:16]

    def identity(self) -> str:
        """Return the configuration and format version as canonical JSON (stored in the cache file)."""
        return json.dumps({**asdict(self), "version": DATABASE_FORMAT_VERSION}, sort_keys=True)


@dataclass(frozen=True)
class StarDatabase:
    """
    vectors: (N, 3) ICRS unit vectors.

    Hip: (N,) Hipparcos ids; magnitude: (N,) Hp; pair_a, pair_b: star indices of each pair,
    sorted by pair_angle [rad] (a < b); kvector: search structure over pair_angle;
    cache_directory: where its cache file lives (None: the default, catalog.cache_dir());
    the databases derived from it (triangles) are cached there too.
    """

    config: DatabaseConfig
    vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray
    kvector: KVector
    build_seconds: float = 0.0
    cache_directory: Path | None = None

    @property
    def pair_angle(self) -> np.ndarray:
        return self.kvector.sorted_values

    @property
    def star_count(self) -> int:
        return int(self.hip.size)

    def pairs_in_range(self, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
        """Star index pairs (a, b) whose separation lies in [lo, hi] [rad]."""
        start, stop = self.kvector.range(lo, hi)
        return self.pair_a[start:stop], self.pair_b[start:stop]


def unblended(catalog: StarCatalog, config: DatabaseConfig) -> np.ndarray:
    """
    Return the mask of stars (Hp <= magnitude_limit) with no brighter companion nearby.

    A companion is within min_separation_rad and brighter than the star's Hp + blend_magnitude_gap.
    """
    field = catalog.brighter_than(config.magnitude_limit + config.blend_magnitude_gap)
    vectors = field.unit_vectors()
    close = cKDTree(vectors).query_pairs(r=2.0 * np.sin(0.5 * config.min_separation_rad), output_type="ndarray")
    blended = np.zeros(len(field), bool)
    if close.size:
        i, j = close[:, 0], close[:, 1]
        blended[i[field.hp[j] <= field.hp[i] + config.blend_magnitude_gap]] = True
        blended[j[field.hp[i] <= field.hp[j] + config.blend_magnitude_gap]] = True
    guide = field.hp <= config.magnitude_limit
    return ~blended[guide]


def build_database(config: DatabaseConfig, catalog: StarCatalog | None = None) -> StarDatabase:
    started = time.perf_counter()
    catalog = (catalog or load_hipparcos()).at_epoch(config.epoch_jyear)
    catalog = catalog.brighter_than(config.magnitude_limit).subset(unblended(catalog, config))
    vectors = catalog.unit_vectors()
    tree = cKDTree(vectors)
    chord = 2.0 * np.sin(0.5 * config.max_pair_angle_rad)
    pairs = tree.query_pairs(r=chord, output_type="ndarray").astype(np.int32)
    angles = chord_angle(vectors[pairs[:, 0]], vectors[pairs[:, 1]])  # exact for small angles, unlike arccos
    order = np.argsort(angles, kind="stable")
    pairs = pairs[order]
    a = np.minimum(pairs[:, 0], pairs[:, 1])
    b = np.maximum(pairs[:, 0], pairs[:, 1])
    kvector = KVector.build(angles[order])
    return StarDatabase(config, vectors, catalog.hip.astype(np.int32), catalog.hp, a, b, kvector,
                        time.perf_counter() - started)


_CACHE_DTYPES = {"vectors": np.float64, "hip": np.int32, "magnitude": np.float64, "pair_a": np.int32,
                 "pair_b": np.int32, "pair_angle": np.float64, "k": np.int64, "slope": np.float64,
                 "intercept": np.float64, "format_version": np.int64}


def database_from_cache(arrays: dict[str, np.ndarray], config: DatabaseConfig) -> StarDatabase:
    """
    Return the database stored in `arrays` (a checksum-valid cache file) for `config`.

    ValueError naming the first problem when the file is of another version or configuration,
    or its structure is not what build_database makes (the kernels index without bounds
    checks).
    """
    for name, dtype in _CACHE_DTYPES.items():
        if name not in arrays:
            raise ValueError(f"array {name!r} missing")
        if arrays[name].dtype != dtype:
            raise ValueError(f"array {name!r} has dtype {arrays[name].dtype}, expected {np.dtype(dtype)}")
    if int(arrays["format_version"]) != DATABASE_FORMAT_VERSION:
        raise ValueError(f"format version {int(arrays['format_version'])}, expected {DATABASE_FORMAT_VERSION}")
    if "config" not in arrays or str(arrays["config"]) != config.identity():
        raise ValueError("built for another configuration")
    vectors, hip, magnitude = arrays["vectors"], arrays["hip"], arrays["magnitude"]
    pair_a, pair_b, angle, k = arrays["pair_a"], arrays["pair_b"], arrays["pair_angle"], arrays["k"]
    slope, intercept = float(arrays["slope"]), float(arrays["intercept"])
    n, m = hip.size, angle.size
    if vectors.shape != (n, 3) or magnitude.shape != (n,) or hip.ndim != 1 or n < 2:
        raise ValueError(f"star arrays disagree: vectors {vectors.shape}, hip {hip.shape}, magnitude {magnitude.shape}")
    if not (np.all(np.isfinite(vectors)) and np.all(np.abs(np.linalg.norm(vectors, axis=1) - 1.0) < 1e-9)):
        raise ValueError("star vectors are not finite unit vectors")
    if not (np.all(hip[1:] > hip[:-1]) and hip[0] > 0 and np.all(np.isfinite(magnitude))):
        raise ValueError("hip ids not strictly increasing, or magnitudes not finite")
    if pair_a.shape != (m,) or pair_b.shape != (m,) or k.shape != (m,) or angle.ndim != 1 or m < 2:
        raise ValueError(f"pair arrays disagree: a {pair_a.shape}, b {pair_b.shape}, angle {angle.shape}, k {k.shape}")
    if not (np.all(pair_a >= 0) and np.all(pair_a < pair_b) and np.all(pair_b < n)):
        raise ValueError("pair star indices out of range")
    if not (np.all(np.isfinite(angle)) and angle[0] >= 0.0 and np.all(angle[1:] >= angle[:-1])
            and angle[-1] <= config.max_pair_angle_rad + 1e-12):
        raise ValueError("pair angles not sorted within [0, max_pair_angle_rad]")
    if not (np.all(k[1:] >= k[:-1]) and k[0] >= 0 and k[-1] <= m and np.isfinite(slope) and slope > 0
            and np.isfinite(intercept)):
        raise ValueError("k-vector inconsistent")
    # The stored angles must be those of the stored stars (a sample: this runs at every start).
    sample = np.linspace(0, m - 1, min(m, 4096)).astype(np.int64)
    stored = chord_angle(vectors[pair_a[sample]], vectors[pair_b[sample]])
    if not np.allclose(stored, angle[sample], rtol=0, atol=1e-12):
        raise ValueError("pair angles do not match the star vectors")
    return StarDatabase(config, vectors, hip, magnitude, pair_a, pair_b, KVector(angle, k, slope, intercept))


# Databases loaded in this process, reused while their cache file is unchanged (a narrow
# field's is ~0.5 GB: the last two only).
_LOADED: FileMemo[StarDatabase] = FileMemo(2)


def load_or_build_database(config: DatabaseConfig, directory: Path | None = None) -> StarDatabase:
    """
    Load the cached database for `config` from `directory`, or build it and cache it there.

    directory None: catalog.cache_dir(); validated: see the module docstring. Reused in the
    process while its file is unchanged (models/file_memo.py). The database
    remembers the directory (cache_directory), so the triangle databases built from it are
    cached beside it. A rejected cache file is logged and rebuilt; an unwritable cache
    directory costs a rebuild at every start (logged), never the database.
    """
    directory = Path(directory) if directory is not None else None
    path = (directory or cache_dir()) / f"pairs_{config.cache_key()}.npz"
    identity = f"{config.identity()}|{directory}"
    loaded = _LOADED.get(path, identity)
    if loaded is not None:
        return loaded
    arrays = load_validated_npz(path)
    if arrays is not None:
        try:
            db = replace(database_from_cache(arrays, config), cache_directory=directory)
            _LOADED.put(path, identity, db)
            return db
        except ValueError as exc:
            log.warning("pattern database cache %s rejected (%s); rebuilding it", path, exc)
    elif path.exists():
        log.warning("pattern database cache %s is unreadable or fails its checksum; rebuilding it", path)
    db = replace(build_database(config), cache_directory=directory)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)  # a directory of the caller's choosing may be new
        save_validated_npz(path, {
            "vectors": db.vectors, "hip": db.hip, "magnitude": db.magnitude, "pair_a": db.pair_a,
            "pair_b": db.pair_b, "pair_angle": db.kvector.sorted_values, "k": db.kvector.k,
            "slope": np.array(db.kvector.slope), "intercept": np.array(db.kvector.intercept),
            "format_version": np.array(DATABASE_FORMAT_VERSION, np.int64), "config": np.array(config.identity())})
    except OSError as exc:
        log.warning("pattern database cache %s not written (%s); it is rebuilt at every start", path, exc)
    _LOADED.put(path, identity, replace(db, build_seconds=0.0))  # the next call loads it (from memory)
    return db
