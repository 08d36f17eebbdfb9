# SPDX-License-Identifier: Apache-2.0
"""
Streak-model fits of the stage's spots.

A free line segment, or the path predicted from a known body rate; on that path one spot per
star (two detections whose fits end on one star leave one) and the split of streaks merged
into one detection.
"""
from __future__ import annotations

from dataclasses import fields, replace
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..detection.candidates import Candidates
from ..config import elongation_limit
from ..detection.measure import clean_hot_pixels, star_peak_to_neighbour_ratio
from ..records import FitContext, FitOutcome, FittedStars, SpotRows, no_spots
from .smear import segment_length
from ..spots import FLAG_BLENDED, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK
from .fit_common import StreakFit, StreakImage
from .free_fit import fit_streaks
from .groups import fit_star_groups_on_path, second_source_on_path
from .path_fit import fit_streaks_on_path

if TYPE_CHECKING:
    from .smear import SmearModel

# Merged streaks: when the residual of a fit on the predicted path holds a further star at a
# matched-filter SNR of MERGED_MIN_SNR or more, whose path comes within MERGED_OVERLAP_SIGMA
# PSF sigmas of the spot's, the spot is refitted with that star added (up to MERGED_MAX_STARS
# per spot); the larger group is kept when it lowers chi^2 on the same window by more than
# MERGED_MIN_DCHI2 (three more parameters, searched over the window: chance alone gives
# ~10-15).
MERGED_MIN_SNR = 5.0
MERGED_MIN_DCHI2 = 25.0
MERGED_MAX_STARS = 3
MERGED_OVERLAP_SIGMA = 5.0
# One star, two detections: fits on the predicted path that end within COINCIDENT_SIGMA PSF
# sigmas of each other and within their own errors (separation d, d^T (C_a + C_b)^-1 d <=
# COINCIDENT_CHI2) measured one star. Its detections were a streak the threshold cut in two, or
# a hot pixel's or a cosmic ray's detection beside a streak whose window holds the star's
# light. In 100 stress tumble frames such pairs lay 0.003-0.5 px apart at chi^2 0.03-2.9 (a
# faint streak's along-track sigma reaches ~1.3 px); pairs of distinct stars within 2.5 px, at
# chi^2 >= 89.
COINCIDENT_SIGMA = 1.0
COINCIDENT_CHI2 = 9.0


def fit_streak_spots(context: FitContext, kept: Candidates, spots: SpotRows, which: np.ndarray,
                     smear: "SmearModel | None", excluded: np.ndarray | None = None) -> FitOutcome:
    """
    Streak-model fit of spots `which`.

    On the predicted path when `smear` is given (flags STREAK | RATE_AIDED), else a free line
    segment seeded from the spot's moments (STREAK); pixels `excluded` (clipped; None = none)
    are left out. On the predicted path, fits of two spots that end on one star leave one spot
    (one_fit_per_star: the other gets SNR 0), and a spot whose fit leaves another star's light is
    refitted with it (split_merged_streaks), the stars split off returned as added spots. A
    spot the model cannot describe gets SNR 0 (dropped) when it should be a streak (rate
    aided, or elongated) unless it is saturated, else keeps its centroid.
    """
    sigma = context.sigma
    reach = streak_reach(kept, spots, which, smear, sigma)
    if smear is not None:
        reach = 2.0 * reach  # room for a merged neighbour's path (a pair's window covers both)
    residual = streak_residual(context, spots.x[which], spots.y[which], reach)
    x, y, flux = spots.x[which], spots.y[which], spots.flux[which]
    if smear is not None:
        path = smear.path(x, y)
        image = StreakImage(residual, sigma, context.noise, context.gain, excluded)
        fit, path, duplicate = one_fit_per_star(image, fit_streaks_on_path(image, x, y, flux, path), x, y, path, smear)
        fit_flag = FLAG_STREAK | FLAG_RATE_AIDED
    else:
        length0 = segment_length(kept.major[which], sigma)
        fit = fit_streaks(StreakImage(residual, sigma, context.noise, context.gain, excluded), x, y, flux, length0,
                          kept.angle[which])
        fit_flag = FLAG_STREAK
        duplicate = np.zeros(which.size, bool)
    good = fit.converged
    t = which[good]
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = fit.flux[good] / fit.flux_sigma[good]  # the fit's (matched-filter) SNR
    spots = spots.with_values(t, x=fit.x[good], y=fit.y[good], flux=fit.flux[good], cov=fit.cov[good],
                              length=fit.length[good], angle=np.nan_to_num(fit.angle[good]),
                              flags=spots.flags[t] | fit_flag, snr=snr)
    added = no_spots()
    if smear is not None and good.any():
        spots, added = split_merged_streaks(context, residual, fit, which, path, spots, excluded)[:2]
    # A spot the streak model could not describe is not reported when it should be a streak
    # (rate aided, or elongated: a fragment or a defect); a point-like one keeps its centroid.
    # So does a saturated one: a clipped star is the brightest in its field (a bloomed 8-bit
    # star's flat top often fits no streak), kept with a covariance as wide as the spot.
    failed = which[~good]
    elongated = kept.major[failed] > elongation_limit(sigma)
    clipped = (spots.flags[failed] & FLAG_SATURATED) != 0
    spots = spots.with_values(failed[(elongated | (smear is not None)) & ~clipped], snr=0.0)
    # A second detection of a star another spot measures is no spot (one_fit_per_star).
    spots = spots.with_values(which[duplicate], snr=0.0)
    return FitOutcome(spots, added)


def one_fit_per_star(image: StreakImage, fit: "StreakFit", x0, y0, path: np.ndarray,
                     smear: "SmearModel") -> tuple["StreakFit", np.ndarray, np.ndarray]:
    """
    One fit per star of fits on the predicted path started at (x0, y0) (paths `path` (n, K, 2)).

    Converged fits that end within COINCIDENT_SIGMA PSF sigmas and COINCIDENT_CHI2 of one
    another measured the same star, each in a window its own start placed. One of them stands
    for the star: the one started nearest the group's mean end, refitted from that mean (its
    window the star's own, its pixels read once; its own fit kept if the refit fails or leaves
    the group); the others are duplicates, unconverged in the returned fit. Returns the fit,
    the paths (the refitted ones' at their new start) and the (n,) duplicate mask.
    """
    duplicate = np.zeros(fit.x.size, bool)
    ok = np.flatnonzero(fit.converged)
    if ok.size < 2:
        return fit, path, duplicate
    tree = cKDTree(np.column_stack([fit.x[ok], fit.y[ok]]))
    pairs = tree.query_pairs(COINCIDENT_SIGMA * image.sigma, output_type="ndarray")
    if pairs.size:
        a, b = ok[pairs[:, 0]], ok[pairs[:, 1]]
        dx, dy = fit.x[a] - fit.x[b], fit.y[a] - fit.y[b]
        c = fit.cov[a] + fit.cov[b]
        with np.errstate(all="ignore"):  # a singular covariance: NaN, no pair
            chi2 = ((c[:, 1, 1] * dx * dx - (c[:, 0, 1] + c[:, 1, 0]) * dx * dy + c[:, 0, 0] * dy * dy)
                    / (c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0]))
        pairs = pairs[chi2 <= COINCIDENT_CHI2]
    if pairs.size == 0:
        return fit, path, duplicate
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(ok.size, ok.size))
    _, group = connected_components(graph, directed=False)
    members = np.unique(pairs)  # the fits in a group of two or more
    kept = []
    for g in np.unique(group[members]):
        rows = ok[group == g]
        mx, my = fit.x[rows].mean(), fit.y[rows].mean()
        rep = rows[np.argmin(np.hypot(x0[rows] - mx, y0[rows] - my))]
        duplicate[rows[rows != rep]] = True
        kept.append((rep, mx, my))
    rep, mx, my = (np.array(v) for v in zip(*kept))
    again = smear.path(mx, my, samples=path.shape[1])
    refit = fit_streaks_on_path(image, mx, my, fit.flux[rep], again)
    better = refit.converged & (np.hypot(refit.x - mx, refit.y - my) <= COINCIDENT_SIGMA * image.sigma)
    columns = {}
    for name in (f.name for f in fields(StreakFit)):
        column = getattr(fit, name).copy()
        column[rep[better]] = getattr(refit, name)[better]
        columns[name] = column
    columns["converged"][duplicate] = False
    path = path.copy()
    path[rep[better]] = again[better]
    return replace(fit, **columns), path, duplicate


def split_merged_streaks(context: FitContext, residual: np.ndarray, fit: "StreakFit", which: np.ndarray,
                         path: np.ndarray, spots: SpotRows, excluded: np.ndarray | None) -> FitOutcome:
    """
    Several stars on one predicted path (streaks merged into one detection, or a neighbour's streak in the window).

    The one-star fit of such a spot is pulled toward the other stars far beyond its
    covariance. Spots `which` with one-star fit `fit` (path (n, K, 2)) whose residual holds
    another star (MERGED_*) are refitted jointly with it, seeded at the matched-filter peak
    of the residual, as long as that helps. When a group wins, its first star (the spot's
    own) replaces the spot (flag BLENDED, covariance of the joint fit) and the others are
    added spots unless they are spots already (within 2 px) or below min_snr.
    """
    k = np.flatnonzero(fit.converged)
    group = _grow_star_groups(context, residual, fit, path[k], excluded)
    gx, gy, gf, gs, gcov = group.x, group.y, group.flux, group.flux_sigma, group.cov
    split = np.flatnonzero(np.isfinite(gx[:, 1:]).any(axis=1)) if gx.shape[1] > 1 else np.zeros(0, np.int64)
    t = which[k[split]]
    x, y = spots.x.copy(), spots.y.copy()  # positions so far: the spots' and the split-off stars'
    added_x, added_y, added_at, added_peak = [], [], [], []  # split-off stars: (group, star) and peak [ADU]
    for j, spot in zip(split, t):
        # Star 0 is the spot's own (its window, started from its fit); the others are neighbours.
        x[spot], y[spot] = gx[j, 0], gy[j, 0]
        for m in np.flatnonzero(np.isfinite(gx[j]))[1:]:
            star_snr = gf[j, m] / gs[j, m]
            others = np.hypot(np.r_[x, added_x] - gx[j, m], np.r_[y, added_y] - gy[j, m])
            others[spot] = np.inf
            # Not a spot (or a split-off star) already.
            if star_snr >= context.config.min_snr and not np.any(others < 2.0):
                row = int(np.clip(np.rint(gy[j, m]), 0, residual.shape[0] - 1))
                col = int(np.clip(np.rint(gx[j, m]), 0, residual.shape[1] - 1))
                added_x.append(gx[j, m])
                added_y.append(gy[j, m])
                added_at.append((j, m))
                added_peak.append(float(residual[row, col]))
    spots = spots.with_values(t, x=gx[split, 0], y=gy[split, 0], flux=gf[split, 0], cov=gcov[split, 0],
                              snr=gf[split, 0] / gs[split, 0], flags=spots.flags[t] | FLAG_BLENDED)
    if not added_at:
        return FitOutcome(spots, no_spots())
    j, m = np.array(added_at).T
    stars = FittedStars(added_x, added_y, gf[j, m], gcov[j, m], gf[j, m] / gs[j, m])
    return FitOutcome(spots, SpotRows.split_off(stars, added_peak, FLAG_STREAK | FLAG_RATE_AIDED | FLAG_BLENDED,
                                                fit.length[k[j]], np.nan_to_num(fit.angle[k[j]])))


class _StarGroups(NamedTuple):
    """
    Stars fitted jointly on one path, one row per spot.

    One column per star of its group (NaN: no such star; column 0 the spot's own): x, y
    [px], flux, flux_sigma [ADU] (n, M), cov (n, M, 2, 2) [px^2].
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    flux_sigma: np.ndarray
    cov: np.ndarray


def _grow_star_groups(context: FitContext, residual, fit: "StreakFit", path, excluded) -> _StarGroups:
    """
    Star groups of the converged one-star fits `fit` (paths `path` (n, K, 2)).

    One star more while the residual holds one (MERGED_*) and the joint fit lowers chi^2
    enough.
    """
    sigma, noise, gain = context.sigma, context.noise, context.gain
    k = np.flatnonzero(fit.converged)
    gx, gy, gf, gs = fit.x[k][:, None], fit.y[k][:, None], fit.flux[k][:, None], fit.flux_sigma[k][:, None]
    gcov = fit.cov[k][:, None]
    chi2 = fit.chi2[k].copy()
    growing = np.ones(k.size, bool)
    for stars in range(1, MERGED_MAX_STARS):
        tried = np.flatnonzero(growing)
        if tried.size == 0:
            break
        image = StreakImage(residual, sigma, noise, gain, excluded)
        sx, sy, sf, found = second_source_on_path(image, gx[tried, :stars], gy[tried, :stars], gf[tried, :stars],
                                                  path[tried])
        # Only a star whose image overlaps the spot's own (its path within MERGED_OVERLAP_SIGMA
        # PSF sigmas of the spot's path somewhere) can pull the fit; others merely share the window.
        offset = np.stack([sx - gx[tried, 0], sy - gy[tried, 0]], axis=1)
        chords = path[tried][:, :, None, :] - path[tried][:, None, :, :]  # (n, K, K, 2): o_a - o_b
        gap = np.min(np.linalg.norm(offset[:, None, None, :] - chords, axis=3), axis=(1, 2))
        seeded = (found >= MERGED_MIN_SNR) & (sf > 0) & (gap <= MERGED_OVERLAP_SIGMA * sigma)
        tried, sx, sy, sf = tried[seeded], sx[seeded], sy[seeded], sf[seeded]
        growing[:] = False
        if tried.size == 0:
            break
        fits = fit_star_groups_on_path(image, np.column_stack([gx[tried, :stars], sx]),
                                       np.column_stack([gy[tried, :stars], sy]),
                                       np.column_stack([gf[tried, :stars], sf]), path[tried])
        better = fits[0].converged & (chi2[tried] - fits[0].chi2 > MERGED_MIN_DCHI2)
        if not better.any():
            break
        won = tried[better]
        growing[won] = True
        pad = lambda a: np.concatenate([a, np.full((a.shape[0], 1) + a.shape[2:], np.nan)], axis=1)  # noqa: E731
        gx, gy, gf, gs, gcov = pad(gx), pad(gy), pad(gf), pad(gs), pad(gcov)
        for m, f in enumerate(fits):
            gx[won, m], gy[won, m], gf[won, m] = f.x[better], f.y[better], f.flux[better]
            gs[won, m], gcov[won, m] = f.flux_sigma[better], f.cov[better]
        chi2[won] = fits[0].chi2[better]
    return _StarGroups(gx, gy, gf, gs, gcov)


def streak_reach(kept: Candidates, spots: SpotRows, which: np.ndarray, smear: "SmearModel | None",
                 sigma: float) -> np.ndarray:
    """
    Half size [px] of the region each streak fit may read.

    Half the predicted (or measured) streak length plus the PSF's reach and slack for the
    window the fitter builds.
    """
    if smear is not None:
        half_length = 0.5 * np.linalg.norm(smear.smear_vectors(spots.x[which], spots.y[which]), axis=1)
    else:
        half_length = np.sqrt(np.maximum(np.nan_to_num(3.0 * kept.major[which]), 0.0))  # NaN: no extent
    return half_length * 1.2 + 5.0 * sigma + 4.0


def streak_residual(context: FitContext, x, y, reach) -> np.ndarray:
    """
    Background-subtracted, hot-pixel-cleaned float32 image for the streak fits.

    The whole frame when there are many streaks (two OpenCV passes), else only square
    regions of half size `reach` [px] around (x, y), the rest left at 0 (the fits read
    nothing else).
    """
    image, det, noise = context.image, context.det, context.noise
    height, width = image.shape
    b = det.binning
    ratio_limit = 2.0 * star_peak_to_neighbour_ratio(context.sigma)
    if x.size > 20:
        full_bg = cv2.resize(det.background, (det.background.shape[1] * b, det.background.shape[0] * b),
                             interpolation=cv2.INTER_NEAREST)
        residual = image.astype(np.float32)
        h, w = min(full_bg.shape[0], height), min(full_bg.shape[1], width)
        residual[:h, :w] -= full_bg[:h, :w]
        residual[h:, :] -= det.background[-1, -1]  # odd sizes: the last row/column
        residual[:h, w:] -= det.background[-1, -1]
        cleaned, _ = clean_hot_pixels(residual[None], np.ones((1,) + residual.shape, bool), noise, ratio_limit)
        return cleaned[0].astype(np.float32, copy=False)
    residual = np.zeros((height, width), np.float32)
    grid_h, grid_w = det.background.shape
    for cx, cy, r in zip(x, y, reach):
        if not (np.isfinite(cx) and np.isfinite(cy)):
            continue
        # One pixel more than the fit reads, so that its border pixels have true neighbours.
        top, bottom = max(int(cy - r) - 1, 0), min(int(cy + r) + 2, height)
        left, right = max(int(cx - r) - 1, 0), min(int(cx + r) + 2, width)
        if top >= bottom or left >= right:
            continue
        bg = det.background[np.clip(np.arange(top, bottom) // b, 0, grid_h - 1)[:, None],
                            np.clip(np.arange(left, right) // b, 0, grid_w - 1)[None, :]]
        region = image[top:bottom, left:right].astype(np.float32) - bg
        cleaned, _ = clean_hot_pixels(region[None], np.ones((1,) + region.shape, bool), noise, ratio_limit)
        residual[top:bottom, left:right] = cleaned[0]
    return residual
