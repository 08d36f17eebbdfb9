# SPDX-License-Identifier: Apache-2.0
"""
Measurement of every detection before any fit.

Aperture (small components) or footprint (large ones) centre of gravity, flux, SNR, shape
and blend peaks, after hot-pixel cleaning. The result is the table of candidate spots
(Candidates) the rest of the stage selects from.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import cv2
import numpy as np

from ..config import CentroidConfig, blend_separation_px, elongation_limit, hot_pixel_ratio, window_half
from .candidate_frame import CandidateFrame
from .detect import Detections
from .point_window_kernel import PointWindowSettings, SmallSpots, brightest_box, measure_small
from .measure import Moments, aperture_moments, box_sums, clean_hot_pixels, major_moment_noise, two_peaks
from ..windows import gather_windows
from ..streak.smear import segment_length
from ..tracks.track_peaks import FoundPeaks, PeakSearch, ring_track_peaks, star_beside_track_peaks, track_screen

FOOTPRINT_NOISE_SIGMAS = 3.0  # the footprint alone makes a streak only this many moment-noise sigmas past the limit
STREAK_COUNT_MIN_SIGMA_PX = 1.0  # _streak_width's count tells a streak from a cosmic-ray track from this PSF sigma
APERTURE_WIDER = 0.7  # an aperture moment this x the elongation limit (~1.75x a star's): wider than a star
SEARCH_MARGIN = 8  # search window = spot window + this [px]: footprints up to 15 px take the point path


@dataclass(frozen=True)
class Candidates:
    """
    Measured detections, one entry per candidate spot.

    x, y [px], flux [ADU], snr [-], cov (n, 2, 2) [px^2]: centre of gravity and its noise;
    minor, major [px^2], angle [rad]: second moments and the major axis; peak, peak_raw:
    brightest pixel background-subtracted and raw [ADU] (hot pixels as cleaned: a cleaned
    pixel's raw value is its cleaned value plus the background); edge: touches the image border;
    area: footprint [px]; cleaned: hot pixels were replaced in it; wx, wy, wcov:
    intensity-weighted centre of gravity and its covariance; has_window: a small spot that
    keeps its cleaned fit window `window` (n, S, S) with mask `window_valid` and top-left pixel
    (window_col0, window_row0); peaks: per spot, (K, 2) full-resolution (x, y) of separate
    peaks (K >= 2: a blend); detection: index of each candidate in the Detections; cut_snr: the
    SNR the defect test and the first cut judge (snr, or where a hot pixel was cleaned from a
    footprint, the SNR of a PSF-sized disk around its centre of gravity when higher).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    cov: np.ndarray
    minor: np.ndarray
    major: np.ndarray
    angle: np.ndarray
    peak: np.ndarray
    peak_raw: np.ndarray
    edge: np.ndarray
    area: np.ndarray
    cleaned: np.ndarray
    wx: np.ndarray
    wy: np.ndarray
    wcov: np.ndarray
    has_window: np.ndarray
    window: np.ndarray
    window_valid: np.ndarray
    window_col0: np.ndarray
    window_row0: np.ndarray
    peaks: list
    detection: np.ndarray
    cut_snr: np.ndarray

    def take(self, index: np.ndarray) -> "Candidates":
        """Return the candidates at integer `index`, in that order."""
        taken = {f.name: getattr(self, f.name)[index] for f in fields(self) if f.name != "peaks"}
        return replace(self, peaks=[self.peaks[i] for i in index], **taken)

    def moment_covariance(self, idx) -> np.ndarray:
        """
        (n, 2, 2) covariance [px^2] as wide as the spots `idx` themselves (their second moments).

        For centres of gravity no noise model describes (blends of streaks, clipped spots no
        fit could measure), so that the identifier gives them little weight.
        """
        major, minor, theta = self.major[idx], self.minor[idx], self.angle[idx]
        # No positive signal left to take moments of (a spot at the clip level everywhere): as wide
        # as a disc of the spot's area (per-axis variance A / 4 pi), at least one pixel's 1/12.
        disc = np.maximum(np.maximum(self.area[idx], 1) / (4.0 * np.pi), 1.0 / 12.0)
        major = np.where(np.isfinite(major) & (major > 0), major, disc)
        minor = np.where(np.isfinite(minor) & (minor >= 0), np.minimum(minor, major), major)
        theta = np.where(np.isfinite(theta), theta, 0.0)
        c, s = np.cos(theta), np.sin(theta)
        cov = np.empty((idx.size, 2, 2))
        cov[:, 0, 0] = major * c * c + minor * s * s
        cov[:, 1, 1] = major * s * s + minor * c * c
        cov[:, 0, 1] = cov[:, 1, 0] = (major - minor) * c * s
        return cov


class _FootprintWindows(NamedTuple):
    """
    Windows (n, R, C) of spots with top-left pixel (col0, row0) [px].

    Cleaned data [ADU]; footprint (the matched-filter mask, not grown); valid (inside the
    image); blend_use (the pixels searched for two stars).
    """

    data: np.ndarray
    footprint: np.ndarray
    valid: np.ndarray
    blend_use: np.ndarray
    col0: np.ndarray
    row0: np.ndarray

    def take(self, index) -> "_FootprintWindows":
        return _FootprintWindows(*(a[index] for a in self))


def measure_candidates(image: np.ndarray, det: Detections, config: CentroidConfig, sigma: float,
                       find_blends: bool = True, rings: bool = False, streaks_expected: bool = False) -> Candidates:
    """
    Measure every detection after hot-pixel cleaning.

    Aperture measurements for small components, footprint measurements for large ones; rings:
    the stars are rings (blend peaks farther apart, config.blend_separation_px);
    streaks_expected: a body rate predicts streaks (the detection footprints are the matched
    streak filter's), so a footprint longer than the aperture's measure is taken as it is.
    """
    half = window_half(sigma) + 1  # measuring window: the fit window plus a pixel of room
    size = 2 * half + 1
    big = size + SEARCH_MARGIN  # search window: the spot window is re-centred on the brightest 3x3 sum in it
    m = det.x.size
    small = ((det.right - det.left) <= big - 2) & ((det.bottom - det.top) <= big - 2)
    out = {k: np.full(m, np.nan) for k in ("x", "y", "flux", "snr", "minor", "major", "angle", "peak", "peak_raw",
                                           "wx", "wy", "disk_snr")}
    out["cov"], out["wcov"] = np.full((m, 2, 2), np.nan), np.full((m, 2, 2), np.nan)
    out["edge"], out["cleaned"] = np.zeros(m, bool), np.zeros(m, bool)
    out["window"], out["window_valid"] = np.zeros((m, size, size)), np.zeros((m, size, size), bool)
    out["window_col0"], out["window_row0"] = np.zeros(m, np.int64), np.zeros(m, np.int64)
    idx = np.flatnonzero(small)
    out["has_window"] = small.copy()
    out["peaks"] = [np.zeros((0, 2))] * m
    frame = CandidateFrame(image, det, config, sigma, find_blends, rings, streaks_expected)
    if idx.size:
        _measure_small(frame, idx, out)
    large = np.flatnonzero(~small)
    if large.size:
        _measure_large(frame, large, out)
    cut_snr = np.fmax(out["snr"], out.pop("disk_snr"))  # disk_snr: NaN but where _measure_large set it
    return Candidates(area=det.area.astype(np.int64), detection=np.arange(m), cut_snr=cut_snr, **out)


def _measure_small(frame: CandidateFrame, idx: np.ndarray, out: dict) -> None:
    """
    Point-window measurements (point_window_kernel.measure_small) of the detections `idx`, written to `out`.

    Footprints wider than the aperture get their shape from the footprint too.
    """
    image, det, config, sigma = frame.image, frame.det, frame.config, frame.sigma
    half = window_half(sigma) + 1
    big = 2 * half + 1 + SEARCH_MARGIN
    plane = det.background_plane_at(det.x[idx], det.y[idx], config.background_block_px)
    spots = SmallSpots(det.x[idx], det.y[idx], plane.level, plane.slope_x, plane.slope_y, det.top[idx],
                       det.bottom[idx], det.left[idx], det.right[idx])
    settings = PointWindowSettings(half, SEARCH_MARGIN, float(sigma), float(det.noise_adu),
                                   float(config.gain_e_per_adu), float(hot_pixel_ratio(config, sigma)),
                                   config.method == "wcog")
    res = measure_small(image, spots, settings)
    for key in ("x", "y", "flux", "snr", "minor", "major", "angle", "peak", "peak_raw", "cov", "wx", "wy", "wcov",
                "edge", "cleaned", "window", "window_valid", "window_col0", "window_row0"):
        out[key][idx] = getattr(res, key)
    win, valid, c0, r0 = res.search, res.search_valid, res.search_col0, res.search_row0
    # The aperture truncates a short faint streak: footprints wider than it get their
    # elongation (and blend peaks) from the detection footprint too.
    extent = np.maximum(det.right[idx] - det.left[idx], det.bottom[idx] - det.top[idx])
    wide = np.flatnonzero(extent > 2.0 * max(2.5, 3.0 * sigma) + 1.0)
    if wide.size:
        grid_r = np.clip((r0[wide][:, None] + np.arange(big)) // det.binning, 0, det.labels.shape[0] - 1)
        grid_c = np.clip((c0[wide][:, None] + np.arange(big)) // det.binning, 0, det.labels.shape[1] - 1)
        footprint = det.labels[grid_r[:, :, None], grid_c[:, None, :]] == det.label[idx[wide]][:, None, None]
        windows = _FootprintWindows(win[wide], footprint & valid[wide], valid[wide], footprint & valid[wide],
                                    c0[wide], r0[wide])
        _footprint_shape(frame, windows, idx[wide], out)


def _measure_large(frame: CandidateFrame, idx: np.ndarray, out: dict) -> None:
    """
    Footprint measurements of the spots too large for a point window (streaks, bright or blended stars).

    Batched by window size: the footprint (grown by one detection-grid pixel) gives flux,
    centre of gravity and SNR; its pixels 2 sigma above the noise give the shape.
    """
    image, det, config, sigma = frame.image, frame.det, frame.config, frame.sigma
    height, width = image.shape
    noise, gain, b = det.noise_adu, config.gain_e_per_adu, det.binning
    ratio_limit = hot_pixel_ratio(config, sigma)
    margin = int(np.ceil(3.0 * sigma)) + 2
    left, top = det.left[idx] - margin, det.top[idx] - margin
    n_rows = -(-(det.bottom[idx] + margin - top) // 8) * 8  # sizes rounded up to 8 px: few batches
    n_cols = -(-(det.right[idx] + margin - left) // 8) * 8
    grid_h, grid_w = det.labels.shape
    for size_r, size_c in sorted(set(zip(n_rows.tolist(), n_cols.tolist()))):
        k = np.flatnonzero((n_rows == size_r) & (n_cols == size_c))
        members = idx[k]
        col0, row0 = left[k], top[k]
        raw, valid = gather_windows(image, col0, row0, (size_r, size_c))
        grid_r = np.clip((row0[:, None] + np.arange(size_r)) // b, 0, grid_h - 1)
        grid_c = np.clip((col0[:, None] + np.arange(size_c)) // b, 0, grid_w - 1)
        bg = det.background[grid_r[:, :, None], grid_c[:, None, :]]
        labels = det.labels[grid_r[:, :, None], grid_c[:, None, :]] == det.label[members][:, None, None]
        grow = 2 * b + 1
        foot = cv2.dilate(labels.astype(np.uint8).reshape(-1, size_c), np.ones((grow, grow), np.uint8))
        use = (foot.reshape(labels.shape) > 0) & valid
        win, hit = clean_hot_pixels(np.where(valid, raw - bg, 0.0), valid, noise, ratio_limit)
        mom = aperture_moments(win, use, col0, row0, noise, gain, power=1)
        # Shape from the pixels clearly above the noise: the wide footprint's positive noise would
        # inflate a faint spot's second moments. The threshold also thins the cross-track
        # profile, so the narrowest moment (cosmic-ray test) needs a peak 10 sigma clear.
        shape = aperture_moments(win, use & (win > 2.0 * noise), col0, row0, noise, gain)
        wmom = aperture_moments(win, use, col0, row0, noise, gain, power=2) if config.method == "wcog" else mom
        for key in ("x", "y", "flux", "snr", "peak", "cov"):
            out[key][members] = getattr(mom, key)
        # A footprint with a hot pixel cleaned from it is a defect when nothing is left (cut_snr <
        # min_snr); a wide faint star merged with one holds far more noise pixels than light, and its
        # centre of gravity lies between the two: judged, and placed, by a PSF-sized disk around its
        # brightest PSF-sized box where that disk's SNR is the higher.
        cleaned = np.flatnonzero(hit.any(axis=(1, 2)))
        if cleaned.size:
            x, y, snr = _brightest_disk(win[cleaned], use[cleaned], sigma, noise, gain)
            better = snr > mom.snr[cleaned]
            chosen = members[cleaned[better]]
            out["x"][chosen] = x[better] + col0[cleaned[better]]
            out["y"][chosen] = y[better] + row0[cleaned[better]]
            out["disk_snr"][chosen] = snr[better]
        out["major"][members], out["angle"][members] = shape.major, shape.angle
        out["minor"][members] = np.where(shape.peak >= 10.0 * noise, shape.minor, np.inf)
        out["wx"][members], out["wy"][members], out["wcov"][members] = wmom.x, wmom.y, wmom.cov
        # A cleaned hot pixel's raw value is its cleaned one: a defect's reading is no star's peak.
        out["peak_raw"][members] = np.where(use, np.where(hit, win + bg, raw), -np.inf).reshape(k.size, -1).max(axis=1)
        out["edge"][members] = ((det.left[members] <= 0) | (det.top[members] <= 0) | (det.right[members] >= width)
                                | (det.bottom[members] >= height))
        out["cleaned"][members] = hit.any(axis=(1, 2))
        _footprint_shape(frame, _FootprintWindows(win, labels & valid, valid, use, col0, row0), members, out)


def _brightest_disk(windows: np.ndarray, use: np.ndarray, sigma: float, noise: float, gain: float):
    """
    Centre of gravity (x, y) [px, window coordinates] and SNR of a PSF-sized disk in each window (n, R, C).

    The disk (radius max(1.5, 1.6 sigma) [px], the pixels in `use`) around the brightest box sum
    (point_window_kernel.brightest_box, as the point windows are seeded); measure.aperture_moments over it.
    """
    n, rows, cols = windows.shape
    seed_half = max(1, int(sigma + 0.5))
    radius = max(1.5, 1.6 * sigma)
    data = np.where(use, windows, 0.0)
    seed_x, seed_y = np.zeros(n), np.zeros(n)
    for k in range(n):
        _, seed_y[k], seed_x[k] = brightest_box(data[k], seed_half, seed_half, rows - seed_half, seed_half,
                                                cols - seed_half)
    dx = np.arange(cols)[None, None, :] - seed_x[:, None, None]
    dy = np.arange(rows)[None, :, None] - seed_y[:, None, None]
    disk = use & (dx * dx + dy * dy <= radius * radius)
    moments = aperture_moments(data, disk, np.zeros(n), np.zeros(n), noise, gain)
    return moments.x, moments.y, np.where(moments.flux > 0, moments.snr, np.nan)


def _footprint_shape(frame: CandidateFrame, windows: _FootprintWindows, members: np.ndarray, out: dict) -> None:
    """
    Refine the shape of spots `members` from their detection footprint (the matched-filter mask, not grown).

    Which traces a faint streak that a threshold or an aperture cuts short: the spot is as
    elongated as the longer measure says (for sigma < STREAK_COUNT_MIN_SIGMA_PX without
    streaks_expected, the footprint's makes a point-like spot elongated only when the
    aperture's is APERTURE_WIDER x the limit, or FOOTPRINT_NOISE_SIGMAS of its noise,
    major_moment_noise, past the limit); elongated spots get the cross-track width test
    (_streak_width) and, with find_blends, a search for two stars (two_peaks over
    windows.blend_use; tracks beside stars: track_peaks.py).
    """
    det, config, sigma = frame.det, frame.config, frame.sigma
    noise, gain = det.noise_adu, config.gain_e_per_adu
    col0, row0 = windows.col0, windows.row0
    ridge = aperture_moments(windows.data, windows.footprint, col0, row0, noise, gain, signed_shape=True)
    # For a PSF sharper than the cross-track count's (_streak_width) reach, the footprint makes a
    # point-like spot a streak only when the aperture saw it wider too (a faint streak the
    # aperture cuts short) or beyond the footprint moment's own noise: a faint point star's wide
    # footprint (grown by its own noise) stretches it by ~0.2-0.4 px^2, past such a PSF's
    # elongation limit (floored at 1.11 px^2), and the count then drops it. Wider PSFs, and
    # predicted streaks, take the footprint as it is (faint smeared stars need it).
    limit = elongation_limit(sigma)
    aperture = out["major"][members]
    trusted = frame.streaks_expected or sigma >= STREAK_COUNT_MIN_SIGMA_PX
    longer = (ridge.major > aperture) & (trusted | (aperture > APERTURE_WIDER * limit))
    doubt = np.flatnonzero((ridge.major > aperture) & ~longer & (ridge.major > limit))
    if doubt.size:  # the moment noise only where it decides
        sub = windows.take(doubt)
        spread = major_moment_noise(sub.data, sub.footprint, sub.col0, sub.row0,
                                    Moments(*(getattr(ridge, f.name)[doubt] for f in fields(Moments))), noise, gain)
        longer[doubt] = ridge.major[doubt] - FOOTPRINT_NOISE_SIGMAS * spread > limit
    out["major"][members] = np.where(longer, ridge.major, out["major"][members])
    out["angle"][members] = np.where(longer, ridge.angle, out["angle"][members])
    stretched = np.flatnonzero(out["major"][members] > limit)
    if stretched.size == 0:
        return
    long = windows.take(stretched)
    out["minor"][members[stretched]] = np.minimum(out["minor"][members[stretched]], _streak_width(
        long, out["major"][members[stretched]], noise, sigma, det.binning))
    if frame.find_blends:
        found, rows, cols = _blend_peaks(frame, long, out["minor"][members[stretched]])
        for j in np.flatnonzero(found):
            k = stretched[j]
            out["peaks"][members[k]] = np.column_stack([cols[j] + col0[k], rows[j] + row0[k]]).astype(float)


def _blend_peaks(frame: CandidateFrame, long: _FootprintWindows, minor: np.ndarray) -> FoundPeaks:
    """
    Search elongated spots' windows for two stars (two_peaks over blend_use), and for stars beside tracks.

    minor (n,): their narrowest second moments [px^2] (the width test's); tracks beside stars:
    track_peaks.py. Returns per window whether two peaks were found and their window pixels.
    """
    config, sigma, noise = frame.config, frame.sigma, frame.det.noise_adu
    box, box_var, maxima = box_sums(long.data, long.blend_use, config.gain_e_per_adu, noise)
    search = PeakSearch(box, box_var, maxima, 3.0 * config.detection_sigma * noise, long.col0, long.row0)
    found = FoundPeaks(*two_peaks(box, box_var, maxima, search.threshold, blend_separation_px(sigma, frame.rings)))
    if frame.rings:
        found = ring_track_peaks(frame, search, found)
    # Thinner than a star, or two peaks found: the brightest peak may be a track's, and the
    # peaks found may all be on it (a rasterised track has dips) with the star not among them.
    thin = (minor < config.min_width_fraction * sigma ** 2) | found.found
    thin[thin] = track_screen(long.data[thin], long.valid[thin], found.rows[thin, 0], found.cols[thin, 0], sigma,
                              config)
    return star_beside_track_peaks(frame, search, found, thin)


def _streak_width(windows: _FootprintWindows, major, noise, sigma, binning) -> np.ndarray:
    """
    Stand-in for the narrowest second moment [px^2] of elongated spots, for the width test.

    Second moments of a faint streak are too noisy to tell a PSF-wide streak from a cosmic-ray
    track a pixel wide, so count instead: where the ridge is >= 10 noise sigmas, a PSF of sigma
    >= 1 px puts >= 5-sigma signal on >= ~2.5 pixels across the track per pixel of length, a
    cosmic-ray track on ~1. Returns 0 (fails the width test) for a spot with fewer than 1.8
    such pixels per pixel of length (length from the major moment), else inf (no verdict).
    """
    win, footprint, valid = windows.data, windows.footprint, windows.valid
    n, rows, cols = win.shape
    grow = 2 * binning + 1
    grown = cv2.dilate(footprint.astype(np.uint8).reshape(n * rows, cols), np.ones((grow, grow), np.uint8))
    use = (grown.reshape(n, rows, cols) > 0) & valid
    signal = np.where(use, win, 0.0)
    strong = (signal > 5.0 * noise).sum(axis=(1, 2))
    length = segment_length(major, sigma) + 1.0
    # The ridge level: the median of the spot's brightest `length` pixels (a noise peak or two
    # must not make a faint streak look bright).
    ranked = -np.sort(-signal.reshape(n, -1), axis=1)
    take = np.clip(np.rint(length).astype(int), 1, ranked.shape[1])
    ridge = ranked[np.arange(n), take // 2]
    return np.where((ridge >= 10.0 * noise) & (strong < 1.8 * length), 0.0, np.inf)
