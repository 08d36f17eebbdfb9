# SPDX-License-Identifier: Apache-2.0
"""
A frame measured with one PSF, up to its sub-pixel fits.

Detect (with a rate aid: its streak kernel) -> measure every detection (candidates) -> the
shape test (hot pixels, cosmic rays; per peak in blends beside tracks) -> the first cut -> no
clipped-star shape, no extended object -> centres of gravity. psf_loop.PsfLoop measures a frame
with one or more PSFs this way; frame_fits.fitted_spots fits the measurement it keeps.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .config import CentroidConfig, elongation_limit, peak_fraction_limit, window_half
from .detection.candidates import STREAK_COUNT_MIN_SIGMA_PX, Candidates, measure_candidates
from .detection.detect import (DetectionGround, Detections, DetectionSettings, background_tiles, detect,
                               detection_ground)
from .detection.extended_objects import extended_candidates
from .detection.measure import cog_phase_bias_rms
from .detection.saturation import CLIP_TOP_FRACTION, clip_levels, clipped_pixels
from .detection.texture import point_every_way, rank_last
from .psf.estimate import MeasuredFrame
from .records import FitContext, PsfTrial, SpotRows
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_SATURATED, Spots
from .streak.rate_aid import footprints_as_predicted, rate_aid_disagrees, smear_kernel, typical_smear_px
from .tracks.blend_screen import blends_beside_tracks

if TYPE_CHECKING:
    from .streak.smear import SmearModel

# A thin footprint in a rate-aided frame is the predicted streak within this many times the
# rate-aid check's tolerance (_choose_candidates): a faint streak's footprint moments are noisy
# (independent renderer, SNR ~25 streaks of 3 px: 0.4-1.0 px from the prediction; cosmic-ray
# tracks >= 2 px).
THIN_STREAK_SLACK = 1.5
# ... and the frame's thin footprints are streaks only when at least this share of them is:
# undersampled streak frames 41-58 of 45-58 (at the 1 px prior), defects in wide-PSF frames
# 0-3 of 2-8.
ON_TRACK_SHARE = 0.75
EMPIRICAL_MAX_SMEAR_PX = 0.5  # predicted smear [px] below which stars keep the optics' shape
# Only the FIT_CANDIDATES_PER_SPOT x max_spots brightest candidates (footprint flux) are fitted:
# the fits rank the spots by fitted flux and keep max_spots, and a deep photograph's thousands of
# faint detections would cost seconds of fits for spots never reported (margin for fitted flux
# reordering the footprint's; see _first_cut).
FIT_CANDIDATES_PER_SPOT = 3


class DetectionGrounds:
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
            binning = detection_binning(self.image, self.config)
            self.by_tiles[tiles] = detection_ground(self.image, binning, block, tiles)
        return self.by_tiles[tiles]


def detection_binning(image: np.ndarray, config: CentroidConfig) -> int:
    """Return the detection grid's bin factor: config.binning, 1 for an image under 16 bins across."""
    return config.binning if min(image.shape) >= 16 * config.binning else 1


@dataclass(frozen=True)
class Clipping:
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


@dataclass(frozen=True)
class FrameMeasurement:
    """
    A frame measured with one PSF width up to its sub-pixel fits.

    Detections judged, defects and extended objects removed, centres of gravity; the fits
    (frame_fits.fitted_spots) run only for the measurement whose spots are returned: a
    measurement made for the PSF estimate alone, replaced by one at the estimated width, never
    pays for them. `frame` None: nothing was detected (`empty` holds the spots). context: what
    the fits read of the frame; kept: the candidates worth fitting; spots: their table before
    any fit (centres of gravity); clipping: their clip levels; multi (n,) bool: several peaks
    (blends); aid: the smear model of a rate-aided frame (None: unaided); rejected_shape: the
    detections the shape test dropped; frame_values: Spots' frame-wide fields;
    rate_aid_rejected: the rate aid disagreed with the image (measured without it);
    track_peaks: per kept blend index with cosmic-ray tracks, its track peaks and PeakShapes.
    """

    frame: MeasuredFrame | None
    empty: Spots | None = None
    context: FitContext | None = None
    kept: Candidates | None = None
    spots: SpotRows | None = None
    clipping: Clipping | None = None
    multi: np.ndarray | None = None
    aid: "SmearModel | None" = None
    rejected_shape: int = 0
    frame_values: dict | None = None
    rate_aid_rejected: bool = False
    track_peaks: dict | None = None  # kept blend index -> ((K,) bool: its track peaks (dropped), PeakShapes)


def detect_at(image: np.ndarray, config: CentroidConfig, trial: PsfTrial, aid: "SmearModel | None",
              ground: DetectionGround) -> Detections:
    """Detect the frame's spots at the trial's PSF width (with a rate aid: its streak kernel)."""
    height, width = image.shape
    sigma = trial.model_sigma_px
    settings = DetectionSettings(ground.binning, config.background_block_px, config.detection_sigma, trial.sigma_px,
                                 config.min_area, config.max_area)
    return detect(image, settings,
                  smear_kernel=smear_kernel(aid, width, height, sigma, ground.binning) if aid is not None else None,
                  ground=ground)


def measure_frame(image: np.ndarray, config: CentroidConfig, trial: PsfTrial, smear: "SmearModel | None",
                  ground: DetectionGround, det: Detections | None = None) -> FrameMeasurement:
    """
    Measure the frame once with the trial's PSF, up to the fits (frame_fits.fitted_spots runs them).

    config: the user's configuration; trial: the PSF tried (its width, rings, the width test's
    narrowest axis, the astigmatic model); smear: the body rate's smear model (None: unknown);
    ground: the frame's detection ground at the trial's width (DetectionGrounds.at); det: the
    detections at this width without a rate aid, when already found (all, or the pilot's), else
    None.
    """
    height, width = image.shape
    saturation = config.saturation_adu or (np.iinfo(image.dtype).max if image.dtype.kind in "ui" else np.inf)
    sigma = trial.model_sigma_px
    aid = smear if smear is not None and typical_smear_px(smear, width, height) >= config.min_smear_px else None
    if det is None or aid is not None:
        det = detect_at(image, config, trial, aid, ground)
    frame_values = dict(background_adu=float(np.median(det.background[::8, ::8])), noise_adu=det.noise_adu)
    if det.x.size == 0:
        return FrameMeasurement(None, empty=Spots.empty(width, height, **frame_values))
    # A known rate that smears the stars by more than EMPIRICAL_MAX_SMEAR_PX (aided or not)
    # shapes them, not the optics: no empirical PSF.
    still = smear is None or typical_smear_px(smear, width, height) < EMPIRICAL_MAX_SMEAR_PX
    context = FitContext(image, det, config, sigma, trial.rings, own_psf=still, elliptical=trial.elliptical)
    cand = measure_candidates(image, det, config, sigma, find_blends=config.split_blends and aid is None,
                              rings=trial.rings, streaks_expected=aid is not None)
    chosen = _choose_candidates(context, cand, trial, aid, saturation)
    kept, clip = chosen.kept, chosen.clip
    saturated = np.isfinite(clip)
    frame = MeasuredFrame(det, cand, _frame_clip_level(kept, clip, saturation), aid is not None, chosen.off_track)
    # Several separate peaks with dips between them: stars blended into one footprint, not a streak.
    multi = np.array([len(p) >= 2 for p in kept.peaks], bool) & ~saturated
    if aid is not None and rate_aid_disagrees(kept, ~saturated & ~kept.edge & ~multi, sigma, aid):
        return replace(measure_frame(image, config, PsfTrial(trial.sigma_px), None, ground), rate_aid_rejected=True)
    spots = _centres_of_gravity(kept, config, sigma, saturated, multi)
    # Clipped spots: their pixels at the clip level carry no shape information, so every fit
    # leaves them out (`excluded`); a saturated spot no fit describes gets a covariance as wide
    # as the spot.
    excluded = clipped_pixels(context, kept.detection[saturated], clip[saturated]) if saturated.any() else None
    clipping = Clipping(clip, excluded, np.zeros(len(spots), bool))
    frame_values["rejected_extended"] = chosen.rejected_extended
    return FrameMeasurement(frame, context=context, kept=kept, spots=spots, clipping=clipping, multi=multi, aid=aid,
                            rejected_shape=chosen.rejected_shape, frame_values=frame_values,
                            track_peaks=chosen.track_peaks)


def _frame_clip_level(kept: Candidates, clip: np.ndarray, saturation: float) -> float:
    """
    Return the sensor's clip level [ADU] for the PSF estimate: every candidate that reaches it is clipped.

    The configured `saturation`, or a flat top's level below it (clip: the kept candidates'
    clip levels, inf: not clipped) when that level is the frame's ceiling: within
    CLIP_TOP_FRACTION (of the range above the background) of the brightest candidate's peak.
    A sensor clips every star at one level and none reads above it; a flat top well below
    another star's peak is a chance tie of one star's top pixels (a wide star's top is nearly
    flat: in a dark frame of equal σ 2.8 px stars one such tie, taken as the frame's clip
    level, left 1 of 39 stars to the estimate, and the frame at the 1 px prior kept 3 spots).
    """
    flat = clip[np.isfinite(clip) & (clip < saturation)]
    finite = np.isfinite(kept.peak_raw)
    if flat.size == 0 or not finite.any():
        return float(saturation)
    top = float(kept.peak_raw[finite].max())
    floor = float(np.median(kept.peak_raw[finite] - kept.peak[finite]))  # the background under the peaks
    at_ceiling = flat[flat >= top - CLIP_TOP_FRACTION * max(top - floor, 0.0)]
    return float(at_ceiling.min()) if at_ceiling.size else float(saturation)


class _Chosen(NamedTuple):
    """
    The candidates worth fitting (_choose_candidates).

    kept: them; clip (n,) their clip levels [ADU] (inf: not clipped); track_peaks: per kept
    blend index with cosmic-ray tracks, its track peaks and PeakShapes; rejected_shape: the
    detections the shape test dropped; rejected_extended: the candidates dropped as extended
    objects; off_track (per candidate): thin footprints of a rate-aided frame that are not the
    predicted streak (cosmic-ray tracks).
    """

    kept: Candidates
    clip: np.ndarray
    track_peaks: dict
    rejected_shape: int
    rejected_extended: int
    off_track: np.ndarray


def _choose_candidates(context: FitContext, cand: Candidates, trial: PsfTrial, aid: "SmearModel | None",
                       saturation: float) -> _Chosen:
    """
    Keep the candidates worth fitting: the shape test (per peak in blends), the first cut, no extended object.

    saturation: the configured clip level [ADU].
    """
    config, sigma = context.config, context.sigma
    narrowest = sigma if trial.narrowest_px is None else min(sigma, trial.narrowest_px)
    rejected, thin = _shape_defects(cand, config, sigma, narrowest)
    off_track = np.zeros(cand.x.size, bool)
    if aid is not None:
        thin_only = np.flatnonzero(thin)
        on_track = footprints_as_predicted(cand, thin_only, sigma, aid, THIN_STREAK_SLACK, thin=True)
        if narrowest < STREAK_COUNT_MIN_SIGMA_PX:
            # An undersampled PSF's streak is as thin as a cosmic-ray track, so the width test
            # cannot tell them apart there; the aid can: a thin footprint that is the predicted
            # streak stays.
            rejected[thin_only[on_track]] = False
        # Where the PSF is still to be measured across the streaks, thin footprints give it only
        # when they agree with the aid as a population, as stars' streaks do; defects agree by
        # chance (a third of short cosmic-ray tracks lie within the tolerance of a 3 px
        # streak's direction).
        if thin_only.size and np.mean(on_track) < ON_TRACK_SHARE:
            on_track[:] = False
        off_track[thin_only[~on_track]] = True
    track_peaks = {}
    if config.split_blends and aid is None and narrowest >= STREAK_COUNT_MIN_SIGMA_PX:
        rejected, track_peaks = blends_beside_tracks(context, cand, rejected, thin, narrowest)
    first = _first_cut(context, cand, rejected, aid is not None)
    kept = cand.take(first)
    if track_peaks:
        track_peaks = {j: track_peaks[i] for j, i in enumerate(first) if i in track_peaks}
    clip = clip_levels(context, kept, saturation)
    saturated = np.isfinite(clip)
    # Clouds and stray-light structure: no star (a rate-aided frame's streaks are not judged).
    extended = (extended_candidates(kept, sigma, saturated, context.image, context.det) if aid is None
                else np.zeros(kept.x.size, bool))
    if extended.any():
        remaining = np.flatnonzero(~extended)
        kept, clip = kept.take(remaining), clip[~extended]
        if track_peaks:
            track_peaks = {j: track_peaks[i] for j, i in enumerate(remaining) if i in track_peaks}
    return _Chosen(kept, clip, track_peaks, int(rejected.sum()), int(extended.sum()), off_track)


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
    local = context.local_noise_factor(cand.x, cand.y, cand.flux)
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
    phase = cog_phase_bias_rms(sigma, min(max(2.5, 3.0 * sigma), float(window_half(sigma) + 1)),
                               2 if config.method == "wcog" else 1)
    cov[aperture] += phase ** 2 * np.eye(2)
    if config.method in ("cog", "wcog") and multi.any():
        # Two stars in one footprint: a centre of gravity between them, as wide as the spot.
        cov[multi] = kept.moment_covariance(np.flatnonzero(multi))
    return SpotRows(x, y, kept.flux.copy(), kept.snr.copy(), cov, flags, np.zeros(n), np.zeros(n), kept.peak,
                    kept.area)
