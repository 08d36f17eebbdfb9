# SPDX-License-Identifier: Apache-2.0
"""
The PSF measured on the frame itself.

The width [px] of the pixel-integrated Gaussian the centroider's fit model, windows, shape
test and blend splitting use, from the frame's bright, isolated, unsaturated point-like stars
(PsfEstimate, estimate_psf).

Each chosen star gets a small fit of a pixel-integrated Gaussian with a free width (and a
background offset) on a window 4 of its widths wide (width_fit_kernel.fit_psf_width): not the raw
second moment, which a pixelated PSF inflates by 1/12 px^2 and a window cuts short. The
frame's width is the median over the stars (a star that is not one, a hot pixel or a blend,
does not move it), its uncertainty the median's spread / sqrt(n). For a non-Gaussian PSF (a
Moffat's wings, a defocused annulus) it is the Gaussian that fits the core best: what the
windows and tests need. A star is the optics' PSF when round on its own shape (adaptive
moments: an elliptical Gaussian weight matched to the star, axis ratio < MAX_AXIS_RATIO), and
the frame's round stars must outnumber its elongated ones: otherwise the frame is smeared (an
unaided rate's streaks, whose least elongated are blends and short ones) and keeps the prior.
Elongation and orientation come from the stars' Gaussian-weighted second moments (corrected
for the weight and the pixel), the median over the chosen stars; where those cannot measure
the shape (a weight twice the round fit's width beside long streaks takes in enough sky that a
sky ramp makes them unmeasurable), the elongation is the median of the round stars' adaptive
axis ratios.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..detection.candidates import Candidates
from ..detection.detect import Detections
from .width_fit_kernel import fit_psf_width
from ..detection.measure import clean_hot_pixels, star_peak_to_neighbour_ratio
from ..windows import gather_windows

SOURCES = ("estimated", "prior", "configured")
MIN_SIGMA_PX, MAX_SIGMA_PX = 0.3, 5.0  # the supported range of the estimate [px]
SHARPEST_STAR_PX = 0.25  # a fit narrower than this is a hot pixel (or an undersampled PSF we cannot tell from one)
MIN_STARS = 5  # fewer usable stars: no estimate (a few cosmic-ray hits must not set the PSF)
MAX_STARS = 12  # the brightest usable stars fitted: the median of 12 is good to ~1-3 % (and cheap)
MIN_PEAK_SNR = 7.0  # brightest pixel above the background [noise sigmas]: enough to fit a width
# A wide PSF spreads a star's light: at SNR 12 a sigma-2 px star's brightest pixel is ~3 sigmas.
# Such a star is usable on its footprint SNR (>= MIN_STAR_SNR) with a peak of MIN_WIDE_PEAK_SNR.
MIN_STAR_SNR = 10.0
MIN_WIDE_PEAK_SNR = 3.0
# A frame re-measured at a wider prior (extract.WIDER_PRIOR_FACTORS) whose stars are all faint
# (a defocused camera's stars at SNR ~10 have peaks of ~2 noise sigmas and, in an aperture
# still narrower than the PSF, a footprint SNR of ~6-8): stars from these levels count.
FAINT_STAR_SNR = 6.0
FAINT_WIDE_PEAK_SNR = 1.5
ISOLATION_SIGMAS = 8.0  # no other candidate closer than this many (rough) PSF widths
EXCLUDED_REACH_PX = 2.0  # a candidate this close to an excluded source [px] is that source (usable_stars' exclude)
MAX_AXIS_RATIO = 3.0  # a star more elongated than this (noise included) is smeared or blended, not the optics' PSF
WIDER_START = 1.2  # stars' moment width beyond this x the prior: the fit starts from the moment (an aperture cuts it)
RERUN_TOLERANCE = 0.1  # relative difference from the prior beyond which a frame is measured again
# A round PSF's estimate is measured again at a smaller difference when the estimate resolves it
# (beyond ROUND_RERUN_SIGMAS of its own uncertainty): bright stars fitted 5-9 % too narrow lean
# and their stated sigma is too small (independent renderer, Gaussian 1.05 / 1.09 px fitted at
# 1 px: RMS error 1.3x the stated sigma at SNR 300-1000; at the estimate 1.0x). The running prior
# carries the width used, so a PSF within RERUN_TOLERANCE of it was fitted too narrow for good.
ROUND_RERUN_TOLERANCE = 0.03
ROUND_RERUN_SIGMAS = 3.0
SMEARED_ELONGATION = 1.2  # stars more elongated than this are measured with the minor-axis width
RING_CENTRE_RATIO = 0.6  # centre-to-ring light below this x a Gaussian's of the same width: a ring PSF


@dataclass(frozen=True)
class PsfEstimate:
    """
    The PSF of one frame as the centroider saw it.

    sigma_px: the equivalent Gaussian 1-sigma [px] (estimated, or the prior / configured value
    when not estimated); sigma_major_px, sigma_minor_px: 1-sigma along the PSF's major and
    minor axes [px] (sigma_px times and over the square root of the pixelated shape's axis
    ratio; both sigma_px when not measured); angle_rad: the major axis' direction
    [rad] from +x toward +y, in (-pi/2, pi/2]; sigma_uncertainty_px: 1-sigma of sigma_px [px]
    (nan when not estimated); stars: stars the estimate used; source: "estimated" (from this
    frame), "prior" (too few usable stars or out of range: the prior was used) or "configured"
    (psf_mode "fixed" or no PSF: nothing estimated); reason: why it fell back ("" when
    estimated); applied_sigma_px: the width the frame was measured with [px] (the prior when
    the estimate agreed with it within its tolerance, see extract.extract_spots); annular:
    the stars are rings (a defocused PSF: less light at the centre than RING_CENTRE_RATIO x
    a Gaussian's), so that a spot's several maxima are one star, not a blend; holds_prior: not
    estimated for want of anything to measure the PSF on (no detections, too few isolated
    point-like stars, no PSF fit converged, a rate-aided frame's streaks too few to measure
    across, too few of the usable stars round): no evidence against the prior, which a running prior
    (running_prior.RunningPsf) keeps.
    """

    sigma_px: float
    sigma_major_px: float
    sigma_minor_px: float
    angle_rad: float
    sigma_uncertainty_px: float
    stars: int
    source: str
    reason: str = ""
    applied_sigma_px: float = float("nan")
    annular: bool = False
    holds_prior: bool = False

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"PsfEstimate.source={self.source!r} must be one of {SOURCES}")
        if np.isnan(self.applied_sigma_px):
            object.__setattr__(self, "applied_sigma_px", float(self.sigma_px))

    @property
    def estimated(self) -> bool:
        return self.source == "estimated"

    @property
    def elongation(self) -> float:
        """sigma_major / sigma_minor [-] (1 for a round PSF)."""
        return float(self.sigma_major_px / self.sigma_minor_px) if self.sigma_minor_px > 0 else 1.0

    @staticmethod
    def assumed(sigma_px: float, source: str, reason: str = "", stars: int = 0,
                holds_prior: bool = False) -> "PsfEstimate":
        """Return a round PSF of sigma_px [px] that was not estimated (source "prior" or "configured")."""
        return PsfEstimate(float(sigma_px), float(sigma_px), float(sigma_px), 0.0, float("nan"), stars, source, reason,
                           holds_prior=holds_prior)


def usable_stars(cand: Candidates, det: Detections, saturation: float, prior_sigma: float, faint: bool = False,
                 neighbours: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 exclude: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """
    Return indices of the candidates fit to measure the PSF on, brightest first (at most MAX_STARS).

    Measured, off the image border, peak >= MIN_PEAK_SNR noise sigmas (or footprint SNR >=
    MIN_STAR_SNR with a peak >= MIN_WIDE_PEAK_SNR sigmas: a wide PSF's star; with `faint`,
    FAINT_STAR_SNR and FAINT_WIDE_PEAK_SNR) and 2 % below the clip
    level (`saturation` [ADU]) and the frame's brightest candidate's peak, not most of their
    light in one pixel once cleaned (hot pixels), not a long track (second moments within 8x of
    each other), and no other candidate within ISOLATION_SIGMAS PSF widths. Candidates the shape
    test rejected with the prior are included: with a prior too wide, that is where sharp stars
    end up. neighbours: (x, y, slack) [px] of every candidate for that isolation test when `cand`
    holds only some (psf.pilot: a neighbour counts within reach + slack; None: cand's measured ones).
    exclude: (x, y) [px] of sources that are not stars (psf_loop: those of an estimate the frame
    contradicted); a candidate within EXCLUDED_REACH_PX of one is not usable (still a neighbour).
    """
    finite = np.isfinite(cand.x) & np.isfinite(cand.y) & np.isfinite(cand.peak_raw)
    amplitude = cand.peak_raw - det.background_at(np.where(finite, cand.x, 0.0), np.where(finite, cand.y, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        # Long streaks and cosmic-ray tracks out now; the fine roundness test is estimate_psf's,
        # on the fit windows (these moments mix an aperture's and a footprint's).
        not_track = (cand.major < 8.0 * cand.minor) & (cand.minor > 0)
        one_pixel = cand.flux < 0.2 * amplitude  # a hot pixel cleaned away leaves almost nothing
    # Clipped: at the clip level (configured or seen as a flat top), or at the frame's brightest
    # value (a clip level no flat top showed; in a frame without one it costs the brightest star).
    ceiling = min(saturation, float(np.max(cand.peak_raw[finite]))) if finite.any() else saturation
    min_snr, min_wide_peak = (FAINT_STAR_SNR, FAINT_WIDE_PEAK_SNR) if faint else (MIN_STAR_SNR, MIN_WIDE_PEAK_SNR)
    bright = (amplitude >= MIN_PEAK_SNR * det.noise_adu) | (
        (cand.snr >= min_snr) & (amplitude >= min_wide_peak * det.noise_adu))
    ok = finite & ~cand.edge & bright & (cand.peak_raw < 0.98 * ceiling) & not_track & ~one_pixel
    if exclude is not None and np.size(exclude[0]):
        near = np.hypot(cand.x[:, None] - exclude[0][None, :], cand.y[:, None] - exclude[1][None, :])
        ok &= ~(near < EXCLUDED_REACH_PX).any(axis=1)
    chosen = np.flatnonzero(ok)
    if chosen.size == 0:
        return chosen
    chosen = chosen[np.argsort(-amplitude[chosen], kind="stable")][: 3 * MAX_STARS]
    all_x, all_y, slack = (cand.x[finite], cand.y[finite], 0.0) if neighbours is None else neighbours
    distance = np.hypot(cand.x[chosen, None] - all_x[None, :], cand.y[chosen, None] - all_y[None, :])
    distance[distance == 0.0] = np.inf  # itself
    distance -= np.atleast_1d(slack)[None, :]
    reach = ISOLATION_SIGMAS * max(prior_sigma, 1.0)
    return chosen[distance.min(axis=1, initial=np.inf) > reach][:MAX_STARS]


@dataclass(frozen=True)
class MeasuredFrame:
    """
    What a measurement of a frame leaves for the PSF estimate.

    Its detections, every measured candidate (shape-test rejects included), the saturation
    level [ADU], whether a body rate predicted smears (then no star shows the optics' PSF) and
    which candidates are thin footprints off the predicted smear (cosmic-ray tracks: no
    profile across a streak; None: none known).
    """

    det: Detections
    cand: Candidates
    saturation: float
    smeared: bool = False
    off_track: np.ndarray | None = None


def estimate_psf(image: np.ndarray, frame: MeasuredFrame, prior_sigma: float, gain: float, faint: bool = False,
                 neighbours: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 min_usable: int = MIN_STARS, exclude: tuple[np.ndarray, np.ndarray] | None = None) -> PsfEstimate:
    """
    Return the frame's PSF from its usable stars (usable_stars), or the prior.

    The stars used are those whose fit converged to a width of at least SHARPEST_STAR_PX and
    whose axis ratio is below MAX_AXIS_RATIO; the prior (source "prior", with the reason) is
    returned when fewer than MIN_STARS remain or no more than the elongated ones (or fewer than
    `min_usable` usable stars: psf.pilot asks for a full MAX_STARS) or the width is outside
    [MIN_SIGMA_PX, MAX_SIGMA_PX]. image [ADU];
    frame: its detections, measured candidates and clip level; prior_sigma: the width the
    candidates were measured with [px]; gain [e-/ADU]; faint, neighbours, exclude: see usable_stars.
    """
    chosen = usable_stars(frame.cand, frame.det, frame.saturation, prior_sigma, faint, neighbours, exclude)
    need = max(MIN_STARS, min_usable)
    if chosen.size < need:
        min_snr = FAINT_STAR_SNR if faint else MIN_STAR_SNR
        # Too few stars to measure is no evidence against the width held (RunningPsf keeps it):
        # emptied, a sparse frame's running 2.7 px fell to the configured 1 px and stayed there,
        # the stars fitted as fragments 60-270" off (stress campaign, seed 2026, task 1033).
        return PsfEstimate.assumed(prior_sigma, "prior", f"{chosen.size} isolated unsaturated point-like stars with "
                                   f"peak SNR >= {MIN_PEAK_SNR:g} or SNR >= {min_snr:g} (need {need})",
                                   int(chosen.size), holds_prior=True)
    fit = _fit_stars(image, frame, chosen, prior_sigma, gain)
    if fit is None:
        # Nothing measured is no evidence against the width held either: a sparse frame's hot
        # pixels and cosmic rays chosen, none fitted, emptied a running 2.55 px, and the
        # rate-aided frames after it (too few streaks to measure across) stayed at the
        # configured 1 px, 19-76" off (stress campaign, seed 2026, task 1297 frames 14-27).
        return PsfEstimate.assumed(prior_sigma, "prior", "no PSF fit converged", 0, holds_prior=True)
    return _estimate_from_fits(fit, prior_sigma, faint)


def _fit_stars(image: np.ndarray, frame: MeasuredFrame, chosen: np.ndarray, prior_sigma: float, gain: float):
    """
    Fit a free-width Gaussian to each of the stars `chosen`, on a window 4 of its widths wide.

    Returns _fit_widths' (x, y, flux, width, windows) of the converged fits, None when none converged.
    """
    cand, det = frame.cand, frame.det
    x, y = cand.x[chosen], cand.y[chosen]
    background = det.background_at(x, y)
    # A window cut to the prior would shrink a wider PSF's fit: start from the candidates' moments
    # (pixel term removed), and widen the window when the fit says the PSF is wider.
    moment = np.sqrt(max(_median(0.5 * (cand.major[chosen] + cand.minor[chosen])) - 1.0 / 12.0, 0.04))
    start, fit = (float(moment) if moment > WIDER_START * prior_sigma else prior_sigma), None
    for _ in range(3):
        half = int(np.clip(np.ceil(4.0 * start), 3, int(np.ceil(4.0 * MAX_SIGMA_PX))))
        wider = _fit_widths(image, x, y, background, half, start, det.noise_adu, gain)
        if wider is None:
            break
        fit = wider
        if 4.0 * _median(fit[3]) <= half + 0.5:
            break
        start = _median(fit[3])
    return fit


def _estimate_from_fits(fit, prior_sigma: float, faint: bool) -> PsfEstimate:
    """Return the PSF of the round stars among the fitted ones (_fit_stars' result), or the prior with the reason."""
    fx, fy, flux, width, windows = fit
    # Round enough to be the optics' PSF (axis ratio < MAX_AXIS_RATIO): smeared stars, blends
    # in one footprint and cosmic-ray tracks out. Judged on the pixelated shape (C + I/12): with
    # the pixel term removed, a faint undersampled star's noisy minor axis goes to ~0 and any
    # such star looked elongated (sigma 0.4 px at SNR ~11: 4 of 11 "round").
    # Faint stars (`faint`) weighed over their own width, not twice it: a weight 2 sigma wide takes
    # in 4x the sky of their footprint, whose noise left 0-4 of 5-12 faint rings (SNR ~11, sigma
    # 3 px) rounder than MAX_AXIS_RATIO: too few for an estimate on three of four bench frames.
    weight_sigma = max((1.0 if faint else 2.0) * _median(width), 1.5)
    moments = _weighted_moments(windows, fx, fy, weight_sigma)
    # Roundness judged on each star's own shape (adaptive moments: an elliptical weight matched
    # to the star): a round weight as wide as twice the round fit's width takes in sky beside a
    # streak, whose noise and any background offset round it. Unaided 13.7 px streaks of a 1 px
    # PSF (2 deg/s, 0.1 s) measured axis ratios of 1.4-2.6 so, and a frame of them was estimated
    # at sigma 3.4 px; their own shapes give 3.7-7.8 (two parallel streaks in one window, 1.5-2.9).
    shape = _adaptive_axis_ratio(windows, fx, fy, _median(width))
    round_ = shape < MAX_AXIS_RATIO
    # And more round than elongated ones (a shape the noise left unmeasurable, inf, is
    # neither): where most are elongated the frame is smeared, and its least elongated stars are
    # blends of streaks and short ones, not the optics' PSF.
    elongated = int((np.isfinite(shape) & ~round_).sum())
    if round_.sum() < MIN_STARS or round_.sum() <= elongated:
        # Mostly elongated: the stars show the motion (or tracks); too few round ones: too few
        # stars. Neither is evidence against the prior: emptied, a sparse jitter mission's running
        # 2.6 px fell to the configured 1 px for its last 10 frames (3 of 5 stars round), 15-75"
        # off or lost (stress campaign, seed 2026, task 462 frames 30-39).
        return PsfEstimate.assumed(prior_sigma, "prior", f"{int(round_.sum())} of {width.size} stars round (axis "
                                   f"ratio < {MAX_AXIS_RATIO:g}; need {MIN_STARS}), {elongated} elongated: smeared "
                                   f"or blended", int(round_.sum()), holds_prior=True)
    width = width[round_]
    sigma = _median(width)
    spread = 1.4826 * _median(np.abs(width - sigma))
    uncertainty = 1.2533 * spread / np.sqrt(width.size)  # a median's 1-sigma: sqrt(pi/2) x the mean's
    if not MIN_SIGMA_PX <= sigma <= MAX_SIGMA_PX:
        return PsfEstimate.assumed(prior_sigma, "prior", f"estimated PSF sigma {sigma:.2f} px is outside the "
                                   f"supported [{MIN_SIGMA_PX}, {MAX_SIGMA_PX}] px", int(width.size))
    # The median star's moments (element-wise): their flux-weighted sum, which one odd star can
    # pull, made a round Moffat PSF 1.46x elongated on one of four bench frames (1.02-1.07 so).
    total = np.median(moments[round_], axis=0)
    ratio, angle = _axes(total[None], weight_sigma)
    # Unmeasurable weighted moments (long streaks on a sky ramp): the stars' own shapes, not round.
    # Stress task 479: 18 px streaks of a 2.5 px PSF read round at 4.4 px, no spot a streak.
    ratio = float(ratio[0]) if np.isfinite(ratio[0]) else _median(shape[round_])
    annular = _is_ring(windows, fx, fy, round_, sigma)
    return PsfEstimate(sigma, float(sigma * np.sqrt(ratio)), float(sigma / np.sqrt(ratio)), float(angle[0]),
                       float(uncertainty), int(width.size), "estimated", annular=annular)


def _is_ring(windows, x, y, use: np.ndarray, sigma: float) -> bool:
    """
    Whether the stars `use` of the fit windows are rings (see RING_CENTRE_RATIO).

    Light within 0.5 sigma of each fitted centre over light at 1-1.5 sigma, the median over
    the stars, against the same ratio of a Gaussian of width sigma [px] (exp(-r^2 / 2 sigma^2)
    averaged over each zone). Needs a PSF of at least 1 px (an undersampled ring is not told
    from a Gaussian) and both zones holding pixels.
    """
    if sigma < 1.0:
        return False
    data, valid, col0, row0 = windows
    size = data.shape[1]
    dx = (col0[use, None] + np.arange(size)) - x[use, None]
    dy = (row0[use, None] + np.arange(size)) - y[use, None]
    r = np.hypot(dy[:, :, None], dx[:, None, :]) / sigma
    ok = valid[use]
    centre, ring = ok & (r < 0.5), ok & (r >= 1.0) & (r < 1.5)
    if not centre.any() or not ring.any():
        return False
    light = np.where(ok, data[use], 0.0)
    # Per star, then the median: a hot pixel or cosmic ray in one window must not decide.
    with np.errstate(divide="ignore", invalid="ignore"):
        centre_mean = (light * centre).sum(axis=(1, 2)) / centre.sum(axis=(1, 2))
        ring_mean = (light * ring).sum(axis=(1, 2)) / ring.sum(axis=(1, 2))
    judged = (centre.sum(axis=(1, 2)) > 0) & (ring_mean > 0)
    if not judged.any():
        return False
    measured = float(np.median(centre_mean[judged] / ring_mean[judged]))
    gaussian = np.exp(-0.5 * r[centre] ** 2).mean() / np.exp(-0.5 * r[ring] ** 2).mean()
    return bool(measured < RING_CENTRE_RATIO * gaussian)


def _median(values: np.ndarray) -> float:
    """Return the median of a few values (np.median's overhead is most of the cost at this size)."""
    ordered = np.sort(values)
    n = ordered.size
    return float(0.5 * (ordered[(n - 1) // 2] + ordered[n // 2]))


def _fit_widths(image, x, y, background, half: int, start: float, noise: float, gain: float):
    """
    Free-width fits of the stars at (x, y) [px] on (2 half + 1)^2 windows.

    The converged stars' x, y, flux, width (sigma [px]) and their windows (data, valid, col0,
    row0), keeping widths of at least SHARPEST_STAR_PX; None when fewer than MIN_STARS remain.
    """
    size = 2 * half + 1
    col0, row0 = np.rint(x).astype(np.int64) - half, np.rint(y).astype(np.int64) - half
    # Hot pixels out (one in a star's window would narrow its fit), judged against the sharpest
    # PSF supported, so that no star the estimate could report is touched; cleaned on windows a
    # pixel larger, so that the border pixels are judged against their true neighbours.
    raw, valid = gather_windows(image, col0 - 1, row0 - 1, size + 2)
    data, _ = clean_hot_pixels(np.where(valid, raw - background[:, None, None], 0.0), valid, noise,
                               2.0 * star_peak_to_neighbour_ratio(MIN_SIGMA_PX))
    data, valid = np.ascontiguousarray(data[:, 1:-1, 1:-1]), np.ascontiguousarray(valid[:, 1:-1, 1:-1])
    flux0 = np.maximum(data.sum(axis=(1, 2)), 1.0)
    fx, fy, flux, width, _, _, ok, offset = fit_psf_width(data, valid, col0.astype(float), row0.astype(float),
                                                          x.copy(), y.copy(), flux0, np.full(x.size, start),
                                                          float(noise), float(gain), 30)
    keep = ok & (width >= SHARPEST_STAR_PX) & (flux > 0)
    if keep.sum() < MIN_STARS:
        return None
    # The windows' shapes (roundness, elongation, rings) are measured without the background the
    # fit found left in them: under a weight wider than the star a constant offset dominates the
    # moments (a 12-bit sensor at 16 e-/ADU: a median background off by up to half an ADU, faint
    # stars' weighted moments negative, a round 1 px PSF read 3.8x elongated).
    data, valid = data[keep], valid[keep]
    data = np.where(valid, data - offset[keep, None, None], 0.0)
    return fx[keep], fy[keep], flux[keep], width[keep], (data, valid, col0[keep], row0[keep])


ADAPTIVE_ITERATIONS = 12  # adaptive moments' (half-step) weight updates: ratios within 0.1 % of 60 updates'
MIN_WEIGHT_PX = 1.5  # the adaptive weight's narrowest 1-sigma [px]: sampled well enough by the pixels


def _adaptive_axis_ratio(windows, x, y, start: float) -> np.ndarray:
    """
    Return each star's axis ratio sigma_major / sigma_minor [-] of its pixelated shape from adaptive moments.

    The weight is an elliptical Gaussian matched to the star (covariance W, from start^2 I,
    `start` [px]): the moments M under it give the star's covariance (C + I/12) =
    (M^-1 - W^-1)^-1 for a Gaussian (2M where the noise leaves the difference not positive
    definite); the next weight goes half way to it (eigenvalues kept within [MIN_WEIGHT_PX^2,
    (window half size)^2]), ADAPTIVE_ITERATIONS times. About the fitted centres (x, y) [px].
    inf where no shape is measurable (no positive weighted light).
    """
    data, valid, col0, row0 = windows
    k, size = data.shape[0], data.shape[1]
    light = np.where(valid, data, 0.0)
    dx = (col0[:, None] + np.arange(size)) - x[:, None]  # (k, S) columns
    dy = (row0[:, None] + np.arange(size)) - y[:, None]  # (k, S) rows
    xx, yy = dx[:, None, :], dy[:, :, None]  # (k, 1, S), (k, S, 1)
    lo, hi = MIN_WEIGHT_PX ** 2, max(0.5 * (size - 1), MIN_WEIGHT_PX) ** 2
    a = np.full(k, np.clip(start ** 2, lo, hi))  # weight covariance [[a, c], [c, b]]
    b, c = a.copy(), np.zeros(k)
    shape = np.stack([a, b, c])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(ADAPTIVE_ITERATIONS):
            det = a * b - c * c
            ia, ib, ic = b / det, a / det, -c / det  # W^-1
            q = ia[:, None, None] * xx * xx + ib[:, None, None] * yy * yy + 2.0 * ic[:, None, None] * xx * yy
            weighted = light * np.exp(-0.5 * q)
            total = weighted.sum(axis=(1, 2))
            mxx = (weighted * xx * xx).sum(axis=(1, 2)) / total
            myy = (weighted * yy * yy).sum(axis=(1, 2)) / total
            mxy = (weighted * xx * yy).sum(axis=(1, 2)) / total
            mdet = mxx * myy - mxy * mxy
            # (M^-1 - W^-1)^-1
            pa, pb, pc = myy / mdet - ia, mxx / mdet - ib, -mxy / mdet - ic
            pdet = pa * pb - pc * pc
            ok = (total > 0) & (mdet > 0) & (pdet > 0) & (pa > 0)
            na, nb, nc = np.where(ok, pb / pdet, 2.0 * mxx), np.where(ok, pa / pdet, 2.0 * myy), \
                np.where(ok, -pc / pdet, 2.0 * mxy)
            shape = np.stack([na, nb, nc])
            # The next weight: the shape, its axes kept within [lo, hi].
            mean, spread = 0.5 * (na + nb), np.sqrt(0.25 * (na - nb) ** 2 + nc * nc)
            major, minor = np.clip(mean + spread, lo, hi), np.clip(mean - spread, lo, hi)
            angle = 0.5 * np.arctan2(2.0 * nc, na - nb)
            cos2, sin2, cs = np.cos(angle) ** 2, np.sin(angle) ** 2, np.cos(angle) * np.sin(angle)
            good = np.isfinite(major) & np.isfinite(minor) & np.isfinite(angle) & (total > 0)
            # Half way there: a full step can oscillate on a noisy star.
            a = np.where(good, 0.5 * (a + major * cos2 + minor * sin2), a)
            b = np.where(good, 0.5 * (b + major * sin2 + minor * cos2), b)
            c = np.where(good, 0.5 * (c + (major - minor) * cs), c)
        na, nb, nc = shape
        mean, spread = 0.5 * (na + nb), np.sqrt(0.25 * (na - nb) ** 2 + nc * nc)
        major, minor = mean + spread, mean - spread
        ratio = np.sqrt(major / minor)
    return np.where(np.isfinite(ratio) & (minor > 0) & (total > 0), ratio, np.inf)


def _weighted_moments(windows, x, y, weight_sigma: float) -> np.ndarray:
    """
    Return each star's Gaussian-weighted second moments M (k, 2, 2) [px^2].

    The moments are about its fitted centre (x, y) [px] (weight 1-sigma weight_sigma [px], wider
    than the PSF so that the product is well sampled by the pixels).
    """
    data, valid, col0, row0 = windows
    size = data.shape[1]
    dx = (col0[:, None] + np.arange(size)) - x[:, None]  # (k, S) columns
    dy = (row0[:, None] + np.arange(size)) - y[:, None]  # (k, S) rows
    gx, gy = np.exp(-0.5 * dx * dx / weight_sigma ** 2), np.exp(-0.5 * dy * dy / weight_sigma ** 2)
    weight = np.where(valid, data, 0.0) * gy[:, :, None] * gx[:, None, :]
    row_sums, col_sums = weight.sum(axis=2), weight.sum(axis=1)  # (k, S) each
    total = row_sums.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mxx = np.sum(col_sums * dx * dx, axis=1) / total
        myy = np.sum(row_sums * dy * dy, axis=1) / total
        mxy = np.einsum("ki,kij,kj->k", dy, weight, dx) / total
    moments = np.empty((x.size, 2, 2))
    moments[:, 0, 0], moments[:, 1, 1] = mxx, myy
    moments[:, 0, 1] = moments[:, 1, 0] = mxy
    return moments


def _axes(moments: np.ndarray, weight_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the axis ratio sigma_major / sigma_minor [-] and major axis angle [rad] of the pixelated PSF.

    The ratio is inf when not measurable, the angle in (-pi/2, pi/2], from Gaussian-weighted
    moments (k, 2, 2): for a Gaussian of covariance C, pixelated (C + I/12), such moments are
    M = ((C + I/12)^-1 + I/w^2)^-1, so C + I/12 = (M^-1 - I/w^2)^-1 (w = weight_sigma [px]).
    The axes are those of C + I/12: with the pixel term taken off, a faint undersampled star's
    noisy minor axis goes to ~0 and any such star looks elongated.
    """
    def inverse(a, b, c):  # of the symmetric [[a, c], [c, b]], and whether it is positive definite
        det = a * b - c * c
        return b / det, a / det, -c / det, np.isfinite(det) & (det > 0) & (a > 0)

    with np.errstate(invalid="ignore", divide="ignore"):
        a, b, c, ok = inverse(moments[:, 0, 0], moments[:, 1, 1], moments[:, 0, 1])
        a, b, c, ok2 = inverse(a - weight_sigma ** -2, b - weight_sigma ** -2, c)
        spread = np.sqrt(0.25 * (a - b) ** 2 + c * c)
        major, minor = 0.5 * (a + b) + spread, 0.5 * (a + b) - spread
        ratio = np.where(ok & ok2 & (minor > 0), np.sqrt(major / minor), np.inf)
        angle = 0.5 * np.arctan2(2.0 * c, a - b)
    return ratio, np.where(np.isfinite(angle), angle, 0.0)
