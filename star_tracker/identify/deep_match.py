# SPDX-License-Identifier: Apache-2.0
"""
The deep re-match: once an attitude is accepted, match the spots left over to the deep catalog.

Identification (the search and its false-positive logic) uses only the pattern database's
guide stars. At the accepted attitude, every spot without a guide star is compared with the
deep catalog's stars projected into the image (deep_catalog.py; fainter than the guide
limit), and a pair is added only when it is unambiguous:

- geometry: the Mahalanobis distance of star to spot, under the spot's own pixel covariance
  (floored as for matching) plus the attitude's covariance carried to that pixel, is at most
  GATE_SIGMA; that covariance is scaled up when the guide matches' offsets under it are
  larger than it says (median chi^2 over its expectation: unmodelled errors, e.g. lens
  distortion, show there first);
- the gate is narrow enough: its ellipse holds at most MAX_CHANCE_STARS_IN_GATE deep stars of
  this view's density on average (a chance star in the gate of an uncatalogued spot is the
  way a deep match goes wrong);
- one spot <-> one star: no second star within AMBIGUITY_FACTOR x the gate of the spot, and
  no second spot (matched or not, its gate narrow enough) within that of the star; a spot
  whose only star is already matched to another spot (a ghost, a split blend) gets none;
- brightness: with the zero point of the guide matches (median of instrumental minus catalog
  magnitude) the spot's magnitude is within MAGNITUDE_SIGMA robust sigmas of the guide
  matches' scatter of the star's (at least MAGNITUDE_TOLERANCE_FLOOR); skipped when
  magnitudes are unknown;
- chance: the frame's expected number of chance pairs as good, chance_pairs (the deep stars of
  this view's density expected nearer than the candidate, times the catalog's share as close
  in brightness, combined as the expected count under chance of stars at least as good on
  both) x the uncatalogued spots (those tried with no deep star within reach: false objects,
  stars beyond the catalog), is at most MAX_CHANCE_MATCHES. A false object is named only when
  a chance star passes all of this: at most MAX_CHANCE_MATCHES per frame, whatever the number
  of false objects.
Base.deep_rematch refits the attitude over the guide matches and the candidates that pass
all but the chance bound, matches once more at the refined attitude and refits, checks the
false-positive bound of verify.py over them with the deep catalog's density (`deep_bound`),
then names the pairs that pass the chance bound at that attitude (its covariance now the
candidates', far smaller than the guide stars' alone) and refits over guide and named matches.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models.camera import CameraModel
from .deep_catalog import DeepCatalog, ViewCone
from . import deep_match_kernel
from .deep_match_kernel import deep_pairs
from .kernel_records import DeepRematchOutcome, DeepRematchSettings, GuideMatches, Pinhole, PreparedSpots
from .spot_geometry import SpotGeometry
from .verify import MIN_STARS, false_positive_bound, log_chance_tuples, log_magnitude_agreement


# A spot and a star pair up within this many sigmas (2-D Mahalanobis; chi^2_2 > 16 has
# probability e^-8 ~ 3e-4 for a true pair).
GATE_SIGMA = 4.0
# A second candidate (star for a spot, spot for a star) within this multiple of the gate
# makes the pair ambiguous: neither is claimed.
AMBIGUITY_FACTOR = 2.0
# Magnitude agreement: robust sigmas of the guide matches' magnitude scatter, and the least
# tolerance [mag] (instrumental magnitudes of faint spots are noisy; colour terms).
MAGNITUDE_SIGMA = 3.0
MAGNITUDE_TOLERANCE_FLOOR = 1.0
# A spot whose gate ellipse would hold more than this many unrelated deep stars on average (the
# view's density x the ellipse's area) is too uncertain to name (e.g. a saturated spot): a
# spot of an uncatalogued source would take a chance star with about this probability.
MAX_CHANCE_STARS_IN_GATE = 0.01
# A pair is named only when the frame's expected number of chance pairs as good (chance_pairs
# x the uncatalogued spots) is at most this: a false object is named at most this often per
# frame on average, however many there are. Without it, `star-tracker characterize false-id
# --option false_stars=50` named one in 137 of 20,000 scenes; with it, none in 10,000 (docs/
# IDENTIFICATION.md). The price: wide gates name few stars (161 of the 979 named without it on
# the real corpus, most of the wide JPEG fields' stars left unnamed).
MAX_CHANCE_MATCHES = 1e-5
# Fewest guide magnitudes for a zero point; below it the brightness test is skipped.
MIN_ZERO_POINT_STARS = 3
# Median chi^2 of a 2-D Gaussian residual (2 ln 2): the reduced-chi^2 scale is
# median(chi^2) / this, robust to a few outliers.
MEDIAN_CHI2_2DOF = 2.0 * np.log(2.0)


@dataclass(frozen=True)
class DeepMatches:
    """
    spot_index (K,) into the flux-sorted spots (base.prepare).

    star_index (K,) deep catalog indices; stars_in_view: deep stars projected inside the
    image; ambiguous: spots with a star inside the gate left unmatched as ambiguous;
    magnitude_rejected: spots left unmatched because their brightness disagreed;
    too_uncertain: spots not tried because their gate was too wide (MAX_CHANCE_STARS_IN_GATE);
    chance (K,) each match's expected chance pairs as good in its spot (chance_pairs);
    chance_rejected: pairs otherwise named left unmatched by the frame's chance bound
    (MAX_CHANCE_MATCHES); uncatalogued: the spots counted as uncatalogued (at least 1).
    """

    spot_index: np.ndarray
    star_index: np.ndarray
    stars_in_view: int
    ambiguous: int = 0
    magnitude_rejected: int = 0
    too_uncertain: int = 0
    chance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    chance_rejected: int = 0
    uncatalogued: int = 1

    def within_chance(self, max_chance: float | None = None) -> "DeepMatches":
        """
        Return these candidates (a match_deep call with max_chance=inf) that pass the frame's chance bound.

        What match_deep returns at the same attitude and covariances with `max_chance` (None:
        MAX_CHANCE_MATCHES).
        """
        named = self.chance * self.uncatalogued <= (MAX_CHANCE_MATCHES if max_chance is None else max_chance)
        return DeepMatches(self.spot_index[named], self.star_index[named], self.stars_in_view, self.ambiguous,
                           self.magnitude_rejected, self.too_uncertain, self.chance[named],
                           self.chance_rejected + int(np.count_nonzero(~named)), self.uncatalogued)


def error_scale(geometry: SpotGeometry, camera: CameraModel, rotation: np.ndarray, spot_index: np.ndarray,
                star_vectors: np.ndarray, cov_px: np.ndarray) -> float:
    """
    Variance scale (>= 1) of the match gate.

    The median squared Mahalanobis offset of the guide matches (spot_index, their ICRS
    star_vectors) from their stars projected with `rotation`, under their gate covariances
    cov_px (N, 2, 2) [px^2] of all spots, over its expectation for a 2-D Gaussian (robust to
    a few outliers).
    """
    u, v, _ = camera.project(np.asarray(star_vectors, float) @ rotation)
    dx, dy = geometry.x[spot_index] - u, geometry.y[spot_index] - v
    cov = cov_px[spot_index]
    a, b, c = cov[:, 0, 0], 0.5 * (cov[:, 0, 1] + cov[:, 1, 0]), cov[:, 1, 1]
    d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / (a * c - b * b)
    d2 = d2[np.isfinite(d2)]
    return 1.0 if d2.size < MIN_STARS else max(1.0, float(np.median(d2)) / MEDIAN_CHI2_2DOF)


class SpotOffsetCovariance:
    """
    Each spot's offset covariance [px^2] from its star's predicted pixel, for any attitude covariance.

    The spot's own covariance + floor_px^2 I + the attitude's, J+ [b]x P [b]x^T J+^T with J =
    d ray / d pixel and P the sensor-frame attitude covariance [rad^2]. The per-spot parts (own
    and the carry J+ [b]x) are computed once per frame; `at(P)` adds the attitude's.
    """

    def __init__(self, geometry: SpotGeometry, camera: CameraModel, floor_px: float):
        rays = geometry.rays
        n = rays.shape[0]
        if geometry.pixel_cov is None:
            self.own = (geometry.sigma / camera.pixel_scale_rad)[:, None, None] ** 2 * np.eye(2)[None]
        else:
            self.own = geometry.pixel_cov + floor_px ** 2 * np.eye(2)[None]
        skew = np.zeros((n, 3, 3))
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -rays[:, 2], rays[:, 1], -rays[:, 0]
        skew -= np.transpose(skew, (0, 2, 1))
        if geometry.jacobian is None:
            pinv = np.broadcast_to(np.eye(2, 3) / camera.pixel_scale_rad, (n, 2, 3))
        else:
            jac = geometry.jacobian
            jt = np.transpose(jac, (0, 2, 1))
            g = jt @ jac  # 2x2 normal matrices, inverted in closed form
            det = g[:, 0, 0] * g[:, 1, 1] - g[:, 0, 1] * g[:, 1, 0]
            g_inv = np.stack([np.stack([g[:, 1, 1], -g[:, 0, 1]], 1),
                              np.stack([-g[:, 1, 0], g[:, 0, 0]], 1)], 1) / det[:, None, None]
            pinv = g_inv @ jt
        self.carry = pinv @ skew  # d pixel / d attitude error (2 x 3)
        self._carry_t = np.transpose(self.carry, (0, 2, 1))

    def at(self, attitude_covariance: np.ndarray) -> np.ndarray:
        """(N, 2, 2) [px^2] under the sensor-frame attitude covariance (3, 3) [rad^2]."""
        return self.own + self.carry @ np.asarray(attitude_covariance, float)[None] @ self._carry_t


def magnitude_gate(spot_magnitude: np.ndarray, star_magnitude: np.ndarray) -> tuple[float, float] | None:
    """
    Return (zero point, tolerance) [mag] from the guide matches' instrumental and catalog magnitudes.

    None when fewer than MIN_ZERO_POINT_STARS are known.
    """
    difference = np.asarray(spot_magnitude, float) - np.asarray(star_magnitude, float)
    difference = difference[np.isfinite(difference)]
    if difference.size < MIN_ZERO_POINT_STARS:
        return None
    zero = float(np.median(difference))
    robust_sigma = 1.4826 * float(np.median(np.abs(difference - zero)))
    return zero, max(MAGNITUDE_SIGMA * robust_sigma, MAGNITUDE_TOLERANCE_FLOOR)


def match_deep(catalog: DeepCatalog, geometry: SpotGeometry, camera: CameraModel, rotation: np.ndarray,
               spot_cov_px: np.ndarray, guide_spots: np.ndarray, guide_hip: np.ndarray,
               guide_magnitude: np.ndarray, max_chance: float | None = None,
               cone: ViewCone | None = None) -> DeepMatches:
    """
    Return the unambiguous deep matches of the spots not in `guide_spots` (flux-sorted indices).

    Under `rotation` (sensor -> ICRS), with each spot's offset covariance spot_cov_px (N, 2, 2)
    [px^2] (SpotOffsetCovariance); guide_hip and guide_magnitude (catalog Hp) of the guide
    matches, in guide_spots' order (the zero point); max_chance: the frame's chance bound (None:
    MAX_CHANCE_MATCHES; inf: the candidates every other condition passes); cone: the view's
    stars queried once for all passes (DeepCatalog.view_cone). See the module docstring.
    """
    star, u, v = catalog.stars_in_view(rotation, camera, cone)
    n, m = geometry.x.size, star.size
    density_px = m / float(camera.width * camera.height)  # deep stars per pixel in this view
    det = spot_cov_px[:, 0, 0] * spot_cov_px[:, 1, 1] - spot_cov_px[:, 0, 1] * spot_cov_px[:, 1, 0]
    narrow = density_px * np.pi * GATE_SIGMA ** 2 * np.sqrt(np.maximum(det, 0.0)) <= MAX_CHANCE_STARS_IN_GATE
    # A spot too uncertain to be named claims no star either (nor makes one ambiguous): one spot
    # with a runaway covariance would otherwise reach every star in the image.
    free = np.ones(n, bool)
    free[guide_spots] = False
    too_uncertain = int(np.count_nonzero(free & ~narrow))
    free &= narrow
    spot_i, star_j, d2_i, ambiguous, uncatalogued = deep_pairs(
        np.ascontiguousarray(geometry.x, float), np.ascontiguousarray(geometry.y, float),
        np.ascontiguousarray(spot_cov_px, float), narrow, free, u, v, catalog.hip[star],
        np.sort(np.asarray(guide_hip, catalog.hip.dtype)), AMBIGUITY_FACTOR * GATE_SIGMA, GATE_SIGMA)
    star_k = star[star_j]
    rejected = 0
    fraction = np.full(spot_i.size, np.nan)  # share of deep stars as close in brightness (NaN: unknown)
    gate = magnitude_gate(geometry.magnitude[guide_spots], guide_magnitude) if spot_i.size else None
    if gate is not None:
        residual = geometry.magnitude[spot_i] - gate[0] - catalog.magnitude[star_k]
        agree = ~(np.abs(residual) > gate[1])  # an unknown (NaN) spot magnitude passes on geometry
        rejected = int(np.count_nonzero(~agree))
        fraction = magnitude_fraction(catalog.sorted_magnitudes, catalog.magnitude[star_k] + residual,
                                      np.abs(residual))
        fraction[~np.isfinite(residual)] = np.nan
        spot_i, star_k, fraction, d2_i = spot_i[agree], star_k[agree], fraction[agree], d2_i[agree]
    gate_stars = density_px * np.pi * GATE_SIGMA ** 2 * np.sqrt(np.maximum(det[spot_i], 0.0))
    chance = chance_pairs(gate_stars * d2_i / GATE_SIGMA ** 2, fraction, gate_stars)
    # The uncatalogued spots (false objects, stars beyond the catalog): those tried without a
    # deep star within reach (an uncatalogued spot has one with probability < 4 x
    # MAX_CHANCE_STARS_IN_GATE), at least one.
    uncatalogued = max(uncatalogued, 1)
    named = chance * uncatalogued <= (MAX_CHANCE_MATCHES if max_chance is None else max_chance)
    chance_rejected = int(np.count_nonzero(~named))
    return DeepMatches(spot_i[named], star_k[named], int(m), int(ambiguous), rejected, too_uncertain,
                       chance[named], chance_rejected, uncatalogued)


def magnitude_fraction(sorted_magnitudes: np.ndarray, center: np.ndarray, half_width: np.ndarray) -> np.ndarray:
    """
    Return the share of catalog stars within half_width [mag] of center [mag] (sorted_magnitudes: the catalog's).

    Under chance (a star unrelated to the spot, its magnitude drawn from the catalog's), the
    share of stars at least as close in brightness: uniform on [0, 1].
    """
    n = max(sorted_magnitudes.size, 1)
    low = np.searchsorted(sorted_magnitudes, center - half_width, side="left")
    high = np.searchsorted(sorted_magnitudes, center + half_width, side="right")
    return (high - low) / n


def chance_pairs(near_stars: np.ndarray, fraction: np.ndarray, gate_stars: np.ndarray) -> np.ndarray:
    """
    Return the expected number of unrelated deep stars in a spot's gate as good as its candidate.

    near_stars: the expected unrelated stars nearer than the candidate (density x its Mahalanobis
    ellipse's area); fraction: the share as close in brightness (magnitude_fraction; NaN when
    unknown: geometry alone); gate_stars: those expected in the whole gate. Unrelated stars
    fall uniformly in the image (expected count `a` up to gate_stars) with a brightness share
    `b` uniform on [0, 1]; the expected number with a b <= t = near_stars x fraction is
    t (1 + ln(gate_stars / t)), or near_stars alone without magnitudes.
    """
    t = np.asarray(near_stars, float) * np.asarray(fraction, float)
    known = np.isfinite(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        joint = np.where(t > 0.0, t * (1.0 + np.log(np.maximum(gate_stars / t, 1.0))), 0.0)
    return np.where(known, joint, np.asarray(near_stars, float))


def deep_bound(geometry: SpotGeometry, spot_index: np.ndarray, star_vectors: np.ndarray, star_magnitude: np.ndarray,
               rotation: np.ndarray, catalog: DeepCatalog, stars_in_view: int, camera: CameraModel,
               magnitude_floor: float) -> float:
    """
    Return the false-positive bound of verify.py over the matches at `rotation`.

    The matches: spot_index into the flux-sorted spots, their ICRS star_vectors and catalog
    magnitudes; with the deep catalog's density (the larger of its mean and its density in this
    view) and magnitude distribution; the matching sigmas as in verification. Matches beyond 5
    sigma count for nothing (left out, as verification leaves them out).
    """
    body, sigma = geometry.rays[spot_index], geometry.sigma[spot_index]
    normalized = np.linalg.norm(body - star_vectors @ rotation, axis=1) / sigma
    keep = normalized <= 5.0
    if np.count_nonzero(keep) < MIN_STARS:
        return 1.0
    density = max(catalog.mean_density, stars_in_view / (camera.width * camera.height * camera.pixel_scale_rad ** 2))
    log_t = log_chance_tuples(body[keep], sigma[keep], float(np.sum(normalized[keep] ** 2)), density)
    log_t += log_magnitude_agreement(geometry.magnitude[spot_index][keep], star_magnitude[keep],
                                     catalog.sorted_magnitudes, magnitude_floor)
    return false_positive_bound(log_t, geometry.x.size, int(np.count_nonzero(keep)))


def deep_rematch_pinhole(geometry: SpotGeometry, camera: CameraModel, catalog: DeepCatalog, cone: ViewCone,
                         guide: GuideMatches, rotation: np.ndarray, covariance: np.ndarray, floor_px: float,
                         fp_limit: float, magnitude_floor: float, fit_screen_chi2: float,
                         passes: int) -> DeepRematchOutcome:
    """
    Run the deep re-match (base.StarIdentifier.deep_rematch) in one compiled call, for a camera without distortion.

    `cone`: the view's deep stars (DeepCatalog.view_cone at the guide fit); guide: the guide
    matches; rotation (sensor -> ICRS) and covariance [rad^2]: the guide fit; floor_px: the
    matching floor [px]; fp_limit: the false-positive bound; magnitude_floor [mag];
    fit_screen_chi2: the final fit's screen; passes: match-and-refit rounds. The same
    conditions and counters as the Python path (match_deep, error_scale, deep_bound).
    """
    isotropic = geometry.pixel_cov is None  # then both (0, ...): the kernels weight by sigma alone
    spots = PreparedSpots(np.zeros(0, np.int64), np.ascontiguousarray(geometry.rays, float),
                          np.ascontiguousarray(geometry.sigma, float), np.ascontiguousarray(geometry.magnitude, float),
                          np.ascontiguousarray(geometry.x, float), np.ascontiguousarray(geometry.y, float),
                          np.zeros((0, 2, 2)) if isotropic else np.ascontiguousarray(geometry.pixel_cov, float),
                          np.zeros((0, 3, 2)) if isotropic else np.ascontiguousarray(geometry.jacobian, float))
    half = min(camera.half_diagonal_fov_rad + 1e-3, np.pi / 2)
    settings = DeepRematchSettings(
        float(camera.pixel_scale_rad), float(floor_px), float(camera.width * camera.height),
        float(2.0 * np.sin(0.5 * half)), cone.axis, float(2.0 * np.sin(0.5 * cone.margin_rad)), float(fp_limit),
        float(magnitude_floor), float(fit_screen_chi2), MIN_STARS, int(passes), GATE_SIGMA, AMBIGUITY_FACTOR,
        MAX_CHANCE_STARS_IN_GATE, MAX_CHANCE_MATCHES, MIN_ZERO_POINT_STARS, MAGNITUDE_SIGMA,
        MAGNITUDE_TOLERANCE_FLOOR, MEDIAN_CHI2_2DOF, float(catalog.mean_density))
    return deep_match_kernel.deep_rematch(spots, catalog.arrays, cone.stars, guide,
                                          np.ascontiguousarray(rotation, float),
                                          np.ascontiguousarray(covariance, float), Pinhole.of(camera), settings)
