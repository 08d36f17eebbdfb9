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
- chance: the frame's expected number of chance pairs as good, deep_match_kernel.chance_pairs
  (the deep stars of this view's density expected nearer than the candidate, times the
  catalog's share as close in brightness, combined as the expected count under chance of
  stars at least as good on both) x the uncatalogued spots (those tried with no deep star
  within reach: false objects, stars beyond the catalog), is at most MAX_CHANCE_MATCHES. A
  false object is named only when a chance star passes all of this: at most
  MAX_CHANCE_MATCHES per frame, whatever the number of false objects.
deep_rematch refits the attitude over the guide matches and the candidates that pass all but
the chance bound, matches once more at the refined attitude and refits (PASSES), checks the
false-positive bound of verify.py over them with the deep catalog's density, then names the
pairs that pass the chance bound at that attitude (its covariance now the candidates', far
smaller than the guide stars' alone) and refits over guide and named matches. It runs as one
compiled call (deep_match_kernel.py) for every camera, distorted or not.
"""
from __future__ import annotations

import math

import numpy as np

from ..models.camera import CameraModel
from . import deep_match_kernel
from .deep_catalog import DeepCatalog
from .kernel_records import DeepRematchOutcome, DeepRematchSettings, GuideMatches, LensModel, PreparedSpots
from .spot_geometry import SpotGeometry
from .verify import MIN_STARS


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
# Rounds: match at the guide fit, refit, match again at the refined attitude.
PASSES = 2
# The passes take the view's deep stars from one cone query widened by this much [rad]: their
# attitudes differ by arcseconds (a farther one queries again).
CONE_MARGIN_RAD = 2e-3


def deep_rematch(geometry: SpotGeometry, camera: CameraModel, catalog: DeepCatalog, guide: GuideMatches,
                 rotation: np.ndarray, covariance: np.ndarray, floor_px: float, fp_limit: float,
                 magnitude_floor: float, fit_screen_chi2: float) -> DeepRematchOutcome:
    """
    Run the deep re-match (base.StarIdentifier.deep_rematch) in one compiled call (deep_match_kernel.deep_rematch).

    geometry: the flux-sorted spots; guide: the guide matches; rotation (sensor -> ICRS) and
    covariance [rad^2]: the guide fit; floor_px: the matching floor [px]; fp_limit: the
    false-positive bound; magnitude_floor [mag]; fit_screen_chi2: the final fit's screen.
    """
    isotropic = geometry.pixel_cov is None  # then both (0, ...): the kernels weight by sigma alone
    spots = PreparedSpots(np.zeros(0, np.int64), np.ascontiguousarray(geometry.rays, float),
                          np.ascontiguousarray(geometry.sigma, float), np.ascontiguousarray(geometry.magnitude, float),
                          np.ascontiguousarray(geometry.x, float), np.ascontiguousarray(geometry.y, float),
                          np.zeros((0, 2, 2)) if isotropic else np.ascontiguousarray(geometry.pixel_cov, float),
                          np.zeros((0, 3, 2)) if isotropic else np.ascontiguousarray(geometry.jacobian, float))
    return deep_match_kernel.deep_rematch(spots, catalog.arrays, catalog.cells, guide,
                                          np.ascontiguousarray(rotation, float),
                                          np.ascontiguousarray(covariance, float), LensModel.of(camera),
                                          rematch_settings(camera, catalog, floor_px, fp_limit, magnitude_floor,
                                                           fit_screen_chi2))


def rematch_settings(camera: CameraModel, catalog: DeepCatalog, floor_px: float, fp_limit: float,
                     magnitude_floor: float, fit_screen_chi2: float) -> DeepRematchSettings:
    """Return the compiled re-match's constants for `camera` and `catalog` (arguments as deep_rematch's)."""
    half = min(camera.half_diagonal_fov_rad + 1e-3, math.pi / 2)
    cone_half = min(half + CONE_MARGIN_RAD, math.pi / 2)
    return DeepRematchSettings(
        float(camera.pixel_scale_rad), float(floor_px), float(camera.width * camera.height),
        2.0 * math.sin(0.5 * half), 2.0 * math.sin(0.5 * cone_half), 2.0 * math.sin(0.5 * CONE_MARGIN_RAD),
        float(fp_limit), float(magnitude_floor), float(fit_screen_chi2), MIN_STARS, PASSES, GATE_SIGMA,
        AMBIGUITY_FACTOR, MAX_CHANCE_STARS_IN_GATE, MAX_CHANCE_MATCHES, MIN_ZERO_POINT_STARS, MAGNITUDE_SIGMA,
        MAGNITUDE_TOLERANCE_FLOOR, MEDIAN_CHI2_2DOF, float(catalog.mean_density))


def deep_stars_in_view(catalog: DeepCatalog, rotation: np.ndarray,
                       camera: CameraModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the deep stars the camera images at `rotation` (sensor -> ICRS): catalog indices and pixels u, v [px].

    As the re-match sees them: those within the field's half diagonal (+1 mrad) of the
    boresight (a cone query of the cell index), projected inside the pixel area.
    """
    half = min(camera.half_diagonal_fov_rad + 1e-3, math.pi / 2)
    chord = 2.0 * math.sin(0.5 * half)
    rotation = np.ascontiguousarray(rotation, float)
    cone = catalog.cone(rotation[:, 2].copy(), chord)
    return deep_match_kernel.view_stars(catalog.arrays, cone, rotation, LensModel.of(camera), chord)
