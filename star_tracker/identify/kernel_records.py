# SPDX-License-Identifier: Apache-2.0
"""
The records the compiled identification kernels take and give (kernels.py, spot_kernels.py, track/kernels.py).

NamedTuples of arrays and scalars, which numba passes as they are, so a kernel's signature
names a few records instead of dozens of arrays.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .skygrid import SkyGrid


class CatalogArrays(NamedTuple):
    """
    The database stars as the kernels read them.

    Vectors (N, 3) ICRS unit vectors; magnitude (N,) [Hp mag]; sorted_magnitudes (N,) the
    same, ascending; the sky grid (skygrid.SkyGrid: cell_start, star_of_cell, grid,
    cell_density [1/sr]); mean_density: the whole catalog's stars per steradian [1/sr].
    """

    vectors: np.ndarray
    magnitude: np.ndarray
    sorted_magnitudes: np.ndarray
    cell_start: np.ndarray
    star_of_cell: np.ndarray
    grid: int
    cell_density: np.ndarray
    mean_density: float

    @staticmethod
    def build(database, grid: SkyGrid) -> "CatalogArrays":
        """Return the arrays of `database` (identify.database.StarDatabase) on `grid` (built over its vectors)."""
        magnitude = np.asarray(database.magnitude, dtype=float)
        return CatalogArrays(np.ascontiguousarray(database.vectors, dtype=float), magnitude, np.sort(magnitude),
                             grid.cell_start, grid.star_of_cell, grid.grid, grid.cell_density,
                             database.star_count / (4.0 * np.pi))


class PairIndex(NamedTuple):
    """
    The star pairs sorted by angle and their k-vector (kvector.KVector).

    pair_angle (P,) [rad]; k (P,); slope, intercept of the k-vector line; pair_a, pair_b
    (P,) star indices (int32, as the database holds them).
    """

    pair_angle: np.ndarray
    k: np.ndarray
    slope: float
    intercept: float
    pair_a: np.ndarray
    pair_b: np.ndarray

    @staticmethod
    def build(database) -> "PairIndex":
        kv = database.kvector
        # The pair arrays as stored (int32 star indices): a copy of tens of millions of pairs
        # would cost more than the search it serves.
        return PairIndex(kv.sorted_values, np.ascontiguousarray(kv.k, dtype=np.int64), float(kv.slope),
                         float(kv.intercept), np.ascontiguousarray(database.pair_a),
                         np.ascontiguousarray(database.pair_b))


class SpotArrays(NamedTuple):
    """
    Flux-sorted spots (base.SpotGeometry).

    Rays (N, 3) sensor-frame unit vectors; sigma (N,) 1-sigma direction errors [rad];
    magnitude (N,) instrumental [mag] (NaN: unknown).
    """

    rays: np.ndarray
    sigma: np.ndarray
    magnitude: np.ndarray


class VerifySettings(NamedTuple):
    """
    How a candidate attitude is verified (verify_candidate).

    Chord of the match radius, 2 sin(radius / 2); min_stars: fewest matches accepted;
    magnitude_floor: smallest magnitude residual credited [mag]
    (verify.log_magnitude_agreement).
    """

    chord: float
    min_stars: int
    magnitude_floor: float


class TriangleTolerances(NamedTuple):
    """
    search_triangles' pattern tolerances.

    A side matches within sigma_multiplier x its angle sigma plus tolerance_floor [rad]; a
    triangle with more than max_candidates catalog matches is ambiguous; a candidate is
    accepted at a false-positive bound <= fp_limit.
    """

    sigma_multiplier: float
    tolerance_floor: float
    max_candidates: int
    fp_limit: float


class SearchScratch(NamedTuple):
    """
    Work arrays of search_triangles.

    head_ik, head_jk (N stars,) all -1 (restored on return); out_spot, out_star (spots,) the
    accepted matches.
    """

    head_ik: np.ndarray
    head_jk: np.ndarray
    out_spot: np.ndarray
    out_star: np.ndarray


class TriangleSearchResult(NamedTuple):
    """
    status 1 = a candidate accepted (its `count` matches in the scratch's out_*), 0 = none in the batch.

    Rotation sensor -> ICRS; fp its false-positive bound; hypotheses tested; stopped: index
    after the last triangle tried.
    """

    status: int
    count: int
    rotation: np.ndarray
    fp: float
    hypotheses: int
    stopped: int


class CandidateCheck(NamedTuple):
    """
    verify_candidate's verdict.

    Count matches (in out_*), the refined rotation (sensor -> ICRS), its false-positive
    bound fp and chi^2 (0 when rejected early).
    """

    count: int
    rotation: np.ndarray
    fp: float
    chi2: float


class Pinhole(NamedTuple):
    """A camera without distortion: fx, fy, cx, cy [px]; width, height [px]."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: float
    height: float

    @staticmethod
    def of(camera) -> "Pinhole":
        """Return the pinhole part of a models.camera.CameraModel."""
        return Pinhole(float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
                       float(camera.width), float(camera.height))


class LensModel(NamedTuple):
    """
    A camera as the compiled deep re-match projects with it (models.camera.CameraModel.project).

    pinhole: its Pinhole; k1, k2, p1, p2, k3: Brown-Conrady distortion [-]; distorted: any of
    them non-zero; max_radius2: squared normalized radius beyond which a distorted camera
    images nothing (CameraModel.max_imaged_radius2; inf: no limit).
    """

    pinhole: Pinhole
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float
    distorted: bool
    max_radius2: float

    @staticmethod
    def of(camera) -> "LensModel":
        """Return the projection of a models.camera.CameraModel."""
        k1, k2, p1, p2, k3 = (float(d) for d in camera.distortion)
        distorted = bool(camera.has_distortion)
        return LensModel(Pinhole.of(camera), k1, k2, p1, p2, k3, distorted,
                         float(camera.max_imaged_radius2) if distorted else math.inf)


class RawSpots(NamedTuple):
    """Spots as the centroider gives them: x, y (N,) [px]; flux (N,); cov (N, 2, 2) [px^2]."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    cov: np.ndarray


class PrepareSettings(NamedTuple):
    """
    prepare_spots' floors.

    sigma_floor_px, the matching sigma's lower bound [px]; min_fit_sigma_px added to the
    final fit's sigma [px]; separation_px: closer spots are one [px].
    """

    sigma_floor_px: float
    min_fit_sigma_px: float
    separation_px: float


class PreparedSpots(NamedTuple):
    """
    prepare_spots' output (base.SpotGeometry's arrays).

    Order (M,) indices into the input; rays (M, 3); sigma (M,) [rad]; magnitude (M,); x, y
    (M,) [px]; pixel_cov (M, 2, 2) [px^2]; jacobian (M, 3, 2) [rad/px].
    """

    order: np.ndarray
    rays: np.ndarray
    sigma: np.ndarray
    magnitude: np.ndarray
    x: np.ndarray
    y: np.ndarray
    pixel_cov: np.ndarray
    jacobian: np.ndarray


class DeepArrays(NamedTuple):
    """The deep catalog (deep_catalog.DeepCatalog): vectors (N, 3) ICRS; hip (N,); magnitude, sorted_magnitudes (N,)."""

    vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray
    sorted_magnitudes: np.ndarray


class GuideMatches(NamedTuple):
    """The accepted guide matches: spot (G,) indices; vectors (G, 3) ICRS; hip (G,); magnitude (G,) catalog Hp."""

    spot: np.ndarray
    vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray


class DeepRematchSettings(NamedTuple):
    """
    The deep re-match's constants and the frame's camera figures (deep_match, base).

    pixel_scale [rad/px]; floor_px: matching floor [px]; image_area [px^2]; view_chord: chord
    of the field's half diagonal + 1 mrad; cone_chord: that + the cone margin, margin_chord: the
    margin's (one cone query serves every pass whose boresight lies within the margin of the
    query's axis); fp_limit: the false-positive bound; magnitude_floor [mag];
    fit_screen_chi2; min_stars; passes; gate_sigma, ambiguity_factor, max_chance_stars_in_gate,
    max_chance_matches, min_zero_point_stars, magnitude_sigma, magnitude_tolerance_floor,
    median_chi2_2dof (deep_match); mean_density: the deep catalog's [1/sr].
    """

    pixel_scale: float
    floor_px: float
    image_area: float
    view_chord: float
    cone_chord: float
    margin_chord: float
    fp_limit: float
    magnitude_floor: float
    fit_screen_chi2: float
    min_stars: int
    passes: int
    gate_sigma: float
    ambiguity_factor: float
    max_chance_stars_in_gate: float
    max_chance_matches: float
    min_zero_point_stars: int
    magnitude_sigma: float
    magnitude_tolerance_floor: float
    median_chi2_2dof: float
    mean_density: float


class DeepRematchOutcome(NamedTuple):
    """
    deep_match_kernel.deep_rematch's result.

    status: 1 named (spot (K,), star (K,) deep catalog indices), 0 the guide solution stands;
    rotation (sensor -> ICRS), covariance
    [rad^2], loss: the fit to guide and named matches; residual (G + K,) their angles [rad];
    fp: their false-positive bound; stats (8,): deep_matches, deep_ambiguous,
    deep_magnitude_rejected, deep_too_uncertain, deep_stars_in_view, deep_candidates,
    deep_chance_rejected, deep_bound_rejected.
    """

    status: int
    spot: np.ndarray
    star: np.ndarray
    rotation: np.ndarray
    covariance: np.ndarray
    loss: float
    residual: np.ndarray
    fp: float
    stats: np.ndarray
