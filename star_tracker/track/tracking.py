# SPDX-License-Identifier: Apache-2.0
"""
Tracking: localized recognition from a predicted attitude.

With lost-in-space fallback, rate and delay compensation (Hu & Huang, seed 004).

After a verified solution the tracker predicts the next frame's attitude from the last one
and the body rate, R_pred = R_last exp([omega dt]x), with a covariance that grows with dt.
Local recognition looks for the catalog stars only where the prediction puts them: the
displacement between spots and predicted stars is voted in a 2-D histogram over the gate
(gate_sigma x the predicted position sigma, at most `max_gate_fov_radii` field radii, the
paper's 2R circle), the matches of the winning displacement give an attitude, and that attitude
is verified against every spot. The false-positive bound is the one of `verify` with the
searched region in place of all of SO(3): the expected number of chance catalog tuples scales
with the volume of attitudes searched, here the gate_sigma ellipsoid of the prediction (see
`log_chance_tuples_in_region`). A small region makes 3-star (even 2-star) frames verifiable,
which lost-in-space can never do at 1e-6. A frame that tracking cannot verify goes to
lost-in-space.

Delay compensation: when a lost-in-space solve of frame k is still running as frames k+1..n
arrive, `bridge` chains their frame-to-frame relative rotations (spots matched between
consecutive frames, no catalog); when the solve ends, the chain carries R_k to frame n, and
local recognition on frame n verifies it. The newest frame gets a fresh, verified attitude.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..models.attitude import matrix_to_quaternion, matrix_to_rotation_vector, rotation_vector_to_matrix
from ..models.attitude_estimation import AttitudeSolution, attitude_covariance
from ..models.camera import CameraModel
from ..centroid import Spots
from ..centroid.applied_motion import AppliedMotion
from ..centroid.streak.smear import SmearModel
from ..parameter_spec import parameter, range_problems
from .rate import ACCELERATION_MAX_AGE_S, AttitudeRateEstimator, RateEstimate
from . import kernels as track_kernels
from ..identify import kernels
from ..identify.kernel_records import CatalogArrays, Pinhole, SpotArrays, VerifySettings
from ..identify import base as identify_base
from ..identify.base import AcceptedMatch, Identification, StarIdentifier
from ..identify.verify import MIN_STARS
from . import recognize_kernel
from ..identify.skygrid import SkyGrid, cell_of

MODE_TRACKING = "tracking"
MODE_LOST_IN_SPACE = "lost_in_space"
MODE_LOST = "lost"
# An innovation beyond chi^2_3 at 1 % is taken for an acceleration step (Tracker._step_covariance);
# scipy.stats.chi2.ppf(0.99, 3).
STEP_CHI2 = 11.345
# Streak length [px] at which a constant-rate path fit's bias under an unknown acceleration is
# halfway from the point-like T^2 / 24 to the long streak's T^2 / 8 (Tracker.bias_gain).
STREAK_BIAS_HALF_PX = 12.0


@dataclass(frozen=True)
class TrackingConfig:
    """
    Parameters of tracking.

    gate_sigma: searched region = this many sigma of the predicted attitude;
    min_stars: fewest matched stars tracking accepts (the bound still decides);
    max_gate_fov_radii: largest gate in field radii (half diagonals), Hu & Huang's 2R;
    max_coast_s: longest time a prediction is used without a new solution [s];
    max_angular_rate_rad_s: rate prior per axis before a rate estimate exists [rad/s];
    max_angular_acceleration_rad_s2: assumed bound on |d omega/dt| for the rate's model error
    and the prediction [rad/s^2]; rate_window_s: attitudes used for the rate estimate [s];
    exposure_s: the frames' exposure [s], for what an uncertain angular acceleration does to
    the measured attitude (0: nothing added); false_positive_bound: as for lost-in-space;
    max_pattern_spots: brightest spots used to vote the displacement.
    """

    gate_sigma: float = parameter(5.0, "searched region around the predicted attitude", "sigmas", 1.0, 20.0)
    min_stars: int = parameter(3, "fewest verified stars a tracked frame needs", "", 2, 10)
    max_gate_fov_radii: float = parameter(2.0, "largest search radius (Hu & Huang's 2R circle)", "field radii", 0.1,
                                          4.0)
    max_coast_s: float = parameter(2.0, "longest prediction without a new solution", "s", 0.01, 60.0)
    max_angular_rate_rad_s: float = parameter(math.radians(5.0), "rate prior per axis before a rate "
                                              "estimate exists (5 deg/s)", "rad/s", 1e-4, 1.0)
    max_angular_acceleration_rad_s2: float = parameter(math.radians(2.0), "assumed bound on the angular "
                                                       "acceleration (rate model error, prediction; 2 deg/s^2)",
                                                       "rad/s^2", 0.0, 1.0)
    rate_window_s: float = parameter(0.45, "attitudes used for the rate estimate", "s", 0.01, 10.0)
    exposure_s: float = parameter(0.1, "the frames' exposure: an uncertain angular acceleration's effect on the "
                                  "attitude (0 = none added)", "s", 0.0, 10.0)
    false_positive_bound: float = 1.0e-6
    max_pattern_spots: int = 40

    def __post_init__(self) -> None:
        bad = range_problems(self)
        if not (0.0 < self.false_positive_bound < 1.0):
            bad.append(f"false_positive_bound={self.false_positive_bound} must be in (0, 1)")
        if not (3 <= self.max_pattern_spots <= 500):
            bad.append(f"max_pattern_spots={self.max_pattern_spots} must be in [3, 500]")
        if bad:
            raise ValueError("invalid tracking config: " + "; ".join(bad))


@dataclass(frozen=True)
class Prediction:
    """
    Predicted attitude (sensor -> ICRS) at `stamp_ns` and its error covariance.

    The covariance is the small-angle one in the sensor frame [rad^2].
    """

    stamp_ns: int
    rotation: np.ndarray
    covariance: np.ndarray


@dataclass(frozen=True)
class TrackedFrame:
    """
    What the tracker made of one frame.

    mode: "tracking" (local recognition), "lost_in_space" or "lost" (no verified attitude);
    identification: the result (its attitude when solved); rate: body rate at this frame when
    estimated; gate_px: searched radius when a prediction was used [px]; bridged_frames: frames
    chained by delay compensation to reach this one; elapsed_s: processing time [s];
    on_exposure_path: the attitude was carried to mid-exposure by the path a gyro measured
    within the exposure (its spots were that path's exposure averages: Tracker._accept_on_path).
    """

    stamp_ns: int
    mode: str
    identification: Identification
    rate: RateEstimate | None = None
    gate_px: float | None = None
    bridged_frames: int = 0
    elapsed_s: float = 0.0
    on_exposure_path: bool = False

    @property
    def solved(self) -> bool:
        return self.identification.solved


def log_chance_tuples_in_region(body: np.ndarray, sigma: np.ndarray, chi2: float, density_per_sr: float,
                                region_covariance: np.ndarray, region_sigma: float) -> float:
    """
    Return ln of the expected number of chance catalog m-tuples fitting `body` in a region.

    Catalog m-tuples (uniform density [1/sr]) fitting the m sensor-frame unit vectors `body`
    with weighted chi^2 <= `chi2` under some attitude inside the region_sigma ellipsoid of
    `region_covariance` [rad^2] (sensor frame).

    verify.log_chance_tuples with the volume of SO(3) (8 pi^2 sqrt(det G) in coordinates scaled
    by G^(1/2), G = sum (I - b b^T)/s^2) replaced by the searched region: there the ellipsoid
    has semi-axes region_sigma sqrt(mu_i), mu_i the eigenvalues of G P, and the tube of radius
    sqrt(c) around it a 3-D cross-section of at most (4/3) pi prod(region_sigma sqrt(mu_i) +
    sqrt(c)); never more than the whole group. The subset bound is kernels.false_positive_bound
    with min_stars = TrackingConfig.min_stars.
    """
    return float(track_kernels.log_chance_tuples_in_region(
        np.ascontiguousarray(body, dtype=float), np.ascontiguousarray(sigma, dtype=float), float(chi2),
        float(density_per_sr), np.ascontiguousarray(region_covariance, dtype=float), float(region_sigma)))


def vote_displacement(spot_x: np.ndarray, spot_y: np.ndarray, ref_x: np.ndarray, ref_y: np.ndarray,
                      gate_px: float, bin_px: float) -> tuple[float, float, int]:
    """
    Vote the displacement (dx, dy) [px] shared by most spot - reference pairs within `gate_px`.

    Voted in a histogram of `bin_px` cells (2x2 neighbourhoods, so a cluster on a cell edge
    still wins), refined as the mean of the pairs within one bin of the winner. Returns (dx,
    dy, votes).
    """
    dx = spot_x[:, None] - ref_x[None, :]
    dy = spot_y[:, None] - ref_y[None, :]
    near = dx * dx + dy * dy <= gate_px * gate_px
    dx, dy = dx[near], dy[near]
    if dx.size == 0:
        return 0.0, 0.0, 0
    bins = max(1, int(math.ceil(2.0 * gate_px / bin_px)))
    edges = np.linspace(-gate_px, gate_px, bins + 1)
    hist, _, _ = np.histogram2d(dx, dy, bins=[edges, edges])
    padded = np.pad(hist, 1)
    block = padded[:-1, :-1] + padded[1:, :-1] + padded[:-1, 1:] + padded[1:, 1:]  # (bins + 1)^2 corners
    i, j = np.unravel_index(int(np.argmax(block)), block.shape)
    cx, cy = edges[0] + i * (edges[1] - edges[0]), edges[0] + j * (edges[1] - edges[0])
    close = (np.abs(dx - cx) <= bin_px) & (np.abs(dy - cy) <= bin_px)
    if not np.any(close):
        return 0.0, 0.0, 0
    return float(np.mean(dx[close])), float(np.mean(dy[close])), int(np.count_nonzero(close))


def unique_nearest(spot_x, spot_y, ref_x, ref_y, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """
    One-to-one nearest pairs within `radius_px`: (spot idx, ref idx).

    A reference claimed by two spots, or a spot with two references within the radius, is
    dropped.
    """
    as_float = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731  one compiled signature
    return track_kernels.unique_nearest(as_float(spot_x), as_float(spot_y), as_float(ref_x), as_float(ref_y),
                                        float(radius_px))


# A tracked frame's failures (recognize_kernel's verdicts) and their reasons.
_FAILURES = {
    recognize_kernel.TOO_FEW_SPOTS: "{count} spots; tracking needs {min_stars}",
    recognize_kernel.TOO_FEW_STARS_NEAR: "{count} catalog stars near the predicted attitude",
    recognize_kernel.TOO_FEW_PAIRS: "{count} spots near predicted stars",
    recognize_kernel.TOO_FEW_VERIFIED: "{count} stars verified; tracking needs {min_stars}",
    recognize_kernel.OUTSIDE_GATE: "solution {sigma:.1f} sigma from the prediction (gate {gate_sigma:g})",
    recognize_kernel.BOUND_FAILED: "{count} stars matched but false-positive bound {fp:.1e} > {bound:.0e}",
}


class Tracker:
    """Per-sensor tracking state around a lost-in-space identifier (any StarIdentifier)."""

    def __init__(self, lost_in_space: StarIdentifier, config: TrackingConfig = TrackingConfig()):
        self.lost_in_space = lost_in_space
        self.config = config
        self.database = lost_in_space.database
        self.grid = getattr(lost_in_space, "grid", None) or SkyGrid.build(self.database.vectors)
        self.catalog = getattr(lost_in_space, "catalog", None) or CatalogArrays.build(self.database, self.grid)
        self._vectors = self.catalog.vectors
        self.rates = AttitudeRateEstimator(config.rate_window_s, config.max_angular_acceleration_rad_s2)
        self._last: tuple[int, np.ndarray, np.ndarray] | None = None  # (stamp_ns, rotation, covariance)
        self.rate: RateEstimate | None = None
        self._pending: list[tuple[int, Spots, CameraModel]] = []  # delay compensation: frames since acquisition
        self._chain: list[tuple[np.ndarray, np.ndarray]] = []  # relative rotations between pending frames
        self._half_diagonal_key, self._half_diagonal_value = None, 0.0

    # --- state -----------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the track (e.g. after a jump in time)."""
        self._last, self.rate = None, None
        self.rates.reset()
        self._pending, self._chain = [], []

    def predict(self, stamp_ns: int) -> Prediction | None:
        """
        Predicted attitude at `stamp_ns` from the last solution and the rate.

        None when there is no solution within max_coast_s (or the stamp is older than it).
        """
        if self._last is None:
            return None
        last_ns, rotation, covariance = self._last
        dt = (stamp_ns - last_ns) * 1e-9
        if dt < 0.0 or dt > self.config.max_coast_s:
            return None
        return self._propagate(stamp_ns, rotation, covariance, dt)

    def attitude_guess(self, stamp_ns: int) -> np.ndarray | None:
        """
        Return the last solution propagated to `stamp_ns` by the last rate, however old (None: no solution yet).

        For what the head can see (its status: blinded or occulted while it has no attitude),
        not for tracking: beyond max_coast_s its error is unbounded by the tracker's standards,
        but a steady body rate (inertial, nadir or Sun pointing) keeps it within degrees.
        """
        if self._last is None:
            return None
        last_ns, rotation, covariance = self._last
        return self._propagate(stamp_ns, rotation, covariance, (stamp_ns - last_ns) * 1e-9).rotation

    def _propagate(self, stamp_ns: int, rotation: np.ndarray, covariance: np.ndarray, dt: float) -> Prediction:
        if self.rate is not None:
            omega, rate_cov = self.rate.angular_velocity, self.rate.covariance
        else:
            omega, rate_cov = np.zeros(3), np.eye(3) * self.config.max_angular_rate_rad_s**2
        accel = 0.5 * self.config.max_angular_acceleration_rad_s2 * dt * dt
        predicted_cov = covariance + dt * dt * rate_cov + np.eye(3) * accel * accel / 3.0
        return Prediction(stamp_ns, rotation @ rotation_vector_to_matrix(omega * dt), predicted_cov)

    # --- per frame -------------------------------------------------------------------
    def process(self, stamp_ns: int, spots: Spots, camera: CameraModel) -> TrackedFrame:
        """
        Track when a prediction exists, else (or when tracking fails) lost-in-space.

        Update the state with a verified result. Synchronous; see begin_acquisition for the
        node's asynchronous path.
        """
        started = time.perf_counter()
        prediction = self.predict(stamp_ns)
        gate_px = None
        if prediction is not None:
            tracked = self.accept_tracked(stamp_ns, spots, camera, prediction)
            if tracked.solved:
                return tracked
            gate_px = tracked.gate_px
        result = self.lost_in_space.identify(spots, camera)
        if result.solved:
            return self._accept(stamp_ns, result, MODE_LOST_IN_SPACE, gate_px, 0, started, camera.pixel_scale_rad,
                                spots.applied_motion)
        return TrackedFrame(stamp_ns, MODE_LOST, result, None, gate_px, 0, time.perf_counter() - started)

    def accept_tracked(self, stamp_ns: int, spots: Spots, camera: CameraModel, prediction: Prediction) -> TrackedFrame:
        """Local recognition around `prediction`; the state is updated when it is verified."""
        started = time.perf_counter()
        result, gate_px = self.track(spots, camera, prediction)
        if result.solved:
            return self._accept(stamp_ns, result, MODE_TRACKING, gate_px, 0, started, camera.pixel_scale_rad,
                                spots.applied_motion)
        return TrackedFrame(stamp_ns, MODE_LOST, result, None, gate_px, 0, time.perf_counter() - started)

    def _accept(self, stamp_ns: int, result: Identification, mode: str, gate_px, bridged: int,
                started: float, pixel_scale_rad: float | None = None,
                applied: AppliedMotion | None = None) -> TrackedFrame:
        """
        Update the state with a verified frame; return it with the covariance its measurement calls for.

        `applied`: the motion the frame's spots were measured with (Spots.applied_motion). When
        None (not known), what a centroider aided by this tracker had (_acceleration_aid): the
        nodes' centroider states it per frame, as its aid may come from an older estimate.

        A frame measured on a gyro's path (applied.exposure_path_offset_rad) measured the
        exposure-average attitude of a known path: it is carried to mid-exposure by the path's
        own offset (R_mid = R_mean exp([phi(0) x])) with that offset's covariance
        (AppliedMotion.exposure_path_offset_covariance) in place of the acceleration terms,
        which bound the offset of a path not known; the rate window gets it as unbiased.
        """
        solution = result.attitude
        if self._last is not None and stamp_ns <= self._last[0]:
            self.rates.reset()  # time went backwards (replay restarted): a new window
        path_offset = None if applied is None else applied.exposure_path_offset_rad
        if path_offset is not None:
            return self._accept_on_path(stamp_ns, result, mode, gate_px, bridged, started, applied)
        # The estimate a rate-aided centroider had for this frame: the last, while it is no older
        # than ACCELERATION_MAX_AGE_S (the centroider ages its acceleration out by the same rule).
        aid = self._acceleration_aid(stamp_ns)
        if applied is None:
            aid_omega = None if aid is None else aid.angular_velocity
            aid_alpha = None if aid is None else aid.angular_acceleration
        else:
            aid_omega, aid_alpha = applied.angular_velocity_rad_s, applied.angular_acceleration_rad_s2
        # Its uncertainty: the estimate's (an older estimate's differs little; a gyro's is not known).
        aid_alpha_cov = None if aid_alpha is None or self.rate is None else self.rate.acceleration_covariance
        # What this frame measured: the exposure-average bias of the acceleration its aid missed (rate.py).
        after = self.rates.add(stamp_ns, solution.rotation, solution.covariance,
                               self.bias_gain(aid_omega, pixel_scale_rad), aid_alpha)
        known = after if after is not None else aid
        gain = self.bias_gain(None if known is None else known.angular_velocity, pixel_scale_rad)
        step = self._step_covariance(stamp_ns, solution.rotation, solution.covariance, gain) if aid is not None \
            else None
        self.rate = after
        self._last = (stamp_ns, solution.rotation, solution.covariance)  # the measurement's own covariance
        added = self.acceleration_covariance(aid_alpha, aid_alpha_cov, step, self.rate, gain)
        if added is not None:
            result = replace(result, attitude=replace(solution, covariance=solution.covariance + added))
        return TrackedFrame(stamp_ns, mode, result, self.rate, gate_px, bridged, time.perf_counter() - started)

    def _accept_on_path(self, stamp_ns: int, result: Identification, mode: str, gate_px, bridged: int,
                        started: float, applied: AppliedMotion) -> TrackedFrame:
        """_accept for a frame measured on a gyro's path: carried to mid-exposure by the path's offset."""
        solution = result.attitude
        rotation, covariance = applied.at_mid_exposure(solution.rotation, solution.covariance)
        mid = replace(solution, quaternion=matrix_to_quaternion(rotation), rotation=rotation, covariance=covariance)
        # A mid-exposure attitude: no acceleration biases it (bias gain 0).
        self.rate = self.rates.add(stamp_ns, rotation, covariance, 0.0, None)
        self._last = (stamp_ns, rotation, covariance)
        return TrackedFrame(stamp_ns, mode, replace(result, attitude=mid), self.rate, gate_px, bridged,
                            time.perf_counter() - started, on_exposure_path=True)

    def centroider_aid(self, stamp_ns: int, camera: CameraModel, exposure_s: float,
                       max_rate_age_s: float = ACCELERATION_MAX_AGE_S) -> SmearModel | None:
        """
        Return the smear model a centroider aided by this tracker gets for the frame at `stamp_ns`, or None.

        As the nodes' centroider takes the identifier's rate (ros/rate_input.motion_for_frame):
        the rate carried to the frame by the acceleration, and the acceleration while the
        estimate is no older than ACCELERATION_MAX_AGE_S before the frame: what this tracker
        assumes a frame was measured with (_accept, rate.py). None without a rate within
        max_rate_age_s [s] of the frame (the centroider's max_rate_age_s) or an exposure.
        """
        rate = self.rate
        if rate is None or exposure_s <= 0.0 or abs(int(stamp_ns) - rate.stamp_ns) > max_rate_age_s * 1e9:
            return None
        omega, alpha = rate.at(stamp_ns)
        current = self._acceleration_aid(stamp_ns) is not None and rate.angular_acceleration is not None
        return SmearModel(camera, omega, exposure_s, alpha if current else None)

    def _acceleration_aid(self, stamp_ns: int) -> RateEstimate | None:
        """Return the estimate a centroider took the frame's acceleration from: the last, unless stale."""
        aid = self.rate
        if aid is None or not 0 <= int(stamp_ns) - aid.stamp_ns <= ACCELERATION_MAX_AGE_S * 1e9:
            return None
        return aid

    def bias_gain(self, omega: np.ndarray | None, pixel_scale_rad: float | None) -> float:
        """
        Return k [s^2]: an acceleration the centroider got wrong by d alpha moves a spot by about k d alpha.

        A point-like spot (the exposure's mean position): T^2 / 24 (T = exposure_s). A streak
        fitted with a constant-rate path when the body accelerates: more, up to T^2 / 8 for a
        long one (the fit follows the streak's ends, whose middle is alpha T^2 / 8 from the
        mid-exposure position; the exposure mean is alpha T^2 / 24). Measured on rendered
        frames (bias / (alpha T^2)): the default chain's 0.041 at 1.7 px streaks, 0.050 at
        6.8 px, 0.078 at 13.6 px, 0.096 at 27 px; the test camera's 0.071 at 9.6 px
        (test_acceleration). Modelled as T^2 (1/24 + (1/12) L^2 / (L^2 + L0^2)), L the
        cross-boresight streak length |omega_xy| T [px], L0 = STREAK_BIAS_HALF_PX: 0.062, 0.088,
        0.111 and 0.074 there (at most 0.016 T^2 above). Without a rate or a pixel scale: T^2 / 24.
        """
        exposure = self.config.exposure_s
        k = 1.0 / 24.0
        if omega is not None and pixel_scale_rad:
            length = math.hypot(omega[0], omega[1]) * exposure / pixel_scale_rad
            k += length * length / (length * length + STREAK_BIAS_HALF_PX ** 2) / 12.0
        return k * exposure * exposure

    def _step_covariance(self, stamp_ns: int, rotation: np.ndarray, covariance: np.ndarray,
                         gain: float | None = None) -> np.ndarray | None:
        """
        Covariance [rad^2] for an acceleration the last rate estimate did not know, from this frame's innovation.

        The innovation nu (sensor frame) of the new attitude against the last one carried by
        the last rate and acceleration, with its expected covariance S (both attitudes', the
        rate's and the acceleration's, or the max_angular_acceleration_rad_s2 bound's when none
        was estimated). An acceleration that changed since by d alpha (a slew starting or
        ending) biases this frame by the offset of the unexpected path within the exposure: at
        most |d alpha| k (a point-like spot, k = T^2 / 24, exactly that for a change before the
        exposure, whose innovation is larger by the path since the change), and never more than
        the innovation; a streak fitted on a constant-rate path more (k = `gain`, bias_gain;
        T^2 / 24 when None). When nu^T S^-1 nu = m2 exceeds STEP_CHI2 (chi^2_3 at 1 %), |nu|
        bounds the bias (this frame's bias is part of nu; the part of nu noise does not explain,
        nu_x = |nu| (1 - sqrt(STEP_CHI2 / m2)), is a small share of it near the threshold: a
        ramp starting inside the exposure left a frame 1.1" off with nu_x 0.2", stress
        campaign, seed 2026, task 1976 frame 8), capped at k d alpha_max,
        d alpha_max the larger of |alpha_last| + alpha_max (any acceleration within the bound
        after the estimated one) and the least change that explains nu_x over dt,
        2 nu_x / (dt^2 + T^2 / 12). The bias is taken uniform within +-B along nu: B^2 / 3 along
        its direction. None when there is no previous attitude or no rate, or the innovation is
        within the noise.

        S leaves out that the last attitude is in the fit that gave the rate and the
        acceleration (their cross-covariances with it), so noise alone fires the test on about
        8 % of the frames at rest, not 1 % (NIS mean 5 on the stress campaign's rest missions;
        test_step_test_independent_frames). That margin is kept: a slew's first frame shows its
        step barely above the noise, and with the cross-covariances in S (the test then at its
        1 %, across the boresight and in roll apart) the stress campaign (seed 2026) had 75
        frames beyond 5 sigma instead of 59 and 1.1 % of its accelerating frames above
        chi^2_3(0.997), for stratum NEES means of 2.64-3.00 instead of 2.50-2.87.
        """
        if self._last is None or self.rate is None or self.config.exposure_s <= 0.0:
            return None
        last_ns, last_rotation, last_covariance = self._last
        dt = (stamp_ns - last_ns) * 1e-9
        if not (0.0 < dt <= self.config.max_coast_s):
            return None
        rate = self.rate
        turn = rate.angular_velocity * dt
        if rate.angular_acceleration is not None:
            turn = turn + 0.5 * dt * dt * rate.angular_acceleration
        spread = last_covariance + covariance + dt * dt * rate.covariance
        if rate.angular_acceleration is not None:
            spread = spread + (0.5 * dt * dt) ** 2 * rate.acceleration_covariance
        else:
            spread = spread + np.eye(3) * (0.5 * self.config.max_angular_acceleration_rad_s2 * dt * dt) ** 2 / 3.0
        predicted = last_rotation @ rotation_vector_to_matrix(turn)
        nu = matrix_to_rotation_vector(predicted.T @ rotation)
        try:
            m2 = float(nu @ np.linalg.solve(spread, nu))
        except np.linalg.LinAlgError:
            return None
        if not m2 > STEP_CHI2:
            return None
        norm = float(np.linalg.norm(nu))
        unexplained = norm * (1.0 - math.sqrt(STEP_CHI2 / m2))
        exposure = self.config.exposure_s
        known = 0.0 if rate.angular_acceleration is None else float(np.linalg.norm(rate.angular_acceleration))
        change = max(known + self.config.max_angular_acceleration_rad_s2,
                     2.0 * unexplained / (dt * dt + exposure * exposure / 12.0))
        bound = min(norm, change * (exposure * exposure / 24.0 if gain is None else gain))
        direction = nu / norm
        return bound * bound / 3.0 * np.outer(direction, direction)

    def acceleration_covariance(self, aid_alpha: np.ndarray | None, aid_alpha_cov: np.ndarray | None,
                                step: np.ndarray | None = None, after: RateEstimate | None = None,
                                gain: float | None = None) -> np.ndarray | None:
        """
        Attitude covariance [rad^2] an uncertain angular acceleration adds to a frame's solution (None: nothing).

        Within an exposure T the attitude moves by phi(t) = omega t + alpha t^2 / 2 about
        mid-exposure. The spots are measured at mid-exposure when the centroider knows alpha
        (SmearModel with the acceleration: path fits on the accelerated path, point-like spots
        moved by the exposure-average offset alpha T^2 / 24); what it gets wrong by d alpha
        moves the attitude by about k d alpha, k = `gain` (bias_gain: T^2 / 24 for point-like
        spots, up to T^2 / 8 for long streaks; T^2 / 24 when None). `aid_alpha` is the
        acceleration the frame was measured with (None: none), `aid_alpha_cov` its covariance
        (None: not estimated). When this frame's innovation shows an acceleration that changed
        since (`step`, _step_covariance): k^2 aid_alpha_cov (the max_angular_acceleration_rad_s2
        bound, uniform per axis, without one) plus `step`. Otherwise, with `after` (the estimate
        that includes this frame) holding an acceleration: k^2 (m m^T + its covariance),
        m = alpha_after - aid_alpha (zero when None), the mean square of what the centroider
        missed. Else k^2 aid_alpha_cov, or the bound, (k alpha_max)^2 / 3 per axis.
        exposure_s = 0 adds nothing.
        """
        exposure = self.config.exposure_s
        if exposure <= 0.0:
            return None
        gain = exposure * exposure / 24.0 if gain is None else gain
        known = aid_alpha is not None and aid_alpha_cov is not None
        bound = np.eye(3) * (gain * self.config.max_angular_acceleration_rad_s2) ** 2 / 3.0
        if step is not None:  # the aid's acceleration no longer holds: its bound, and the step's
            return (gain * gain * aid_alpha_cov if known else bound) + step
        if after is not None and after.acceleration_covariance is not None:
            miss = after.angular_acceleration - (aid_alpha if aid_alpha is not None else 0.0)
            return gain * gain * (np.outer(miss, miss) + after.acceleration_covariance)
        return gain * gain * aid_alpha_cov if known else bound

    def gate_px(self, camera: CameraModel, prediction: Prediction, tolerance_px: float) -> float:
        """
        Search radius [px].

        gate_sigma x the predicted position sigma of a star at the field corner
        (cross-boresight and roll), plus the match tolerance, capped at max_gate_fov_radii
        field radii.
        """
        cov = prediction.covariance
        cross = math.sqrt(max(cov[0, 0], cov[1, 1], 0.0))
        half_diagonal = self._half_diagonal(camera)
        roll = math.sqrt(max(cov[2, 2], 0.0)) * half_diagonal
        sigma_px = math.hypot(cross, roll) / camera.pixel_scale_rad
        cap = self.config.max_gate_fov_radii * half_diagonal / camera.pixel_scale_rad
        return min(self.config.gate_sigma * sigma_px + tolerance_px, cap)

    def track(self, spots: Spots, camera: CameraModel, prediction: Prediction) -> tuple[Identification, float]:
        """
        Local recognition of `spots` around `prediction`: (result, gate [px]).

        For a camera without distortion its common path is one compiled call
        (recognize_kernel.recognize), same results as the Python steps (_track_steps); a wide
        gate's displacement is voted here (_vote) and the kernel goes on from it
        (recognize_kernel.from_pairs); a guide star to name again goes to StarIdentifier.solved.
        """
        started = time.perf_counter()
        if camera.has_distortion:
            return self._track_steps(spots, camera, prediction, started)
        lis = self.lost_in_space
        settings = self._recognize_settings(camera)
        rotation = np.ascontiguousarray(prediction.rotation, float)
        covariance = np.ascontiguousarray(prediction.covariance, float)
        finish = self._finish_settings(camera)
        (verdict, prepared, gate, count, mahalanobis2, fp, spot, star, verified, guide_spot, guide_star, too_uncertain,
         fitted, fitted_covariance, loss, residual, near, u, v, tolerance_px) = recognize_kernel.recognize(
            lis.raw_spots(spots), Pinhole.of(camera), lis.prepare_settings(), settings, rotation, covariance,
            self.catalog, self.grid.cell_density, finish)
        order, geometry = lis.geometry_of(prepared, camera)
        if verdict == recognize_kernel.VOTE_IN_PYTHON:  # voted here, then the kernel goes on from the vote
            voted = self._vote(geometry, camera, prediction, u, v, gate, tolerance_px)
            if voted is None:
                return self._no_displacement(started, gate)
            (verdict, prepared, gate, count, mahalanobis2, fp, spot, star, verified, guide_spot, guide_star,
             too_uncertain, fitted, fitted_covariance, loss, residual, near, u, v, tolerance_px) = \
                recognize_kernel.from_pairs(prepared, gate, tolerance_px, near, u, v, *voted, settings, rotation,
                                            covariance, self.catalog, self.grid.cell_density, finish)
        if verdict == recognize_kernel.NAME_IN_PYTHON:
            return lis.solved(geometry, order, AcceptedMatch(spot, star, verified, fp), 1, started,
                              algorithm="tracking", deep_match=False), gate
        if verdict != recognize_kernel.SOLVED:
            return self._failed(verdict, started, gate, count=count, sigma=math.sqrt(mahalanobis2), fp=fp)
        if too_uncertain:
            lis.stats["guide_too_uncertain"] = too_uncertain
        solution = AttitudeSolution(matrix_to_quaternion(fitted), fitted, fitted_covariance, loss)
        return lis.published(geometry, order, lis.guide_matches(guide_spot, guide_star), solution, residual, fp, 1,
                             started, "tracking"), gate

    def _recognize_settings(self, camera: CameraModel) -> tuple:
        """Return recognize_kernel.recognize's `tracking` settings for `camera`."""
        config, lis = self.config, self.lost_in_space
        return (int(config.min_stars), int(config.max_pattern_spots), float(config.gate_sigma),
                float(config.max_gate_fov_radii), float(config.false_positive_bound),
                float(lis.config.match_radius_px), float(camera.pixel_scale_rad), float(self._half_diagonal(camera)),
                float(self.grid.max_radius_rad), int(self.grid.grid), float(lis.magnitude_floor))

    def _finish_settings(self, camera: CameraModel) -> tuple:
        """Return recognize_kernel.recognize's `finish` settings: StarIdentifier.solved's for `camera`."""
        lis = self.lost_in_space
        unnameable = lis.unnameable_settings(camera)
        return (MIN_STARS, unnameable, identify_base.FIT_SCREEN_CHI2, identify_base.FIT_OUTLIER_SIGMA)

    def _failed(self, verdict: int, started: float, gate: float, **values) -> tuple[Identification, float]:
        """Return a failed tracked frame (`verdict`, recognize_kernel's) with its reason, and the gate [px]."""
        reason = _FAILURES[verdict].format(min_stars=self.config.min_stars, gate_sigma=self.config.gate_sigma,
                                           bound=self.config.false_positive_bound, **values)
        return Identification("no_match", reason, "tracking", time.perf_counter() - started), gate

    def _vote(self, geometry, camera: CameraModel, prediction: Prediction, u: np.ndarray, v: np.ndarray, gate: float,
              tolerance_px: float) -> tuple[float, float, float] | None:
        """
        Return (dx, dy, radius) [px]: the displacement the brightest spots vote for, and the pairing radius.

        The stars in view at (u, v) [px]; None when no displacement is shared by two stars
        within the gate [px].
        """
        voters = min(geometry.x.size, self.config.max_pattern_spots)
        # Roll error spreads the displacement over the field; the bins must hold that spread.
        roll_spread = (self.config.gate_sigma * math.sqrt(max(prediction.covariance[2, 2], 0.0))
                       * self._half_diagonal(camera) / camera.pixel_scale_rad)
        dx, dy, votes = vote_displacement(geometry.x[:voters], geometry.y[:voters], u, v, gate,
                                          max(2.0 * tolerance_px, roll_spread))
        if votes < 2:
            return None
        return dx, dy, max(tolerance_px, min(roll_spread, gate))

    @staticmethod
    def _no_displacement(started: float, gate: float) -> tuple[Identification, float]:
        return Identification("no_match", f"no displacement shared by two stars within the {gate:.0f} px gate",
                              "tracking", time.perf_counter() - started), gate

    def _track_steps(self, spots: Spots, camera: CameraModel, prediction: Prediction,
                     started: float) -> tuple[Identification, float]:
        """Tracker.track step by step: any camera, any gate."""
        lis = self.lost_in_space
        order, geometry = self.lost_in_space.prepare(spots, camera)
        n = order.size
        tolerance_px = lis.verification_radius_px(geometry, camera)
        gate = self.gate_px(camera, prediction, tolerance_px)
        if n < self.config.min_stars:
            return self._failed(recognize_kernel.TOO_FEW_SPOTS, started, gate, count=n)
        # Catalog stars the predicted attitude puts in (or within the gate of) the image.
        rotation = prediction.rotation
        half_diagonal = self._half_diagonal(camera)
        reach = half_diagonal + gate * camera.pixel_scale_rad
        cos_reach = math.cos(min(reach, math.pi / 2))
        if camera.has_distortion:
            near = np.flatnonzero(self._vectors @ rotation[:, 2] > cos_reach)
            u, v, front = camera.project(self._vectors[near] @ rotation)
            keep = front & camera.in_image(u, v, margin=-gate)
            near, u, v = near[keep], u[keep], v[keep]
        else:
            near, u, v = track_kernels.stars_in_view(self._vectors, rotation, cos_reach, Pinhole.of(camera),
                                                     -float(gate))
        if near.size < self.config.min_stars:
            return self._failed(recognize_kernel.TOO_FEW_STARS_NEAR, started, gate, count=near.size)
        voters = min(n, self.config.max_pattern_spots)
        sx, sy = geometry.x[:voters], geometry.y[:voters]
        if gate <= 3.0 * tolerance_px:  # small gate: nearest stars directly
            dx = dy = 0.0
            radius = gate
        else:
            voted = self._vote(geometry, camera, prediction, u, v, gate, tolerance_px)
            if voted is None:
                return self._no_displacement(started, gate)
            dx, dy, radius = voted
        spot_i, star_j = unique_nearest(sx, sy, u + dx, v + dy, radius)
        if spot_i.size < 2:
            return self._failed(recognize_kernel.TOO_FEW_PAIRS, started, gate, count=spot_i.size)
        rough = kernels.q_method(geometry.rays[spot_i], self._vectors[near[star_j]], 1.0 / geometry.sigma[spot_i] ** 2)
        return self._verify_in_region(geometry, order, camera, rough, prediction, gate, tolerance_px, started)

    def _verify_in_region(self, geometry, order, camera, rotation, prediction, gate, tolerance_px, started):
        lis = self.lost_in_space
        n = order.size
        chord = 2.0 * math.sin(0.5 * min(tolerance_px * camera.pixel_scale_rad, self.grid.max_radius_rad))
        out_spot = np.empty(n, np.int64)
        out_star = np.empty(n, np.int64)
        check = kernels.verify_candidate(
            rotation, SpotArrays(geometry.rays, geometry.sigma, geometry.magnitude), self.catalog,
            VerifySettings(chord, self.config.min_stars, lis.magnitude_floor),
            out_spot, out_star, 1)  # the rough rotation is already fitted to the voters' pairs
        count, rotation, chi2 = check.count, check.rotation, check.chi2
        if count < self.config.min_stars:
            return self._failed(recognize_kernel.TOO_FEW_VERIFIED, started, gate, count=count)
        # The bound holds for the searched region only: a solution outside it was not searched for.
        mahalanobis2 = float(track_kernels.offset_mahalanobis2(prediction.rotation, rotation, prediction.covariance))
        if mahalanobis2 > self.config.gate_sigma**2:
            return self._failed(recognize_kernel.OUTSIDE_GATE, started, gate, sigma=math.sqrt(mahalanobis2))
        spot_index, star_index = out_spot[:count].copy(), out_star[:count].copy()
        body, sigma = geometry.rays[spot_index], geometry.sigma[spot_index]
        density = max(self.catalog.mean_density, float(self.grid.cell_density[self._cell(rotation[:, 2])]))
        log_t = float(track_kernels.log_chance_tuples_in_region(body, sigma, chi2, density, prediction.covariance,
                                                                self.config.gate_sigma))
        log_t += float(kernels.log_magnitude_agreement(geometry.magnitude[spot_index],
                                                       self.catalog.magnitude[star_index],
                                                       self.catalog.sorted_magnitudes, lis.magnitude_floor))
        fp = float(kernels.false_positive_bound(log_t, n, count, self.config.min_stars))
        if fp > self.config.false_positive_bound:
            return self._failed(recognize_kernel.BOUND_FAILED, started, gate, count=count, fp=fp)
        # No deep re-match on tracked frames: under a slew the faint spots' covariances are
        # optimistic and the rate's NEES leaves its bound (test_tracking's slew: 4.4 on one axis
        # with it); lost-in-space solves keep it.
        return lis.solved(geometry, order, AcceptedMatch(spot_index, star_index, rotation, fp), 1, started,
                          algorithm="tracking", deep_match=False), gate

    def _half_diagonal(self, camera: CameraModel) -> float:
        key = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, tuple(camera.distortion))
        if self._half_diagonal_key != key:
            self._half_diagonal_key, self._half_diagonal_value = key, camera.half_diagonal_fov_rad
        return self._half_diagonal_value

    def warm_up(self, camera: CameraModel) -> None:
        """Compile (or load from numba's cache) the kernels tracking adds to lost-in-space."""
        if hasattr(self.lost_in_space, "warm_up"):
            self.lost_in_space.warm_up(camera)
        rng = np.random.default_rng(1)
        rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        rotation *= np.linalg.det(rotation)
        stars = np.flatnonzero(self._vectors @ rotation[:, 2] > math.cos(0.1))[:12]
        u, v, _ = camera.project(self._vectors[stars] @ rotation)
        n = stars.size
        spots = Spots(u, v, np.linspace(2e4, 1e3, n), np.full(n, 50.0), np.tile(np.eye(2) * 0.01, (n, 1, 1)),
                      np.zeros(n, np.uint32), np.full(n, 9, np.int32), np.full(n, 1e3), camera.width, camera.height)
        saved = (self._last, self.rate)
        self._last, self.rate = (0, rotation, np.eye(3) * 1e-8), None
        self.track(spots, camera, self.predict(100_000_000))
        self._last, self.rate = saved
        # The bound and the rate fit, whether or not the synthetic frame verified.
        log_chance_tuples_in_region(np.eye(3), np.full(3, 1e-5), 3.0, 1.0, np.eye(3) * 1e-8, 5.0)
        rates = AttitudeRateEstimator(1.0, 0.01)
        for k in range(4):
            rates.add(k * 100_000_000, rotation @ rotation_vector_to_matrix(np.array([0.0, 0.0, 1e-3 * k])),
                      np.eye(3) * 1e-10)

    def _cell(self, direction: np.ndarray) -> int:
        return int(cell_of(float(direction[0]), float(direction[1]), float(direction[2]), self.grid.grid))

    # --- delay compensation ------------------------------------------------------------
    def begin_acquisition(self, stamp_ns: int, spots: Spots, camera: CameraModel) -> None:
        """Note that a lost-in-space solve of this frame starts (elsewhere, e.g. in a worker thread)."""
        self._pending = [(stamp_ns, spots, camera)]
        self._chain = []

    def pending_spots(self) -> Spots | None:
        """Spots of the newest frame waiting for the running solve (what complete_acquisition will publish), or None."""
        return self._pending[-1][1] if self._pending else None

    def bridge(self, stamp_ns: int, spots: Spots, camera: CameraModel) -> bool:
        """
        Chain a newer frame that arrived during the solve, relative to the previous pending frame.

        False when the two frames share too few stars (the chain restarts from this frame on
        the next acquisition).
        """
        if not self._pending:
            return False
        prev_ns, prev_spots, prev_camera = self._pending[-1]
        relative = self.relative_rotation(prev_spots, prev_camera, spots, camera, (stamp_ns - prev_ns) * 1e-9)
        if relative is None:
            return False
        self._pending.append((stamp_ns, spots, camera))
        self._chain.append(relative)
        return True

    def complete_acquisition(self, result: Identification) -> TrackedFrame | None:
        """
        End the solve of the first pending frame with `result`.

        Returns the newest pending frame's TrackedFrame (attitude chained and verified by
        local recognition), or the solved frame's own when nothing was bridged; None when
        unsolved.
        """
        started = time.perf_counter()
        pending, chain = self._pending, self._chain
        self._pending, self._chain = [], []
        if not pending or not result.solved:
            return None
        stamp_ns = pending[0][0]
        solved_spots = pending[0][1]
        if not chain:
            return self._accept(stamp_ns, result, MODE_LOST_IN_SPACE, None, 0, started, pending[0][2].pixel_scale_rad,
                                solved_spots.applied_motion)
        rotation, covariance = result.attitude.rotation, result.attitude.covariance
        for relative, relative_cov in chain:  # R_{j+1} = R_j dR_j; errors expressed in frame j+1
            rotation = rotation @ relative
            covariance = relative.T @ covariance @ relative + relative_cov
        newest_ns, spots, camera = pending[-1]
        # Verified on the newest frame; the prior covers the chain with gate_sigma to spare.
        prediction = Prediction(newest_ns, rotation, covariance + np.eye(3) * (1e-2 * camera.pixel_scale_rad) ** 2)
        tracked, gate = self.track(spots, camera, prediction)
        if not tracked.solved:
            return None
        # The rate window restarts: the bridged frames' attitudes were not verified one by one.
        self.rates.reset()
        applied = solved_spots.applied_motion or AppliedMotion()  # not known: measured without a rate (no aid)
        if applied.exposure_path_offset_rad is not None:  # on a gyro's path: its mid-exposure attitude, unbiased
            self.rates.add(stamp_ns, *applied.at_mid_exposure(result.attitude.rotation, result.attitude.covariance))
        else:
            self.rates.add(stamp_ns, result.attitude.rotation, result.attitude.covariance,
                           self.bias_gain(applied.angular_velocity_rad_s, pending[0][2].pixel_scale_rad),
                           applied.angular_acceleration_rad_s2)
        return self._accept(newest_ns, tracked, MODE_TRACKING, gate, len(chain), started, camera.pixel_scale_rad,
                            spots.applied_motion)

    def relative_rotation(self, spots_a: Spots, camera_a: CameraModel, spots_b: Spots, camera_b: CameraModel,
                          dt: float) -> tuple[np.ndarray, np.ndarray] | None:
        """
        Rotation dR of the sensor between frames a and b (R_b = R_a dR) from their spots alone.

        With its covariance [rad^2, frame b]: the rate (or its prior) predicts where frame
        a's spots land in frame b, the displacement is voted, spots are paired, and dR is
        the q-method fit of the pairs. None with fewer than 3 pairs.
        """
        lis = self.lost_in_space
        _, ga = self.lost_in_space.prepare(spots_a, camera_a)
        _, gb = self.lost_in_space.prepare(spots_b, camera_b)
        if ga.x.size < 3 or gb.x.size < 3:
            return None
        predicted = self._propagate(0, np.eye(3), np.zeros((3, 3)), max(dt, 0.0))
        # Frame a's rays seen from frame b: b = dR^T a.
        u, v, front = camera_b.project(ga.rays @ predicted.rotation)
        keep = np.flatnonzero(front)
        tolerance_px = max(lis.verification_radius_px(gb, camera_b), 3.0 * float(np.median(ga.sigma))
                           / camera_b.pixel_scale_rad)
        gate = self.gate_px(camera_b, predicted, tolerance_px)
        roll_spread = (self.config.gate_sigma * math.sqrt(predicted.covariance[2, 2])
                       * self._half_diagonal(camera_b) / camera_b.pixel_scale_rad)
        voters = self.config.max_pattern_spots
        ax, ay = u[keep][:voters], v[keep][:voters]
        bx, by = gb.x[:voters], gb.y[:voters]
        dx, dy, votes = vote_displacement(bx, by, ax, ay, gate, max(2.0 * tolerance_px, roll_spread))
        if votes < 3:
            return None
        spot_i, ref_j = unique_nearest(bx, by, ax + dx, ay + dy, max(tolerance_px, min(roll_spread, gate)))
        if spot_i.size < 3:
            return None
        body_b, body_a = gb.rays[spot_i], ga.rays[keep[ref_j]]
        sigma = np.hypot(gb.sigma[spot_i], ga.sigma[keep[ref_j]])
        rough = kernels.q_method(body_b, body_a, 1.0 / sigma**2)  # b -> a: body_a = dR body_b
        # Second pass with the fitted rotation: all spots, tight radius.
        u, v, front = camera_b.project(ga.rays @ rough)
        keep = np.flatnonzero(front)
        spot_i, ref_j = unique_nearest(gb.x, gb.y, u[keep], v[keep], tolerance_px)
        if spot_i.size < 3:
            return None
        body_b, body_a = gb.rays[spot_i], ga.rays[keep[ref_j]]
        sigma = np.hypot(gb.sigma[spot_i], ga.sigma[keep[ref_j]])
        return kernels.q_method(body_b, body_a, 1.0 / sigma**2), attitude_covariance(body_b, sigma)
