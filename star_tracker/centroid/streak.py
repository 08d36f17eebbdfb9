"""Streak centroiding: mid-exposure position, length and direction of motion-smeared stars.

When the spacecraft turns during the exposure a star's image is smeared along its path over
the detector. The attitude solution needs the position at MID-EXPOSURE, so the streak is
fitted with a model of the smeared point-spread function rather than reduced to a centre of
gravity (which is off the path when the path is curved).

- SmearModel: each star's image path over the exposure from the body rate and the camera
  model (distortion included).
- fit_streaks: free fit of a straight streak (x, y, flux, length, angle) seeded from moments.
- fit_streaks_on_path: fit of (x, y, flux) on a known path (a straight line or a roll arc).
- second_source_on_path, fit_star_groups_on_path: the star a known-path fit leaves in its
  window (matched filter of the residual), and the joint fit of several stars on one path
  shape (streaks merged into one detection).

Image convention: pixel (0, 0) is the centre of the top-left pixel; x = column, y = row [px].
Angles are measured from +x toward +y (clockwise on the displayed image, y down) [rad].

PSF model: the pixel-integrated Gaussian of 1-sigma `sigma` [px] is approximated by a
Gaussian of variance sigma^2 + 1/12 px^2 (the pixel's box variance added) evaluated at the
pixel centres. It matches the pixel integral to second order and differs from it by < 0.2 %
of the peak for sigma = 1 px (the box's excess kurtosis, an even error that moves no
centre; the fits reach the Cramer-Rao bound of the exact model, see test/centroid/test_streak.py),
and it needs exp only, ~5x cheaper than erf. A streak is a weighted sum of PSF copies along
its path: Simpson's rule with nodes <= 1 PSF sigma apart for a straight segment (< 1 % of
the peak from the continuous segment, at its ends; symmetric, so no position error, and
lengths come out within 0.01 px), the given samples for a known path. Each copy is
separable in x and y, so a window's model and its derivatives are batched matrix products
sum_k w_k py_k px_k^T, as in the renderer; the profiles are float32 in window coordinates.

Fitting: weighted least squares by Levenberg-Marquardt on all spots at once, each in its own
window (padded to one size per batch, pixels outside the window, off the image or non-finite
masked); one spot's failure never affects another's. Noise model as fit_gaussian_psf: pixel
variance = max(model, 0) / gain + noise^2 [ADU^2]; residual images are background-
subtracted [ADU]. The covariance reported is the (x, y) block of the inverse Fisher matrix
of all fitted parameters at the solution.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..models.camera import CameraModel

__all__ = ["SmearModel", "StreakFit", "fit_star_groups_on_path", "fit_streaks", "fit_streaks_on_path",
           "second_source_on_path"]

PSF_RADIUS_SIGMA = 4.0  # window margin beyond the streak ends [sigma] (plus 1 px)
PATH_SPACING_PX = 0.5  # SmearModel.path's default: samples at most this far apart [px]
NODE_SPACING_SIGMA = 1.0  # free fit: Simpson nodes along the segment this far apart [PSF sigma]
# A converged fit's flux exceeds this many sigma: five free parameters find some streak in pure
# noise, with flux > 2 sigma in ~20 % of empty windows and > 3 sigma in ~3 %.
SIGNIFICANT_FLUX = 3.0
_MAX_WINDOW_ELEMENTS = 3_000_000  # spots x parameters x pixels per batch (memory bound)


# ---------------------------------------------------------------- smear geometry

def segment_length(major, sigma: float) -> np.ndarray:
    """Length [px] of a straight streak whose image (a segment swept by a Gaussian PSF of
    1-sigma `sigma` [px]) has the second moment `major` [px^2] along it: a uniform segment of
    length L adds L^2 / 12. 0 where `major` is below sigma^2 (NaN stays NaN)."""
    return np.sqrt(np.maximum(12.0 * (np.asarray(major, dtype=float) - sigma * sigma), 0.0))


@dataclass(frozen=True, eq=False)
class SmearModel:
    """Image motion of fixed stars during one exposure under a constant body rate.

    camera: sensor geometry (distortion included); angular_velocity_rad_s: (3,) body rate
    omega in the sensor frame [rad/s] (+Z boresight, +X right, +Y down); exposure_s: exposure
    time [s]. A star's sensor-frame direction at time t from mid-exposure is
    s(t) = exp(-[omega x] t) s(0), the attitude being R(t) = R_mid exp([omega x] t).
    """

    camera: CameraModel
    angular_velocity_rad_s: np.ndarray
    exposure_s: float

    def __post_init__(self) -> None:
        if not all(callable(getattr(self.camera, m, None)) for m in ("project", "pixel_to_ray")):
            raise ValueError(f"camera must be a CameraModel (project, pixel_to_ray), got {self.camera!r}")
        try:
            omega = np.array(self.angular_velocity_rad_s, dtype=float)
            exposure = float(self.exposure_s)
        except (TypeError, ValueError):
            raise ValueError("angular_velocity_rad_s must be 3 numbers [rad/s] and exposure_s a number [s]") from None
        if omega.shape != (3,) or not np.all(np.isfinite(omega)):
            raise ValueError("angular_velocity_rad_s must be 3 finite values [rad/s], "
                             f"got {self.angular_velocity_rad_s!r}")
        if not (np.isfinite(exposure) and exposure >= 0):
            raise ValueError(f"exposure_s must be finite and >= 0 [s], got {self.exposure_s!r}")
        omega.flags.writeable = False
        object.__setattr__(self, "angular_velocity_rad_s", omega)
        object.__setattr__(self, "exposure_s", exposure)

    def sample_times(self, samples: int) -> np.ndarray:
        """Mid-points of `samples` equal slices of the exposure, from mid-exposure [s]."""
        return ((np.arange(samples) + 0.5) / samples - 0.5) * self.exposure_s

    def _positions(self, x, y, times: np.ndarray) -> np.ndarray:
        """Offsets (N, K, 2) [px] at `times` [s] from the stars' mid-exposure pixels (x, y)."""
        x, y = _pixels(x, y)
        rays = self.camera.pixel_to_ray(x, y)  # (N, 3) directions at mid-exposure
        u0, v0, _ = self.camera.project(rays)  # reference: cancels the undistortion round trip
        turns = Rotation.from_rotvec(-np.multiply.outer(times, self.angular_velocity_rad_s)).as_matrix()  # (K, 3, 3)
        u, v, in_front = self.camera.project(np.einsum("kij,nj->nki", turns, rays))
        offsets = np.stack([u - u0[:, None], v - v0[:, None]], axis=-1)
        return np.where(in_front[..., None], offsets, np.nan)  # behind the camera: no image

    def path(self, x, y, samples: int | None = None) -> np.ndarray:
        """Pixel offsets (N, K, 2) [px] of the star images whose mid-exposure positions are
        (x, y) [px], at the K times t_k = ((k + 0.5) / K - 0.5) exposure_s, relative to (x, y)
        (zero at t = 0, antisymmetric for straight constant-speed smear). samples: K; default
        the fewest giving <= PATH_SPACING_PX between samples along the longest path (>= 1).
        NaN where the direction is behind the camera."""
        if samples is None:
            probe = self._positions(x, y, self.sample_times(16))
            longest = np.nan_to_num(np.sum(np.linalg.norm(np.diff(probe, axis=1), axis=2), axis=1)) * 16 / 15
            samples = max(1, int(np.ceil(float(np.max(longest, initial=0.0)) / PATH_SPACING_PX)))
        elif not (isinstance(samples, (int, np.integer)) and samples >= 1):
            raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
        return self._positions(x, y, self.sample_times(int(samples)))

    def smear_vectors(self, x, y) -> np.ndarray:
        """End minus start image position (N, 2) [px] over the exposure (t = +T/2 and -T/2) of
        the stars at mid-exposure pixels (x, y) [px]."""
        ends = self._positions(x, y, np.array([-0.5, 0.5]) * self.exposure_s)
        return ends[:, 1] - ends[:, 0]


def _pixels(x, y) -> tuple[np.ndarray, np.ndarray]:
    try:
        x = np.asarray(x, dtype=float).ravel()
        y = np.asarray(y, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError("pixel coordinates x, y must be numeric") from None
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same number of values, got {x.size} and {y.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("pixel coordinates x, y must be finite")
    return x, y


# ---------------------------------------------------------------- results

@dataclass(frozen=True)
class StreakFit:
    """Fitted streaks, parallel arrays of N entries.

    x, y: position at mid-exposure [px]; flux: total [ADU]; length: streak length [px] (end to
    end of the exposure); angle: streak direction from +x toward +y [rad], in (-pi/2, pi/2]
    from a free fit (the sense of motion is unknown; NaN when the length is not significant:
    < 2 length_sigma), in (-pi, pi] from start to end for a fit on a known path (NaN if the
    path has no extent); cov: (N, 2, 2) covariance of (x, y) [px^2], the (x, y) block of the
    inverse Fisher matrix of all fitted parameters at the solution; length_sigma: 1-sigma of
    length [px] (0 when the path was given); converged: the fit reached a minimum with a
    flux above SIGNIFICANT_FLUX sigma, a finite covariance and its centre inside its window,
    on a window free of non-finite pixels (the values are filled in either way when a fit
    was possible, NaN otherwise). flux_sigma [ADU], angle_sigma [rad] (0 on a given path):
    1-sigma errors. chi2: weighted sum of squared residuals over the window at the solution
    (weights of the noise model); dof: the window's used pixels minus the fitted parameters.
    chi2 well above dof (by many sqrt(2 dof)) means light the model does not describe: a
    neighbour's star or streak merged into the spot.
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    length: np.ndarray
    angle: np.ndarray
    cov: np.ndarray
    length_sigma: np.ndarray
    converged: np.ndarray
    flux_sigma: np.ndarray
    angle_sigma: np.ndarray
    chi2: np.ndarray | None = None
    dof: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("chi2", "dof"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(self.x.size, np.nan))

    def __len__(self) -> int:
        return int(self.x.size)

    @staticmethod
    def _failed(n: int) -> "StreakFit":
        nan = np.full(n, np.nan)
        return StreakFit(nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(), np.full((n, 2, 2), np.nan),
                         nan.copy(), np.zeros(n, bool), nan.copy(), nan.copy())


# ---------------------------------------------------------------- windows and the separable model

@dataclass
class _Windows:
    """Pixel windows of a batch of spots, padded to one size (R rows x C columns): origin
    (n, 2) = pixel (col, row) of each window's first element [px]; data (n, R*C) [ADU] (0
    where masked), mask (n, R*C) (1 = use), float32; bad (n,) True if a non-finite pixel fell
    inside the spot's own window; bounds (n, 4) col_lo, col_hi, row_lo, row_hi of its own
    window [px]."""

    n_rows: int
    n_cols: int
    origin: np.ndarray
    data: np.ndarray
    mask: np.ndarray
    bad: np.ndarray
    bounds: np.ndarray


def _cut_windows(residual: np.ndarray, col_lo, col_hi, row_lo, row_hi, excluded=None) -> _Windows:
    """Windows [col_lo, col_hi] x [row_lo, row_hi] (integer pixel bounds, inclusive) padded to
    the largest; pixels outside the image, outside the spot's own window, non-finite or
    `excluded` ((H, W) bool, e.g. clipped at the full well; None = none) are masked."""
    height, width = residual.shape
    n_cols = int(np.max(col_hi - col_lo)) + 1
    n_rows = int(np.max(row_hi - row_lo)) + 1
    cols = col_lo[:, None] + np.arange(n_cols)[None, :]
    rows = row_lo[:, None] + np.arange(n_rows)[None, :]
    col_ok = (cols <= col_hi[:, None]) & (cols >= 0) & (cols < width)
    row_ok = (rows <= row_hi[:, None]) & (rows >= 0) & (rows < height)
    flat = np.clip(rows, 0, height - 1)[:, :, None] * width + np.clip(cols, 0, width - 1)[:, None, :]
    data = np.take(residual.reshape(-1), flat).astype(np.float32)
    use = row_ok[:, :, None] & col_ok[:, None, :]
    if excluded is not None:
        use &= ~np.take(excluded.reshape(-1), flat)
    finite = np.isfinite(data)
    bad = ~np.all(finite | ~use, axis=(1, 2))
    use &= finite
    data[~use] = 0.0
    n = cols.shape[0]
    return _Windows(n_rows, n_cols, np.stack([col_lo, row_lo], axis=1).astype(np.float64), data.reshape(n, -1),
                    use.reshape(n, -1).astype(np.float32), bad, np.stack([col_lo, col_hi, row_lo, row_hi], axis=1))


def _profiles(count: int, positions: np.ndarray, scale: float, log_weights, g_out, vg_out, transposed: bool):
    """Gaussian profiles over the pixel centres 0..count-1 of a window for K sample positions
    p (n, K) [px, window frame], written to g_out and vg_out (float32): g = w exp(-v^2) and
    v g, v = (c - p) scale, scale = 1 / sqrt(2 var), w the sample weights (log_weights (n, K),
    or None for 1); dg/dp = 2 scale (v g). Shapes (n, K, count), or (n, count, K) if
    transposed. Window-frame coordinates (< 1e3 px) keep float32 to 1e-4 px."""
    centres = np.arange(count, dtype=np.float32) * np.float32(scale)
    p = (positions * scale).astype(np.float32)
    v = centres[None, :, None] - p[:, None, :] if transposed else centres[None, None, :] - p[:, :, None]
    exponent = v * v
    # Floor at exp(-30) ~ 1e-13: float32 denormals (below exp(-87), and their products in the
    # sums) are ~100x slower to compute with; the floor's light is negligible.
    np.minimum(exponent, np.float32(30.0), out=exponent)
    if log_weights is None:
        np.negative(exponent, out=exponent)
    else:
        log_weights = log_weights.astype(np.float32)
        np.subtract(log_weights[:, None, :] if transposed else log_weights[:, :, None], exponent, out=exponent)
    np.exp(exponent, out=g_out)
    np.multiply(v, g_out, out=vg_out)


def _simpson(intervals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Simpson's rule on [-1/2, 1/2] with an even number of intervals per spot (n,): node
    fractions s and weights (n, K), K = max(intervals) + 1; spots with fewer intervals get
    weight-0 nodes at 0 to fill up."""
    node = np.arange(int(np.max(intervals)) + 1)[None, :]
    count = intervals[:, None]
    used = node <= count
    weights = np.where((node == 0) | (node == count), 1.0, np.where(node % 2 == 1, 4.0, 2.0))
    return np.where(used, node / count - 0.5, 0.0), np.where(used, weights / (3.0 * count), 0.0)


def _sample_sums(win: _Windows, sx: np.ndarray, sy: np.ndarray, weights: np.ndarray, lever, scale: float):
    """Weighted sums over the K samples of a streak of separable PSF copies, for every window
    pixel, unnormalized (see _profiles): (n, Q, R*C) float32 holding shape = sum w gy gx,
    gx' = sum w gy (v g)_x, gy' = sum w (v g)_y gx (the x and y derivatives / 2 scale), and
    with a lever s (n, K) also s gy' and s gx' (the same weighted by s: derivatives along
    the streak). sx, sy: (n, K) sample positions [px] in the window frame; weights: (n, K)
    >= 0, summing to 1 per spot. Batched matrix products do every sum over samples."""
    n_rows, n_cols = win.n_rows, win.n_cols
    n, k = sx.shape
    x_profiles = np.empty((n, 2, k, n_cols), np.float32)  # g, v g along x
    _profiles(n_cols, sx, scale, None, x_profiles[:, 0], x_profiles[:, 1], transposed=False)
    gy = np.empty((n, n_rows, k), np.float32)
    vgy = np.empty((n, 1 if lever is None else 2, n_rows, k), np.float32)  # v g [, s v g] along y
    _profiles(n_rows, sy, scale, np.log(weights), gy, vgy[:, 0], transposed=True)
    sums = np.empty((n, 3 if lever is None else 5, n_rows, n_cols), np.float32)
    stacked = sums.reshape(n, -1, n_cols)  # a view: slices of it are outputs for matmul
    np.matmul(gy, x_profiles[:, 0], out=sums[:, 0])  # shape
    np.matmul(gy, x_profiles[:, 1], out=sums[:, 1])  # gx'
    if lever is None:
        np.matmul(vgy[:, 0], x_profiles[:, 0], out=sums[:, 2])  # gy'
    else:
        lever = lever.astype(np.float32)[:, None, :]
        np.multiply(vgy[:, 0], lever, out=vgy[:, 1])
        np.matmul(vgy.reshape(n, 2 * n_rows, k), x_profiles[:, 0], out=stacked[:, 2 * n_rows:4 * n_rows])  # gy', s gy'
        np.multiply(gy, lever, out=gy)  # gy is not needed any more
        np.matmul(gy, x_profiles[:, 1], out=sums[:, 4])  # s gx'
    return sums.reshape(n, sums.shape[1], -1)


# ---------------------------------------------------------------- Levenberg-Marquardt on batches

def _damping_floor(normal: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """1e-10 of the total information, per parameter in the units of `scale` (n, P): keeps
    degenerate systems solvable (a zero-length streak has no information on its angle)."""
    diag = np.diagonal(normal, axis1=1, axis2=2)
    return 1e-10 * np.sum(diag * scale * scale, axis=1, keepdims=True) / (scale * scale) + 1e-300


REWEIGHT_STEPS = 3  # linearizations whose model sets the weights (then they stay)
DECREMENT_TOLERANCE = 1e-3  # chi^2 still to gain: stop within ~3 % of a sigma of the minimum


def _levenberg_marquardt(evaluate, params, win: _Windows, valid, noise: float, gain: float, iterations: int,
                         max_step, constrain, scale_of, undetermined=None):
    """Weighted least squares by Levenberg-Marquardt, all spots at once (those still moving).

    evaluate(index, params (n, P)) -> aug (n, P + 1, M) float32: the jacobian (P rows) and the
    model [ADU] over the M window pixels of the spots `index` of the batch;
    max_step(params) -> (n, P) trust-region half-widths; constrain(index, params) -> params
    projected onto the feasible set; scale_of(params) -> (n, P) typical parameter units;
    undetermined(params, covariance (n, P, P)) -> two (n, P) bool masks: parameters left out
    of the convergence test, and parameters held fixed in the step (a zero-length streak's
    length and angle, see fit_streaks).

    Weights 1 / (max(model, 0) / gain + noise^2) follow the model for REWEIGHT_STEPS
    linearizations, then stay: reweighting at every step changes the objective under the
    acceptance test and can cycle at low SNR. With noisy data the Gauss-Newton matrix N,
    which omits the residuals' second-order term, can be far from the chi^2 curvature along
    a poorly measured direction (a faint streak's ends): steps overshoot to the mirror
    point or crawl. So steps use B = N + S, S a symmetric rank-one correction per step
    that makes B's curvature along the last step match the change of the gradient (secant
    condition, once the weights are fixed); damping follows the ratio of actual to
    predicted chi^2 decrease (Nielsen's rule). A spot stops when its Gauss-Newton decrement
    g^T N^-1 g (the chi^2 still to gain) is below DECREMENT_TOLERANCE. The Fisher matrix
    returned is N.
    Returns params, Fisher matrices (N, P, P) at the solution, done (N,) bool (a minimum was
    reached within the iterations), chi2 (N,) at the solution (inf where never evaluated)."""
    n, n_par = params.shape
    noise2, inv_gain = np.float32(noise * noise), np.float32(1.0 / gain)
    normal = np.zeros((n, n_par, n_par))
    grad = np.zeros((n, n_par))
    chi2 = np.full(n, np.inf)
    weights = np.zeros_like(win.data)
    lam = np.full(n, 1e-3)
    nu = np.full(n, 2.0)
    done = np.zeros(n, bool)
    reweighted = np.zeros(n, np.int64)
    correction = np.zeros((n, n_par, n_par))  # S
    eye = np.eye(n_par)

    def weighted_sum(a, b):  # sum over pixels of a * b (float32), accumulated in float64
        return np.sum(a * b, axis=1, dtype=np.float64)

    def linearize(index, aug, residual):
        # aug: jacobian rows, then the model (replaced by the residual here)
        w = weights[index]
        fresh = reweighted[index] < REWEIGHT_STEPS
        if np.all(fresh):
            np.maximum(aug[:, n_par], 0.0, out=w)
            w *= inv_gain
            w += noise2
            np.divide(win.mask[index], w, out=w)
        elif np.any(fresh):
            w[fresh] = win.mask[index[fresh]] / (np.maximum(aug[fresh, n_par], 0.0) * inv_gain + noise2)
        reweighted[index] += 1
        aug[:, n_par] = residual
        weighted = aug * w[:, None, :]
        # One product gives the normal matrix and the gradient.
        products = np.matmul(weighted, aug.transpose(0, 2, 1)).astype(np.float64)
        weights[index] = w
        normal[index], grad[index] = products[:, :n_par, :n_par], products[:, :n_par, n_par]
        chi2[index] = weighted_sum(weighted[:, n_par], residual)

    active = np.flatnonzero(valid)
    if active.size:
        aug = evaluate(active, params[active])
        linearize(active, aug, win.data[active] - aug[:, n_par])
        active = active[np.isfinite(chi2[active])]
    for _ in range(iterations):
        if active.size == 0:
            break
        p, g = params[active], grad[active]
        floor = _damping_floor(normal[active], scale_of(p))
        floored = normal[active] + floor[:, :, None] * eye
        if undetermined is None:
            judged, hold = g, np.zeros(p.shape, bool)
        else:  # decrement over the other parameters, the undetermined ones held fixed
            skip, hold = undetermined(p, _batched_inverse(floored))
            judged = np.where(skip, 0.0, g)
            floored = np.where(skip[:, :, None] | skip[:, None, :], eye, floored)
        decrement = np.sum(_solve(floored, judged) * judged, axis=1)
        a = normal[active] + correction[active]
        finished = ~(decrement > DECREMENT_TOLERANCE)  # NaN: give up
        done[active[finished & np.isfinite(decrement)]] = True
        keep = ~finished
        active, p, a, g, floor, hold = active[keep], p[keep], a[keep], g[keep], floor[keep], hold[keep]
        if active.size == 0:
            break
        diag = np.diagonal(a, axis1=1, axis2=2)
        damped = a + (lam[active, None] * diag + floor)[:, :, None] * eye
        if np.any(hold):  # a free direction would take the whole trust region
            damped = np.where(hold[:, :, None] | hold[:, None, :], eye, damped)
        step = _solve(damped, np.where(hold, 0.0, g))
        over = np.max(np.abs(step) / max_step(p), axis=1)
        step /= np.maximum(over, 1.0)[:, None]  # trust region, direction kept
        trial = constrain(active, p + step)
        finite = np.all(np.isfinite(trial), axis=1)
        trial = np.where(finite[:, None], trial, p)  # a failed solve: evaluated, never taken
        step = trial - p
        aug = evaluate(active, trial)
        r = win.data[active] - aug[:, n_par]
        trial_chi2 = weighted_sum(weights[active] * r, r)
        old = chi2[active]
        actual = old - trial_chi2
        predicted = 2.0 * np.sum(step * g, axis=1) - np.einsum("ni,nij,nj->n", step, a, step)
        # The float32 model makes chi^2 uncertain by ~1e-3 for the brightest streaks: smaller
        # changes count as none (1e-3 in chi^2 is 3 % of a sigma).
        better = (actual >= -(1e-6 * old + 1e-3)) & finite
        ratio = actual / np.maximum(predicted, 1e-300)
        if np.any(better):
            idx = active[better]
            params[idx] = trial[better]
            # Measure curvature on steps with the same weights before and after, and large
            # enough that the gradient change stands above float32 rounding.
            frozen = (reweighted[idx] >= REWEIGHT_STEPS) & (predicted[better] > 1e-2)
            if better.all():
                linearize(idx, aug, r)
            else:
                linearize(idx, aug[better], r[better])
            _secant_update(correction, idx[frozen], step[better][frozen], a[better][frozen],
                           g[better][frozen] - grad[idx[frozen]])
            lam[idx] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * np.clip(ratio[better], 0.0, 1.0) - 1.0) ** 3)
            lam[idx] = np.maximum(lam[idx], 1e-9)
            nu[idx] = 2.0
        worse = active[~better]
        lam[worse] *= nu[worse]
        nu[worse] *= 2.0
        stuck = worse[lam[worse] > 1e12]  # no step lowers chi^2: a minimum to rounding
        done[stuck] = True
        active = active[~np.isin(active, stuck)]
    return params, normal, done, chi2


def _secant_update(correction, index, step, model_matrix, gradient_change) -> None:
    """S += (c - b) / b^2 (B step)(B step)^T with b = step^T B step, c = step^T (g_old -
    g_new) the measured curvature along the step, clipped to [b / 4, 4 b] (keeps B
    positive definite and a noisy measurement from flattening it)."""
    if index.size == 0:
        return
    b_step = np.matmul(model_matrix, step[:, :, None])[..., 0]
    b = np.sum(step * b_step, axis=1)
    c = np.clip(np.sum(step * gradient_change, axis=1), b / 4.0, 4.0 * b)
    ok = b > 0
    alpha = np.where(ok, (c - b) / np.where(ok, b * b, 1.0), 0.0)
    correction[index] += alpha[:, None, None] * b_step[:, :, None] * b_step[:, None, :]


# ---------------------------------------------------------------- shared set-up and results

def _check_common(residual, sigma, noise, gain, iterations, *per_spot):
    residual = np.asarray(residual)
    if residual.ndim != 2 or residual.size == 0 or residual.dtype.kind not in "uif":
        raise ValueError(f"residual must be a non-empty 2-D numeric image [ADU], got shape {residual.shape} "
                         f"dtype {residual.dtype}")
    for name, value in (("sigma", sigma), ("noise", noise), ("gain", gain)):
        if not (np.isscalar(value) and np.isreal(value) and np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 0):
        raise ValueError(f"iterations must be an integer >= 0, got {iterations!r}")
    try:
        arrays = [np.asarray(a, dtype=float).ravel() for a in per_spot]
    except (TypeError, ValueError):
        raise ValueError("per-spot inputs must be numeric arrays") from None
    if len({a.size for a in arrays}) > 1:
        raise ValueError(f"per-spot inputs must have one length, got sizes {[a.size for a in arrays]}")
    return residual, arrays


def _check_excluded(excluded, residual: np.ndarray):
    """`excluded` as a (H, W) bool image matching `residual`, or None."""
    if excluded is None:
        return None
    excluded = np.asarray(excluded, dtype=bool)
    if excluded.shape != residual.shape:
        raise ValueError(f"excluded must have the residual's shape {residual.shape}, got {excluded.shape}")
    return excluded


def _window_bounds(residual, valid, lo_x, hi_x, lo_y, hi_y):
    """Integer pixel bounds of each spot's window (inclusive, clipped to the image) from float
    extents [px]; spots whose window misses the image become invalid."""
    height, width = residual.shape
    col_lo, col_hi = (np.floor(np.where(valid, lo_x, 0.0)).astype(np.int64),
                      np.ceil(np.where(valid, hi_x, 0.0)).astype(np.int64))
    row_lo, row_hi = (np.floor(np.where(valid, lo_y, 0.0)).astype(np.int64),
                      np.ceil(np.where(valid, hi_y, 0.0)).astype(np.int64))
    valid = valid & (col_hi >= 0) & (col_lo < width) & (row_hi >= 0) & (row_lo < height)
    # Only pixels on the image count: clipping bounds the work for absurd guesses.
    col_lo, col_hi = np.clip(col_lo, 0, width - 1), np.clip(col_hi, 0, width - 1)
    row_lo, row_hi = np.clip(row_lo, 0, height - 1), np.clip(row_hi, 0, height - 1)
    return valid, np.stack([col_lo, col_hi, row_lo, row_hi], axis=1)


def _batches(valid: np.ndarray, bounds: np.ndarray, n_par: int):
    """Valid spots in batches of similar window size (less padding), each holding at most
    _MAX_WINDOW_ELEMENTS padded window elements (spots x (parameters + 1) x pixels)."""
    pixels = (bounds[:, 1] - bounds[:, 0] + 1) * (bounds[:, 3] - bounds[:, 2] + 1)
    order = np.flatnonzero(valid)
    order = order[np.argsort(pixels[order], kind="stable")]
    per_spot = pixels[order] * (n_par + 1)  # sorted ascending: a batch's largest is its last
    start = 0
    while start < order.size:
        fits = per_spot[start:] * np.arange(1, order.size - start + 1) <= _MAX_WINDOW_ELEMENTS
        stop = start + max(1, int(np.sum(fits)))
        yield order[start:stop]
        start = stop


def _solve(matrices: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Batched solve; a singular system gives NaN for its spot instead of failing the batch."""
    try:
        return np.linalg.solve(matrices, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.full(rhs.shape, np.nan)
        for i in range(rhs.shape[0]):
            try:
                out[i] = np.linalg.solve(matrices[i], rhs[i])
            except np.linalg.LinAlgError:
                pass
        return out


def _inverse_fisher(normal: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Inverse of the Fisher matrices (n, P, P); degenerate directions floored (see
    _damping_floor): they come out with huge variance instead of failing the batch."""
    floored = normal + _damping_floor(normal, scale)[:, :, None] * np.eye(normal.shape[1])[None]
    return _batched_inverse(floored)


def _batched_inverse(matrices: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(matrices)
    except np.linalg.LinAlgError:
        out = np.full(matrices.shape, np.nan)
        for i in range(matrices.shape[0]):
            try:
                out[i] = np.linalg.inv(matrices[i])
            except np.linalg.LinAlgError:
                pass
        return out


def _store(result: StreakFit, batch, win: _Windows, params, inverse, done, valid, chi2) -> np.ndarray:
    """Write x, y, flux, cov, flux_sigma, converged, chi2, dof of a batch; return the 1-sigma
    errors of all parameters (n, P). Converged: the fit stopped at a minimum with a finite
    covariance,
    its centre inside its window, a significant flux, on a window free of non-finite
    pixels."""
    n = batch.size
    cov = inverse[:, :2, :2]
    variances = np.diagonal(inverse, axis1=1, axis2=2)
    sigmas = np.sqrt(np.where(variances >= 0, variances, np.inf))
    col_lo, col_hi, row_lo, row_hi = win.bounds.T
    x, y, flux = params[:, 0], params[:, 1], params[:, 2]
    result.converged[batch] = (
        done & valid & ~win.bad & np.all(np.isfinite(params), axis=1)
        & np.all(np.isfinite(cov.reshape(n, -1)), axis=1) & (cov[:, 0, 0] > 0) & (cov[:, 1, 1] > 0)
        & (x >= col_lo) & (x <= col_hi) & (y >= row_lo) & (y <= row_hi)
        & (np.maximum(sigmas[:, 0], sigmas[:, 1]) < np.hypot(col_hi - col_lo, row_hi - row_lo))
        & (flux > SIGNIFICANT_FLUX * sigmas[:, 2]))
    result.x[batch] = np.where(valid, x, np.nan)
    result.y[batch] = np.where(valid, y, np.nan)
    result.flux[batch] = np.where(valid, flux, np.nan)
    result.cov[batch] = np.where(valid[:, None, None], cov, np.nan)
    result.flux_sigma[batch] = np.where(valid, sigmas[:, 2], np.nan)
    result.chi2[batch] = np.where(valid & np.isfinite(chi2), chi2, np.nan)
    result.dof[batch] = np.where(valid, win.mask.sum(axis=1) - params.shape[1], np.nan)
    return sigmas


def _flux_start(flux0: np.ndarray, win: _Windows, noise: float) -> np.ndarray:
    """The caller's flux where positive, else the window sum (at least the pixel noise)."""
    window_sum = np.sum(win.data, axis=1, dtype=np.float64)
    return np.where(flux0 > 0, flux0, np.maximum(window_sum, noise))


# ---------------------------------------------------------------- free straight-streak fit

def fit_streaks(residual, x0, y0, flux0, length0, angle0, sigma: float, noise: float, gain: float,
                iterations: int = 30, excluded: np.ndarray | None = None) -> StreakFit:
    """Fit straight streaks (the PSF swept uniformly along a segment) to a background-
    subtracted image; all spots at once.

    residual: (H, W) image minus background [ADU]. x0, y0: (N,) initial streak centres [px];
    flux0: (N,) initial total fluxes [ADU] (<= 0 or NaN: the window sum); length0: (N,)
    initial lengths [px], e.g. sqrt(max(12 (major moment - sigma^2), 0)); angle0: (N,)
    initial directions [rad] from +x toward +y (the moments' major axis). NaN length0 or
    angle0: a window for a point-like spot and a start from its moments. sigma: PSF 1-sigma
    [px]; noise: 1-sigma pixel noise [ADU]; gain [e-/ADU]; iterations: at most this many
    Levenberg-Marquardt steps per spot; excluded: (H, W) bool, pixels no fit may use (clipped
    at the full well: they carry no shape information), or None.

    Model: F times the PSF (module docstring) averaged along the segment of length L at angle
    theta centred on (x, y): parameters (x, y, F, L, theta). The centre is the mid-exposure
    position when the image moves at constant speed; the perspective speeds the image up
    away from the boresight, which moves the centre toward the faster end by up to
    L^2 (pixel scale [rad/px]) tan(off-axis angle) / 4 (~0.006 px for 40 px streaks in a
    15 deg field, more than the noise above SNR ~500): fit_streaks_on_path models it when
    the rate is known. Window: the
    axis-aligned rectangle around the guessed segment (length0 + max(2 px, 10 %) for the
    guess's error) grown by 4 sigma + 1 px on every side; pixels outside it, off the image
    or non-finite are not used. L >= 0: the model is even in L (symmetric nodes), so
    L -> |L| is exact. Near L = 0 the angle is undefined: the fit starts at L >= sigma / 2
    (off the saddle at 0), a damping floor keeps the systems solvable, the angle comes out
    NaN when L < 2 length_sigma and (x, y) is the PSF fit. A spot with unusable inputs or
    data is returned unconverged (NaN where nothing could be fitted); others are unaffected.
    """
    residual, (x0, y0, flux0, length0, angle0) = _check_common(residual, sigma, noise, gain, iterations,
                                                               x0, y0, flux0, length0, angle0)
    excluded = _check_excluded(excluded, residual)
    n = x0.size
    result = StreakFit._failed(n)
    valid = np.isfinite(x0) & np.isfinite(y0) & (np.abs(x0) < 1e7) & (np.abs(y0) < 1e7)
    guess_ok = np.isfinite(length0) & np.isfinite(angle0)
    length_w = np.where(guess_ok, np.maximum(length0, 0.0), 0.0)
    length_w = length_w + np.maximum(2.0, 0.1 * length_w)
    angle_w = np.where(guess_ok, angle0, 0.0)
    reach = PSF_RADIUS_SIGMA * sigma + 1.0
    half_x = 0.5 * length_w * np.abs(np.cos(angle_w)) + reach
    half_y = 0.5 * length_w * np.abs(np.sin(angle_w)) + reach
    cx, cy = np.round(np.where(valid, x0, 0.0)), np.round(np.where(valid, y0, 0.0))
    valid, bounds = _window_bounds(residual, valid, cx - half_x, cx + half_x, cy - half_y, cy + half_y)
    with np.errstate(all="ignore"):  # degenerate spots end up non-finite or unconverged, not as warnings
        for batch in _batches(valid, bounds, 5):
            _fit_free_batch(residual, batch, bounds[batch], x0[batch], y0[batch], flux0[batch], length0[batch],
                            angle0[batch], guess_ok[batch], sigma, noise, gain, iterations, result, excluded)
    return result


def _window_moments(win: _Windows):
    """Major second moment [px^2] and its axis angle [rad] of the positive pixels of each
    window."""
    n = win.data.shape[0]
    c = np.broadcast_to(np.arange(win.n_cols, dtype=float)[None, None, :], (n, win.n_rows, win.n_cols)).reshape(n, -1)
    r = np.broadcast_to(np.arange(win.n_rows, dtype=float)[None, :, None], (n, win.n_rows, win.n_cols)).reshape(n, -1)
    w = np.maximum(win.data, 0.0) * win.mask
    total = np.maximum(w.sum(axis=1, dtype=np.float64), 1e-300)
    cx, cy = (w * c).sum(axis=1) / total, (w * r).sum(axis=1) / total
    dx, dy = c - cx[:, None], r - cy[:, None]
    mxx, myy, mxy = ((w * dx * dx).sum(1) / total, (w * dy * dy).sum(1) / total, (w * dx * dy).sum(1) / total)
    major = 0.5 * (mxx + myy) + np.sqrt(0.25 * (mxx - myy) ** 2 + mxy ** 2)
    return major, 0.5 * np.arctan2(2 * mxy, mxx - myy)


def _even_intervals(count: np.ndarray) -> np.ndarray:
    """Smallest even integers >= count (at least 2): Simpson interval counts."""
    n = np.maximum(np.ceil(count), 2).astype(np.int64)
    return n + n % 2


def _fit_free_batch(residual, batch, bounds, x0, y0, flux0, length0, angle0, guess_ok, sigma, noise, gain,
                    iterations, result: StreakFit, excluded=None) -> None:
    win = _cut_windows(residual, *bounds.T, excluded)
    length, angle = length0.copy(), angle0.copy()
    if not np.all(guess_ok):
        major, axis = _window_moments(win)
        length = np.where(guess_ok, length, segment_length(major, sigma))
        angle = np.where(guess_ok, angle, axis)
    # Longest streak that fits its window (diagonal): beyond it the fit has run away.
    max_length = np.hypot(bounds[:, 1] - bounds[:, 0], bounds[:, 3] - bounds[:, 2]) + 1.0
    # Start off L = 0: there the model is flat in L and theta (a saddle the fit cannot leave).
    length = np.clip(length, 0.5 * sigma, 2.0 * max_length)
    var_eff = sigma * sigma + 1.0 / 12.0
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    amplitude_unit = 1.0 / (2.0 * np.pi * var_eff)  # peak of the unit-flux Gaussian
    node_spacing = NODE_SPACING_SIGMA * np.sqrt(var_eff)

    # Nodes per spot: a fixed count keeps each spot's model a smooth function of L (a count
    # following L would change the model in steps the acceptance test sees as noise); it
    # grows, once in a while, only when L outgrows the node spacing.
    intervals = _even_intervals(1.2 * length / node_spacing)

    def evaluate(index, p):
        xc, yc, f, ell, th = p.T
        needed = _even_intervals(ell / node_spacing)
        grow = needed > intervals[index]
        if np.any(grow):
            intervals[index[grow]] = _even_intervals(1.2 * ell[grow] / node_spacing)
        s, w = _simpson(intervals[index])
        ct, st = np.cos(th), np.sin(th)
        sx = (xc - win.origin[index, 0])[:, None] + (ell * ct)[:, None] * s
        sy = (yc - win.origin[index, 1])[:, None] + (ell * st)[:, None] * s
        sums = _sample_sums(win, sx, sy, w, s, scale)  # shape, gx', gy', s gy', s gx'
        a = f * amplitude_unit
        b = a * (2.0 * scale)  # d/d(sample position) of the unnormalized profiles
        bl = b * ell
        # Jacobian rows (x, y, F, L, theta) and the model as combinations of the sums.
        mix = np.zeros((index.size, 6, 5), np.float32)
        mix[:, 0, 1] = b
        mix[:, 1, 2] = b
        mix[:, 2, 0] = amplitude_unit
        mix[:, 3, 3], mix[:, 3, 4] = b * st, b * ct  # along the streak, growing with s
        mix[:, 4, 3], mix[:, 4, 4] = bl * ct, -bl * st  # across it, growing with s
        mix[:, 5, 0] = a
        return np.matmul(mix, sums)

    def max_step(p):
        limit = np.empty_like(p)
        limit[:, 0:2] = 1.0  # px per iteration
        limit[:, 2] = np.inf  # the model is linear in flux
        limit[:, 3] = np.maximum(2.0, 0.5 * p[:, 3])  # px
        limit[:, 4] = 0.3  # rad
        return limit

    def constrain(index, p):
        p = p.copy()
        # The model is even in L; the cap (flagged below) bounds the nodes of a runaway fit.
        p[:, 3] = np.minimum(np.abs(p[:, 3]), 2.0 * max_length[index])
        return p

    def scale_of(p):
        units = np.ones_like(p)
        units[:, 2] = np.maximum(np.abs(p[:, 2]), noise)
        return units

    def undetermined(p, covariance):
        # An unresolved streak (L < 2 sigma_L): the model is even in L, so near L = 0 the chi^2
        # still to gain in L and theta stays at the noise level, ~1, however small L gets;
        # (x, y, F) decouple from them: judge convergence on (x, y, F). Theta is held (it
        # would wander by the trust region and shrink every step with it); L stays free to
        # grow if the spot is a streak after all.
        unresolved = p[:, 3] < 2.0 * np.sqrt(np.maximum(covariance[:, 3, 3], 0.0))
        skip, hold = np.zeros(p.shape, bool), np.zeros(p.shape, bool)
        skip[:, 3:] = unresolved[:, None]
        hold[:, 4] = unresolved
        return skip, hold

    params = np.column_stack([x0, y0, _flux_start(flux0, win, noise), length, angle])
    valid = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > 6)
    params, normal, done, chi2 = _levenberg_marquardt(evaluate, params, win, valid, noise, gain, iterations,
                                                      max_step, constrain, scale_of, undetermined)
    sigmas = _store(result, batch, win, params, _inverse_fisher(normal, scale_of(params)), done, valid, chi2)
    fitted_length, fitted_angle = params[:, 3], params[:, 4]
    result.converged[batch] &= fitted_length <= max_length
    # Direction of an undirected segment in (-pi/2, pi/2]; undefined for an unresolved one.
    direction = np.pi / 2 - np.mod(np.pi / 2 - fitted_angle, np.pi)
    resolved = valid & (fitted_length >= 2.0 * sigmas[:, 3])
    result.length[batch] = np.where(valid, fitted_length, np.nan)
    result.length_sigma[batch] = np.where(valid, sigmas[:, 3], np.nan)
    result.angle[batch] = np.where(resolved, direction, np.nan)
    result.angle_sigma[batch] = np.where(resolved, sigmas[:, 4], np.nan)


# ---------------------------------------------------------------- fit on a known path

def fit_streaks_on_path(residual, x0, y0, flux0, path, sigma: float, noise: float, gain: float,
                        iterations: int = 20, excluded: np.ndarray | None = None) -> StreakFit:
    """Fit streaks whose shape is known from the body rate (e.g. SmearModel.path); all spots
    at once.

    residual: (H, W) image minus background [ADU]; x0, y0, flux0: (N,) initial mid-exposure
    positions [px] and total fluxes [ADU] (<= 0 or NaN: the window sum); path: (N, K, 2)
    offsets [px] of each star's image at K equally spaced times across the exposure from its
    mid-exposure position (a straight line, or an arc under roll); sigma, noise, gain,
    iterations, excluded as fit_streaks.

    Model: F mean_k PSF(pixel - (c + path[n, k])); only c = (x, y) and F are fitted, so
    curved paths and uneven speed are modelled exactly. The path's shape changes slowly with
    position (by ~ path length x field angle moved): compute it at the guess and, for long
    arcs, again at the fitted position for a second fit. Window: the path's bounding box
    around (x0, y0) grown by 4 sigma + 2 px (1 px for the guess's error). length: the chord
    [px] from the first to the last sample times K / (K - 1), i.e. extended by half a
    sample interval at both ends (a straight path's full length, as fit_streaks and the
    renderer's extent_px report it);
    angle: direction of motion, start to end, in (-pi, pi] (NaN for a path of one sample);
    length_sigma and angle_sigma are 0 (given, not fitted). A spot whose inputs or path are
    not finite is returned unconverged; others are unaffected.
    """
    residual, (x0, y0, flux0) = _check_common(residual, sigma, noise, gain, iterations, x0, y0, flux0)
    excluded = _check_excluded(excluded, residual)
    n = x0.size
    try:
        path = np.asarray(path, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("path must be a numeric (N, K, 2) array of pixel offsets") from None
    if path.ndim != 3 or path.shape[0] != n or path.shape[2] != 2 or path.shape[1] < 1:
        raise ValueError(f"path must have shape (N={n}, K>=1, 2), got {path.shape}")
    result = StreakFit._failed(n)
    valid = (np.isfinite(x0) & np.isfinite(y0) & (np.abs(x0) < 1e7) & (np.abs(y0) < 1e7)
             & np.isfinite(path).all(axis=(1, 2)))
    path = np.where(valid[:, None, None], path, 0.0)
    reach = PSF_RADIUS_SIGMA * sigma + 2.0
    cx, cy = np.round(np.where(valid, x0, 0.0)), np.round(np.where(valid, y0, 0.0))
    valid, bounds = _window_bounds(residual, valid, cx + path[:, :, 0].min(axis=1) - reach,
                                   cx + path[:, :, 0].max(axis=1) + reach, cy + path[:, :, 1].min(axis=1) - reach,
                                   cy + path[:, :, 1].max(axis=1) + reach)
    with np.errstate(all="ignore"):  # degenerate spots end up non-finite or unconverged, not as warnings
        for batch in _batches(valid, bounds, 3):
            _fit_path_batch(residual, batch, bounds[batch], x0[batch], y0[batch], flux0[batch], path[batch], sigma,
                            noise, gain, iterations, result, excluded)
    if path.shape[1] >= 2:  # the samples are mid-points of K slices of the exposure
        chord = (path[:, -1] - path[:, 0]) * path.shape[1] / (path.shape[1] - 1)
    else:
        chord = np.zeros((n, 2))
    length = np.hypot(chord[:, 0], chord[:, 1])
    fitted = np.isfinite(result.x)
    result.length[:] = np.where(fitted, length, np.nan)
    result.length_sigma[:] = np.where(fitted, 0.0, np.nan)
    result.angle[:] = np.where(fitted & (length > 0), np.arctan2(chord[:, 1], chord[:, 0]), np.nan)
    result.angle_sigma[:] = np.where(fitted & (length > 0), 0.0, np.nan)
    return result


def _fit_path_batch(residual, batch, bounds, x0, y0, flux0, offsets, sigma, noise, gain, iterations,
                    result: StreakFit, excluded=None) -> None:
    win = _cut_windows(residual, *bounds.T, excluded)
    weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])
    var_eff = sigma * sigma + 1.0 / 12.0
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    amplitude_unit = 1.0 / (2.0 * np.pi * var_eff)

    def evaluate(index, p):
        xc, yc, f = p.T
        sx = (xc - win.origin[index, 0])[:, None] + offsets[index, :, 0]
        sy = (yc - win.origin[index, 1])[:, None] + offsets[index, :, 1]
        sums = _sample_sums(win, sx, sy, weights[index], None, scale)  # shape, gx', gy'
        a = f * amplitude_unit
        mix = np.zeros((index.size, 4, 3), np.float32)  # jacobian rows (x, y, F) and the model
        mix[:, 0, 1] = mix[:, 1, 2] = a * (2.0 * scale)
        mix[:, 2, 0] = amplitude_unit
        mix[:, 3, 0] = a
        return np.matmul(mix, sums)

    def max_step(p):
        limit = np.full_like(p, 1.0)  # px per iteration
        limit[:, 2] = np.inf  # the model is linear in flux
        return limit

    def scale_of(p):
        units = np.ones_like(p)
        units[:, 2] = np.maximum(np.abs(p[:, 2]), noise)
        return units

    params = np.column_stack([x0, y0, _flux_start(flux0, win, noise)])
    valid = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > 4)
    params, normal, done, chi2 = _levenberg_marquardt(evaluate, params, win, valid, noise, gain, iterations,
                                                      max_step, lambda index, p: p, scale_of)
    _store(result, batch, win, params, _inverse_fisher(normal, scale_of(params)), done, valid, chi2)


# ---------------------------------------------------------------- merged pairs on a known path

def _path_windows(residual, x, y, path, reach, valid):
    """Integer bounds of windows covering the paths `path` (n, K, 2) around every centre
    x, y (n, M) [px], grown by `reach` [px] (see _window_bounds)."""
    cx, cy = np.round(np.where(valid[:, None], x, 0.0)), np.round(np.where(valid[:, None], y, 0.0))
    return _window_bounds(residual, valid, cx.min(axis=1) + path[:, :, 0].min(axis=1) - reach,
                          cx.max(axis=1) + path[:, :, 0].max(axis=1) + reach,
                          cy.min(axis=1) + path[:, :, 1].min(axis=1) - reach,
                          cy.max(axis=1) + path[:, :, 1].max(axis=1) + reach)


def _path_model(win: _Windows, x, y, flux, offsets, sigma: float) -> np.ndarray:
    """(n, R*C) model [ADU] of one star per window on its path (the fits' PSF model)."""
    var_eff = sigma * sigma + 1.0 / 12.0
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    sx = (x - win.origin[:, 0])[:, None] + offsets[:, :, 0]
    sy = (y - win.origin[:, 1])[:, None] + offsets[:, :, 1]
    weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])
    shape = _sample_sums(win, sx, sy, weights, None, scale)[:, 0]
    return shape * (flux / (2.0 * np.pi * var_eff))[:, None]


def second_source_on_path(residual, x, y, flux, path, sigma: float, noise: float, gain: float,
                          excluded: np.ndarray | None = None):
    """Where one more star on the same path shape would best explain what a fit of M stars
    (x, y, flux (N,) or (N, M) [px, ADU]; path (N, K, 2) as fit_streaks_on_path) leaves in
    the window of the first star (the window fit_streaks_on_path uses): the residual (data -
    model) correlated with the path's own unit-flux profile t (a matched filter), divided by
    its noise sqrt(sum var t^2) (var = max(data, 0) / gain + noise^2 per pixel). Returns, at
    the peak of that ratio, x, y [px], the template's least-squares flux [ADU] and the ratio
    (the matched-filter SNR of the best extra star), each (N,); NaN where nothing is usable.
    All windows at once (padded to one size, correlations by FFT)."""
    residual = np.asarray(residual)
    excluded = _check_excluded(excluded, residual)
    x, y, flux = (np.asarray(v, dtype=float).reshape(np.shape(v)[0], -1) for v in (x, y, flux))
    path = np.asarray(path, dtype=float)
    n = x.shape[0]
    out = np.full((4, n), np.nan)
    ok = np.all(np.isfinite(x) & np.isfinite(y) & np.isfinite(flux), axis=1) & np.isfinite(path).all(axis=(1, 2))
    ok, bounds = _path_windows(residual, x[:, :1], y[:, :1], np.where(ok[:, None, None], path, 0.0),
                               PSF_RADIUS_SIGMA * sigma + 2.0, ok)
    use = np.flatnonzero(ok)
    if use.size == 0:
        return out[0], out[1], out[2], out[3]
    win = _cut_windows(residual, *bounds[use].T, excluded)
    offsets = path[use]
    model = sum(_path_model(win, x[use, m], y[use, m], flux[use, m], offsets, sigma) for m in range(x.shape[1])
                if np.all(np.isfinite(x[use, m])))
    shape = (use.size, win.n_rows, win.n_cols)
    left = ((win.data - model) * win.mask).reshape(shape)
    variance = ((np.maximum(win.data, 0.0) / gain + noise * noise) * win.mask).reshape(shape)
    # Templates: each path's unit-flux profile (the fits' PSF model) on a grid centred on its
    # mid-exposure point, one size for all: separable sums over the path samples.
    var_eff = sigma * sigma + 1.0 / 12.0
    half = np.ceil(np.max(np.abs(offsets), axis=(0, 1)) + 3.0 * np.sqrt(var_eff)).astype(int)
    gx = np.arange(-half[0], half[0] + 1, dtype=float)
    gy = np.arange(-half[1], half[1] + 1, dtype=float)
    px = np.exp(-0.5 * (gx[None, None, :] - offsets[:, :, 0, None]) ** 2 / var_eff)  # (n, K, TC)
    py = np.exp(-0.5 * (gy[None, None, :] - offsets[:, :, 1, None]) ** 2 / var_eff)  # (n, K, TR)
    template = np.matmul(np.transpose(py, (0, 2, 1)), px)  # (n, TR, TC)
    template /= template.sum(axis=(1, 2), keepdims=True)
    # Correlation with the template centred: score[c] = sum_u left[c + u - h] t[u], i.e. the
    # full convolution with the flipped template, cropped at (h, h).
    size = (win.n_rows + gy.size - 1, win.n_cols + gx.size - 1)

    def correlate(image, kernel):
        full = np.fft.irfft2(np.fft.rfft2(image, size) * np.fft.rfft2(kernel[:, ::-1, ::-1], size), size)
        return full[:, half[1]:half[1] + win.n_rows, half[0]:half[0] + win.n_cols]

    score = correlate(left, template)
    spread = correlate(variance, template * template)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((win.mask.reshape(shape) > 0) & (spread > 0), score / np.sqrt(np.abs(spread)), -np.inf)
    flat = ratio.reshape(use.size, -1)
    best = np.argmax(flat, axis=1)
    found = np.isfinite(flat[np.arange(use.size), best])
    row, col = best // win.n_cols, best % win.n_cols
    keep = use[found]
    out[0, keep] = win.origin[found, 0] + col[found]
    out[1, keep] = win.origin[found, 1] + row[found]
    out[2, keep] = (score.reshape(use.size, -1)[np.arange(use.size), best][found]
                    / np.sum(template * template, axis=(1, 2))[found])
    out[3, keep] = flat[np.arange(use.size), best][found]
    return out[0], out[1], out[2], out[3]


def fit_star_groups_on_path(residual, x0, y0, flux0, path, sigma: float, noise: float, gain: float,
                            iterations: int = 30, excluded: np.ndarray | None = None) -> list[StreakFit]:
    """Joint fit of M stars moving on the same path shape (streaks merged into one spot, or a
    neighbour's streak in its window): x0, y0, flux0 (N, M) initial positions [px] and fluxes
    [ADU], the first star of each group the one whose window is fitted (the window
    fit_streaks_on_path uses for it, so that the chi^2 of the two fits compare); path (N, K,
    2) and the rest as fit_streaks_on_path. Returns M StreakFit (star m of every group) with
    positions, fluxes and covariances (blocks of the joint inverse Fisher matrix: each star's
    error includes what the others' uncertainty does to it); all carry the group's chi2 and
    dof. converged: the first star's test of fit_streaks_on_path, and finite values for the
    others (whose centres may lie outside the window: only their light inside it is used)."""
    residual = np.asarray(residual)
    excluded = _check_excluded(excluded, residual)
    x0, y0, flux0 = (np.asarray(v, dtype=float) for v in (x0, y0, flux0))
    n, m_stars = x0.shape
    path = np.asarray(path, dtype=float)
    fits = [StreakFit._failed(n) for _ in range(m_stars)]
    if n == 0:
        return fits
    valid = (np.all(np.isfinite(x0) & np.isfinite(y0) & np.isfinite(flux0), axis=1)
             & np.isfinite(path).all(axis=(1, 2)))
    path = np.where(valid[:, None, None], path, 0.0)
    valid, bounds = _path_windows(residual, x0[:, :1], y0[:, :1], path, PSF_RADIUS_SIGMA * sigma + 2.0, valid)
    var_eff = sigma * sigma + 1.0 / 12.0
    scale = 1.0 / np.sqrt(2.0 * var_eff)
    amplitude_unit = 1.0 / (2.0 * np.pi * var_eff)
    n_par = 3 * m_stars

    def max_step(p):
        limit = np.full_like(p, 1.0)  # px per iteration
        limit[:, 2::3] = np.inf  # the model is linear in the fluxes
        return limit

    def scale_of(p):
        units = np.ones_like(p)
        units[:, 2::3] = np.maximum(np.abs(p[:, 2::3]), noise)
        return units

    with np.errstate(all="ignore"):  # degenerate groups end up non-finite or unconverged
        for batch in _batches(valid, bounds, n_par):
            win = _cut_windows(residual, *bounds[batch].T, excluded)
            offsets = path[batch]
            weights = np.full(offsets.shape[:2], 1.0 / offsets.shape[1])

            def evaluate(index, p, win=win, offsets=offsets, weights=weights):
                aug = np.zeros((index.size, n_par + 1, win.data.shape[1]), np.float32)  # jacobian rows, model
                for m in range(m_stars):
                    sx = (p[:, 3 * m] - win.origin[index, 0])[:, None] + offsets[index, :, 0]
                    sy = (p[:, 3 * m + 1] - win.origin[index, 1])[:, None] + offsets[index, :, 1]
                    sums = _sample_sums(win, sx, sy, weights[index], None, scale)  # shape, gx', gy'
                    a = (p[:, 3 * m + 2] * amplitude_unit).astype(np.float32)[:, None]
                    aug[:, 3 * m] = a * np.float32(2.0 * scale) * sums[:, 1]
                    aug[:, 3 * m + 1] = a * np.float32(2.0 * scale) * sums[:, 2]
                    aug[:, 3 * m + 2] = np.float32(amplitude_unit) * sums[:, 0]
                    aug[:, n_par] += a * sums[:, 0]
                return aug

            params = np.stack([x0[batch], y0[batch], flux0[batch]], axis=2).reshape(batch.size, n_par)
            ok = np.all(np.isfinite(params), axis=1) & (win.mask.sum(axis=1) > n_par + 1)
            params, normal, done, chi2 = _levenberg_marquardt(evaluate, params, win, ok, noise, gain, iterations,
                                                              max_step, lambda index, p: p, scale_of)
            inverse = _inverse_fisher(normal, scale_of(params))
            for m, result in enumerate(fits):
                block = slice(3 * m, 3 * m + 3)
                _store(result, batch, win, params[:, block], inverse[:, block, block], done, ok, chi2)
                result.dof[batch] -= n_par - 3  # the group's parameters
                if m > 0:  # a neighbour: only its light in the window matters
                    result.converged[batch] = (done & ok & ~win.bad & np.all(np.isfinite(params), axis=1)
                                               & np.isfinite(result.cov[batch]).all(axis=(1, 2))
                                               & (result.cov[batch, 0, 0] > 0) & (result.cov[batch, 1, 1] > 0))
    every = np.all([f.converged for f in fits], axis=0)
    if path.shape[1] >= 2:
        chord = (path[:, -1] - path[:, 0]) * path.shape[1] / (path.shape[1] - 1)
    else:
        chord = np.zeros((n, 2))
    length = np.hypot(chord[:, 0], chord[:, 1])
    for result in fits:
        result.converged[:] = every
        fitted = np.isfinite(result.x)
        result.length[:] = np.where(fitted, length, np.nan)
        result.length_sigma[:] = np.where(fitted, 0.0, np.nan)
        result.angle[:] = np.where(fitted & (length > 0), np.arctan2(chord[:, 1], chord[:, 0]), np.nan)
        result.angle_sigma[:] = np.where(fitted & (length > 0), 0.0, np.nan)
    return fits
