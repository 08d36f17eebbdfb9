# SPDX-License-Identifier: Apache-2.0
"""
The default identifier: compiled pyramid-order triangle search with immediate verification.

It combines what measured best in the seed papers:
- spot triangles in Mortari's pyramid order over the brightest spots (moves away from a
  false spot fastest), then every further spot, dimmest last, while time remains (Toloei's
  robustness to many false stars comes from searching beyond the brightest few);
- each side looked up in the pair k-vector within sigma_multiplier x the angle sigma of
  Cole's eq. (14), sqrt(s_a^2 + s_b^2), plus a floor;
- the handedness (mirror) test of van Bezooijen on every catalog triangle;
- each surviving catalog triangle verified against all spots at once (the 4th-star
  confirmation of the pyramid generalised), with the false-positive bound of `verify`,
  which uses magnitudes when they are known (van Bezooijen) and never needs them.
The search, the q-method, the matching and the bound run in numba (kernels.py) in batches of
triangles, so the time budget is checked between batches. For a camera without distortion the
whole common path of a solve, the first batch included, is one compiled call (solve_kernel.py).
"""
from __future__ import annotations

import itertools
import math
import time
import weakref
from dataclasses import replace
from functools import lru_cache

import numpy as np

from ..models.attitude import matrix_to_quaternion
from ..models.attitude_estimation import AttitudeSolution, refine_with_covariances
from ..models.camera import CameraModel
from ..centroid import Spots
from . import base, deep_match, final_fit_kernel, kernels, solve_kernel
from .base import (NO_MATCH, TIMEOUT, TOO_FEW_SPOTS, AcceptedMatch, Identification, IdentifyConfig, SearchOutcome,
                   StarIdentifier, lever_limits)
from .kernel_records import (CatalogArrays, LensModel, PairIndex, Pinhole, SearchScratch, SpotArrays,
                             TriangleTolerances, VerifySettings)
from .spot_geometry import SpotGeometry
from .database import StarDatabase
from .geometry import pyramid_triangles
from .skygrid import SkyGrid
from .verify import MIN_STARS, log_chance_tuples
from .deadline import Deadline

# Triangles per compiled call; the deadline is checked between calls. Small enough that a
# frame of wide spots (loose tolerances: ~2 ms a triangle over a wide field's pairs) still
# checks it every ~0.03-0.06 s; an easy frame solves within the first call.
PYRAMID_BATCH = 16
BATCH_TRIANGLES = 16
# Degrees of freedom the one-call solve has lever-arm limits for (2 x matches - 3): more
# matches finish in Python, which computes the limit itself.
LEVER_LIMIT_DOF = 1024


@lru_cache(maxsize=256)
def triangles_closing_at(k: int) -> np.ndarray:
    """(C(k, 2), 3) triangles (i, j, k), i < j < k: the ones spot k adds (read-only, shared)."""
    i, j = np.triu_indices(k, 1)
    triangles = np.stack([i, j, np.full(i.size, k)], axis=1).astype(np.int64)
    triangles.flags.writeable = False
    return triangles


def triangle_batches(pattern_count: int, spot_count: int):
    """
    (triangles, screen_limit) in search order.

    The pyramid over the brightest `pattern_count` spots, then the triangles each further
    spot adds (brightest first), in slices of at most PYRAMID_BATCH / BATCH_TRIANGLES so the
    deadline is checked often. The 4th-star screen looks at the pattern spots during the
    pyramid and at every spot after.
    """
    pyramid = pyramid_triangles(pattern_count)
    for start in range(0, pyramid.shape[0], PYRAMID_BATCH):
        yield pyramid[start:start + PYRAMID_BATCH], pattern_count
    for k in range(pattern_count, spot_count):
        block = triangles_closing_at(k)
        for start in range(0, block.shape[0], BATCH_TRIANGLES):
            yield block[start:start + BATCH_TRIANGLES], spot_count


# The search's read-only tables of each database alive in the process (id -> (weak reference,
# tables)): a process solving many images makes an identifier per image on the same database.
_TABLES: dict[int, tuple] = {}


def _search_tables(database: StarDatabase) -> tuple[SkyGrid, CatalogArrays, PairIndex]:
    """Return the sky grid, catalog arrays and pair index of `database`, built once while it lives."""
    key = id(database)
    entry = _TABLES.get(key)
    if entry is not None and entry[0]() is database:
        return entry[1]
    grid = SkyGrid.build(database.vectors)
    tables = (grid, CatalogArrays.build(database, grid), PairIndex.build(database))
    _TABLES[key] = (weakref.ref(database, lambda _ref, key=key: _TABLES.pop(key, None)), tables)
    return tables


class HybridIdentifier(StarIdentifier):
    name = "hybrid"
    _kernels_ready = False  # warm_up ran in this process

    def __init__(self, database: StarDatabase, config: IdentifyConfig):
        super().__init__(database, config)
        self.grid, self.catalog, self._pairs = _search_tables(database)
        # Search scratch: heads of the adjacency lists, all -1 between calls (search_triangles).
        self._head_ik = np.full(database.star_count, -1, np.int64)
        self._head_jk = np.full(database.star_count, -1, np.int64)
        # The lever-arm check's chi^2 limits by degrees of freedom (base._chi2_limit), for solve_kernel.
        self._lever_limits = lever_limits(LEVER_LIMIT_DOF)
        self._inputs_key: tuple | None = None  # (camera, config) of _inputs (_solve_inputs)
        self._inputs: tuple = ()

    def warm_up(self, camera: CameraModel) -> None:
        """
        Compile the kernels (or load them from numba's cache) on a small random scene, with the longest time budget.

        Compiling the first kernels must not spend the budget before the search runs (on a
        loaded host it did, and the search compiled at the first frame). Once per process: the
        compiled kernels are shared by every identifier (a process solving many images made a
        new one per image).
        """
        if HybridIdentifier._kernels_ready:
            return
        rng = np.random.default_rng(0)
        n = 8
        x, y = rng.uniform(0, camera.width - 1, n), rng.uniform(0, camera.height - 1, n)
        saved, self.config = self.config, replace(self.config, max_time_s=60.0)
        try:
            self.identify(Spots(x, y, np.linspace(2e4, 1e3, n), np.full(n, 50.0),
                                np.tile(np.eye(2) * 0.01, (n, 1, 1)), np.zeros(n, np.uint32), np.full(n, 9, np.int32),
                                np.full(n, 1e3), camera.width, camera.height), camera)
        finally:
            self.config = saved
        final_fit_kernel.warm_up()  # the Python steps' final fit and screens (rare branches, distorted cameras)
        refine_with_covariances(np.eye(3), np.eye(3), np.eye(3), np.tile(np.eye(3), (3, 1, 1)))  # aberration's fit
        log_chance_tuples(np.eye(3), np.full(3, 1e-5), 3.0, 1e3)  # the bound after the deep re-match
        self.warm_up_deep_rematch(camera)
        HybridIdentifier._kernels_ready = True

    def identify(self, spots: Spots, camera: CameraModel) -> Identification:
        """
        StarIdentifier.identify with its common path in one compiled call (solve_kernel.solve), same results.

        For a camera without distortion with the deep re-match on: the spots prepared, the first
        batch of triangles searched, the match checked and fitted and the deep re-match run in
        one call; the Python steps take over where that path ends (no match in the first
        batch, a lever-arm outlier to examine, guide stars to name again). Otherwise
        StarIdentifier.identify.
        """
        config = self.config  # read per call: a caller may replace it (commands/solve.py)
        if camera.has_distortion or not config.deep_match or config.max_pattern_spots < 3:
            return super().identify(spots, camera)
        started = time.perf_counter()
        deadline = Deadline(config.max_time_s, config.budget_clock)
        if deadline.passed():  # a budget spent before the first batch: the Python steps say so
            return super().identify(spots, camera)
        raw = self.raw_spots(spots)
        (verdict, prepared, tested, tried, spot, star, rotation, fp, guide_spot, guide_star, too_uncertain, fitted,
         covariance, loss, residual, ran_deep, outcome) = solve_kernel.solve(raw, *self._solve_inputs(camera))
        order, geometry = self.geometry_of(prepared, camera)
        if verdict == solve_kernel.TOO_FEW_SPOTS:
            return self._fail(TOO_FEW_SPOTS, f"{order.size} spots; at least {MIN_STARS} are needed", started, 0)
        if verdict == solve_kernel.NOT_FOUND:
            outcome = self._search_batches(geometry, camera, deadline, 1, tested, tried)
            return self.after_search(spots, camera, geometry, order, outcome, deadline, started)
        self.stats["triangles"] = tried
        match = AcceptedMatch(spot, star, rotation, fp)
        if verdict == solve_kernel.FINISH_IN_PYTHON:
            return self.after_search(spots, camera, geometry, order, SearchOutcome(match, tested), deadline, started)
        if too_uncertain:
            self.stats["guide_too_uncertain"] = too_uncertain
        matches = self.guide_matches(guide_spot, guide_star)
        solution, final_fp = AttitudeSolution(matrix_to_quaternion(fitted), fitted, covariance, loss), fp
        if not ran_deep:
            self.stats["deep_matches"] = 0  # every spot named by a guide star: nothing left to match
        else:
            extended = self.deep_result(outcome, matches)
            if extended is not None:
                matches, solution, residual, final_fp = extended
        result = self.published(geometry, order, matches, solution, residual, final_fp, tested, started)
        return self.with_second_opinion(spots, camera, geometry, order, match, result, deadline, started)

    def _solve_inputs(self, camera: CameraModel) -> tuple:
        """
        Return solve_kernel.solve's arguments after the spots for `camera` and the current config.

        What depends on the camera and the config alone is built once per pair (a caller may
        replace either; both are immutable); the rules' constants (base, deep_match) are read
        per call.
        """
        config = self.config
        if self._inputs_key is None or self._inputs_key[0] is not camera or self._inputs_key[1] is not config:
            search = (int(config.max_pattern_spots), PYRAMID_BATCH, float(config.match_radius_px),
                      float(camera.pixel_scale_rad), float(self.grid.max_radius_rad), MIN_STARS,
                      float(self.magnitude_floor))
            self._inputs = (Pinhole.of(camera), self.prepare_settings(), search, self._tolerances(),
                            LensModel.of(camera))
            self._inputs_key = (camera, config)
        pinhole, prepare_settings, search, tolerances, lens = self._inputs
        catalog = self.deep_catalog()
        finish = (self._lever_limits, self.catalog.vectors, self.database.hip, self.catalog.magnitude,
                  self.unnameable_settings(camera), base.FIT_SCREEN_CHI2, base.FIT_OUTLIER_SIGMA)
        settings = deep_match.rematch_settings(camera, catalog, config.centroid_sigma_floor_px,
                                               config.false_positive_bound, self.magnitude_floor, base.FIT_SCREEN_CHI2)
        return (pinhole, prepare_settings, search, self._pairs, self.catalog, tolerances,
                (self._head_ik, self._head_jk), finish, catalog.arrays, catalog.cells, lens, settings)

    def _tolerances(self) -> TriangleTolerances:
        config = self.config
        return TriangleTolerances(float(config.sigma_multiplier), float(config.angle_tolerance_floor_rad),
                                  int(config.max_candidates_per_pattern), float(config.false_positive_bound))

    def search(self, geometry: SpotGeometry, camera: CameraModel, deadline: Deadline) -> SearchOutcome:
        """
        Run kernels.search_triangles, the compiled triangle search, in batches.

        The deadline is checked between batches; each candidate triangle is verified inside the kernel.
        """
        return self._search_batches(geometry, camera, deadline, 0, 0, 0)

    def _search_batches(self, geometry: SpotGeometry, camera: CameraModel, deadline: Deadline, skip: int,
                        tested: int, tried: int) -> SearchOutcome:
        """Search from batch `skip` of triangle_batches on, after `tested` hypotheses in `tried` triangles."""
        n = geometry.x.size
        radius_rad = min(self.verification_radius_px(geometry, camera) * camera.pixel_scale_rad,
                         self.grid.max_radius_rad)
        tolerances = self._tolerances()
        verification = VerifySettings(2.0 * math.sin(0.5 * radius_rad), MIN_STARS, self.magnitude_floor)
        spots = SpotArrays(geometry.rays, geometry.sigma, geometry.magnitude)
        scratch = SearchScratch(self._head_ik, self._head_jk, np.empty(n, np.int64), np.empty(n, np.int64))
        for triangles, screen_limit in itertools.islice(triangle_batches(geometry.pattern_count, n), skip, None):
            if deadline.passed():
                self.stats["triangles"] = tried
                return SearchOutcome(None, tested, TIMEOUT, f"time budget {self.config.max_time_s:.3f} s spent "
                                     f"after {tried} of {math.comb(n, 3)} triangles")
            found = kernels.search_triangles(triangles, 0, triangles.shape[0], spots, self._pairs, self.catalog,
                                             tolerances, verification, scratch, screen_limit)
            tested += found.hypotheses
            tried += found.stopped
            if found.status == 1:
                self.stats["triangles"] = tried
                match = AcceptedMatch(scratch.out_spot[:found.count].copy(), scratch.out_star[:found.count].copy(),
                                      found.rotation, found.fp)
                return SearchOutcome(match, tested)
        self.stats["triangles"] = tried
        return SearchOutcome(None, tested, NO_MATCH, f"no hypothesis passed verification ({tested} tested, {n} spots)")
