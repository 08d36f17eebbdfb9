# SPDX-License-Identifier: Apache-2.0
"""
The real-image corpus: its images and references, and our `solve` command run on them.

The corpus is ../shared/realdata (MANIFEST.json; the folder beside the repository, from a git
worktree the one beside the main worktree), used in place, never copied. Each image's
reference attitude (`reference.quat_xyzw_sensor_to_icrs`) is an astrometry.net TAN-SIP solve in
our sensor frame (+x image right, +y image down, +z boresight; quaternion sensor -> ICRS).

Where the manifest also holds a `reference_dense` block for an image (beside its `reference`, or
inside it; an independent dense re-fit: hundreds to thousands of matched stars, the sky position
of the centre pixel), the boresight is judged
against it: the reference rotation is the astrometry.net one turned by the smallest rotation that
carries its boresight onto the dense centre (its roll is the astrometry.net solve's).

Used by the real-image benchmarks (bench_realdata, bench_psf_sensitivity, bench_corpus_centroid)
and by the tests that solve corpus images.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CORPUS_RELATIVE = Path("shared") / "realdata"  # beside the repository
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi


class CorpusMissing(RuntimeError):
    """The real-image corpus (MANIFEST.json) is not where it should be."""


def find_corpus(explicit: Path | None = None, repo: Path = REPO) -> Path:
    """
    Return the corpus folder (holding MANIFEST.json): `explicit`, else shared/realdata beside the repository.

    Raises CorpusMissing naming the place looked at.
    """
    candidates = [Path(explicit) if explicit is not None else repo.parent / CORPUS_RELATIVE]
    for folder in candidates:
        if (folder / "MANIFEST.json").is_file():
            return folder.resolve()
    raise CorpusMissing("real-image corpus not found: no MANIFEST.json in " + ", ".join(str(c) for c in candidates)
                        + " (the corpus lives in shared/realdata beside the repository; give --corpus DIR)")


def manifest_entries(corpus: Path) -> list[dict]:
    """Return the manifest's image entries, in manifest order."""
    return json.loads((corpus / "MANIFEST.json").read_text())["images"]


@dataclass(frozen=True)
class CorpusImage:
    """
    One manifest entry.

    Id, path (absolute), source (the public repository it came from), width, height [px],
    fov_h_deg: the horizontal field hint [deg]; reference: the reference rotation sensor ->
    ICRS (3x3; its boresight the dense re-fit's where the manifest has one) or None when the
    corpus has none; confidence: the astrometry.net reference's; dense_stars: the dense
    re-fit's matched stars (None without one).
    """

    id: str
    path: Path
    source: str
    width: int
    height: int
    fov_h_deg: float
    reference: np.ndarray | None
    confidence: str | None
    field_error: float = 0.0  # the hint given to every solver is fov_h_deg x (1 + field_error)
    dense_stars: int | None = None

    @property
    def hint_deg(self) -> float:
        """The field of view every solver is told [deg]: the manifest's, made field_error off."""
        return self.fov_h_deg * (1.0 + self.field_error)

    @property
    def reference_kind(self) -> str | None:
        """'dense re-fit', 'astrometry.net' or None: what the boresight is judged against."""
        if self.reference is None:
            return None
        return "dense re-fit" if self.dense_stars is not None else "astrometry.net"


def unit_vector(ra_deg: float, dec_deg: float) -> np.ndarray:
    """Return the ICRS unit vector of a sky position [deg]."""
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def turned_to(rotation: np.ndarray, boresight: np.ndarray) -> np.ndarray:
    """Return `rotation` (sensor -> ICRS) turned by the smallest rotation carrying its +z onto `boresight`."""
    z = rotation[:, 2]
    target = boresight / np.linalg.norm(boresight)
    axis = np.cross(z, target)
    sin, cos = float(np.linalg.norm(axis)), float(z @ target)
    if sin < 1e-15:
        return rotation.copy()
    k = axis / sin
    skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    turn = np.eye(3) + sin * skew + (1.0 - cos) * skew @ skew
    return turn @ rotation


def reference_rotation(entry: dict) -> tuple[np.ndarray | None, int | None]:
    """
    Return (the reference rotation sensor -> ICRS, the dense re-fit's matched stars) of a manifest entry.

    The astrometry.net rotation, its boresight moved onto the entry's `reference_dense` where present.
    """
    from star_tracker.models.attitude import quaternion_to_matrix

    reference = entry.get("reference") or None
    if not reference:
        return None, None
    rotation = quaternion_to_matrix(np.asarray(reference["quat_xyzw_sensor_to_icrs"], float))
    dense = entry.get("reference_dense") or reference.get("reference_dense")
    if not dense:
        return rotation, None
    return turned_to(rotation, unit_vector(dense["ra_deg"], dense["dec_deg"])), int(dense["matched_stars"])


def load_corpus(corpus: Path, only: list[str] | None = None) -> list[CorpusImage]:
    """Return the manifest's images, in manifest order (only those named in `only` when given)."""
    images = []
    for entry in manifest_entries(corpus):
        if only and entry["id"] not in only:
            continue
        reference = entry.get("reference") or None
        rotation, dense_stars = reference_rotation(entry)
        images.append(CorpusImage(entry["id"], corpus / entry["file"], entry["source_repo"], int(entry["width"]),
                                  int(entry["height"]), float(entry["fov_h_deg"]), rotation,
                                  reference.get("confidence") if reference else None, dense_stars=dense_stars))
    if only:
        unknown = sorted(set(only) - {image.id for image in images})
        if unknown:
            raise ValueError(f"unknown image id(s) {', '.join(unknown)}; see {corpus / 'MANIFEST.json'}")
    return images


def attitude_errors(solved: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """
    (boresight, roll) errors [rad] of a solved sensor -> ICRS rotation against the reference one.

    Boresight = angle between the two +z axes (in ICRS); roll = |angle about +z| of the error
    rotation R_ref^T R_solved (expressed in the reference sensor frame).
    """
    solved, reference = np.asarray(solved, float), np.asarray(reference, float)
    z, z_ref = solved[:, 2], reference[:, 2]
    boresight = math.atan2(float(np.linalg.norm(np.cross(z, z_ref))), float(z @ z_ref))
    error = reference.T @ solved
    roll = math.atan2(error[1, 0] - error[0, 1], error[0, 0] + error[1, 1])
    return boresight, abs(roll)


def solve_argv(image: CorpusImage) -> list[str]:
    """Return the command line of our solve, every option but the field at its default."""
    return ["solve", str(image.path), "--fov", f"{image.hint_deg:g}", "--json", "--quiet"]


def run_solve_command(argv: list[str]) -> tuple[int, dict | None, float, str]:
    """
    Run `star-tracker <argv>` in-process through the CLI's parser and the command's run().

    Returns (exit code, its --json document or None, wall time [s], its stderr).
    """
    from star_tracker.cli import build_parser

    args = build_parser().parse_args(argv)
    out, err = io.StringIO(), io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = args.func(args)
    elapsed = time.perf_counter() - started
    text = out.getvalue().strip()
    return code, (json.loads(text) if text else None), elapsed, err.getvalue()
