# SPDX-License-Identifier: Apache-2.0
"""
The sub-pixel fits a measured frame calls for, and its spot table.

Per spot the model its shape calls for (frame_fits routes): blends fitted jointly (their
cosmic-ray track peaks fitted and dropped), streaks (free, or on the path a rate aid predicts),
point PSFs (the frame's single-star model; clipped stars without their clipped pixels; point
and streak fits without the pixels sharper than the PSF, detection.sharp_pixels), then
the stars whose fit shows a clipped core refitted; the table scaled to the local noise, cut at
min_snr and max_spots, brightest first.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .config import elongation_limit
from .detection.candidates import Candidates
from .detection.saturation import clipped_pixels, undershot_peaks
from .detection.sharp_pixels import sharp_pixels
from .detection.texture import rank_last, texture_streaks
from .frame_measurement import Clipping, FrameMeasurement
from .psf.point_fits import fit_blends, fit_clipped_points, fit_points, own_centres
from .records import FitContext, SpotRows, no_spots
from .spots import FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, Spots
from .streak.smear import segment_length
from .streak.streak_spots import fit_streak_spots
from .tracks.beside_tracks import refit_beside_tracks

if TYPE_CHECKING:
    from .streak.smear import SmearModel


def fitted_spots(measurement: FrameMeasurement) -> Spots:
    """Return the measurement's spots: its sub-pixel fits (the method's) run, the spot table assembled."""
    if measurement.frame is None:
        return measurement.empty
    m = measurement
    spots, added, clipping, fit_model = m.spots, [], m.clipping, ""
    if m.context.config.method not in ("cog", "wcog"):
        spots, added, clipping, fit_model = _fit_spots(m)
    wide = np.flatnonzero(clipping.saturated & ~clipping.fitted)
    if wide.size:
        spots = spots.with_values(wide, cov=m.kept.moment_covariance(wide))
    result = _assemble(m.context, SpotRows.concatenate([spots, *added]), m.rejected_shape, m.frame_values, fit_model)
    return replace(result, rate_aid_rejected=True) if m.rate_aid_rejected else result


class _Routes(NamedTuple):
    """
    Which fit each spot of a measurement goes to, (n,) bool each.

    as_streak: the streak model; as_point: a point PSF; clipped_point: a point PSF without its
    clipped pixels; round_frame: the frame's well-measured spots are round (no smear, _round_frame).
    """

    as_streak: np.ndarray
    as_point: np.ndarray
    clipped_point: np.ndarray
    round_frame: bool


def _routes(m: FrameMeasurement) -> _Routes:
    """Route each spot by the method, its shape (elongated or not), blends and clipping."""
    config, kept, multi, aid = m.context.config, m.kept, m.multi, m.aid
    n = len(m.spots)
    saturated = m.clipping.saturated
    elongated = kept.major > elongation_limit(m.context.sigma)  # beyond the PSF (a segment of length L adds L^2/12)
    if config.method == "streak" or (aid is not None and config.method == "auto"):
        as_streak = np.ones(n, bool)
    elif config.method == "auto":
        as_streak = elongated.copy()
    else:  # gaussian: streaks keep the centre of gravity
        as_streak = np.zeros(n, bool)
    as_streak &= ~multi
    # In a frame whose well-measured stars are round, a faint spot's elongation is its noise:
    # measured as a streak it gains the flux of the noise along the fitted segment and outranks
    # real stars (real photographs' dark frames). Such spots are measured as points.
    noise_elongated = np.zeros(n, bool)
    round_frame = aid is None and _round_frame(kept, elongated, saturated, multi)
    if round_frame and config.method == "auto":
        noise_elongated = elongated & ~multi & ~saturated & (kept.snr < STATIC_STREAK_MIN_SNR)
        as_streak &= ~noise_elongated
    # On a sensor that blooms, a clipped star's footprint runs along its column with the spill:
    # in a frame not smeared it is a point, fitted without its clipped pixels and their spill
    # (the streak model often fails on it, leaving the frame's brightest star a covariance as
    # wide as its footprint).
    bloom_elongated = np.zeros(n, bool)
    if config.method == "auto" and config.sensor_blooms and saturated.any() and not _smeared_frame(m):
        along_column = np.abs(np.sin(kept.angle)) > np.cos(BLOOM_ANGLE_RAD)
        bloom_elongated = elongated & ~multi & saturated & along_column
        as_streak &= ~bloom_elongated
    as_point = ~as_streak & (~elongated | noise_elongated | bloom_elongated) & ~multi
    clipped_point = as_point & saturated
    as_point &= ~saturated
    return _Routes(as_streak, as_point, clipped_point, round_frame)


def _smeared_frame(m: FrameMeasurement) -> bool:
    """
    Whether most well-measured spots are streaks (or a rate aid predicts them).

    In a smeared frame a spot with several peaks is streaks crossing stars or streaks, which
    point-PSF fits would misplace: it keeps its centre of gravity with a covariance as wide as
    the spot itself (its second moments).
    """
    kept, multi = m.kept, m.multi
    elongated = kept.major > elongation_limit(m.context.sigma)
    clear = (kept.snr >= 20) & ~m.clipping.saturated
    return m.aid is not None or (np.sum(elongated & clear & ~multi) >= max(5, 0.5 * np.sum(clear)))


def _fit_spots(m: FrameMeasurement) -> tuple[SpotRows, list[SpotRows], Clipping, str]:
    """
    Return the fits the method calls for.

    Blends (their track peaks, m.track_peaks (tracks.peak_shape.blends_beside_tracks), fitted
    and dropped), streaks (on the predicted path with the rate aid; in a frame of round stars
    those the streak model failed on join the points), point PSFs (clipped ones without their
    clipped pixels), then the refit of spots whose fit shows a clipped core. Returns the spot
    table, the stars split off, the clipping state and the single stars' fit model
    (Spots.fit_model).
    """
    context, kept, spots, clipping, multi, aid = m.context, m.kept, m.spots, m.clipping, m.multi, m.aid
    track_peaks = m.track_peaks or {}
    # Saturated (clipped), a blend with a track is not fitted: its star is measured by its own
    # pixels at the end (_own_brightest_stars).
    beside_track = np.array([t for t in track_peaks if not multi[t]], np.int64)
    saturated = clipping.saturated
    as_streak, as_point, clipped_point, round_frame = _routes(m)
    added, fitted = [], clipping.fitted.copy()
    # Point and streak fits leave out the clipped pixels and those sharper than the PSF (hot pixels on starlight).
    excluded = _with_sharp_pixels(context, kept, spots, as_point | as_streak, clipping.excluded)
    fitted_blends = False  # blends fitted star by star (fit_blends), not left at their centres of gravity
    if multi.any() and (_smeared_frame(m) or not context.config.split_blends):
        spots = spots.with_values(np.flatnonzero(multi), cov=kept.moment_covariance(np.flatnonzero(multi)))
        # The footprint's centre would hold the track: its brightest star, model-free (no point
        # fit in a smeared frame).
        spots = _own_brightest_stars(spots, np.array([t for t in track_peaks if multi[t]], np.int64), track_peaks)
    elif multi.any():
        spots, more = fit_blends(context, kept, spots, np.flatnonzero(multi), track_peaks)[:2]
        added.append(more)
        fitted_blends = True
    if as_streak.any():
        spots, more = fit_streak_spots(context, kept, spots, np.flatnonzero(as_streak), aid, excluded)[:2]
        added.append(more)
        fitted |= as_streak & ((spots.flags & FLAG_STREAK) != 0)
        if round_frame:
            # An elongated spot the streak model failed on, in a frame of round stars, may be a star
            # whose footprint merged with a cosmic-ray track's (its moments stretched by the track's
            # footprint): measured with the point spots, in the frame's point model.
            as_point |= as_streak & (spots.snr <= 0) & ~saturated
    fit_model = ""
    if as_point.any():
        outcome = fit_points(context, kept, spots, np.flatnonzero(as_point), excluded)
        spots, more, fit_model = outcome.spots, outcome.added, outcome.model
        added.append(more)
        if outcome.psf is not None and fitted_blends:  # beside_tracks.py: the frame's model, not the Gaussian
            peaks = {t: (kept.peaks[t], track) for t, (track, _) in track_peaks.items() if multi[t]}
            spots = refit_beside_tracks(context, peaks, spots, outcome.psf, excluded)
    if clipped_point.any():
        outcome = fit_clipped_points(context, spots, np.flatnonzero(clipped_point), clipping.excluded)
        spots, fitted[clipped_point] = outcome.spots, outcome.converged
    path_fitted = (spots.flags & FLAG_RATE_AIDED) != 0
    probe = np.flatnonzero(~saturated & ~multi & ((as_point & (spots.snr > 0)) | path_fitted))
    spots, more, clipping = _refit_undershot(context, kept, spots, replace(clipping, fitted=fitted), probe, aid)
    # A clipped blend with a track: its star's own pixels (nearer its peak than the track's)
    # measure it. A track's charge can read as a clipped flat top (several pixels tied at its
    # maximum), so the star beside it is often not saturated at all.
    spots = _own_brightest_stars(spots, beside_track, track_peaks)
    return spots, added + [more], clipping, fit_model


def _with_sharp_pixels(context: FitContext, kept: Candidates, spots: SpotRows, which: np.ndarray,
                       excluded: np.ndarray | None) -> np.ndarray | None:
    """
    Return `excluded` (H, W) bool (None: none) with the pixels sharper than the PSF in the windows of spots `which`.

    detection.sharp_pixels; a streak's window reaches half its length (from its second moments) along it.
    """
    which = np.flatnonzero(which)
    length = np.minimum(segment_length(np.nan_to_num(kept.major[which]), context.sigma), MAX_SHARP_REACH_PX)
    sharp = sharp_pixels(context, spots.x[which], spots.y[which],
                         context.window_half + np.ceil(0.5 * length).astype(np.int64))
    if sharp is None:
        return excluded
    return sharp if excluded is None else excluded | sharp


def _own_brightest_stars(spots: SpotRows, rows: np.ndarray, track_peaks: dict) -> SpotRows:
    """Spots `rows` (blends with tracks) replaced by their brightest star's own-pixel centre; none: dropped."""
    for t in rows.tolist():
        stars, _ = own_centres(*track_peaks[t])
        spots = (spots.with_stars(np.array([t]), stars.take(slice(0, 1))) if stars.x.size
                 else spots.with_values(np.array([t]), snr=0.0))
    return spots


MAX_SHARP_REACH_PX = 128.0  # a streak's length searched for sharp pixels at most [px] (a track's moments can run away)

# A clipped star's footprint whose major axis lies within BLOOM_ANGLE_RAD of its column is
# elongated by its bloom spill (config.sensor_blooms).
BLOOM_ANGLE_RAD = np.radians(15.0)

# A frame is judged static (its stars round) from at least ROUND_FRAME_MIN_SPOTS spots of SNR >=
# ROUND_FRAME_MIN_SNR, unsaturated and single-peaked, of which fewer than half are elongated;
# there, elongated spots below STATIC_STREAK_MIN_SNR are measured as points.
ROUND_FRAME_MIN_SNR = 10.0
ROUND_FRAME_MIN_SPOTS = 2
STATIC_STREAK_MIN_SNR = 10.0


def _round_frame(kept: Candidates, elongated: np.ndarray, saturated: np.ndarray, multi: np.ndarray) -> bool:
    """Whether the frame's well-measured spots show round stars (no smear): see ROUND_FRAME_*."""
    clear = (kept.snr >= ROUND_FRAME_MIN_SNR) & ~saturated & ~multi
    count = int(clear.sum())
    return count >= ROUND_FRAME_MIN_SPOTS and int((elongated & clear).sum()) < 0.5 * count


def _refit_undershot(context: FitContext, kept: Candidates, spots: SpotRows, clipping: Clipping,
                     probe: np.ndarray, aid: "SmearModel | None") -> tuple[SpotRows, SpotRows, Clipping]:
    """
    Flag and refit the stars clipped in a single pixel (no flat top, but their fit shows it).

    The model at its brightest pixel exceeds the data there by many sigmas. The fitted spots
    `probe` that show it are flagged SATURATED and refitted without their clipped pixels.
    """
    path_fitted = (spots.flags & FLAG_RATE_AIDED) != 0
    level = undershot_peaks(context, kept.detection[probe], spots.take(probe),
                            aid.path(spots.x[probe], spots.y[probe]) if aid is not None and probe.size else None)
    hit = probe[np.isfinite(level)]
    if hit.size == 0:
        return spots, no_spots(), clipping
    clip, fitted = clipping.level.copy(), clipping.fitted.copy()
    clip[hit] = level[np.isfinite(level)]
    spots = spots.with_values(hit, flags=spots.flags[hit] | FLAG_SATURATED)
    more = clipped_pixels(context, kept.detection[hit], clip[hit])
    excluded = more if clipping.excluded is None else clipping.excluded | more
    points, streaks = hit[~path_fitted[hit]], hit[path_fitted[hit]]
    added = no_spots()
    if points.size:
        outcome = fit_clipped_points(context, spots, points, excluded)
        spots, fitted[points] = outcome.spots, outcome.converged
    if streaks.size:
        spots, added = fit_streak_spots(context, kept, spots, streaks, aid, excluded)[:2]
        fitted[streaks] = spots.snr[streaks] > 0
    return spots, added, Clipping(clip, excluded, fitted)


def runs_past_border(spots: SpotRows, width: int, height: int) -> np.ndarray:
    """
    Return True for the streaks whose fitted segment runs past the image border (flagged EDGE).

    The light beyond the border is lost; a faint streak's fit on the part left can be pulled
    px across its track at a stated tenth of that (stress campaign, seed 2026, task 2217 frame 31:
    a 19 px streak half past the border at SNR 6, fitted 1.9 px across it at 0.24 px). Its
    footprint ends at the border, so the detection's edge test does not see it.
    """
    streak = ((spots.flags & FLAG_STREAK) != 0) & (spots.length > 0)
    half = 0.5 * np.where(streak, spots.length, 0.0)
    dx, dy = np.abs(half * np.cos(spots.angle)), np.abs(half * np.sin(spots.angle))
    past = (spots.x - dx < -0.5) | (spots.x + dx > width - 0.5) | (spots.y - dy < -0.5) | (spots.y + dy > height - 0.5)
    return streak & past


def _assemble(context: FitContext, spots: SpotRows, rejected_shape: int, frame_values: dict,
              fit_model: str = "") -> Spots:
    """
    `Spots` from the measured table (fit_model: Spots.fit_model).

    SNR and covariance scaled to the local noise, spots outside the image or below min_snr
    dropped, the brightest max_spots kept, by flux (config.texture_last: texture after the others).
    """
    config = context.config
    height, width = context.image.shape
    # Measurements above used the frame's typical pixel noise; where stray light makes the local
    # noise higher (or lower), scale the SNR and covariance by the local/typical variance ratio.
    local = context.local_noise_factor(spots.x, spots.y, spots.flux)
    snr, cov = spots.snr / np.sqrt(local), spots.cov * local[:, None, None]
    # A centre of gravity of a window summing to ~0 can land anywhere: a position outside the
    # image measured nothing in it.
    x, y = spots.x, spots.y
    inside = (x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5)
    final = np.flatnonzero((snr >= config.min_snr) & inside)
    order = final[np.argsort(-spots.flux[final], kind="stable")]
    if config.texture_last:  # texture.py: the point-like spots kept first, the kept ones brightest first
        texture = texture_streaks(spots.flags[order], spots.angle[order])
        if texture.any():
            order = order[np.sort(rank_last(np.arange(order.size), texture)[: config.max_spots])]
    order = order[: config.max_spots]
    flags = spots.flags | np.where(runs_past_border(spots, width, height), FLAG_EDGE, 0).astype(spots.flags.dtype)
    return Spots(x=x[order], y=y[order], flux=spots.flux[order], snr=snr[order], cov=cov[order],
                 flags=flags[order], area=spots.area[order].astype(np.int32), peak=spots.peak[order],
                 width=width, height=height, rejected_shape=rejected_shape, streak_length=spots.length[order],
                 streak_angle=spots.angle[order], fit_model=fit_model, **frame_values)
