# SPDX-License-Identifier: Apache-2.0
"""
PSF fits of point-like spots.

Single stars (with the frame's empirical PSF where the Gaussian misfits its bright stars),
two stars in one point window, blends of several peaks in one footprint, and saturated stars
fitted on their unclipped wings.
"""
from __future__ import annotations

import numpy as np

from ..detection.candidates import Candidates
from ..config import blend_separation_px
from .empirical import MIN_TEMPLATE_STARS, SMOOTHING_PX, EmpiricalPsf, build_empirical_psf, fit_empirical
from ..detection.measure import clean_hot_pixels, secondary_peaks, star_peak_to_neighbour_ratio
from ..windows import PsfStart, PsfWindows, gather_windows
from .gaussian_fit import PsfFit, fit_psf_windows
from ..detection.hidden_neighbours import HIDDEN_MIN_SNR, hidden_neighbour_peaks, hidden_window_half
from ..records import FitContext, FitOutcome, FittedStars, SpotRows, no_spots
from .single_star_model import fit_frame_model, window_shares
from ..spots import FLAG_BLENDED


def cleaned_windows(context: FitContext, col0, row0, size: int, x, y):
    """
    Background-subtracted (n, size, size) windows with hot pixels cleaned, top-left pixel (col0, row0) [px].

    The background is the plane of the map at the spots' positions x, y (n,) [px]
    (detect.BackgroundPlane); cleaned on windows one pixel larger, so that a hot pixel on the
    border is judged against its true neighbours. Returns data and mask.
    """
    col0, row0 = np.asarray(col0) - 1, np.asarray(row0) - 1
    raw, valid = gather_windows(context.image, col0, row0, size + 2)
    plane = context.det.background_plane_at(x, y, context.config.background_block_px)
    background = plane.over_window(col0, row0, size + 2)
    win, _ = clean_hot_pixels(np.where(valid, raw - background, 0.0), valid,
                              context.noise, 2.0 * star_peak_to_neighbour_ratio(context.sigma))
    return win[:, 1:-1, 1:-1], valid[:, 1:-1, 1:-1]


def fit_points(context: FitContext, kept: Candidates, spots: SpotRows, which: np.ndarray,
               excluded: np.ndarray | None = None) -> FitOutcome:
    """
    Gaussian PSF fit of point-like spots `which`.

    Those whose window shows a second peak get a joint 2-PSF fit (flag BLENDED; kept when it
    determines both stars, _determined, and the brighter has min_snr), the second star
    returned as an added spot unless it is a spot already or below min_snr; in a frame the
    round Gaussian describes, so do bright stars whose fit leaves a fainter star in its
    residual (detection/hidden_neighbours.py; kept when both have min_snr). Pixels
    `excluded` (a neighbour's clipped core; None = none) are left out of the fits. The single
    stars are fitted with the frame's model (single_star_model), or its empirical PSF where
    the Gaussian does not describe the frame (_template_fits).
    """
    windows = _point_windows(context, kept, spots, which, excluded)
    blended = np.zeros(which.size, bool)
    added = no_spots()
    if context.config.split_blends:
        spots, added, blended = _fit_second_stars(context, spots, which, windows)
    single = np.flatnonzero(~blended)
    if single.size == 0:
        return FitOutcome(spots, added)
    sigma, noise, gain = context.sigma, context.noise, context.gain
    alone = PsfWindows(*(a[single] for a in windows))
    start = PsfStart(spots.x[which[single]][:, None], spots.y[which[single]][:, None],
                     spots.flux[which[single]][:, None])
    fit = fit_psf_windows(alone, start, sigma, noise, gain)
    # Only round spots: an elongated one is smeared (no body rate known) or a blend, which the
    # symmetric Gaussian centres better than a centre of gravity.
    round_ = kept.major[which[single]] <= MISFIT_MAX_ELONGATION ** 2 * kept.minor[which[single]]
    model, fit = fit_frame_model(context, alone, fit, start, round_)
    not_gaussian = _misfits(*alone, fit, context, model)
    misfit = not_gaussian & round_
    converged = fit.converged[:, 0] & ~misfit
    good = np.flatnonzero(converged)
    spots = spots.with_stars(which[single[good]], psf_stars(fit, good, 0))
    # Enough bright stars the Gaussian does not describe (round or elongated alike: an
    # astigmatic PSF): the frame's own PSF fits every one.
    rows, stars, template = _template_fits(context, alone, fit, not_gaussian, spots.x[which[single]],
                                           spots.y[which[single]])
    label = "gaussian" if model is None else model.label
    if rows.size:
        spots = spots.with_stars(which[single[rows]], stars)
        label, model = "template", template
    elif model is None and context.config.split_blends:
        spots, more = _fit_hidden_neighbours(context, spots, which[single[good]], fit.flux[good, 0] / np.sqrt(
            np.abs(fit.flux_var[good, 0])), excluded)
        added = SpotRows.concatenate([added, more])
    return FitOutcome(spots, added, None, label, model)


def _fit_hidden_neighbours(context: FitContext, spots: SpotRows, which: np.ndarray, snr: np.ndarray,
                           excluded: np.ndarray | None) -> tuple[SpotRows, SpotRows]:
    """
    Fit bright single stars `which` (flux SNR `snr`) with a fainter star their residual shows.

    detection/hidden_neighbours.py finds it, searched in windows hidden_window_half wide around
    the fitted star (a fit window ends where such a neighbour's light is). Returns the spots
    and the stars added.
    """
    which = which[snr >= HIDDEN_MIN_SNR]
    if which.size == 0:
        return spots, no_spots()
    half = hidden_window_half(context.sigma)
    x, y = spots.x[which], spots.y[which]
    col0, row0 = np.rint(x).astype(np.int64) - half, np.rint(y).astype(np.int64) - half
    win, valid = cleaned_windows(context, col0, row0, 2 * half + 1, x, y)
    if excluded is not None:
        clipped, _ = gather_windows(excluded, col0, row0, 2 * half + 1)
        valid &= clipped == 0
    windows = PsfWindows(win, valid, col0, row0)
    model = spots.flux[which][:, None, None] * window_shares(None, col0, row0, x, y, 2 * half + 1, context.sigma)
    peaks = hidden_neighbour_peaks(context, windows, x, y, model)
    if not peaks[0].any():
        return spots, no_spots()
    spots, added, _ = _fit_second_stars(context, spots, which, windows, peaks)
    return spots, added


def _point_windows(context: FitContext, kept: Candidates, spots: SpotRows, which: np.ndarray,
                   excluded: np.ndarray | None) -> PsfWindows:
    """
    Return the fit windows of the spots `which`, hot pixels cleaned, `excluded` pixels not valid.

    Windows measured already (small spots, centred on their peak) are reused, cropped to the
    fit window around the same centre pixel; the others are cut around the spot.
    """
    half = context.window_half
    size = 2 * half + 1
    x, y = spots.x, spots.y
    crop = (kept.window.shape[1] - size) // 2
    win = kept.window[which][:, crop:crop + size, crop:crop + size].copy()
    valid = kept.window_valid[which][:, crop:crop + size, crop:crop + size].copy()
    col0, row0 = kept.window_col0[which] + crop, kept.window_row0[which] + crop
    fresh = np.flatnonzero(~kept.has_window[which])
    if fresh.size:
        col0[fresh] = np.rint(x[which[fresh]]).astype(np.int64) - half
        row0[fresh] = np.rint(y[which[fresh]]).astype(np.int64) - half
        win[fresh], valid[fresh] = cleaned_windows(context, col0[fresh], row0[fresh], size, x[which[fresh]],
                                                   y[which[fresh]])
    if excluded is not None:
        clipped, _ = gather_windows(excluded, col0, row0, size)
        valid &= clipped == 0
    return PsfWindows(win, valid, col0, row0)


def _fit_second_stars(context: FitContext, spots: SpotRows, which: np.ndarray, windows: PsfWindows,
                      peaks: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                      ) -> tuple[SpotRows, SpotRows, np.ndarray]:
    """
    Fit two PSFs where a spot's window shows a second star; return the spots, the stars added, which blended.

    peaks: (found, row, col) per window, the second star's pixel; None: a second peak
    (secondary_peaks). Given (a hidden neighbour, detection/hidden_neighbours.py), the pair is kept only
    when the second star too has min_snr.
    """
    config, sigma, noise, gain = context.config, context.sigma, context.noise, context.gain
    win, valid, col0, row0 = windows
    size = win.shape[1]
    half = size // 2
    x, y, flux = spots.x, spots.y, spots.flux
    added = no_spots()
    hidden = peaks is not None
    if peaks is None:
        peaks = secondary_peaks(win, valid, half, config.detection_sigma * 3.0 * noise,
                                min_separation=blend_separation_px(sigma, context.rings), radius=half - 1.5,
                                gain=gain, noise=noise)
    found, pr, pc = peaks
    px, py = col0 + pc, row0 + pr
    blended = found
    if blended.any():
        b = np.flatnonzero(blended)
        # A second peak that is another detected spot is fitted jointly but not reported
        # twice (distances from the second peaks only: all pairs cost seconds on big frames).
        duplicate = np.zeros(which.size, bool)
        if x.size > 1:
            others = np.hypot(px[b, None] - x[None, :], py[b, None] - y[None, :])
            others[np.arange(b.size), which[b]] = np.inf
            duplicate[b] = others.min(axis=1) < 2.0
        bx0 = np.column_stack([x[which[b]], px[b].astype(float)])
        by0 = np.column_stack([y[which[b]], py[b].astype(float)])
        bf0 = np.column_stack([flux[which[b]], np.maximum(win[b, pr[b], pc[b]] * 2 * np.pi * sigma ** 2, 1.0)])
        fit = fit_psf_windows(PsfWindows(win[b], valid[b], col0[b], row0[b]), PsfStart(bx0, by0, bf0), sigma,
                              noise, gain)
        # Two stars only if the brighter one stands out on its own: a split that leaves both
        # below min_snr is one non-Gaussian star (a defocused ring's two sides), not a pair.
        snr = fit.flux / np.sqrt(np.abs(fit.flux_var))
        both = fit.converged.all(axis=1) & _determined(fit, size) & (snr.max(axis=1) >= config.min_snr)
        if hidden:
            both &= snr.min(axis=1) >= config.min_snr
        blended[b[~both]] = False
        j, k = np.flatnonzero(both), b[both]
        t = which[k]
        spots = spots.with_stars(t, psf_stars(fit, j, 0), flags=spots.flags[t] | FLAG_BLENDED)
        second = psf_stars(fit, j, 1)
        new = ~duplicate[k] & (second.snr >= config.min_snr)
        k = k[new]
        added = SpotRows.split_off(second.take(new), win[k, pr[k], pc[k]], FLAG_BLENDED)
    return spots, added, blended


def _template_fits(context: FitContext, windows: PsfWindows, fit: PsfFit, misfit: np.ndarray, x, y
                   ) -> tuple[np.ndarray, FittedStars, "EmpiricalPsf | None"]:
    """
    Fit the single-star windows with the frame's empirical PSF, where the Gaussian does not describe the frame.

    That is where MIN_TEMPLATE_STARS or more bright stars misfit (`misfit`), at least
    TEMPLATE_MIN_SHARE of the bright ones (flux SNR >= MISFIT_MIN_SNR); or, in a frame of
    ring stars (context.rings), where MIN_TEMPLATE_STARS are bright. Never where
    context.own_psf is False. The profile is built from those stars; every window is fitted
    with it, from the Gaussian fit's position where it converged, else from (x, y), unless it
    scatters the bright stars (_scatters_stars). Returns the windows fitted (indices), their
    stars and the profile (None when none was built or used).
    """
    win, valid, col0, row0 = windows
    empty = np.zeros(0, np.int64), FittedStars(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 2, 2)),
                                               np.zeros(0)), None
    if not context.own_psf:
        return empty
    with np.errstate(divide="ignore", invalid="ignore"):
        bright = fit.converged[:, 0] & (fit.flux[:, 0] / np.sqrt(np.abs(fit.flux_var[:, 0])) >= MISFIT_MIN_SNR)
    # The PSF's shape is the frame's: many bright stars misfit (a few: smear onset, blends; 6 of 54).
    template = misfit if misfit.sum() >= TEMPLATE_MIN_SHARE * bright.sum() else np.zeros_like(misfit)
    smoothing, faint = SMOOTHING_PX, False
    if template.sum() < MIN_TEMPLATE_STARS and context.rings:  # a ring the Gaussian fits within its noise
        template = bright
        if bright.sum() < MIN_TEMPLATE_STARS:  # faint rings: the profile pools more of them
            with np.errstate(divide="ignore", invalid="ignore"):
                snr = fit.flux[:, 0] / np.sqrt(np.abs(fit.flux_var[:, 0]))
            template = fit.converged[:, 0] & (snr >= RING_TEMPLATE_MIN_SNR)
            if template.sum() < RING_TEMPLATE_MIN_STARS:
                return empty
            smoothing, faint = max(SMOOTHING_PX, FAINT_RING_SMOOTHING_SIGMAS * context.sigma), True
    if template.sum() < MIN_TEMPLATE_STARS:
        return empty
    start_x = np.where(fit.converged[:, 0], fit.x[:, 0], x)
    start_y = np.where(fit.converged[:, 0], fit.y[:, 0], y)
    m = np.flatnonzero(template)
    psf = build_empirical_psf(PsfWindows(win[m], valid[m], col0[m], row0[m]), start_x[m], start_y[m], context.noise,
                              context.gain, smoothing, round_=faint)
    if psf is None:
        return empty
    flux0 = np.where(valid, win, 0.0).sum(axis=(1, 2))
    start = PsfStart(start_x, start_y, np.where(fit.converged[:, 0], fit.flux[:, 0], flux0))
    fx, fy, flux, cov, flux_var, ok = fit_empirical(psf, windows, start, context.noise, context.gain)
    if _scatters_stars(fx, fy, cov, fit, ok & bright):
        return empty
    rows = np.flatnonzero(ok)
    return rows, FittedStars(fx[rows], fy[rows], flux[rows], cov[rows], flux[rows] / np.sqrt(flux_var[rows])), psf


def _scatters_stars(fx, fy, cov, fit: PsfFit, bright: np.ndarray) -> bool:
    """
    Whether a profile's fits move the bright stars from their Gaussian fits in differing directions beyond their noise.

    A profile that describes the stars moves each of them from its Gaussian fit by the two
    models' difference in centre (the same for every star of one PSF: a coma's offset) and
    noise of the order of its stated sigma: median shift less the frames' median shift, in
    stated sigmas, 0.5-2.0 on the real corpus's and the second renderer's template frames.
    One built from stars that share no shape (their misfits a hot-pixel storm's pixels, a
    blur that differs across the field) moved every bright star 0.1-0.3 px in its own
    direction at a stated 0.005-0.02 px: 5-23 sigmas (stress campaign, seed 2026, tasks 1278
    and 265). Beyond TEMPLATE_MAX_SCATTER the profile is not used. Needs
    TEMPLATE_SCATTER_MIN_STARS bright stars fitted by both.
    """
    both = np.flatnonzero(bright & fit.converged[:, 0])
    if both.size < TEMPLATE_SCATTER_MIN_STARS:
        return False
    dx, dy = fx[both] - fit.x[both, 0], fy[both] - fit.y[both, 0]
    sigma = np.sqrt(np.maximum(0.5 * (cov[both, 0, 0] + cov[both, 1, 1]), 1e-12))
    scatter = np.hypot(dx - np.median(dx), dy - np.median(dy)) / sigma
    return bool(np.median(scatter) > TEMPLATE_MAX_SCATTER)


MISFIT_MIN_SNR = 30.0  # fainter spots' residuals are noise whatever the PSF
MISFIT_CHI2 = 4.0  # reduced chi^2 of a fit the model does not describe ...
MISFIT_RESIDUAL = 0.1  # ... with a residual this large a fraction of the model (norm): not PRNU's 1 %
MISFIT_MAX_ELONGATION = 1.2  # ... and a spot no more elongated than this (axis ratio of its moments)
# Faint ring frames: a profile from RING_TEMPLATE_MIN_STARS stars whose Gaussian fit reads this
# SNR (below a ring's own: SNR-11 rings of sigma 3 px read 6-12) ...
RING_TEMPLATE_MIN_SNR = 7.0
RING_TEMPLATE_MIN_STARS = 15  # ... (noise pooled over their pixels)
# ... smoothed over this x the PSF sigma (over 0.3 px, as bright frames' profiles: 1.2-1.6x the
# bound on SNR-11 rings of sigma 3 px; over 0.25 sigma 1.0-1.2x: their edges are as soft)
FAINT_RING_SMOOTHING_SIGMAS = 0.25
TEMPLATE_MIN_SHARE = 0.25  # the empirical PSF replaces the Gaussian when this share of the bright stars misfit
TEMPLATE_MAX_SCATTER = 4.0  # ... unless it moves them apart by more than this many stated sigmas (_scatters_stars)
TEMPLATE_SCATTER_MIN_STARS = 3  # judged on at least this many bright stars


def _misfits(win, valid, col0, row0, fit: PsfFit, context: FitContext, psf_model=None) -> np.ndarray:
    """
    Return the single-PSF fits (bool per window) that the frame's PSF model does not describe.

    psf_model: the round Gaussian (None), or the frame's own shape (any model with `sample`:
    the elliptical Gaussian of an astigmatic frame, the core/halo of one with wings). A PSF
    it does not describe (a defocused ring, strong coma): bright (flux SNR >=
    MISFIT_MIN_SNR), reduced chi^2 above MISFIT_CHI2 and a residual norm above
    MISFIT_RESIDUAL of the model's. Such a spot keeps its model-free centre of gravity (and
    its phase-bias covariance) instead.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        bright = fit.converged[:, 0] & (fit.flux[:, 0] / np.sqrt(np.abs(fit.flux_var[:, 0])) >= MISFIT_MIN_SNR)
    out = np.zeros(bright.size, bool)
    k = np.flatnonzero(bright)
    if k.size == 0:
        return out
    share = window_shares(psf_model, col0[k], row0[k], fit.x[k, 0], fit.y[k, 0], win.shape[1], context.sigma)
    model = fit.flux[k, 0][:, None, None] * share
    use = valid[k]
    residual = np.where(use, win[k] - model, 0.0)
    chi2 = np.sum(residual ** 2 / (np.maximum(model, 0.0) / context.gain + context.noise ** 2), axis=(1, 2))
    chi2 /= np.maximum(use.sum(axis=(1, 2)) - 3, 1)
    relative = np.sqrt(np.sum(residual ** 2, axis=(1, 2)) / np.sum(np.where(use, model, 0.0) ** 2, axis=(1, 2)))
    out[k] = (chi2 > MISFIT_CHI2) & (relative > MISFIT_RESIDUAL)
    return out


TRACK_PULL_SIGMAS = 1.0  # a star fitted beside a track: its largest offset from its pixels' centre (x sigma, >= 1 px)


def fit_blends(context: FitContext, kept: Candidates, spots: SpotRows, which: np.ndarray,
               track_peaks: dict | None = None) -> FitOutcome:
    """
    Joint fit of one PSF per peak over the footprint window of each blended spot `which`.

    The brightest star replaces the spot, the others above min_snr are added spots. A blend
    whose fit fails (not converged, or a star undetermined: _determined) keeps its centre of
    gravity. track_peaks: blend index -> ((K,) bool, its
    peaks that are cosmic-ray tracks; their peak_shape.PeakShapes):
    tracks are fitted with the stars, never a star; a star fitted more than TRACK_PULL_SIGMAS
    x sigma (>= 1 px) from its own pixels' centre of gravity, or every star when the fit fails,
    is measured by that centre of gravity instead (_stars_beside_track); with no star left the
    blend is dropped (SNR 0): its centre of gravity holds the track.
    """
    sigma, noise, gain = context.sigma, context.noise, context.gain
    track_peaks = track_peaks or {}
    margin = int(np.ceil(3.0 * sigma)) + 2
    fitted, first_stars, others, other_peaks, dropped = [], [], [], [], []
    for t in which:
        peaks = kept.peaks[t]
        left = int(np.floor(peaks[:, 0].min())) - margin
        top = int(np.floor(peaks[:, 1].min())) - margin
        size = int(max(np.ptp(peaks[:, 0]), np.ptp(peaks[:, 1]))) + 2 * margin + 1
        win, valid = cleaned_windows(context, np.array([left]), np.array([top]), size, peaks[:1, 0], peaks[:1, 1])
        amplitude = win[0, (peaks[:, 1] - top).astype(int), (peaks[:, 0] - left).astype(int)]
        flux0 = np.maximum(amplitude * 2.0 * np.pi * sigma ** 2, 1.0)
        fit = fit_psf_windows(PsfWindows(win, valid, np.array([left]), np.array([top])),
                              PsfStart(peaks[None, :, 0], peaks[None, :, 1], flux0[None]), sigma, noise, gain)
        converged = bool(fit.converged[0].all() and _determined(fit, size)[0])
        if not converged and t not in track_peaks:
            continue  # keep the centre of gravity, flagged as a blend
        if t in track_peaks:
            stars, order = _stars_beside_track(fit, converged, *track_peaks[t], max(TRACK_PULL_SIGMAS * sigma, 1.0))
            if order.size == 0:
                dropped.append(t)
                continue
        else:
            order = np.argsort(-fit.flux[0])  # brightest first
            stars = FittedStars(fit.x[0, order], fit.y[0, order], fit.flux[0, order], fit.cov[0, order],
                                fit.flux[0, order] / np.sqrt(fit.flux_var[0, order]))
        fitted.append(t)
        first_stars.append(stars.take(slice(0, 1)))
        bright = 1 + np.flatnonzero(stars.snr[1:] >= context.config.min_snr)
        others.append(stars.take(bright))
        other_peaks.append(amplitude[order[bright]])
    if fitted:
        spots = spots.with_stars(np.array(fitted), FittedStars.concatenate(first_stars))
    if dropped:
        spots = spots.with_values(np.array(dropped), snr=0.0)
    if not others:
        return FitOutcome(spots, no_spots())
    return FitOutcome(spots, SpotRows.split_off(FittedStars.concatenate(others), np.concatenate(other_peaks),
                                                FLAG_BLENDED))


def _determined(fit: PsfFit, size: int) -> np.ndarray:
    """
    Whether each window's joint fit determined every star (n,): light > 0, position variances finite and <= size^2.

    A star fitted with no light leaves its position to nothing and the joint covariance
    singular: its neighbour's position variance came out at 1e23 px^2 on a real frame, and
    that one spot's match gate took in every star of the image.
    """
    variance = np.concatenate([fit.cov[..., 0, 0], fit.cov[..., 1, 1]], axis=1)
    return (np.all(fit.flux > 0, axis=1) & np.all(np.isfinite(fit.cov), axis=(1, 2, 3))
            & np.all(variance <= size * size, axis=1))


def _stars_beside_track(fit: PsfFit, converged: bool, track: np.ndarray, shapes, pull_px: float):
    """
    Return (stars brightest first, their peak indices) of a blend fitted with cosmic-ray `track` peaks.

    Tracks are never stars. A star the fit placed more than pull_px [px] from its own pixels'
    centre of gravity (pulled by the track's light, which no PSF describes), or every star
    when the fit failed, is measured model-free: that centre of gravity, its noise covariance,
    flux and SNR (peak_shape.PeakShapes).
    """
    if not converged:
        return own_centres(track, shapes)
    order = np.argsort(-fit.flux[0])
    order = order[~track[order]]
    centre = shapes.centre[order]
    pulled = np.hypot(fit.x[0, order] - centre[:, 0], fit.y[0, order] - centre[:, 1]) > pull_px
    own = pulled & np.isfinite(shapes.centre_cov[order]).all(axis=(1, 2)) & (shapes.flux[order] > 0)
    keep = own | ~pulled
    order, own, centre = order[keep], own[keep], centre[keep]
    with np.errstate(divide="ignore", invalid="ignore"):
        fitted_snr = fit.flux[0, order] / np.sqrt(fit.flux_var[0, order])
    stars = FittedStars(np.where(own, centre[:, 0], fit.x[0, order]), np.where(own, centre[:, 1], fit.y[0, order]),
                        np.where(own, shapes.flux[order], fit.flux[0, order]),
                        np.where(own[:, None, None], shapes.centre_cov[order], fit.cov[0, order]),
                        np.where(own, shapes.snr[order], fitted_snr))
    resorted = np.argsort(-stars.flux, kind="stable")
    return stars.take(resorted), order[resorted]


def own_centres(track: np.ndarray, shapes) -> tuple[FittedStars, np.ndarray]:
    """
    Return (stars brightest first, their peak indices): the model-free measure of a blend's non-track peaks.

    Each star's own pixels' centre of gravity, its noise covariance, flux and SNR
    (peak_shape.PeakShapes); peaks with no positive flux left out.
    """
    order = np.argsort(-shapes.flux)
    order = order[~track[order] & (shapes.flux[order] > 0) & np.isfinite(shapes.centre_cov[order]).all(axis=(1, 2))]
    return FittedStars(shapes.centre[order, 0], shapes.centre[order, 1], shapes.flux[order],
                       shapes.centre_cov[order], shapes.snr[order]), order


def psf_stars(fit: PsfFit, rows: np.ndarray, source: int) -> FittedStars:
    """Source `source` of the PSF fits `rows` as FittedStars (SNR = flux / its 1-sigma)."""
    return FittedStars(fit.x[rows, source], fit.y[rows, source], fit.flux[rows, source], fit.cov[rows, source],
                       fit.flux[rows, source] / np.sqrt(fit.flux_var[rows, source]))


def fit_clipped_points(context: FitContext, spots: SpotRows, which: np.ndarray, excluded: np.ndarray) -> FitOutcome:
    """
    PSF fit of saturated point-like spots `which` without their clipped pixels (`excluded`).

    The wings alone fix the centre, and the inverse Fisher information of those pixels is its
    covariance. The window is the point window grown by the clipped core's radius. converged:
    which of them the fit describes (the others keep their centre of gravity).
    """
    sigma, noise, gain = context.sigma, context.noise, context.gain
    x, y, flux = spots.x, spots.y, spots.flux
    cx, cy = np.rint(x[which]).astype(np.int64), np.rint(y[which]).astype(np.int64)
    ok = np.zeros(which.size, bool)
    probe = context.window_half
    core, _ = gather_windows(excluded, cx - probe, cy - probe, 2 * probe + 1)
    radius = np.ceil(np.sqrt(core.sum(axis=(1, 2)) / np.pi)).astype(np.int64)
    half_all = context.window_half + radius
    fitted = spots
    for half in np.unique(half_all):
        k = np.flatnonzero(half_all == half)
        size = 2 * int(half) + 1
        col0, row0 = cx[k] - half, cy[k] - half
        win, valid = cleaned_windows(context, col0, row0, size, x[which[k]], y[which[k]])
        clipped, _ = gather_windows(excluded, col0, row0, size)
        valid &= clipped == 0
        # The flux is linear in the model: start from the window's sum (the clipped core short).
        flux0 = np.maximum(np.where(valid, win, 0.0).sum(axis=(1, 2)), flux[which[k]])
        fit = fit_psf_windows(PsfWindows(win, valid, col0, row0),
                              PsfStart(x[which[k]][:, None], y[which[k]][:, None], flux0[:, None]), sigma, noise, gain)
        good = fit.converged[:, 0] & (valid.sum(axis=(1, 2)) > 6)
        fitted = fitted.with_stars(which[k[good]], psf_stars(fit, np.flatnonzero(good), 0))
        ok[k] = good
    return FitOutcome(fitted, no_spots(), ok)
