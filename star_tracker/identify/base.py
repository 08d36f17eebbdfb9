# SPDX-License-Identifier: Apache-2.0
"""
The common identification interface and the machinery every algorithm shares.

An algorithm only searches: it proposes hypotheses (pattern spot indices, database star
indices), or overrides the whole search step (hybrid, compiled). The base class turns each
hypothesis into an attitude, verifies it against all spots with the
false-positive bound of `verify`, refines the accepted one over every matched star (QUEST
for matching, with spot sigmas floored at centroid_sigma_floor_px; then the published fit,
`final_fit`, weighted by each spot's own 2-D covariance), adds the remaining spots'
unambiguous matches to the deep catalog (`deep_rematch`: deep_match.py) with a new fit and
bound, and enforces the per-frame time budget.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np

from ..models.attitude import matrix_to_quaternion
from ..models.attitude_estimation import AttitudeSolution, quest_rotation
from ..models.camera import CameraModel
from ..centroid import FLAG_EDGE, Spots
from ..parameter_spec import parameter, range_problems
from . import spot_kernels
from .kernel_records import DeepRematchOutcome, GuideMatches, Pinhole, PrepareSettings, PreparedSpots, RawSpots
from .database import StarDatabase
from .deep_catalog import DeepCatalog, load_or_build_deep_catalog
from . import deep_match, final_fit_kernel
from .spot_geometry import SpotGeometry
from .verify import MIN_STARS, false_positive_bound, log_chance_tuples, log_magnitude_agreement, verify
from .deadline import BUDGET_CLOCKS, Deadline

SOLVED = "solved"
TOO_FEW_SPOTS = "too_few_spots"
NO_MATCH = "no_match"
TIMEOUT = "timeout"


# Spots closer than this [px] are one: the later one is dropped (prepare). Coincident spots
# carry no geometry, and their parallel rays make kernels.triad divide by zero.
COINCIDENT_SEPARATION_PX = 0.01


@dataclass(frozen=True)
class IdentifyConfig:
    """
    Parameters of the lost-in-space identification.

    max_pattern_spots: brightest spots used to form patterns; sigma_multiplier: pattern tolerance in standard
    deviations; angle_tolerance_floor_rad: added to every angle tolerance for model errors
    (aberration, distortion calibration) [rad]; centroid_sigma_floor_px: lower bound on a spot's
    1-sigma for matching (pattern tolerances, verification radius) [px] -- the published attitude
    and its covariance use each spot's own covariance (final_fit); match_radius_px: spot to
    projected-star radius for verification [px]; false_positive_bound: largest accepted
    probability that a published solution is a chance match (all hypotheses of the frame);
    second_opinion_bound: a solve whose final bound (deep stars included) exceeds this gets a
    second opinion (StarIdentifier.second_opinion); max_time_s: time budget of one identify()
    call [s], counted on budget_clock: "wall" (elapsed time, a node's real-time budget) or "cpu"
    (this process's CPU time: the same search on an idle and on a loaded host;
    identify/deadline.py); max_candidates_per_pattern: cap on hypotheses
    taken from one pattern (a pattern with more is ambiguous); deep_match: after a match is
    accepted, add the unambiguous matches of the remaining spots to the deep catalog's stars
    (every Hipparcos star to the guide limit + deep_magnitude_margin [mag]; deep_match.py) before
    the final fit and bound. Each node parameter's default, unit and range is its field's
    `parameter(...)` (parameter_spec.py).
    """

    max_pattern_spots: int = parameter(12, "brightest spots used to form patterns", "", 3, 100)
    sigma_multiplier: float = parameter(3.0, "pattern tolerance", "sigmas", 0.1, 20.0, dynamic=True)
    angle_tolerance_floor_rad: float = parameter(2.0e-5, "added to every angle tolerance (aberration, distortion "
                                                 "calibration)", "rad", 0.0, 0.01, high_open=True, dynamic=True)
    centroid_sigma_floor_px: float = parameter(0.05, "smallest spot 1-sigma for the matching tolerances; the "
                                               "published fit uses each spot's own covariance", "px", 1e-4, 10.0,
                                               dynamic=True)
    match_radius_px: float = parameter(1.5, "verification match radius", "px", 0.01, 50.0, dynamic=True)
    false_positive_bound: float = parameter(1.0e-6, "largest accepted chance-match probability", "-", 1e-30, 0.5,
                                            dynamic=True)
    max_time_s: float = parameter(0.5, "time budget of one identification", "s", 1e-3, 60.0, dynamic=True)
    second_opinion_bound: float = parameter(1.0e-9, "a solve whose final chance-match bound exceeds this is "
                                            "checked by a second search without its stars", "-", 1e-300, 0.5,
                                            dynamic=True)
    max_candidates_per_pattern: int = 50
    budget_clock: str = "wall"
    deep_match: bool = parameter(True, "after identification, match the remaining spots to every Hipparcos star "
                                 "to database.magnitude_limit + deep_match.magnitude_margin")
    deep_magnitude_margin: float = parameter(2.0, "deep catalog's limit beyond the guide stars'", "mag", 0.0, 6.0)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        if self.budget_clock not in BUDGET_CLOCKS:
            bad.append(f"budget_clock={self.budget_clock!r} must be one of {tuple(BUDGET_CLOCKS)}")
        if not (1 <= self.max_candidates_per_pattern <= 100000):
            bad.append(f"max_candidates_per_pattern={self.max_candidates_per_pattern} must be >= 1")
        if bad:
            raise ValueError("invalid identify config: " + "; ".join(bad))


@dataclass(frozen=True)
class Identification:
    """
    Result of one identify() call.

    status: "solved", "too_few_spots", "no_match" or "timeout"; reason: human-readable.
    When solved: spot_index (M,) into the input spots; hip (M,); star_vectors (M, 3) ICRS;
    body_vectors (M, 3) sensor frame; residual_rad (M,) angle between each measured and
    predicted direction [rad]; magnitude (M,) the stars' catalog Hp [mag]; deep (M,) True
    where the match was added by the deep re-match (deep_match.py), not the guide search;
    attitude: the final fit (sensor -> ICRS, covariance [rad^2]); false_positive_probability:
    bound over all hypotheses of the frame, over every match (guide and deep).
    """

    status: str
    reason: str
    algorithm: str
    elapsed_s: float
    hypotheses: int = 0
    spot_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    hip: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    star_vectors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    body_vectors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    residual_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    magnitude: np.ndarray = field(default_factory=lambda: np.zeros(0))
    deep: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    attitude: AttitudeSolution | None = None
    false_positive_probability: float = 1.0
    stats: dict = field(default_factory=dict)

    @property
    def solved(self) -> bool:
        return self.status == SOLVED

    @property
    def deep_count(self) -> int:
        """
        Matches the deep re-match added.

        Stars fainter than the guide stars, or left out of them, or left unmatched by the guide
        verification.
        """
        return int(np.count_nonzero(self.deep))


@dataclass(frozen=True)
class AcceptedMatch:
    """
    A verified match.

    spot_index (M,) into the flux-sorted spots (prepare); star_index (M,) database star
    indices; rotation (3, 3) the matching fit, sensor -> ICRS; false_positive_probability: its
    bound over all hypotheses of the frame (verify).
    """

    spot_index: np.ndarray
    star_index: np.ndarray
    rotation: np.ndarray
    false_positive_probability: float


@dataclass(frozen=True)
class SearchOutcome:
    """
    What an algorithm's search step found.

    `match` when a hypothesis was accepted, else None with the failing `status` (NO_MATCH or
    TIMEOUT) and its `reason`; `tested`: hypotheses tested.
    """

    match: AcceptedMatch | None
    tested: int
    status: str = SOLVED
    reason: str = ""


# Added to every spot's variance in the final fit [px, 1-sigma]: a guard against a zero or
# singular covariance (an infinite weight), far below any real centroid's error.
MIN_FIT_SIGMA_PX = 1e-4
# A guide star whose residual exceeds this many of its own sigmas at the published attitude
# makes the frame be named again there (StarIdentifier.solved).
FIT_OUTLIER_SIGMA = 5.0
# Final fit: a matched star whose chi^2 (2 DOF) exceeds this is left out of the attitude (a
# neighbour's light or a clipped core the centroider did not see): chi^2_2's 1e-3 tail, ~3.7
# sigma. At 5 sigma, the stars of defocused frames (PSF 3 px) pulled by a neighbour's light
# gave a mean NEES of 5.2-5.9; at this limit 4.1, at 1 px 2.5 either way (stress campaign
# probe, 15 frames each), and a consistent star is lost 0.1 % of the time.
FIT_SCREEN_CHI2 = 13.815510557964274  # scipy.stats.chi2.isf(1e-3, 2)


# A matched spot is named only when its match gate (FIT_OUTLIER_SIGMA sigmas of its own
# covariance + the matching floor) would hold at most this many unrelated guide stars on
# average at the guide catalog's mean density: the deep re-match's rule
# (deep_match.MAX_CHANCE_STARS_IN_GATE) for the guide stars. A spot whose position is that
# uncertain (a saturated hot-pixel cluster stated at 1.4 x 20 px: stress campaign, seed 2026,
# task 1484, named after a guide star 25 px away while tracking a tumble) adds nothing to the
# attitude, only a name it may not have.
MAX_CHANCE_GUIDE_STARS_IN_GATE = deep_match.MAX_CHANCE_STARS_IN_GATE


# An accepted match whose fit's chi^2 (matching sigmas) is less likely than this is examined
# for one wrong star on a long lever arm (StarIdentifier.without_lever_outlier).
LEVER_TEST_PROBABILITY = 1e-6
MAX_LEVER_OUTLIERS = 2  # wrong stars the examination may leave out


# The isotropic spots' placeholders in final_fit_kernel's signatures (SpotGeometry.pixel_cov None).
_NO_PIXEL_COV = np.zeros((0, 2, 2))
_NO_JACOBIAN = np.zeros((0, 3, 2))


def _pixel_cov_or_empty(geometry: SpotGeometry) -> np.ndarray:
    """Return the spots' pixel covariances, or an empty (0, 2, 2) array for isotropic spots (final_fit_kernel)."""
    return _NO_PIXEL_COV if geometry.pixel_cov is None else geometry.pixel_cov


@functools.lru_cache(maxsize=None)
def _chi2_limit(dof: int) -> float:
    """Return the chi^2 (dof degrees of freedom) exceeded with probability LEVER_TEST_PROBABILITY."""
    from scipy.stats import chi2

    return float(chi2.isf(LEVER_TEST_PROBABILITY, dof))


def lever_limits(max_dof: int) -> np.ndarray:
    """Return _chi2_limit(dof) for dof = 0..max_dof - 1 (inf at 0), as one array (solve_kernel)."""
    from scipy.stats import chi2

    limits = np.full(max_dof, np.inf)
    limits[1:] = chi2.isf(LEVER_TEST_PROBABILITY, np.arange(1, max_dof))
    return limits


@dataclass(frozen=True)
class _Matches:
    """
    Matches being published.

    spot_index (M,) into the flux-sorted spots; star_vectors (M, 3) ICRS; hip (M,);
    magnitude (M,) catalog Hp [mag]; deep (M,) from the deep catalog.
    """

    spot_index: np.ndarray
    star_vectors: np.ndarray
    hip: np.ndarray
    magnitude: np.ndarray
    deep: np.ndarray

    def extended(self, spot_index: np.ndarray, star_vectors: np.ndarray, hip: np.ndarray,
                 magnitude: np.ndarray) -> "_Matches":
        """Return these matches followed by deep ones."""
        return _Matches(np.concatenate([self.spot_index, spot_index]),
                        np.concatenate([self.star_vectors, star_vectors]),
                        np.concatenate([self.hip, hip.astype(self.hip.dtype)]),
                        np.concatenate([self.magnitude, magnitude]),
                        np.concatenate([self.deep, np.ones(spot_index.size, bool)]))


def ray_jacobian(camera: CameraModel, x: np.ndarray, y: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
    """
    (N, 3, 2) derivative of the sensor-frame unit ray with respect to the pixel position (x, y) [rad/px].

    For the pinhole, ray = p / |p| with p = ((x - cx) / fx, (y - cy) / fy, 1), J = r_z (I - r
    r^T)[:, :2] diag(1/fx, 1/fy) (compiled; `rays` if already known); with distortion, central
    differences of camera.pixel_to_ray.
    """
    x, y = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
    if camera.has_distortion:
        h = 0.5
        jx = (camera.pixel_to_ray(x + h, y) - camera.pixel_to_ray(x - h, y)) / (2 * h)
        jy = (camera.pixel_to_ray(x, y + h) - camera.pixel_to_ray(x, y - h)) / (2 * h)
        return np.stack([jx, jy], axis=2)
    rays = camera.pixel_to_ray(x, y) if rays is None else rays
    return spot_kernels.pinhole_jacobian(np.ascontiguousarray(rays, dtype=float), float(camera.fx), float(camera.fy))


def sanitized_covariance(cov_px: np.ndarray) -> np.ndarray:
    """
    Spot covariances (N, 2, 2) [px^2] for the final fit.

    Unknown (non-finite) ones count as 1 px^2, and MIN_FIT_SIGMA_PX^2 is added on both axes.
    """
    cov_px = np.asarray(cov_px, dtype=float).reshape(-1, 2, 2)
    cov = np.where(np.isfinite(cov_px).all(axis=(1, 2))[:, None, None], cov_px, np.eye(2)[None])
    return cov + MIN_FIT_SIGMA_PX ** 2 * np.eye(2)[None]


def direction_covariance(camera: CameraModel, x: np.ndarray, y: np.ndarray, cov_px: np.ndarray) -> np.ndarray:
    """
    Return the (N, 3, 3) covariance [rad^2] of the sensor-frame rays of spots at (x, y) [px].

    From the pixel covariance cov_px (N, 2, 2) [px^2]: J C J^T (ray_jacobian,
    sanitized_covariance).
    """
    jac = ray_jacobian(camera, x, y)
    return jac @ sanitized_covariance(cov_px) @ np.transpose(jac, (0, 2, 1))


def direction_sigma(camera: CameraModel, x: np.ndarray, y: np.ndarray, cov_px: np.ndarray) -> np.ndarray:
    """
    Isotropic 1-sigma direction error [rad] of the rays of spots at (x, y) [px].

    From the pixel covariance cov_px (N, 2, 2) [px^2]: sqrt(trace(J C J^T) / 2)
    (direction_covariance), so the field angle's foreshortening and the spot's anisotropy
    enter the variance.
    """
    return np.sqrt(0.5 * np.trace(direction_covariance(camera, x, y, cov_px), axis1=1, axis2=2))


class StarIdentifier:
    """
    Lost-in-space identification: identify() = prepare -> search -> solved (final fit).

    A subclass overrides one step: `hypotheses` (correspondences the default `search`
    verifies one by one) or, with a search of its own, `search` itself (e.g. hybrid's
    compiled triangle search, which verifies inside it). Checked when the subclass is
    defined.
    """

    name = "base"

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if cls.hypotheses is StarIdentifier.hypotheses and cls.search is StarIdentifier.search:
            raise TypeError(f"{cls.__name__} must override StarIdentifier.hypotheses or StarIdentifier.search")

    def __init__(self, database: StarDatabase, config: IdentifyConfig):
        self.database = database
        self.config = config
        # Per-call counters an algorithm may fill (e.g. "pivots", "patterns"); reset by
        # identify() and returned in Identification.stats.
        self.stats: dict[str, float] = {}
        self._mean_density = database.star_count / (4.0 * np.pi)  # [1/sr]
        self._sorted_magnitudes = np.sort(database.magnitude)
        self._deep: DeepCatalog | None = None
        if config.deep_match:
            self.deep_catalog()  # load (or build and cache) it now, not in the first frame's time

    # Smallest magnitude residual credited as evidence [mag]: below it, agreement is luck of
    # the noise, not information (see verify.log_magnitude_agreement).
    magnitude_floor = 0.05

    def hypotheses(self, geometry: SpotGeometry, deadline: Deadline) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """
        Yield (pattern spot indices, database star indices) correspondences, most promising first.

        For the default `search`. Spot indices refer to the flux-sorted spot list. None here:
        an algorithm that overrides `search` proposes none outside it.
        """
        return iter(())

    def angle_tolerance(self, sigma_a: np.ndarray, sigma_b: np.ndarray) -> np.ndarray:
        """Half-width of the accepted interval for an inter-star angle [rad]."""
        return self.config.sigma_multiplier * np.sqrt(sigma_a**2 + sigma_b**2) + self.config.angle_tolerance_floor_rad

    def prepare(self, spots: Spots, camera: CameraModel) -> tuple[np.ndarray, SpotGeometry]:
        """
        Return the finite spots' indices (into `spots`) and the geometry algorithms work on.

        The finite spots not flagged EDGE sorted by flux, brightest first, and their geometry in
        that order. Resets the per-call stats. Compiled (spot_kernels.prepare_spots) for
        undistorted cameras, numpy with distortion. A malformed record is refused first
        (Spots.validate: ValueError).
        """
        raw = self.raw_spots(spots)
        if not camera.has_distortion:
            return self.geometry_of(spot_kernels.prepare_spots(raw, Pinhole.of(camera), self.prepare_settings()),
                                    camera)
        floor_px = self.config.centroid_sigma_floor_px
        x, y, flux = raw.x, raw.y, spots.flux
        finite = np.isfinite(x) & np.isfinite(y) & ~spot_kernels.coincident_later(x, y, COINCIDENT_SEPARATION_PX)
        brightness = np.where(np.isnan(flux), -np.inf, flux)
        kept = np.flatnonzero(finite)
        order = kept[np.argsort(-brightness[kept], kind="stable")]
        x, y, flux = x[order], y[order], flux[order]
        # Direction 1-sigma from each spot's covariance; unknown (NaN) counts as 1 px; floored.
        cov = spots.cov[order]
        variance = 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])
        sigma_px = np.maximum(np.sqrt(np.where(np.isfinite(variance), np.maximum(variance, 0.0), 1.0)), floor_px)
        magnitude = np.full(flux.size, np.nan)
        bright = flux > 0  # NaN compares False
        magnitude[bright] = -2.5 * np.log10(flux[bright])
        return order, SpotGeometry(rays=camera.pixel_to_ray(x, y), sigma=sigma_px * camera.pixel_scale_rad,
                                   pattern_count=min(x.size, self.config.max_pattern_spots),
                                   magnitude=magnitude, x=x, y=y, pixel_cov=sanitized_covariance(cov),
                                   jacobian=ray_jacobian(camera, x, y), camera=camera)

    def raw_spots(self, spots: Spots) -> RawSpots:
        """
        Return `spots` as prepare's kernels read them, after Spots.validate (ValueError); resets the per-call stats.

        Float64 arrays; x NaN where the spot is flagged EDGE: a spot whose light runs past the
        border is not used (what the fit lost can pull it beyond its covariance, and a faint
        one then takes a star's name: frame_fits).
        """
        spots.validate()
        self.stats = {}
        as_float = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731  one compiled signature
        edge = (np.asarray(spots.flags) & FLAG_EDGE) != 0
        return RawSpots(as_float(np.where(edge, np.nan, spots.x)), as_float(spots.y), as_float(spots.flux),
                        as_float(spots.cov))

    def prepare_settings(self) -> PrepareSettings:
        """Return spot_kernels.prepare_spots' floors for this identifier's config."""
        return PrepareSettings(float(self.config.centroid_sigma_floor_px), MIN_FIT_SIGMA_PX, COINCIDENT_SEPARATION_PX)

    def geometry_of(self, prepared: PreparedSpots, camera: CameraModel) -> tuple[np.ndarray, SpotGeometry]:
        """Return prepare's (order, SpotGeometry) from spot_kernels.prepare_spots' record."""
        return prepared.order, SpotGeometry(prepared.rays, prepared.sigma,
                                            min(prepared.order.size, self.config.max_pattern_spots),
                                            prepared.magnitude, prepared.x, prepared.y, prepared.pixel_cov,
                                            prepared.jacobian, camera)

    def identify(self, spots: Spots, camera: CameraModel) -> Identification:
        """
        Identify the stars behind `spots` (pixel positions in `camera`); see Identification.

        Every algorithm runs the same steps: prepare the spots, `search` (the algorithm's step:
        propose and verify hypotheses), then the accepted match's final fit (`solved`).
        ValueError for a malformed Spots record (Spots.validate).
        """
        started = time.perf_counter()
        deadline = Deadline(self.config.max_time_s, self.config.budget_clock)
        order, geometry = self.prepare(spots, camera)
        n = order.size
        if n < MIN_STARS:
            return self._fail(TOO_FEW_SPOTS, f"{n} spots; at least {MIN_STARS} are needed", started, 0)
        return self.after_search(spots, camera, geometry, order, self.search(geometry, camera, deadline), deadline,
                                 started)

    def after_search(self, spots: Spots, camera: CameraModel, geometry: SpotGeometry, order: np.ndarray,
                     outcome: SearchOutcome, deadline: Deadline, started: float) -> Identification:
        """
        Finish identify() from the search's outcome: the lever-arm check, the final fit (solved), a second opinion.

        `started`: the call's time.perf_counter() [s].
        """
        if outcome.match is None:
            return self._fail(outcome.status, outcome.reason, started, outcome.tested)
        match = self.without_lever_outlier(geometry, camera, outcome.match)
        if match is None:
            self.stats["lever_outlier_rejected"] = 1
            return self._fail(NO_MATCH, "the accepted match's fit held a lever-arm outlier, and without it the frame "
                              "did not verify", started, outcome.tested)
        return self.with_second_opinion(spots, camera, geometry, order, match,
                                        self.solved(geometry, order, match, outcome.tested, started), deadline,
                                        started)

    def with_second_opinion(self, spots: Spots, camera: CameraModel, geometry: SpotGeometry, order: np.ndarray,
                            match: AcceptedMatch, result: Identification, deadline: Deadline,
                            started: float) -> Identification:
        """Return `result`, or second_opinion's when its bound is above config.second_opinion_bound."""
        if result.false_positive_probability > self.config.second_opinion_bound:
            result = self.second_opinion(spots, camera, geometry, order, match, result, deadline, started)
        return result

    def second_opinion(self, spots: Spots, camera: CameraModel, geometry: SpotGeometry, order: np.ndarray,
                       match: AcceptedMatch, result: Identification, deadline: Deadline,
                       started: float) -> Identification:
        """
        Return the better-evidenced of `result` and a search of the spots it left unmatched.

        A solve whose final bound is weak (above config.second_opinion_bound: few stars, no deep
        star confirming it) may be a chance match that the search met before the true one: in
        the false-id campaign, five right stars of a tight group and one wrong star farther out
        verified at 8.7e-7 with 6 of 38 spots, 200" off, while the true attitude verifies 35
        spots at 1e-153. The search runs again, within what is left of the time budget, over
        the spots the match did not use; an attitude it finds is verified on every spot
        (verify_hypothesis) and finished as identify's, and the lower final bound is published.
        A true weak solve (a sparse field) keeps its answer: the rest finds nothing better.
        """
        rest = np.setdiff1d(np.arange(order.size), match.spot_index)
        if rest.size < MIN_STARS or deadline.passed():
            return result
        first_stats = dict(self.stats)
        _, rest_geometry = self.prepare(spots.take(np.sort(order[rest])), camera)  # prepare resets stats
        outcome = self.search(rest_geometry, camera, deadline)
        self.stats = first_stats
        better = result
        if outcome.match is not None:
            again = self.verify_hypothesis(geometry, camera, outcome.match.rotation)
            if again is not None:
                other = self.solved(geometry, order, again, result.hypotheses + outcome.tested, started)
                if other.false_positive_probability < result.false_positive_probability:
                    better = other
        stats = {**better.stats, "second_opinion": 1 if better is result else 2}
        return replace(better, stats=stats, elapsed_s=time.perf_counter() - started)

    def without_lever_outlier(self, geometry: SpotGeometry, camera: CameraModel,
                              match: AcceptedMatch) -> AcceptedMatch | None:
        """
        Return the match, or the frame re-verified without the wrong stars (one or two) that a short lever arm let in.

        A wrong star far from a tight cluster of right ones sets the roll about the cluster: its
        own residual stays small (the fit follows it), the other stars' grow but stay within the
        5-sigma cut, and stars farther out fall outside the radius, so the match is consistent
        with itself and passes its false-positive bound at a wrong attitude (found by
        `star-tracker characterize sky-coverage`: 213" and 0.7 deg of roll off with 13 right
        stars and a false object); two stars of close pairs named crosswise do the same (the
        false-id campaign: HIP 50954/50976 and 52633/52595, 233" and 264" apart, 0.3 deg off
        with 11 right stars). Its fit's chi^2 (matching sigmas) is then improbable. When it is
        (below LEVER_TEST_PROBABILITY) and leaving out up to MAX_LEVER_OUTLIERS stars, one at a
        time the one whose absence fits the rest best, makes the rest consistent while each
        lies beyond FIT_OUTLIER_SIGMA of the rest's final fit, the frame is verified again from the
        rest's attitude (verify_hypothesis: every spot matched anew); None when that fails.
        Otherwise the match unchanged.
        """
        spot_index, star_index = match.spot_index, match.star_index
        n = spot_index.size
        if n <= MIN_STARS:
            return match
        if final_fit_kernel.match_chi2(geometry.rays, geometry.sigma, self.database.vectors, spot_index, star_index,
                                       match.rotation) <= _chi2_limit(2 * n - 3):
            return match  # the match's own fit is consistent
        body, stars, sigma = geometry.rays[spot_index], self.database.vectors[star_index], geometry.sigma[spot_index]
        kept = np.ones(n, bool)
        for _ in range(MAX_LEVER_OUTLIERS):
            if kept.sum() <= MIN_STARS:
                return match
            best, best_chi2, best_rotation = -1, np.inf, None
            for i in np.flatnonzero(kept):
                rest = kept.copy()
                rest[i] = False
                turned = quest_rotation(body[rest], stars[rest], sigma[rest])
                others = np.linalg.norm(body[rest] - stars[rest] @ turned, axis=1) / sigma[rest]
                if others @ others < best_chi2:
                    best, best_chi2, best_rotation = i, float(others @ others), turned
            kept[best] = False
            if best_chi2 <= _chi2_limit(2 * int(kept.sum()) - 3):
                deleted = np.linalg.norm(body[~kept] - stars[~kept] @ best_rotation, axis=1) / sigma[~kept]
                if np.any(deleted <= FIT_OUTLIER_SIGMA):
                    return match  # no star stands out (e.g. a lens distortion the camera model lacks)
                self.stats["lever_outliers"] = self.stats.get("lever_outliers", 0) + int(n - kept.sum())
                return self.verify_hypothesis(geometry, camera, best_rotation)
        return match  # more wrong stars than MAX_LEVER_OUTLIERS explain

    def identify_near(self, spots: Spots, camera: CameraModel, rotation: np.ndarray) -> Identification:
        """
        Identify `spots` near a known attitude `rotation` (sensor -> ICRS).

        E.g. the same frame's solve before its camera was refined: its stars within the
        verification radius (verification_radius_px) of where they are predicted. The attitude
        is verified as the only hypothesis (verify_hypothesis: every spot matched under it,
        refitted, the false-positive bound applied) and the match finished as identify's; when
        it fails, the full search (identify).
        """
        started = time.perf_counter()
        order, geometry = self.prepare(spots, camera)
        if order.size >= MIN_STARS:
            match = self.verify_hypothesis(geometry, camera, np.asarray(rotation, float))
            if match is not None:
                return self.solved(geometry, order, match, 1, started)
        return self.identify(spots, camera)

    def search(self, geometry: SpotGeometry, camera: CameraModel, deadline: Deadline) -> SearchOutcome:
        """
        Run the algorithm's step between `prepare` and the final fit.

        Find a verified match of the flux-sorted spots in `geometry` before `deadline` is
        passed. This default draws correspondences from `hypotheses`, turns each into a QUEST
        attitude and accepts the first that `verify_hypothesis` passes; an algorithm with its
        own (e.g. compiled) search overrides this instead of `hypotheses`.
        """
        tested = 0
        for pattern_spots, stars in self.hypotheses(geometry, deadline):
            if deadline.passed():
                return self._timed_out(tested)
            tested += 1
            try:
                rotation = quest_rotation(geometry.rays[pattern_spots], self.database.vectors[stars],
                                          geometry.sigma[pattern_spots])
            except (ValueError, np.linalg.LinAlgError):
                continue
            match = self.verify_hypothesis(geometry, camera, rotation)
            if match is not None:
                return SearchOutcome(match, tested)
        if deadline.passed():
            return self._timed_out(tested)
        return SearchOutcome(None, tested, NO_MATCH, f"no hypothesis passed verification ({tested} tested, "
                             f"{geometry.x.size} spots)")

    def _timed_out(self, tested: int) -> SearchOutcome:
        return SearchOutcome(None, tested, TIMEOUT, f"time budget {self.config.max_time_s:.3f} s spent after "
                             f"{tested} hypotheses")

    def verification_radius_px(self, geometry: SpotGeometry, camera: CameraModel) -> float:
        """Verification radius: the configured one, widened to 4 sigma of the typical spot."""
        return float(final_fit_kernel.verification_radius_px(geometry.sigma, float(camera.pixel_scale_rad),
                                                             float(self.config.match_radius_px)))

    def verify_hypothesis(self, geometry: SpotGeometry, camera: CameraModel,
                          rotation: np.ndarray) -> AcceptedMatch | None:
        """
        Match all spots under `rotation` (sensor -> ICRS) and verify the refined attitude.

        Refine with QUEST over the matches (twice), drop matches beyond 5 sigma, and accept only
        under the false-positive bound of `verify`; None when rejected.
        """
        radius = self.verification_radius_px(geometry, camera)
        vectors = self.database.vectors
        spot_index = star_index = None
        for _ in range(3):  # match, refit; the third match uses the refined attitude
            check = verify(rotation, geometry.x, geometry.y, self.database, camera, radius)
            if check.spot_index.size < MIN_STARS:
                return None
            if spot_index is not None and np.array_equal(check.spot_index, spot_index) \
                    and np.array_equal(check.star_index, star_index):
                break  # the same matches: the refit, and every pass after it, would repeat the last
            spot_index, star_index = check.spot_index, check.star_index
            rotation = quest_rotation(geometry.rays[spot_index], vectors[star_index], geometry.sigma[spot_index])
        body = geometry.rays[spot_index]
        normalized = np.linalg.norm(body - vectors[star_index] @ rotation, axis=1) / geometry.sigma[spot_index]
        keep = normalized <= 5.0
        if not np.all(keep):
            spot_index, star_index, body = spot_index[keep], star_index[keep], body[keep]
            if spot_index.size < MIN_STARS:
                return None
            rotation = quest_rotation(body, vectors[star_index], geometry.sigma[spot_index])
            normalized = (np.linalg.norm(body - vectors[star_index] @ rotation, axis=1)
                          / geometry.sigma[spot_index])
        sigma = geometry.sigma[spot_index]
        chi2 = float(np.sum(normalized**2))
        density = max(self._mean_density,
                      check.stars_in_view / (camera.width * camera.height * camera.pixel_scale_rad**2))
        log_t = log_chance_tuples(body, sigma, chi2, density)
        log_t += log_magnitude_agreement(geometry.magnitude[spot_index], self.database.magnitude[star_index],
                                         self._sorted_magnitudes, self.magnitude_floor)
        fp = false_positive_bound(log_t, geometry.x.size, spot_index.size)
        if fp > self.config.false_positive_bound:
            return None
        return AcceptedMatch(spot_index, star_index, rotation, fp)

    def solved(self, geometry: SpotGeometry, order: np.ndarray, match: AcceptedMatch, tested: int,
               started: float, algorithm: str | None = None, deep_match: bool = True,
               renamed: bool = False) -> Identification:
        """
        Return the Identification of an accepted match.

        Refitted with the final weights (final_fit), then, with config.deep_match and `deep_match` (False: a tracked
        frame), extended by the deep re-match (deep_rematch) when its bound holds; match.spot_index refers to the
        flux-sorted spots of `geometry` and is mapped back to the input spots through `order` (prepare). `started`: the
        call's time.perf_counter() [s]; `algorithm`: the name reported (default: this one's). When a
        guide star lies beyond FIT_OUTLIER_SIGMA of the published attitude, the frame is verified
        again at that attitude (verify_hypothesis) and, when that names as many stars as the
        rest, solved from it (`renamed`: already done once).
        """
        match = self.without_unnameable(geometry, match)
        guide = self.guide_matches(match.spot_index, match.star_index)
        solution, _, residual = self._fit(geometry, guide.spot_index, guide.star_vectors, match.rotation)
        matches, fp = guide, match.false_positive_probability
        if deep_match and self.config.deep_match and geometry.camera is not None:
            extended = self.deep_rematch(geometry, guide, solution)
            if extended is not None:
                matches, solution, residual, fp = extended
        if not renamed and geometry.camera is not None:
            # A guide star beyond FIT_OUTLIER_SIGMA of the published attitude was named at a
            # hypothesis the fit moved away from (two stars of close pairs named crosswise, the
            # deep stars pulling the attitude right): name the stars again there, once.
            off = residual[:guide.spot_index.size] / geometry.sigma[guide.spot_index] > FIT_OUTLIER_SIGMA
            if off.any():
                again = self.verify_hypothesis(geometry, geometry.camera, solution.rotation)
                if again is not None and again.spot_index.size >= guide.spot_index.size - int(off.sum()):
                    self.stats["guide_renamed"] = int(off.sum())
                    return self.solved(geometry, order, again, tested, started, algorithm, deep_match, renamed=True)
        return self.published(geometry, order, matches, solution, residual, fp, tested, started, algorithm)

    def published(self, geometry: SpotGeometry, order: np.ndarray, matches: "_Matches", solution: AttitudeSolution,
                  residual: np.ndarray, fp: float, tested: int, started: float,
                  algorithm: str | None = None) -> Identification:
        """
        Return the solved Identification of final `matches` (spot_index into the flux-sorted spots), sorted by spot.

        solution: their fit; residual (M,) their angles [rad]; fp their false-positive bound;
        tested: hypotheses; started: the call's time.perf_counter() [s].
        """
        by_spot = np.argsort(matches.spot_index)
        spot_index = matches.spot_index[by_spot]
        deep = matches.deep[by_spot]
        reason = f"{spot_index.size} stars matched"
        if deep.any():
            reason += f" ({np.count_nonzero(deep)} from the deep catalog)"
        return Identification(
            status=SOLVED, reason=f"{reason}, false-positive bound {fp:.1e}",
            algorithm=algorithm or self.name, elapsed_s=time.perf_counter() - started, hypotheses=tested,
            spot_index=order[spot_index], hip=matches.hip[by_spot], star_vectors=matches.star_vectors[by_spot],
            body_vectors=geometry.rays[spot_index], residual_rad=residual[by_spot],
            magnitude=matches.magnitude[by_spot], deep=deep, attitude=solution, false_positive_probability=fp,
            stats=dict(self.stats))

    def unnameable_settings(self, camera: CameraModel) -> tuple[float, float, float, float]:
        """
        Return final_fit_kernel.nameable's rule for `camera`: (floor_px, density_px, gate_sigma, max_chance).

        The matching floor [px], the guide stars per pixel, FIT_OUTLIER_SIGMA and
        MAX_CHANCE_GUIDE_STARS_IN_GATE (without_unnameable), in nameable's order.
        """
        return (float(self.config.centroid_sigma_floor_px), self._mean_density * camera.pixel_scale_rad ** 2,
                FIT_OUTLIER_SIGMA, MAX_CHANCE_GUIDE_STARS_IN_GATE)

    def guide_matches(self, spot_index: np.ndarray, star_index: np.ndarray) -> "_Matches":
        """Return the matches of flux-sorted spots `spot_index` to database stars `star_index`, as published."""
        return _Matches(spot_index, self.database.vectors[star_index], self.database.hip[star_index],
                        self.database.magnitude[star_index], np.zeros(spot_index.size, bool))

    def without_unnameable(self, geometry: SpotGeometry, match: AcceptedMatch) -> AcceptedMatch:
        """
        Return the match without the spots too uncertain to name (MAX_CHANCE_GUIDE_STARS_IN_GATE).

        A spot's gate: the ellipse of FIT_OUTLIER_SIGMA sigmas of its own covariance +
        config.centroid_sigma_floor_px^2 I [px^2] (isotropic spots: sigma / pixel scale); its
        unrelated guide stars: the guide catalog's mean density times that area. The match
        unchanged when fewer than MIN_STARS would stay (the frame's solve rests on them: its
        bound, not this rule, decides) or without a camera. Counter: stats guide_too_uncertain.
        """
        camera = geometry.camera
        if camera is None or match.spot_index.size <= MIN_STARS:
            return match
        spot = match.spot_index
        keep = final_fit_kernel.nameable(_pixel_cov_or_empty(geometry), geometry.sigma, spot,
                                         float(camera.pixel_scale_rad), *self.unnameable_settings(camera))
        if keep.all() or np.count_nonzero(keep) < MIN_STARS:
            return match
        self.stats["guide_too_uncertain"] = int(np.count_nonzero(~keep))
        return AcceptedMatch(spot[keep], match.star_index[keep], match.rotation, match.false_positive_probability)

    def deep_catalog(self) -> DeepCatalog:
        """
        Return the deep catalog of this identifier's database.

        Every Hipparcos star to its guide limit + config.deep_magnitude_margin at its epoch,
        cached beside it (deep_catalog.py).
        """
        limit = self.database.config.magnitude_limit + self.config.deep_magnitude_margin
        if self._deep is None or self._deep.magnitude_limit != limit:  # config may be replaced (commands/solve.py)
            self._deep = load_or_build_deep_catalog(limit, self.database.config.epoch_jyear,
                                                    self.database.cache_directory)
        return self._deep

    def deep_rematch(self, geometry: SpotGeometry, guide: "_Matches",
                     solution: AttitudeSolution) -> tuple["_Matches", AttitudeSolution, np.ndarray, float] | None:
        """
        Extend the guide matches by the deep catalog and refit (deep_match.deep_rematch, one compiled call).

        At their fitted `solution` (their offsets scale the match gate), the candidates (every
        condition but the chance bound) refitted, matched again at the refined attitude and
        refitted (deep_match.PASSES); at that attitude the pairs within the chance bound
        (deep_match.MAX_CHANCE_MATCHES) are named and the attitude refitted to guide and named
        matches. Returns the matches, solution, residuals [rad] and their false-positive bound,
        or None when no deep star was named or a bound (the candidates', the named matches')
        exceeds config.false_positive_bound (the guide solution stands); not run when every
        spot has its guide star.
        Counters in stats: deep_matches (named), deep_ambiguous, deep_magnitude_rejected,
        deep_too_uncertain, deep_stars_in_view; deep_candidates and deep_chance_rejected when
        the candidates passed their bound; deep_bound_rejected when a bound failed.
        """
        if guide.spot_index.size >= geometry.x.size:
            self.stats["deep_matches"] = 0  # every spot named by a guide star: nothing left to match
            return None
        catalog = self.deep_catalog()
        guide_record = GuideMatches(np.ascontiguousarray(guide.spot_index, np.int64),
                                    np.ascontiguousarray(guide.star_vectors, float),
                                    np.ascontiguousarray(guide.hip, np.int64),
                                    np.ascontiguousarray(guide.magnitude, float))
        outcome = deep_match.deep_rematch(
            geometry, geometry.camera, catalog, guide_record, solution.rotation, solution.covariance,
            self.config.centroid_sigma_floor_px, self.config.false_positive_bound, self.magnitude_floor,
            FIT_SCREEN_CHI2)
        return self.deep_result(outcome, guide)

    def deep_result(self, outcome: DeepRematchOutcome,
                    guide: "_Matches") -> tuple["_Matches", AttitudeSolution, np.ndarray, float] | None:
        """Return deep_rematch's result from the compiled re-match's `outcome` on `guide`; its counters go to stats."""
        catalog = self.deep_catalog()
        stats = outcome.stats.tolist()
        self.stats.update(deep_matches=stats[0], deep_ambiguous=stats[1], deep_magnitude_rejected=stats[2],
                          deep_too_uncertain=stats[3], deep_stars_in_view=stats[4])
        if stats[5]:  # the candidates passed their bound: pairs were named
            self.stats.update(deep_candidates=stats[5], deep_chance_rejected=stats[6])
        if stats[7]:
            self.stats["deep_bound_rejected"] = 1
        if outcome.status == 0:
            return None
        star = outcome.star
        matches = guide.extended(outcome.spot, catalog.vectors[star], catalog.hip[star], catalog.magnitude[star])
        rotation = outcome.rotation
        fitted = AttitudeSolution(matrix_to_quaternion(rotation), rotation, outcome.covariance, float(outcome.loss))
        return matches, fitted, outcome.residual, float(outcome.fp)

    def final_fit(self, geometry: SpotGeometry, spot_index: np.ndarray, star_index: np.ndarray,
                  rotation: np.ndarray) -> tuple[AttitudeSolution, np.ndarray]:
        """
        Fit the published attitude of accepted matches (database star indices).

        Weighted by each spot's own covariance, see _fit. Returns the solution and every match's residual angle [rad].
        """
        solution, _, residual = self._fit(geometry, spot_index, self.database.vectors[star_index], rotation)
        return solution, residual

    def warm_up_deep_rematch(self, camera: CameraModel) -> None:
        """
        Compile (or load from numba's cache) the compiled deep re-match and its cone query.

        On a synthetic frame: deep stars in view at the identity attitude, four of them as guide
        matches. A node calls it at start, so that its first solve compiles nothing.
        """
        if not self.config.deep_match:
            return
        catalog = self.deep_catalog()
        rotation = np.eye(3)
        star, u, v = deep_match.deep_stars_in_view(catalog, rotation, camera)
        n = min(star.size, 12)
        if n <= MIN_STARS:
            return
        spots = Spots(u[:n], v[:n], np.linspace(2e4, 1e3, n), np.full(n, 50.0), np.tile(np.eye(2) * 0.01, (n, 1, 1)),
                      np.zeros(n, np.uint32), np.full(n, 9, np.int32), np.full(n, 1e3), camera.width, camera.height)
        order, geometry = self.prepare(spots, camera)
        named = star[order[:MIN_STARS]]
        guide = _Matches(np.arange(MIN_STARS), catalog.vectors[named], catalog.hip[named], catalog.magnitude[named],
                         np.zeros(MIN_STARS, bool))
        solution = AttitudeSolution(matrix_to_quaternion(rotation), rotation, np.eye(3) * 1e-10, 0.0)
        self.deep_rematch(geometry, guide, solution)

    def _fit(self, geometry: SpotGeometry, spot_index: np.ndarray, stars: np.ndarray,
             rotation: np.ndarray) -> tuple[AttitudeSolution, np.ndarray, np.ndarray]:
        """
        Fit the published attitude of matches (spot_index into the flux-sorted spots).

        `stars` are their ICRS unit vectors. Weighted by each spot's own covariance (the
        centroider's, without the matching floor):
        from `rotation` (the matching fit, sensor -> ICRS, weighted with the floored sigma), a
        maximum-likelihood refinement with each ray's full 2-D covariance
        (final_fit_kernel.published_fit, attitude_estimation.refine_kernel; a streak's error is far larger along its
        smear than across it). Stars whose studentized residual exceeds FIT_SCREEN_CHI2 (chi^2
        with 2 DOF, ~3.7 sigma, under the residual's covariance: a bright star the fit leans on
        is judged by how far it would be from the others' fit) are left out of the fit (once;
        never below MIN_STARS). Returns the solution (sensor -> ICRS; covariance [rad^2] in the
        sensor frame, the inverse information of the fit: Shuster & Oh's for isotropic
        covariances), every match's studentized chi^2 (2 DOF) and residual angle [rad] under it.
        """
        pixel_cov = _pixel_cov_or_empty(geometry)
        fitted, covariance, loss, chi2, residual = final_fit_kernel.published_fit(
            geometry.rays, geometry.sigma, pixel_cov, geometry.jacobian if pixel_cov.size else _NO_JACOBIAN,
            np.ascontiguousarray(spot_index, np.int64), np.ascontiguousarray(stars, float),
            np.ascontiguousarray(rotation, float), FIT_SCREEN_CHI2, MIN_STARS)
        return AttitudeSolution(matrix_to_quaternion(fitted), fitted, covariance, loss), chi2, residual

    def _fail(self, status: str, reason: str, started: float, tested: int) -> Identification:
        return Identification(status=status, reason=reason, algorithm=self.name,
                              elapsed_s=time.perf_counter() - started, hypotheses=tested, stats=dict(self.stats))
