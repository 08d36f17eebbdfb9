"""Guide-star catalog and star-pair database with a k-vector on inter-star angle.

Built once per parameter set and cached on disk (validated .npz, no pickle). Angles are
radians; star vectors are ICRS unit vectors at the configured epoch.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..catalog import StarCatalog, cache_dir, load_hipparcos, load_validated_npz, save_validated_npz
from .kvector import KVector

DATABASE_FORMAT_VERSION = 2


@dataclass(frozen=True)
class DatabaseConfig:
    """magnitude_limit: faintest guide star [Hp mag]; max_pair_angle_rad: largest star-pair
    separation stored (must cover the camera's full diagonal FOV) [rad]; epoch_jyear: epoch
    the positions are propagated to [Julian year]; min_separation_rad: a guide star with a
    companion closer than this (and less than `blend_magnitude_gap` fainter) is left out,
    because the camera sees the two as one blended spot of ambiguous identity and position
    [rad]."""

    magnitude_limit: float = 6.5
    max_pair_angle_rad: float = float(np.radians(22.0))
    epoch_jyear: float = 2026.0
    min_separation_rad: float = float(np.radians(180.0 / 3600.0))
    blend_magnitude_gap: float = 2.5

    def __post_init__(self) -> None:
        if not (-2.0 <= self.magnitude_limit <= 12.0):
            raise ValueError(f"magnitude_limit={self.magnitude_limit} must be in [-2, 12]")
        if not (0.0 < self.max_pair_angle_rad <= np.radians(90.0)):
            raise ValueError(f"max_pair_angle_rad={self.max_pair_angle_rad} must be in (0, pi/2]")
        if not (1900.0 <= self.epoch_jyear <= 2200.0):
            raise ValueError(f"epoch_jyear={self.epoch_jyear} must be in [1900, 2200]")
        if not (0.0 <= self.min_separation_rad < self.max_pair_angle_rad):
            raise ValueError(f"min_separation_rad={self.min_separation_rad} must be in [0, max_pair_angle_rad)")
        if not (0.0 <= self.blend_magnitude_gap <= 10.0):
            raise ValueError(f"blend_magnitude_gap={self.blend_magnitude_gap} must be in [0, 10]")

    def cache_key(self) -> str:
        text = json.dumps({**asdict(self), "version": DATABASE_FORMAT_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class StarDatabase:
    """vectors: (N, 3) ICRS unit vectors; hip: (N,) Hipparcos ids; magnitude: (N,) Hp;
    pair_a, pair_b: star indices of each pair, sorted by pair_angle [rad] (a < b);
    kvector: search structure over pair_angle."""

    config: DatabaseConfig
    vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray
    kvector: KVector
    build_seconds: float = 0.0

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
    """Mask of stars (Hp <= magnitude_limit) with no companion within min_separation_rad
    that is brighter than the star's Hp + blend_magnitude_gap."""
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
    diff = np.linalg.norm(vectors[pairs[:, 0]] - vectors[pairs[:, 1]], axis=1)
    angles = 2.0 * np.arcsin(np.clip(0.5 * diff, 0.0, 1.0))  # exact for small angles, unlike arccos
    order = np.argsort(angles, kind="stable")
    pairs = pairs[order]
    a = np.minimum(pairs[:, 0], pairs[:, 1])
    b = np.maximum(pairs[:, 0], pairs[:, 1])
    kvector = KVector.build(angles[order])
    return StarDatabase(config, vectors, catalog.hip.astype(np.int32), catalog.hp, a, b, kvector,
                        time.perf_counter() - started)


def load_or_build_database(config: DatabaseConfig, directory: Path | None = None) -> StarDatabase:
    """Load the cached database for `config` (checksum-validated) or build and cache it."""
    path = (directory or cache_dir()) / f"pairs_{config.cache_key()}.npz"
    arrays = load_validated_npz(path)
    if arrays is not None:
        try:
            kvector = KVector(arrays["pair_angle"], arrays["k"], float(arrays["slope"]), float(arrays["intercept"]))
            return StarDatabase(config, arrays["vectors"], arrays["hip"], arrays["magnitude"],
                                arrays["pair_a"], arrays["pair_b"], kvector)
        except KeyError:
            pass  # written by another layout: rebuild below
    db = build_database(config)
    save_validated_npz(path, {
        "vectors": db.vectors, "hip": db.hip, "magnitude": db.magnitude, "pair_a": db.pair_a,
        "pair_b": db.pair_b, "pair_angle": db.kvector.sorted_values, "k": db.kvector.k,
        "slope": np.array(db.kvector.slope), "intercept": np.array(db.kvector.intercept)})
    return db
