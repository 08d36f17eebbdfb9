# SPDX-License-Identifier: Apache-2.0
"""
Spot extraction, the centroiding stage.

Detect -> measure -> reject defects and extended objects -> sub-pixel fit (points, blends,
streaks) -> `Spots`.

Input: a 2-D image in ADU (uint8/uint16/float). Output: `Spots` in pixel coordinates with
(0, 0) at the centre of the top-left pixel, sorted by flux (brightest first). Optionally a
`SmearModel` (camera + body rate + exposure) turns on rate-aided detection and fitting.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .tracks.beside_tracks import refit_beside_tracks
from .detection.candidates import STREAK_COUNT_MIN_SIGMA_PX, Candidates, measure_candidates
from .config import CentroidConfig, elongation_limit, peak_fraction_limit
from .detection.detect import DetectionGround, Detections, background_tiles, detect, detection_ground
from .psf.elliptical import EllipticalGaussianPsf
from .detection.extended_objects import extended_candidates
from .detection.measure import cog_phase_bias_rms
from .tracks.peak_shape import KEPT_BLEND_TRACK_FRACTION, RING_BLEND_TRACK_FRACTION, peak_minor_moments, peak_width_limit
from .psf.point_fits import fit_blends, fit_clipped_points, fit_points, own_centres
from .psf.estimate import MAX_SIGMA_PX, MIN_SIGMA_PX, RERUN_TOLERANCE, SMEARED_ELONGATION, PsfEstimate, estimate_psf
from .psf.estimate import MAX_STARS as MAX_ESTIMATE_STARS
from .psf.estimate import MIN_STARS as MIN_ESTIMATE_STARS
from .psf.pilot import neighbour_positions, pilot_detections
from .streak.rate_aid import rate_aid_disagrees, smear_kernel, typical_smear_px
from .records import FitContext, SpotRows, no_spots
from .detection.saturation import clip_levels, clipped_pixels, undershot_peaks
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, Spots
from .streak.streak_spots import fit_streak_spots
from .detection.texture import point_every_way, rank_last, texture_streaks

if TYPE_CHECKING:
    from .streak.smear import SmearModel


# A frame with WIDER_PRIOR_MIN_CANDIDATES detections whose PSF could not be estimated for too
# few usable stars is measured again at these multiples of the prior width (up to MAX_SIGMA_PX),
# until one gives an estimate.
WIDER_PRIOR_FACTORS = (2.0, 3.0)
WIDER_PRIOR_MIN_CANDIDATES = 20
EMPIRICAL_MAX_SMEAR_PX = 0.5  # predicted smear [px] below which stars keep the optics' shape
# Only the FIT_CANDIDATES_PER_SPOT x max_spots brightest candidates (footprint flux) are fitted:
# the fits rank the spots by fitted flux and keep max_spots, and a deep photograph's thousands of
# faint detections would cost seconds of fits for spots never reported (margin for fitted flux
# reordering the footprint's; see _first_cut).
FIT_CANDIDATES_PER_SPOT = 3


@dataclass(frozen=True)
class _Clipping:
    """
    Clipped spots of a frame.

    Level (n,) raw level [ADU] from which each spot is clipped (inf: not clipped); excluded:
    (H, W) bool pixels no fit may use (None: none); fitted (n,): clipped spots measured by a
    fit without their clipped pixels.
    """

    level: np.ndarray
    excluded: np.ndarray | None
    fitted: np.ndarray

    @property
    def saturated(self) -> np.ndarray:
        return np.isfinite(self.level)


def extract_spots(image: np.ndarray, config: CentroidConfig = CentroidConfig(),
                  smear: "SmearModel | None" = None, psf_prior: float | None = None, prior_rings: bool = False
                  ) -> Spots:
    """
    Detect spots and measure them (see CentroidConfig).

    `smear`, when given, predicts each star's streak from the body rate and exposure:
    detection uses the matched streak kernel and positions come from a fit on the predicted
    path (mid-exposure, curved arcs included).

    PSF (config.psf_mode "auto"): the frame is measured with the prior width (`psf_prior` [px]
    when given, e.g. the last frames' estimate, else config.psf_sigma_px), its PSF estimated
    from the stars found (psf_estimate.estimate_psf), and, when the estimate differs from the
    prior by more than RERUN_TOLERANCE (relative), measured again with the estimate. A crowded
    frame without `psf_prior` is first measured at the prior for its brightest detections only
    (psf_pilot). `prior_rings` with `psf_prior`: the last frames' stars were rings (a defocused
    camera), so the first measurement already treats them so and, when the estimate agrees, is
    the only one. The returned Spots carry the estimate (`Spots.psf`, applied_sigma_px = the
    width used).
    """
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {image.shape}")
    if image.dtype.kind not in "uif":
        raise ValueError(f"expected a numeric image, got dtype {image.dtype}")
    grounds = _Grounds(image, config)
    if config.psf_mode == "fixed" or config.psf_sigma_px <= 0:
        return replace(_finish(_measure_frame(image, config, smear, grounds.at(config.psf_sigma_px))),
                       psf=PsfEstimate.assumed(config.psf_sigma_px, "configured"))
    prior, rings = config.psf_sigma_px, False
    if psf_prior is not None and np.isfinite(psf_prior) and MIN_SIGMA_PX <= psf_prior <= MAX_SIGMA_PX:
        prior, rings = float(psf_prior), bool(prior_rings)
    first = config if prior == config.psf_sigma_px else replace(config, psf_sigma_px=prior)
    guess = None  # the pilot's estimate (from a full set of stars when estimated)
    if smear is None:
        det = _detect(image, first, None, grounds.at(prior))
        # A running prior (the node's last estimates) is expected to hold: no pilot to waste.
        pilot = pilot_detections(image, det, prior) if psf_prior is None else None
        if pilot is not None:
            # Measured at the prior only to estimate the PSF: its brightest detections first. An
            # estimate from a full set of stars is the frame's; if it calls for another width, the
            # measurement at the prior is not needed. Too few stars: as without a pilot.
            trial = _measure_frame(image, first, None, grounds.at(prior), det=det.take(pilot)).frame
            if trial is not None:
                guess = estimate_psf(image, trial.det, trial.cand, trial.saturation, prior, config.gain_e_per_adu,
                                     neighbours=neighbour_positions(trial.cand, det, pilot),
                                     min_usable=MAX_ESTIMATE_STARS)
                if guess.estimated and _remeasured(guess, prior):
                    return _at_estimate(image, config, None, grounds, guess)
        measured = _measure_frame(image, first, None, grounds.at(prior), det=det, rings=rings)
    else:
        measured = _measure_frame(image, first, smear, grounds.at(prior), rings=rings)
    frame = measured.frame
    if frame is None:
        return replace(_finish(measured), psf=PsfEstimate.assumed(prior, "prior", "no detections"))
    if frame.smeared:
        return replace(_finish(measured),
                       psf=PsfEstimate.assumed(prior, "prior", "rate-aided frame: the stars are smeared"))
    estimate = guess if guess is not None and guess.estimated else \
        estimate_psf(image, frame.det, frame.cand, frame.saturation, prior, config.gain_e_per_adu)
    if not estimate.estimated and estimate.stars < MIN_ESTIMATE_STARS \
            and frame.cand.x.size >= WIDER_PRIOR_MIN_CANDIDATES:
        # Many detections but too few usable stars (not: usable ones all elongated, a smear): a
        # PSF much wider than the prior (a defocused camera's faint rings are fragments and
        # streaks at a narrow width, their light outside its apertures). Measured once more at a
        # wider width, estimated there (from fainter stars too: psf_estimate.FAINT_STAR_SNR).
        for factor in WIDER_PRIOR_FACTORS:
            wider = prior * factor
            if wider > MAX_SIGMA_PX:
                break
            wide = _measure_frame(image, replace(config, psf_sigma_px=wider), smear, grounds.at(wider))
            if wide.frame is None:
                break
            again = estimate_psf(image, wide.frame.det, wide.frame.cand, wide.frame.saturation, wider,
                                 config.gain_e_per_adu, faint=True)
            if again.estimated:
                measured, prior, estimate, rings = wide, wider, again, False
                break
    if not estimate.estimated:
        return replace(_finish(measured), psf=estimate)
    if _remeasured(estimate, prior, rings):
        return _at_estimate(image, config, smear, grounds, estimate)
    width, elongated = _estimated_width(estimate)
    elliptical = _elliptical(image, config, smear, estimate)
    if elongated and width < (1.0 - RERUN_TOLERANCE) * prior:
        # Astigmatic stars are narrower across than the prior: measured again with the width
        # test at their minor axis, which the prior's rejected some of them at.
        measured = _measure_frame(image, replace(config, psf_sigma_px=prior), smear, grounds.at(prior),
                                  rings=rings, narrowest_px=width, elliptical=elliptical)
    elif elliptical is not None:
        measured = replace(measured, context=replace(measured.context, elliptical=elliptical))
    return replace(_finish(measured), psf=replace(estimate, applied_sigma_px=prior))


def _estimated_width(estimate: PsfEstimate) -> tuple[float, bool]:
    """
    Return the width [px] a frame is measured with at its estimated PSF, and whether its stars are elongated.

    Stars elongated alike are smeared (an unknown body rate) or astigmatic: their minor axis is
    the PSF, and a round width would hide the smear from the streak fits.
    """
    elongated = estimate.elongation > SMEARED_ELONGATION
    return (estimate.sigma_minor_px if elongated else estimate.sigma_px), elongated


def _remeasured(estimate: PsfEstimate, prior: float, rings: bool = False) -> bool:
    """
    Return whether a frame measured at `prior` [px] (`rings`: as ring stars) is measured again at its estimate's width.

    An elongated PSF's minor width is only approximate (the round fit over the axis ratio): it
    overrides the prior only when clearly different. Ring stars (a defocused PSF) are, unless
    measured as rings already: a ring's maxima are one star, split as a blend only farther
    apart; and stars measured as rings that are not.
    """
    width, elongated = _estimated_width(estimate)
    return abs(width - prior) > (3.0 if elongated else 1.0) * RERUN_TOLERANCE * prior or estimate.annular != rings


def _elliptical(image: np.ndarray, config: CentroidConfig, smear: "SmearModel | None",
                estimate: PsfEstimate) -> EllipticalGaussianPsf | None:
    """
    Return the astigmatic stars' fit model (elongated with no known rate that smears them), else None.

    A round Gaussian's centre is pulled with the sub-pixel phase. Under a known rate the
    elongation is motion, not the optics' shape.
    """
    still = smear is None or typical_smear_px(smear, image.shape[1], image.shape[0]) < config.min_smear_px
    if estimate.elongation <= SMEARED_ELONGATION or not still:
        return None
    return EllipticalGaussianPsf(estimate.sigma_major_px, estimate.sigma_minor_px, estimate.angle_rad)


def _at_estimate(image: np.ndarray, config: CentroidConfig, smear: "SmearModel | None", grounds: "_Grounds",
                 estimate: PsfEstimate) -> Spots:
    """Measure and fit the frame at its estimated PSF (_estimated_width; rings, astigmatism)."""
    width, _ = _estimated_width(estimate)
    spots = _finish(_measure_frame(image, replace(config, psf_sigma_px=width), smear, grounds.at(width),
                                   rings=estimate.annular, elliptical=_elliptical(image, config, smear, estimate)))
    return replace(spots, psf=replace(estimate, applied_sigma_px=width))


class _Grounds:
    """
    A frame's detection grounds (background, noise), computed once per background smoothing.

    The background does not depend on the PSF, except that stars as wide as a background tile
    take it over 3x3 tiles (detect.background_tiles).
    """

    def __init__(self, image: np.ndarray, config: CentroidConfig):
        self.image, self.config, self.by_tiles = image, config, {}

    def at(self, psf_sigma_px: float) -> DetectionGround:
        """Return the ground for stars of 1-sigma psf_sigma_px [px]."""
        block = self.config.background_block_px
        tiles = background_tiles(psf_sigma_px, block)
        if tiles not in self.by_tiles:
            self.by_tiles[tiles] = detection_ground(self.image, _binning(self.image, self.config), block, tiles)
        return self.by_tiles[tiles]


@dataclass(frozen=True)
class _Frame:
    """
    What a measurement of a frame leaves for the PSF estimate.

    Its detections, every measured candidate (shape-test rejects included), the saturation
    level [ADU] and whether a body rate predicted smears (then no star shows the optics'
    PSF).
    """

    det: Detections
    cand: Candidates
    saturation: float
    smeared: bool = False


@dataclass(frozen=True)
class _Measurement:
    """
    A frame measured with one PSF width up to its sub-pixel fits.

    Detections judged, defects and extended objects removed, centres of gravity; the fits
    (`_finish`) run only for the measurement whose spots are returned: a measurement made
    for the PSF estimate alone, replaced by one at the estimated width, never pays for them.
    `frame` None: nothing was detected (`empty` holds the spots).
    """

    frame: _Frame | None
    empty: Spots | None = None
    context: FitContext | None = None
    kept: Candidates | None = None
    spots: SpotRows | None = None
    clipping: _Clipping | None = None
    multi: np.ndarray | None = None
    aid: "SmearModel | None" = None
    rejected_shape: int = 0
    frame_values: dict | None = None
    rate_aid_rejected: bool = False
    track_peaks: dict | None = None  # kept blend index -> ((K,) bool: its track peaks (dropped), PeakShapes)


def _finish(measurement: _Measurement) -> Spots:
    """Return the measurement's spots: its sub-pixel fits (the method's) run, the spot table assembled."""
    if measurement.frame is None:
        return measurement.empty
    m = measurement
    spots, added, clipping, fit_model = m.spots, [], m.clipping, ""
    if m.context.config.method not in ("cog", "wcog"):
        spots, added, clipping, fit_model = _fit_spots(m.context, m.kept, spots, clipping, m.multi, m.aid,
                                                       m.track_peaks or {})
    wide = np.flatnonzero(clipping.saturated & ~clipping.fitted)
    if wide.size:
        spots = spots.with_values(wide, cov=m.kept.moment_covariance(wide))
    result = _assemble(m.context, SpotRows.concatenate([spots, *added]), m.rejected_shape, m.frame_values, fit_model)
    return replace(result, rate_aid_rejected=True) if m.rate_aid_rejected else result


def _binning(image: np.ndarray, config: CentroidConfig) -> int:
    """Return the detection grid's bin factor: config.binning, 1 for an image under 16 bins across."""
    return config.binning if min(image.shape) >= 16 * config.binning else 1


def _detect(image: np.ndarray, config: CentroidConfig, aid: "SmearModel | None", ground: DetectionGround
            ) -> Detections:
    """Detect the frame's spots at config's PSF width (with a rate aid: its streak kernel)."""
    height, width = image.shape
    sigma = max(config.psf_sigma_px, MIN_SIGMA_PX) if config.psf_sigma_px > 0 else 0.5
    return detect(image, binning=ground.binning, background_block_px=config.background_block_px,
                  detection_sigma=config.detection_sigma, psf_sigma_px=config.psf_sigma_px,
                  min_area=config.min_area, max_area=config.max_area,
                  smear_kernel=smear_kernel(aid, width, height, sigma, ground.binning) if aid is not None else None,
                  ground=ground)


def _measure_frame(image: np.ndarray, config: CentroidConfig, smear: "SmearModel | None", ground: DetectionGround,
                   rings: bool = False, narrowest_px: float | None = None,
                   elliptical: EllipticalGaussianPsf | None = None, det: Detections | None = None) -> _Measurement:
    """
    Measure the frame once with config's PSF width, up to the fits (`_finish` runs them).

    ground: the frame's detection_ground (_Grounds.at the width); rings: the stars are rings
    (PsfEstimate.annular; config.blend_separation_px); narrowest_px: an elongated PSF's
    minor-axis 1-sigma [px] for the width test (None: the PSF width); elliptical: an
    astigmatic PSF, the single stars' fit model (FitContext); det: the detections at this width
    without a rate aid, when already found (all, or psf_pilot's), else None.
    """
    height, width = image.shape
    saturation = config.saturation_adu or (np.iinfo(image.dtype).max if image.dtype.kind in "ui" else np.inf)
    sigma = max(config.psf_sigma_px, MIN_SIGMA_PX) if config.psf_sigma_px > 0 else 0.5
    aid = smear if smear is not None and typical_smear_px(smear, width, height) >= config.min_smear_px else None
    if det is None or aid is not None:
        det = _detect(image, config, aid, ground)
    frame_values = dict(background_adu=float(np.median(det.background[::8, ::8])), noise_adu=det.noise_adu)
    if det.x.size == 0:
        return _Measurement(None, empty=Spots.empty(width, height, **frame_values))
    # A known rate that smears the stars by more than EMPIRICAL_MAX_SMEAR_PX (aided or not)
    # shapes them, not the optics: no empirical PSF.
    still = smear is None or typical_smear_px(smear, width, height) < EMPIRICAL_MAX_SMEAR_PX
    context = FitContext(image, det, config, sigma, rings, own_psf=still, elliptical=elliptical)
    cand = measure_candidates(image, det, config, sigma, find_blends=config.split_blends and aid is None, rings=rings,
                              streaks_expected=aid is not None)
    narrowest = sigma if narrowest_px is None else min(sigma, narrowest_px)
    rejected, thin = _shape_defects(cand, config, sigma, narrowest)
    track_peaks = {}
    if config.split_blends and aid is None and narrowest >= STREAK_COUNT_MIN_SIGMA_PX:
        rejected, track_peaks = _stars_beside_tracks(context, cand, rejected, thin, narrowest)
    first = _first_cut(context, cand, rejected, aid is not None)
    kept = cand.take(first)
    if track_peaks:
        track_peaks = {j: track_peaks[i] for j, i in enumerate(first) if i in track_peaks}
    clip = clip_levels(context, kept, saturation)
    saturated = np.isfinite(clip)
    # Clouds and stray-light structure: no star (a rate-aided frame's streaks are not judged).
    extended = extended_candidates(kept, sigma, saturated, image, det) if aid is None else np.zeros(kept.x.size, bool)
    if extended.any():
        remaining = np.flatnonzero(~extended)
        kept, clip = kept.take(remaining), clip[~extended]
        saturated = np.isfinite(clip)
        if track_peaks:
            track_peaks = {j: track_peaks[i] for j, i in enumerate(remaining) if i in track_peaks}
    # The sensor's clip level, where a flat top showed it below the configured one: every
    # candidate that reaches it is clipped too, for the PSF estimate.
    frame = _Frame(det, cand, float(min(saturation, clip[saturated].min() if saturated.any() else np.inf)),
                   aid is not None)
    # Several separate peaks with dips between them: stars blended into one footprint, not a streak.
    multi = np.array([len(p) >= 2 for p in kept.peaks], bool) & ~saturated
    if aid is not None and rate_aid_disagrees(kept, ~saturated & ~kept.edge & ~multi, sigma, aid):
        return replace(_measure_frame(image, config, None, ground), rate_aid_rejected=True)
    spots = _centres_of_gravity(kept, config, sigma, saturated, multi)
    # Clipped spots: their pixels at the clip level carry no shape information, so every fit
    # leaves them out (`excluded`); a saturated spot no fit describes gets a covariance as wide
    # as the spot.
    excluded = clipped_pixels(context, kept.detection[saturated], clip[saturated]) if saturated.any() else None
    clipping = _Clipping(clip, excluded, np.zeros(len(spots), bool))
    frame_values["rejected_extended"] = int(extended.sum())
    return _Measurement(frame, context=context, kept=kept, spots=spots, clipping=clipping, multi=multi, aid=aid,
                        rejected_shape=int(rejected.sum()), frame_values=frame_values, track_peaks=track_peaks)


def _shape_defects(cand: Candidates, config: CentroidConfig, sigma: float, narrowest: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """
    Defects (bool per candidate), and which of them only the width test rejected.

    Cleaned-away hot pixels (nothing left) and spots too sharp for a PSF of 1-sigma `sigma`
    [px] (peak share beyond peak_fraction_limit by more than its noise allows) or thinner than
    its narrowest axis `narrowest` [px] (default sigma) (CentroidConfig's shape test; none
    without a PSF).
    """
    narrowest = sigma if narrowest is None else narrowest
    rejected = np.zeros(cand.x.size, bool)
    thin = rejected.copy()
    if config.psf_sigma_px > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            sharp = cand.peak / cand.flux
            # A faint star's peak share is as noisy as its flux: the limit widened by 2 of its sigmas.
            sharp_limit = np.minimum(peak_fraction_limit(config, sigma) * (1.0 + 2.0 / np.fmax(cand.snr, 2.0)),
                                     0.95)
        other = (cand.cleaned & (cand.cut_snr < config.min_snr)) | (sharp > sharp_limit)
        thin = (cand.snr >= config.shape_min_snr) & (cand.minor < config.min_width_fraction * narrowest ** 2)
        finite = np.isfinite(cand.x)
        rejected = (other | thin) & finite
        thin &= ~other & finite
    return rejected, thin


def _stars_beside_tracks(context: FitContext, cand: Candidates, rejected: np.ndarray, thin: np.ndarray,
                         narrowest: float) -> tuple[np.ndarray, dict]:
    """
    Apply the width test per peak to every blend kept or rejected only by it (peak_shape).

    A peak is a star when its second moment is >= min_width_fraction x TRUNCATED_MOMENT x
    narrowest^2 [px^2] (the limit) at an SNR >= shape_min_snr. A blend the width test rejected
    whole is kept when a peak is a star (its other peaks count as tracks); in a kept blend a
    peak below KEPT_BLEND_TRACK_FRACTION (ring stars: RING_BLEND_TRACK_FRACTION) x the limit at
    that SNR is a track (a cosmic ray merged with a star, which the footprint's moments did not
    show). Returns the rejections and, per
    blend with tracks, the mask of its track peaks and the peaks' PeakShapes.
    """
    config = context.config
    rejected, tracks = rejected.copy(), {}
    limit = peak_width_limit(config.min_width_fraction, narrowest)
    track_fraction = RING_BLEND_TRACK_FRACTION if context.rings else KEPT_BLEND_TRACK_FRACTION
    # A peak's SNR is at most its footprint's: fainter footprints have no measured peak.
    for i in np.flatnonzero((thin | ~rejected) & (cand.snr >= config.shape_min_snr)):
        peaks = cand.peaks[i]
        if len(peaks) < 2:
            continue
        shapes = peak_minor_moments(context.image, context.det, peaks, context.sigma, context.gain, centres=False)
        minor = shapes.minor
        measured = shapes.snr >= config.shape_min_snr
        star = measured & (minor >= limit)
        if not star.any():
            continue
        # In a blend the footprint test kept, only a peak far thinner than a star is a track: a
        # star's core without its wings (cut at 2.5 sigma) can read ~0.8x the limit on a real lens.
        track = ~star if rejected[i] else measured & (minor < track_fraction * limit)
        rejected[i] = False
        if track.any():  # their centres only where a fit may need the fallback
            tracks[int(i)] = (track, peak_minor_moments(context.image, context.det, peaks, context.sigma, context.gain))
    return rejected, tracks


def _first_cut(context: FitContext, cand: Candidates, rejected: np.ndarray, rate_aided: bool) -> np.ndarray:
    """
    Return indices of the candidates worth fitting.

    Measured, not defects, positive flux, large enough and with an SNR (under the local
    noise) above the first cut; of those at most FIT_CANDIDATES_PER_SPOT x max_spots, the
    brightest by footprint flux (config.texture_last: elongated candidates pointing every way last).
    """
    config = context.config
    # Streaks spread their signal: their footprint SNR understates what the streak fit recovers,
    # so they pass a lower first cut and face min_snr with the fit's SNR.
    streaky = (rate_aided or (cand.major > elongation_limit(context.sigma))) & (config.method in ("auto", "streak"))
    first_cut = np.where(streaky, 0.4 * config.min_snr, config.min_snr)
    local = _local_noise_factor(context, cand.x, cand.y, cand.flux)
    keep = np.flatnonzero(~rejected & np.isfinite(cand.x) & np.isfinite(cand.y) & (cand.flux > 0)
                          & (cand.cut_snr / np.sqrt(local) >= first_cut) & (cand.area >= config.min_area))
    limit = FIT_CANDIDATES_PER_SPOT * config.max_spots
    if keep.size > limit:
        ranked = keep[np.argsort(-cand.flux[keep], kind="stable")]
        if config.texture_last and not rate_aided:  # texture.py: the round candidates first
            elongated = cand.major[ranked] > elongation_limit(context.sigma)
            if point_every_way(cand.angle[ranked][elongated]):
                ranked = rank_last(ranked, elongated)
        keep = np.sort(ranked[:limit])
    return keep


def _centres_of_gravity(kept: Candidates, config: CentroidConfig, sigma: float, saturated: np.ndarray,
                        multi: np.ndarray) -> SpotRows:
    """
    Return the spot table before any fit.

    Each candidate's centre of gravity (intensity-weighted for "wcog"), flags SATURATED,
    EDGE and BLENDED (`multi`: several peaks).
    """
    n = kept.x.size
    flags = np.zeros(n, np.uint32)
    flags[saturated] |= FLAG_SATURATED
    flags[kept.edge] |= FLAG_EDGE
    flags[multi] |= FLAG_BLENDED
    if config.method == "wcog":
        x, y, cov = kept.wx.copy(), kept.wy.copy(), kept.wcov.copy()
    else:
        x, y, cov = kept.x.copy(), kept.y.copy(), kept.cov.copy()
    # An aperture centre of gravity is biased by the star's sub-pixel phase, beyond its noise
    # term: add that bias's RMS, computed for this PSF and aperture (measure_small's), to the
    # covariance of the spots measured so. A fit replaces both.
    aperture = np.flatnonzero(kept.has_window)
    phase = cog_phase_bias_rms(sigma, min(max(2.5, 3.0 * sigma), float(config.window_half + 1)),
                               2 if config.method == "wcog" else 1)
    cov[aperture] += phase ** 2 * np.eye(2)
    if config.method in ("cog", "wcog") and multi.any():
        # Two stars in one footprint: a centre of gravity between them, as wide as the spot.
        cov[multi] = kept.moment_covariance(np.flatnonzero(multi))
    return SpotRows(x, y, kept.flux.copy(), kept.snr.copy(), cov, flags, np.zeros(n), np.zeros(n), kept.peak,
                    kept.area)


def _fit_spots(context: FitContext, kept: Candidates, spots: SpotRows, clipping: _Clipping, multi: np.ndarray,
               aid: "SmearModel | None", track_peaks: dict | None = None
               ) -> tuple[SpotRows, list[SpotRows], _Clipping]:
    """
    Return the fits the method calls for.

    Blends (their track peaks, `track_peaks` (_stars_beside_tracks), fitted and dropped),
    streaks (on the predicted path with `aid`; in a frame of round stars those the streak
    model failed on join the points), point PSFs (clipped ones without their clipped pixels),
    then the refit of spots whose fit shows a clipped core. Returns the spot table, the stars
    split off, the clipping state.
    """
    track_peaks = track_peaks or {}
    # Saturated (clipped), a blend with a track is not fitted: its star is measured by its own
    # pixels at the end (_own_brightest_stars).
    beside_track = np.array([t for t in track_peaks if not multi[t]], np.int64)
    config, sigma = context.config, context.sigma
    n = len(spots)
    saturated = clipping.saturated
    elongated = kept.major > elongation_limit(sigma)  # beyond the PSF (a segment of length L adds L^2/12)
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
    as_point = ~as_streak & (~elongated | noise_elongated) & ~multi
    clipped_point = as_point & saturated
    as_point &= ~saturated
    # In a smeared frame (most well-measured spots are streaks) a spot with several peaks is
    # streaks crossing stars or streaks, which point-PSF fits would misplace: it keeps its
    # centre of gravity with a covariance as wide as the spot itself (its second moments).
    clear = (kept.snr >= 20) & ~saturated
    smeared_frame = aid is not None or (np.sum(elongated & clear & ~multi) >= max(5, 0.5 * np.sum(clear)))
    added, fitted = [], clipping.fitted.copy()
    fitted_blends = False  # blends fitted star by star (fit_blends), not left at their centres of gravity
    if multi.any() and (smeared_frame or not config.split_blends):
        spots = spots.with_values(np.flatnonzero(multi), cov=kept.moment_covariance(np.flatnonzero(multi)))
        # The footprint's centre would hold the track: its brightest star, model-free (no point
        # fit in a smeared frame).
        spots = _own_brightest_stars(spots, np.array([t for t in track_peaks if multi[t]], np.int64), track_peaks)
    elif multi.any():
        spots, more = fit_blends(context, kept, spots, np.flatnonzero(multi), track_peaks)[:2]
        added.append(more)
        fitted_blends = True
    if as_streak.any():
        spots, more = fit_streak_spots(context, kept, spots, np.flatnonzero(as_streak), aid, clipping.excluded)[:2]
        added.append(more)
        fitted |= as_streak & ((spots.flags & FLAG_STREAK) != 0)
        if round_frame:
            # An elongated spot the streak model failed on, in a frame of round stars, may be a star
            # whose footprint merged with a cosmic-ray track's (its moments stretched by the track's
            # footprint): measured with the point spots, in the frame's point model.
            as_point |= as_streak & (spots.snr <= 0) & ~saturated
    fit_model = ""
    if as_point.any():
        outcome = fit_points(context, kept, spots, np.flatnonzero(as_point), clipping.excluded)
        spots, more, fit_model = outcome.spots, outcome.added, outcome.model
        added.append(more)
        if outcome.psf is not None and fitted_blends:  # beside_tracks.py: the frame's model, not the Gaussian
            peaks = {t: (kept.peaks[t], track) for t, (track, _) in track_peaks.items() if multi[t]}
            spots = refit_beside_tracks(context, peaks, spots, outcome.psf, clipping.excluded)
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


def _own_brightest_stars(spots: SpotRows, rows: np.ndarray, track_peaks: dict) -> SpotRows:
    """Spots `rows` (blends with tracks) replaced by their brightest star's own-pixel centre; none: dropped."""
    for t in rows.tolist():
        stars, _ = own_centres(*track_peaks[t])
        spots = (spots.with_stars(np.array([t]), stars.take(slice(0, 1))) if stars.x.size
                 else spots.with_values(np.array([t]), snr=0.0))
    return spots


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


def _refit_undershot(context: FitContext, kept: Candidates, spots: SpotRows, clipping: _Clipping,
                     probe: np.ndarray, aid: "SmearModel | None") -> tuple[SpotRows, SpotRows, _Clipping]:
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
    return spots, added, _Clipping(clip, excluded, fitted)


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
    local = _local_noise_factor(context, spots.x, spots.y, spots.flux)
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
    return Spots(x=x[order], y=y[order], flux=spots.flux[order], snr=snr[order], cov=cov[order],
                 flags=spots.flags[order], area=spots.area[order].astype(np.int32), peak=spots.peak[order],
                 width=width, height=height, rejected_shape=rejected_shape, streak_length=spots.length[order],
                 streak_angle=spots.angle[order], fit_model=fit_model, **frame_values)


def _local_noise_factor(context: FitContext, x, y, flux) -> np.ndarray:
    """
    Variance ratio of a spot's measurement under the local pixel noise vs the frame's typical one.

    (F/g + N s_local^2) / (F/g + N s^2), N = 4 pi sigma^2 the PSF's effective pixels.
    """
    det = context.det
    scale = det.noise_scale_at(np.nan_to_num(x), np.nan_to_num(y))
    shot = np.maximum(np.nan_to_num(flux), 0.0) / context.gain
    pixels = 4.0 * np.pi * context.sigma ** 2 * det.noise_adu ** 2
    return (shot + pixels * scale ** 2) / (shot + pixels)
