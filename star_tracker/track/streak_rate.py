# SPDX-License-Identifier: Apache-2.0
"""
Body angular velocity from the streaks of a motion-smeared frame.

Frames: sensor frame `star_tracker_optical` (+Z boresight, +X image right, +Y image down);
the attitude R maps sensor to ICRS (v_icrs = R v_sensor) and the body rate omega [rad/s] is in
the sensor frame, dR/dt = R [omega x]. Pixels: (0, 0) is the centre of the top-left pixel.

Model. A star fixed in ICRS at r has sensor direction b = R^T r, so

    db/dt = -[omega x] R^T r = b x omega = [b x] omega.

Its image moves at du/dt = J(b) db/dt, J = d(u, v)/db the 2x3 projection Jacobian (pinhole
and distortion; for a pure pinhole J = [[fx/Z, 0, -fx X/Z^2], [0, fy/Z, -fy Y/Z^2]]). Over
a global-shutter exposure T the streak (end minus start) is, to first order in omega T,

    s_i = T J(b_i) [b_i x] omega = A_i omega,      A_i: 2x3 [px s/rad],

linear in omega once the streak's sense (start -> end) is known. The error of the linear model
is of order (omega T)^2 relative: < 1e-5 at 5 deg/s and 0.1 s. A rolling shutter is ignored:
it would turn s_i into ~ T v / (1 - v_y t_row) (v the image velocity [px/s], t_row the row
delay [s/px]), stretching streaks that move along the readout.

Observability. Cross-boresight rates (x, y) move every star the same way, by ~ f T omega
pixels; a roll (z) moves a star at radius rho [px] from the principal point by rho T omega_z
along the tangent, so it is seen only through the spread of streak directions and lengths over
the field. The covariance shows it: roll's sigma is ~ f / rho_rms (~ 10x for a 15 deg field)
larger than the cross-boresight sigmas.

Noise. Spots carries neither the length nor the angle precision of a streak, so each streak's
error is modelled by its shape only, and the scale is estimated a posteriori from the residuals:
along the streak (length error) sigma = s_along sqrt(L) / snr, across it (angle error times
length) sigma = s_cross / snr, the forms the free streak fit's errors follow on rendered
frames (L the length [px], snr the spot's fit SNR), each with a floor of MODEL_FLOOR_PX in
quadrature. Outliers (blends, false objects, fragments of faint streaks) beyond
OUTLIER_SIGMA are dropped by iterated reweighting from a median-based scale; the reported
covariance uses the RMS scale of the streaks kept, widened to a Student-t's variance for
few streaks, plus a length error common to all free streaks (COMMON_LENGTH_SIGMA_PX: the free
fit shortens faint streaks, and a common offset is indistinguishable from the rate's
magnitude). On rendered frames at 1-3 deg/s the NEES averages 2.0-2.7 (3 expected).

Caveat: a rate-aided centroider (extract_spots(..., smear=SmearModel)) does not measure the
streaks: it fits positions on the path predicted from the aiding rate and reports that path's
length and direction. The estimate from rate-aided spots therefore reproduces the aiding rate
(to the linear model's accuracy, with the covariance of MODEL_FLOOR_PX per streak): a
consistency check of the aid and the source of the sign, not an independent measurement.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.camera import CameraModel
from ..centroid.spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_STREAK, FLAG_SATURATED, Spots

__all__ = ["StreakRate", "rate_from_streaks", "streak_design_matrix"]

MIN_STREAKS = 3  # 6 equations for 3 unknowns, 3 degrees of freedom for the scale
OUTLIER_SIGMA = 4.0  # residuals beyond this many sigma (either component) drop the streak
# Accuracy of a streak's length and end points from the streak model itself (its Simpson
# quadrature reproduces lengths to ~0.01 px): the floor of a streak's sigma [px] per
# component, which keeps the covariance honest when the residuals are ~0 (rate-aided spots).
MODEL_FLOOR_PX = 0.01
# The free streak fit's lengths share an error: faint streaks come out short (on rendered frames
# the weighted mean is -0.01 to -0.05 px per frame, -0.1 to -0.6 px for SNR < 15). A common
# length offset is not separable from the rate's magnitude, so it enters the covariance as a
# fully correlated 1-sigma error of this size [px] on every free (not rate-aided) streak.
COMMON_LENGTH_SIGMA_PX = 0.04
SEPARATE_SCALES_MIN = 8  # fewer inlier streaks: one scale for both components
HINT_AGREEMENT = 0.5  # |cos| between the hint's and the estimate's image motion to trust its sign
_MAX_ITERATIONS = 30
_JACOBIAN_STEP = 1e-6  # [rad] central-difference step on the ray (distortion included)


@dataclass(frozen=True)
class StreakRate:
    """
    Body rate from one frame's streaks.

    angular_velocity: (3,) omega [rad/s] in the sensor frame (dR/dt = R [omega x], R sensor ->
    ICRS) over the exposure; covariance: (3, 3) its covariance [rad^2/s^2]; streaks_used:
    streaks kept after outlier rejection; sign_known: False when no rate-aided streak and no
    decisive hint fixed the sense of motion, so that only +-angular_velocity is determined
    (the caller disambiguates, e.g. with the rate from successive attitudes).
    """

    angular_velocity: np.ndarray
    covariance: np.ndarray
    streaks_used: int
    sign_known: bool

    @property
    def sigma(self) -> np.ndarray:
        """(3,) 1-sigma per sensor axis [rad/s]."""
        return np.sqrt(np.diag(self.covariance))


def streak_design_matrix(camera: CameraModel, x, y, exposure_s: float) -> np.ndarray:
    """
    Return the streak design matrix A (N, 2, 3) [px s/rad].

    The streak (end minus start) [px] of the stars imaged at mid-exposure pixels (x, y) under
    body rate omega is A @ omega (global shutter, first order in omega T). Column k is T J(b)
    (b x e_k), J the projection Jacobian by central differences along the ray (so distortion
    is included).
    """
    rays = camera.pixel_to_ray(x, y)  # (N, 3) unit, sensor frame
    tangents = np.cross(rays[:, None, :], np.eye(3)[None, :, :])  # (N, 3, 3): [k] = b x e_k
    h = _JACOBIAN_STEP
    forward = camera.project(rays[:, None, :] + h * tangents)
    backward = camera.project(rays[:, None, :] - h * tangents)
    du = (forward[0] - backward[0]) / (2.0 * h)  # (N, 3)
    dv = (forward[1] - backward[1]) / (2.0 * h)
    return exposure_s * np.stack([du, dv], axis=1)


def rate_from_streaks(spots: Spots, camera: CameraModel, exposure_s: float, hint=None,
                      min_length_px: float = 3.0) -> StreakRate | None:
    """
    Body angular velocity [rad/s, sensor frame] from the streaks of one frame.

    spots: the centroider's output; used: spots flagged FLAG_STREAK, not saturated, blended
    or at the image edge (their length is cut), with a finite length >= min_length_px [px],
    finite angle and SNR > 0. camera: the model the spots were measured with; exposure_s:
    exposure time T [s] (global shutter). hint: optional (3,) rate [rad/s, sensor frame],
    e.g. from successive attitudes, that fixes the sense of streaks without one (its
    magnitude and a moderate direction error do not matter). Rate-aided streaks carry their
    sense (start -> end); others, known modulo pi, take the sense that agrees with the
    hint's or, without one, with a consistent field of image motion (see _initial_senses).

    Rate-aided spots report the aiding rate's predicted streaks, so from them the result
    reproduces the aid (see the module's caveat). Returns None with fewer than MIN_STREAKS
    usable streaks (before or after outlier rejection) or a singular system.
    """
    if not (np.isfinite(exposure_s) and exposure_s > 0):
        raise ValueError(f"exposure_s must be finite and > 0 [s], got {exposure_s!r}")
    if hint is not None:
        hint = np.asarray(hint, dtype=float)
        if hint.shape != (3,) or not np.all(np.isfinite(hint)):
            raise ValueError(f"hint must be 3 finite values [rad/s], got {hint!r}")
    streaks = _usable_streaks(spots, min_length_px)
    if streaks.size < MIN_STREAKS:
        return None
    length, angle = spots.streak_length[streaks], spots.streak_angle[streaks]
    measured = length[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)  # (n, 2) [px], sense unknown
    aided = (spots.flags[streaks] & FLAG_RATE_AIDED) != 0
    design = streak_design_matrix(camera, spots.x[streaks], spots.y[streaks], exposure_s)
    snr = spots.snr[streaks]
    shape = np.stack([np.sqrt(length) / snr, 1.0 / snr], axis=1)  # (n, 2): along, cross [px / scale]

    best = None
    for senses in _initial_senses(measured, design, shape, aided, hint):
        fit = _robust_fit(measured, design, shape, aided, senses)
        if fit is not None and (best is None or fit.cost < best.cost):
            best = fit
    if best is None:
        return None

    omega, sign_known = best.omega, bool(np.any(aided & best.inliers))
    if not sign_known and hint is not None:
        # The hint decides the global sense if its image motion is clearly (anti-)parallel to
        # the estimate's over the streaks used.
        used = best.inliers
        predicted, expected = design[used] @ omega, design[used] @ hint
        agreement = np.sum(predicted * expected) / np.sqrt(np.sum(predicted ** 2) * np.sum(expected ** 2) + 1e-300)
        if abs(agreement) >= HINT_AGREEMENT:
            omega, sign_known = np.sign(agreement) * omega, True
    omega = omega + 0.0  # no negative zeros
    return StreakRate(angular_velocity=omega, covariance=best.covariance, streaks_used=int(best.inliers.sum()),
                      sign_known=sign_known)


# ---------------------------------------------------------------- internals

def _usable_streaks(spots: Spots, min_length_px: float) -> np.ndarray:
    """Return indices of the spots whose streak length and direction are usable."""
    flags = np.asarray(spots.flags)
    length, angle, snr = (np.asarray(a, dtype=float) for a in (spots.streak_length, spots.streak_angle, spots.snr))
    ok = ((flags & FLAG_STREAK) != 0) & ((flags & (FLAG_SATURATED | FLAG_BLENDED | FLAG_EDGE)) == 0)
    ok &= np.isfinite(length) & np.isfinite(angle) & np.isfinite(snr) & (snr > 0)
    ok &= np.isfinite(spots.x) & np.isfinite(spots.y)
    with np.errstate(invalid="ignore"):
        ok &= length >= min_length_px
    return np.flatnonzero(ok)


def _initial_senses(measured, design, shape, aided, hint):
    """
    Candidate senses (n,) of +-1 for the measured streak vectors, one list per start.

    From the hint when given; from the direction field (streak directions only, sense-free:
    the image motion A_i omega must be parallel to streak i, so perp(s_i) . A_i omega = 0, a
    homogeneous system whose smallest singular vector is omega's direction); and all aligned
    with the longest streak (a field that is mostly a translation). Rate-aided streaks keep
    +1.
    """
    starts = []
    if hint is not None and np.any(hint):
        starts.append(np.sign(np.sum(measured * (design @ hint), axis=1)))
    unit = measured / np.linalg.norm(measured, axis=1, keepdims=True)
    perp = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
    rows = np.einsum("ni,nij->nj", perp, design) / shape[:, 1:2]  # cross-track residual per unit scale
    try:
        direction = np.linalg.svd(rows, full_matrices=False)[2][-1]
        starts.append(np.sign(np.sum(measured * (design @ direction), axis=1)))
    except np.linalg.LinAlgError:
        pass
    longest = int(np.argmax(np.linalg.norm(measured, axis=1)))
    starts.append(np.sign(unit @ unit[longest]))
    out = []
    for senses in starts:
        senses = np.where(senses == 0, 1.0, senses)
        if np.any(aided):
            # The rate-aided streaks are right: flip the whole start to agree with them.
            if np.sum(senses[aided]) < 0:
                senses = -senses
            senses[aided] = 1.0
        out.append(senses)
    return out


@dataclass
class _Fit:
    omega: np.ndarray
    covariance: np.ndarray
    inliers: np.ndarray
    cost: float  # median residual / shape over all streaks (outliers included): compares starts


def _robust_fit(measured, design, shape, aided, senses) -> _Fit | None:
    """
    Fit the rate by iterated weighted least squares in the streak frames (along, cross).

    With sense re-choice and OUTLIER_SIGMA rejection, until senses and inliers settle.
    """
    n = measured.shape[0]
    unit = measured / np.linalg.norm(measured, axis=1, keepdims=True)
    frame = np.stack([unit, np.stack([-unit[:, 1], unit[:, 0]], axis=1)], axis=1)  # (n, 2, 2): rows along, cross
    # Projections onto the streak frames: measurement (|s_i|, 0) times its sense, design F_i A_i.
    lengths = np.linalg.norm(measured, axis=1)
    projected = frame @ design  # (n, 2, 3)
    inliers = np.ones(n, bool)
    scales = np.ones(2)
    state = None
    for _ in range(_MAX_ITERATIONS):
        sigma = np.sqrt((scales * shape) ** 2 + MODEL_FLOOR_PX ** 2)  # (n, 2) [px]
        solved = _solve(projected[inliers], senses[inliers], lengths[inliers], sigma[inliers])
        if solved is None:
            return None
        omega, _ = solved
        predicted = projected @ omega  # (n, 2): along, cross [px]
        # Sense: that of the predicted motion (rate-aided streaks keep theirs).
        senses = np.where(aided, 1.0, np.where(predicted[:, 0] >= 0, 1.0, -1.0))
        residual = np.stack([senses * lengths - predicted[:, 0], -predicted[:, 1]], axis=1)
        normalized = residual / shape
        scales = _robust_scales(normalized[inliers])
        sigma = np.sqrt((scales * shape) ** 2 + MODEL_FLOOR_PX ** 2)
        new_inliers = np.all(np.abs(residual) <= OUTLIER_SIGMA * sigma, axis=1)
        if new_inliers.sum() < MIN_STREAKS:
            return None
        key = (new_inliers.tobytes(), senses.tobytes())
        inliers = new_inliers
        if key == state:
            break
        state = key
    # Final: scales from the RMS of the kept streaks (honest with heavier-than-Gaussian tails
    # inside the cut), dof-corrected for the 3 fitted parameters.
    kept = normalized[inliers]
    dof_per_component = max(kept.shape[0] - 1.5, 0.5)
    if kept.shape[0] >= SEPARATE_SCALES_MIN:
        scales = np.sqrt(np.sum(kept ** 2, axis=0) / dof_per_component)
    else:
        scales = np.full(2, np.sqrt(np.sum(kept ** 2) / (2.0 * dof_per_component)))
    sigma = np.sqrt((scales * shape) ** 2 + MODEL_FLOOR_PX ** 2)
    solved = _solve(projected[inliers], senses[inliers], lengths[inliers], sigma[inliers])
    if solved is None:
        return None
    omega, covariance = solved
    # Common length offset of the free streaks: d omega / d offset = C sum_i P_i,along / sigma_i,along^2.
    # Few streaks: the scale is itself uncertain, so the error is Student-t with nu = 2n - 3
    # degrees of freedom, of variance nu / (nu - 2) times the scaled normal one.
    nu = 2.0 * inliers.sum() - 3.0
    covariance = covariance * nu / (nu - 2.0)
    free = inliers & ~aided
    gain = covariance @ np.sum(projected[free, 0, :] / sigma[free, 0:1] ** 2, axis=0)
    covariance = covariance + COMMON_LENGTH_SIGMA_PX ** 2 * np.outer(gain, gain)
    # In shape units, not divided by the start's own scale: a wrong sense field has larger residuals.
    cost = float(np.median(np.hypot(normalized[:, 0], normalized[:, 1])))
    return _Fit(omega, covariance, inliers, cost)


def _robust_scales(normalized: np.ndarray) -> np.ndarray:
    """
    Return the scale (along, cross) of residuals / shape from the median absolute value.

    1.4826 x MAD about zero, the model's mean; pooled when too few streaks for two.
    """
    if normalized.shape[0] >= SEPARATE_SCALES_MIN:
        scales = 1.4826 * np.median(np.abs(normalized), axis=0)
    else:
        scales = np.full(2, 1.4826 * np.median(np.abs(normalized)))
    return np.maximum(scales, 1e-12)


def _solve(projected, senses, lengths, sigma):
    """
    Weighted least squares of F_i A_i omega = (sense_i |s_i|, 0).

    Omega and its covariance (inverse normal matrix); None if singular.
    """
    weighted = projected / sigma[:, :, None]  # (m, 2, 3)
    target = np.stack([senses * lengths, np.zeros_like(lengths)], axis=1) / sigma
    normal = np.einsum("mki,mkj->ij", weighted, weighted)
    rhs = np.einsum("mki,mk->i", weighted, target)
    eig = np.linalg.eigvalsh(normal)
    if not (np.all(np.isfinite(eig)) and eig[0] > 1e-12 * eig[-1] > 0):
        return None
    covariance = np.linalg.inv(normal)
    covariance = 0.5 * (covariance + covariance.T)
    return covariance @ rhs, covariance
