# SPDX-License-Identifier: Apache-2.0
"""
The PSF loop: measure the frame, estimate its PSF from the stars found, measure again at the estimate.

`PsfLoop` owns it: the prior (the width the frame is first measured with), the estimate and
the PSF being tried (`records.PsfTrial`), and runs measure -> estimate -> measure again as one
loop with one exit. `CentroidConfig` stays the user's configuration (psf_sigma_px is the prior,
or the width in psf_mode "fixed"); the width under trial never travels in it.

The steps, each a trial measured and then judged (`_Step.then`):
- psf_mode "fixed" (or no PSF): the configured width, kept.
- A crowded frame without a running prior first measures its brightest detections alone
  (psf.pilot): an estimate from a full set of stars that calls for another width skips the
  measurement at the prior.
- A rate-aided frame (its stars smeared): measured at the prior, its PSF estimated across the
  streaks (streak.streak_width) and, when that differs from the prior, measured there, kept;
  too few streaks to measure across, one or two of them at another width: measured again at
  theirs, kept when enough streaks there give a width (three, or two that agree); else the
  prior, held (PsfEstimate.holds_prior). A smear shorter everywhere than a profile across
  needs (streak_width.MIN_LENGTH_PX), or at most of the bright stars where they are, leaves
  the stars nearly round: estimated as a frame without a rate (the steps below).
- The prior: measured, its PSF estimated (psf.estimate); without a rate, when no estimate
  comes of the round stars, across the streaks' own tracks (streak.own_tracks). Too few
  usable stars among many detections (a defocused camera's faint rings, fragments at a narrow width), or an estimate
  from fewer than a full set of stars that most of the frame's detections contradict (far wider
  than it: short cosmic-ray tracks taken for the stars of a frame of faint wide ones; not one
  that agrees with a running prior): measured again at WIDER_PRIOR_FACTORS x the prior, until
  one gives an estimate (for a contradicted one: from more stars, without its stars; else it
  stands).
- An estimate that differs from the width measured with (by more than RERUN_TOLERANCE, a round one by
  more than ROUND_RERUN_TOLERANCE when its uncertainty resolves it, or
  ring stars measured as points or points as rings): measured at the estimate, kept.
  Astigmatic stars narrower across than the prior: measured again at the prior with the width
  test at their minor axis, kept.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Callable

import numpy as np

from .config import CentroidConfig
from .frame_fits import fitted_spots
from .frame_measurement import DetectionGrounds, FrameMeasurement, detect_at, measure_frame
from .psf.elliptical import EllipticalGaussianPsf
from .psf.estimate import (FAINT_STAR_SNR, MAX_SIGMA_PX, MIN_SIGMA_PX, RERUN_TOLERANCE, ROUND_RERUN_SIGMAS,
                           ROUND_RERUN_TOLERANCE, SMEARED_ELONGATION, PsfEstimate,
                           estimate_psf, usable_stars)
from .psf.estimate import MAX_STARS as MAX_ESTIMATE_STARS
from .psf.estimate import MIN_STARS as MIN_ESTIMATE_STARS
from .psf.pilot import neighbour_positions, pilot_detections
from .streak.streak_width import MIN_LENGTH_PX as MIN_STREAK_LENGTH_PX
from .streak.streak_width import AGREEMENT as STREAK_AGREEMENT
from .streak.own_tracks import own_track_width
from .streak.streak_width import MIN_AGREEING_STREAKS, frame_width, streak_widths
from .streak.streak_width import MIN_SNR as STREAK_MIN_SNR
from .streak.streak_width import MIN_STREAKS as MIN_STREAKS_ACROSS
from .records import PsfTrial
from .spots import Spots
from .streak.rate_aid import typical_smear_px

CLIP_MARGIN = 0.98  # a streak peaking within 2 % of the clip level is left out of its width (as psf.estimate)

if TYPE_CHECKING:
    from .detection.candidates import Candidates
    from .detection.detect import Detections
    from .streak.smear import SmearModel

# A frame with WIDER_PRIOR_MIN_CANDIDATES detections whose PSF could not be estimated for too
# few usable stars is measured again at these multiples of the prior width (up to MAX_SIGMA_PX),
# until one gives an estimate.
WIDER_PRIOR_FACTORS = (2.0, 3.0)
WIDER_PRIOR_MIN_CANDIDATES = 20
# An estimate from fewer than MAX_ESTIMATE_STARS stars is contradicted by the frame (measured at
# the wider priors too) when, of its >= WIDER_PRIOR_MIN_CANDIDATES detections, most of those at
# SNR >= FAINT_STAR_SNR have a moment width beyond CONTRADICTING_WIDTH x the estimated width. A
# frame of faint sigma-3 px stars (none usable at the 1 px prior) and 7 cosmic rays was estimated
# at sigma 0.73 px (minor axis 0.58) from 5 short tracks: 80 % of those detections read beyond
# 2x 0.58 px (its stars 1.3-2.0 px at the prior). In the other 475 cold frames of
# bench/bench_psf_cold.py, at most 17 % do (sigma-0.4 px stars at 1,000 e-).
CONTRADICTING_WIDTH = 2.0


@dataclass(frozen=True)
class _Step:
    """A trial to measure, what judges its measurement (returns the next step, None: done), and its detections."""

    trial: PsfTrial
    then: Callable[[PsfTrial, FrameMeasurement], "_Step | None"]
    detections: "Detections | None" = None


class PsfLoop:
    """
    One frame's PSF loop (module docstring): `run()` returns its spots with the PSF they were measured with.

    image [ADU] (2-D); config: the user's CentroidConfig; smear: the body rate's smear model
    (None: unknown); psf_prior [px]: the last frames' width (the centroider node's running
    prior; None or out of [MIN_SIGMA_PX, MAX_SIGMA_PX]: config.psf_sigma_px); prior_rings: the
    last frames' stars were rings. After run(): `estimate`, the frame's PSF as estimated or
    assumed, and `kept`, the trial and measurement whose spots are returned.
    """

    def __init__(self, image: np.ndarray, config: CentroidConfig, smear: "SmearModel | None" = None,
                 psf_prior: float | None = None, prior_rings: bool = False):
        self.image, self.config, self.smear = image, config, smear
        self.grounds = DetectionGrounds(image, config)
        self.prior_given = psf_prior is not None
        usable = self.prior_given and bool(np.isfinite(psf_prior)) and MIN_SIGMA_PX <= psf_prior <= MAX_SIGMA_PX
        self.prior = PsfTrial(float(psf_prior), bool(prior_rings)) if usable else PsfTrial(config.psf_sigma_px)
        self.estimate: PsfEstimate | None = None
        self.kept: tuple[PsfTrial, FrameMeasurement] | None = None
        self._pilot_estimate: PsfEstimate | None = None
        self._contradicted: tuple[PsfTrial, FrameMeasurement, PsfEstimate] | None = None
        self._not_stars: tuple[np.ndarray, np.ndarray] | None = None  # (x, y) [px] of a contradicted estimate's stars

    def run(self) -> Spots:
        """Measure until a step keeps its measurement; return the kept measurement's spots, fitted, with their PSF."""
        step = self._first_step()
        while step is not None:
            measurement = measure_frame(self.image, self.config, step.trial, self.smear,
                                        self.grounds.at(step.trial.sigma_px), det=step.detections)
            step = step.then(step.trial, measurement)
        trial, measurement = self.kept
        psf = replace(self.estimate, applied_sigma_px=trial.sigma_px) if self.estimate.estimated else self.estimate
        return replace(fitted_spots(measurement), psf=psf)

    def _first_step(self) -> _Step:
        config = self.config
        if config.psf_mode == "fixed" or config.psf_sigma_px <= 0:
            self.estimate = PsfEstimate.assumed(config.psf_sigma_px, "configured")
            return _Step(PsfTrial(config.psf_sigma_px), self._keep)
        if self.smear is not None:
            return _Step(self.prior, self._after_prior)
        det = detect_at(self.image, config, self.prior, None, self.grounds.at(self.prior.sigma_px))
        # A running prior (the node's last estimates) is expected to hold: no pilot to waste.
        pilot = None if self.prior_given else pilot_detections(self.image, det, self.prior.sigma_px)
        if pilot is not None:
            return _Step(self.prior, lambda trial, measured: self._after_pilot(measured, det, pilot), det.take(pilot))
        return _Step(self.prior, self._after_prior, det)

    def _keep(self, trial: PsfTrial, measured: FrameMeasurement) -> None:
        self.kept = (trial, measured)
        return None

    def _after_pilot(self, measured: FrameMeasurement, det: "Detections", pilot: np.ndarray) -> _Step:
        """
        Judge the pilot's measurement (the brightest detections, at the prior).

        An estimate from a full set of stars is the frame's: one that calls for another width
        skips the measurement at the prior. Otherwise the whole frame is measured at the prior
        (too few stars: as without a pilot).
        """
        frame = measured.frame
        if frame is not None:
            guess = estimate_psf(self.image, frame, self.prior.sigma_px, self.config.gain_e_per_adu,
                                 neighbours=neighbour_positions(frame.cand, det, pilot), min_usable=MAX_ESTIMATE_STARS)
            if guess.estimated and _remeasured(guess, self.prior.sigma_px):
                self.estimate = guess
                return _Step(self._at_estimate(), self._keep)
            self._pilot_estimate = guess
        return _Step(self.prior, self._after_prior, det)

    def _after_prior(self, trial: PsfTrial, measured: FrameMeasurement) -> _Step | None:
        """Judge the measurement at the prior: estimate its PSF, then as _settle (or the wider-prior search)."""
        self.kept = (trial, measured)
        frame = measured.frame
        if frame is None:
            self.estimate = PsfEstimate.assumed(trial.sigma_px, "prior", "no detections", holds_prior=True)
            return None
        if frame.smeared and not self._short_smear():
            return self._across_streaks(trial)
        return self._round_stars(trial, measured)

    def _round_stars(self, trial: PsfTrial, measured: FrameMeasurement) -> _Step | None:
        """Estimate the PSF of a frame measured at the prior from its round stars (psf.estimate), then as _settle."""
        frame = measured.frame
        guess = self._pilot_estimate
        self.estimate = guess if guess is not None and guess.estimated else \
            estimate_psf(self.image, frame, trial.sigma_px, self.config.gain_e_per_adu)
        if not self.estimate.estimated and self.smear is None:
            # Streaks of an unknown motion, no star round: the width across their own tracks (a
            # tumble's first frame of a 2.84 px PSF, 9 streaks none round, was measured at the 1 px
            # prior, 20" off at NEES 51: stress campaign, seed 2026, task 1832).
            sigma, uncertainty, used = own_track_width(self.image, frame.cand, _unclipped(frame), trial.sigma_px)
            if _usable_width(sigma):
                return self._width_across(trial, measured, sigma, uncertainty, used)
        if not self.estimate.estimated:
            # Many detections but too few usable stars (not: usable ones all elongated, a smear):
            # a PSF much wider than the prior (a defocused camera's faint rings are fragments
            # and streaks at a narrow width, their light outside its apertures).
            many = frame.cand.x.size >= WIDER_PRIOR_MIN_CANDIDATES
            return self._wider(0) if many and self.estimate.stars < MIN_ESTIMATE_STARS else None
        corroborated = self.prior_given and not _remeasured(self.estimate, trial.sigma_px, trial.rings)
        if not corroborated and _contradicted(self.estimate, frame.cand):
            # Its few stars are not the frame's (short cosmic-ray tracks beside faint wide stars):
            # searched for as for too few usable stars, without them; it stands unless a wider
            # width gives an estimate from more stars. One that agrees with a running prior (the
            # last frames' estimates) is corroborated: a cloud bank's wide detections beside a
            # real photograph's 11 stars at 0.53 px (a 0.58 px running prior) are not stars.
            self._contradicted = (trial, measured, self.estimate)
            used = usable_stars(frame.cand, frame.det, frame.saturation, trial.sigma_px)
            self._not_stars = (frame.cand.x[used], frame.cand.y[used])  # nor are they at the wider widths
            return self._wider(0)
        return self._settle(trial, measured)

    def _short_smear(self) -> bool:
        """
        Whether the aid's smear is too short to measure a profile across (below streak_width.MIN_LENGTH_PX everywhere).

        Such stars are nearly round at any PSF the estimate supports (a smear L adds L^2/12 px^2
        along the track: under 0.75 px^2), so their PSF is estimated as an unaided frame's.
        """
        height, width = self.image.shape
        return typical_smear_px(self.smear, width, height) < MIN_STREAK_LENGTH_PX

    def _across_streaks(self, trial: PsfTrial) -> _Step | None:
        """
        Estimate a rate-aided frame's PSF across its streaks (streak.streak_width); measure again there when it differs.

        No star shows the round PSF under a known rate, but a streak's profile across its track
        does. Fewer than streak_width.MIN_STREAKS streaks measured at the prior, one or two of
        them beyond RERUN_TOLERANCE of it: the frame is measured again at their width
        (_after_few_streaks), where a PSF wider than the prior lifts more streaks above
        streak_width.MIN_SNR. No width across the streaks and no running prior (a cold frame:
        the configured width is a guess, not the last frames' measurement): the PSF is
        estimated from its round stars, as where the bright smears are short (on the
        independent renderer's cold frames of faint 1.5-3 px streaks smeared 3 px, held at
        1 px, their positions were 3-43 times their stated variance; bench_psf_cold). A gyro-aided jitter's
        first frames of a defocused 2.46 px PSF (stress campaign, seed 2026, task 1987) had
        3 of 22 bright stars smeared to the 3 px a width across needs, none measured there;
        held at the configured 1 px, frame 0 was lost and frame 1 72" off at NEES 886.
        """
        widths = self._streak_widths(self.kept)
        if widths.size == 0 and (self._bright_smears_short() or not self.prior_given):
            return self._round_stars(*self.kept)
        sigma, uncertainty, used = frame_width(widths)
        if not _usable_width(sigma):
            few = float(np.median(widths)) if widths.size else float("nan")
            if _usable_width(few) and abs(few - trial.sigma_px) > RERUN_TOLERANCE * trial.sigma_px:
                return _Step(PsfTrial(few), self._after_few_streaks)
            return self._without_width_across(used)
        return self._width_across(*self.kept, sigma, uncertainty, used)

    def _after_few_streaks(self, trial: PsfTrial, measured: FrameMeasurement) -> _Step | None:
        """
        Judge a rate-aided frame measured at its few streaks' width: kept when enough streaks there give a width.

        A width from streak_width.MIN_STREAKS streaks or more is the estimate (measured again
        where it differs beyond RERUN_TOLERANCE), as is one from MIN_AGREEING_STREAKS whose
        widths agree within streak_width.AGREEMENT (two streaks measured twice, at the prior and
        at their width, both away from the prior); else the measurement at the prior stands,
        the prior held (a cold frame's PSF from its round stars, as _across_streaks). A sparse
        field of sigma-2.7 px stars (stress campaign, seed 2026, task 2056) had one or two
        streaks above MIN_SNR at the 1 px prior for three frames, measured at 1 px and
        27-131" off; a gyro-aided tumble of a 1.76 px PSF (task 2217) showed two
        streaks of 1.8-2.0 px frame after frame and was measured at 1 px for all its 40 frames
        (27 lost, frame 39 62" off). (Measuring at 2x and 3x the prior when no
        streak gave a width rescued none of 12 sparse frames of faint 2.7 px streaks of the
        independent renderer: they are below MIN_SNR at any width.)
        """
        widths = self._streak_widths((trial, measured))
        sigma, uncertainty, used = frame_width(widths)
        if not np.isfinite(sigma) and widths.size >= MIN_AGREEING_STREAKS \
                and np.ptp(widths) <= STREAK_AGREEMENT * float(np.median(widths)):
            sigma, uncertainty, used = frame_width(widths, MIN_AGREEING_STREAKS)
        if not _usable_width(sigma):
            return self._without_width_across(used)
        return self._width_across(trial, measured, sigma, uncertainty, used)

    def _without_width_across(self, used: int) -> _Step | None:
        """
        Settle a rate-aided frame whose streaks gave no width across (`used` streaks measured).

        A running prior holds (_hold_prior); a cold frame's configured width is a guess, not a
        measurement, so its PSF is estimated from its round stars (_across_streaks).
        """
        if not self.prior_given:
            return self._round_stars(*self.kept)
        self._hold_prior(used)
        return None

    def _width_across(self, trial: PsfTrial, measured: FrameMeasurement, sigma: float, uncertainty: float,
                      used: int) -> _Step | None:
        """
        Keep the measurement at `trial` with the PSF `sigma` [px] across streaks; measure again there if needed.

        Again when sigma differs from the trial's width beyond RERUN_TOLERANCE; uncertainty [px]
        and used (streaks) as streak_width.frame_width.
        """
        self.kept = (trial, measured)
        self.estimate = PsfEstimate(sigma, sigma, sigma, 0.0, uncertainty, used, "estimated")
        if abs(sigma - trial.sigma_px) > RERUN_TOLERANCE * trial.sigma_px:
            return _Step(PsfTrial(sigma), self._keep)
        return None

    def _bright_smears_short(self) -> bool:
        """
        Whether the aid's smear at the bright candidates is mostly shorter than a profile across needs.

        Fewer than streak_width.MIN_STREAKS of them reach streak_width.MIN_LENGTH_PX, and their
        median does not: such a frame's stars are nearly round where they are, whatever the smear
        elsewhere in the field (_short_smear looks at a 3x3 grid), and too few streaks could give
        a width: its PSF is estimated as an unaided frame's.
        A gyro-aided tumble's first frame (stress campaign, seed 2026, task 775) had 31 candidates
        at SNR >= 15 smeared 2.1-3.0 px, a 3.1 px smear at a grid corner: no streak to measure
        across, a 1.96 px PSF measured at the 1 px prior and the frame 3" off at NEES 48.
        """
        frame = self.kept[1].frame
        cand = frame.cand
        bright = np.flatnonzero(np.isfinite(cand.snr) & (cand.snr >= STREAK_MIN_SNR) & np.isfinite(cand.x)
                                & np.isfinite(cand.y))
        if bright.size == 0:
            return False
        lengths = np.nan_to_num(np.linalg.norm(self.smear.smear_vectors(cand.x[bright], cand.y[bright]), axis=1))
        return bool(np.count_nonzero(lengths >= MIN_STREAK_LENGTH_PX) < MIN_STREAKS_ACROSS
                    and np.median(lengths) < MIN_STREAK_LENGTH_PX)

    def _streak_widths(self, kept: tuple[PsfTrial, FrameMeasurement]) -> np.ndarray:
        """Return the widths [px] across a measurement's streaks (streak_width.streak_widths); none without streaks."""
        frame = kept[1].frame
        if frame is None or not frame.smeared:
            return np.zeros(0)
        cand, unclipped = frame.cand, _unclipped(frame)
        if frame.off_track is not None:  # a cosmic-ray track's width is not the PSF's
            unclipped &= ~frame.off_track
        return streak_widths(self.image, cand.x[unclipped], cand.y[unclipped], cand.snr[unclipped], self.smear)

    def _hold_prior(self, used: int) -> None:
        """Too few bright streaks says nothing against the prior: a running prior holds (its measurement kept)."""
        self.estimate = PsfEstimate.assumed(self.kept[0].sigma_px, "prior", "rate-aided frame: too few streaks to "
                                            "measure across", used, holds_prior=True)

    def _wider(self, index: int) -> _Step | None:
        """Return the next wider width's step (WIDER_PRIOR_FACTORS[index] x the prior); past them: _unwidened."""
        if index >= len(WIDER_PRIOR_FACTORS) or self.prior.sigma_px * WIDER_PRIOR_FACTORS[index] > MAX_SIGMA_PX:
            return self._unwidened()
        return _Step(PsfTrial(self.prior.sigma_px * WIDER_PRIOR_FACTORS[index]),
                     lambda trial, measured: self._after_wider(trial, measured, index))

    def _after_wider(self, trial: PsfTrial, measured: FrameMeasurement, index: int) -> _Step | None:
        """
        Estimate at the wider width (fainter stars too: estimate.FAINT_STAR_SNR); one replaces the prior's.

        A contradicted estimate (_contradicted) is replaced only by one from more stars.
        """
        frame = measured.frame
        if frame is None:
            return self._unwidened()
        again = estimate_psf(self.image, frame, trial.sigma_px, self.config.gain_e_per_adu, faint=True,
                             exclude=self._not_stars)
        if not again.estimated:
            return self._wider(index + 1)
        if self._contradicted is not None and again.stars <= self._contradicted[2].stars:
            return self._unwidened()  # no better supported than the contradicted estimate: that one stands
        self.kept, self.estimate = (trial, measured), again
        return self._settle(trial, measured)

    def _unwidened(self) -> _Step | None:
        """No wider width gave a (better supported) estimate: a contradicted one stands (settled), else the prior."""
        if self._contradicted is None:
            return None
        trial, measured, estimate = self._contradicted
        self.kept, self.estimate, self._contradicted = (trial, measured), estimate, None
        return self._settle(trial, measured)

    def _settle(self, trial: PsfTrial, measured: FrameMeasurement) -> _Step | None:
        """With an estimate of the frame measured at `trial`: measure again where it calls for it, else keep."""
        estimate = self.estimate
        if _remeasured(estimate, trial.sigma_px, trial.rings):
            return _Step(self._at_estimate(), self._keep)
        width, elongated = _estimated_width(estimate)
        elliptical = self._elliptical()
        if elongated and width < (1.0 - RERUN_TOLERANCE) * trial.sigma_px:
            # Astigmatic stars are narrower across than the prior: measured again with the width
            # test at their minor axis, which the prior's rejected some of them at.
            return _Step(PsfTrial(trial.sigma_px, trial.rings, narrowest_px=width, elliptical=elliptical), self._keep)
        if elliptical is not None:
            self.kept = (trial, replace(measured, context=replace(measured.context, elliptical=elliptical)))
        return None

    def _at_estimate(self) -> PsfTrial:
        """Return the trial at the estimated PSF (_estimated_width; rings, astigmatism)."""
        width, _ = _estimated_width(self.estimate)
        return PsfTrial(width, self.estimate.annular, elliptical=self._elliptical())

    def _elliptical(self) -> EllipticalGaussianPsf | None:
        """
        Return the astigmatic stars' fit model (elongated with no known rate that smears them), else None.

        A round Gaussian's centre is pulled with the sub-pixel phase. Under a known rate the
        elongation is motion, not the optics' shape.
        """
        estimate, smear, (height, width) = self.estimate, self.smear, self.image.shape
        still = smear is None or typical_smear_px(smear, width, height) < self.config.min_smear_px
        if estimate.elongation <= SMEARED_ELONGATION or not still:
            return None
        return EllipticalGaussianPsf(estimate.sigma_major_px, estimate.sigma_minor_px, estimate.angle_rad)


def _unclipped(frame) -> np.ndarray:
    """Return the frame's candidates (bool) peaking below CLIP_MARGIN of the clip level: a flat top is no profile."""
    return np.asarray(frame.cand.peak_raw, float) < CLIP_MARGIN * frame.saturation


def _usable_width(sigma: float) -> bool:
    """Whether a measured width [px] is one the fits support ([MIN_SIGMA_PX, MAX_SIGMA_PX]; NaN: no)."""
    return bool(np.isfinite(sigma) and MIN_SIGMA_PX <= sigma <= MAX_SIGMA_PX)


def _estimated_width(estimate: PsfEstimate) -> tuple[float, bool]:
    """
    Return the width [px] a frame is measured with at its estimated PSF, and whether its stars are elongated.

    Stars elongated alike are smeared (an unknown body rate) or astigmatic: their minor axis is
    the PSF, and a round width would hide the smear from the streak fits.
    """
    elongated = estimate.elongation > SMEARED_ELONGATION
    return (estimate.sigma_minor_px if elongated else estimate.sigma_px), elongated


def _contradicted(estimate: PsfEstimate, cand: "Candidates") -> bool:
    """
    Return whether most of a frame's detections are far wider than its estimate from few stars (CONTRADICTING_WIDTH).

    cand: the candidates measured at the prior. Moment widths as psf.estimate's (the pixel's
    1/12 px^2 off); at a prior narrower than the PSF an aperture cuts them short, so wider
    than CONTRADICTING_WIDTH x the estimate is wider still.
    """
    if estimate.stars >= MAX_ESTIMATE_STARS or cand.x.size < WIDER_PRIOR_MIN_CANDIDATES:
        return False
    measured = np.isfinite(cand.x) & np.isfinite(cand.y) & (cand.snr >= FAINT_STAR_SNR)
    if not measured.any():
        return False
    with np.errstate(invalid="ignore"):
        width = np.sqrt(np.maximum(0.5 * (cand.major[measured] + cand.minor[measured]) - 1.0 / 12.0, 0.0))
    wide = width > CONTRADICTING_WIDTH * _estimated_width(estimate)[0]
    return 2 * int(wide.sum()) > int(measured.sum())


def _remeasured(estimate: PsfEstimate, prior: float, rings: bool = False) -> bool:
    """
    Return whether a frame measured at `prior` [px] (`rings`: as ring stars) is measured again at its estimate's width.

    A round estimate beyond RERUN_TOLERANCE of the prior, or beyond ROUND_RERUN_TOLERANCE when
    that difference exceeds ROUND_RERUN_SIGMAS of the estimate's own uncertainty (bright stars
    fitted a few per cent too narrow lean, and their stated sigma is too small). An elongated
    PSF's minor width is only approximate (the round fit over the axis ratio): it overrides the
    prior only when clearly different (3 RERUN_TOLERANCE). Ring stars (a defocused PSF) are, unless
    measured as rings already: a ring's maxima are one star, split as a blend only farther
    apart; and stars measured as rings that are not.
    """
    width, elongated = _estimated_width(estimate)
    if estimate.annular != rings:
        return True
    if elongated:
        return abs(width - prior) > 3.0 * RERUN_TOLERANCE * prior
    # A round estimate: beyond RERUN_TOLERANCE, or beyond ROUND_RERUN_TOLERANCE when its own
    # uncertainty resolves the difference (bright stars fitted too narrow lean, psf.estimate).
    resolved = not np.isfinite(estimate.sigma_uncertainty_px) \
        or abs(width - prior) > ROUND_RERUN_SIGMAS * estimate.sigma_uncertainty_px
    return abs(width - prior) > (ROUND_RERUN_TOLERANCE if resolved else RERUN_TOLERANCE) * prior
