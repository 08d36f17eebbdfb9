"""Spot extraction: detect -> measure -> reject defects -> sub-pixel fit -> `Spots`.

Input: a 2-D image in ADU (uint8/uint16/float). Output: `Spots` in pixel coordinates with
(0, 0) at the centre of the top-left pixel, sorted by flux (brightest first). Optionally a
`SmearModel` (camera + body rate + exposure) turns on rate-aided detection and fitting.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .detect import Detections, detect
from .measure import (aperture_moments, box_sums, clean_hot_pixels, cog_phase_bias_rms, secondary_peaks,
                      star_peak_to_neighbour_ratio, two_peaks)
from .kernels import measure_small
from .psf_fit import fit_psf_windows, gather_windows
from .spots import FLAG_BLENDED, FLAG_EDGE, FLAG_RATE_AIDED, FLAG_SATURATED, FLAG_STREAK, Spots
from .streak import segment_length

if TYPE_CHECKING:
    from .streak import SmearModel

SEARCH_MARGIN = 8  # search window = spot window + this [px]: footprints up to 15 px take the point path
CENTROID_METHODS = ("auto", "cog", "wcog", "gaussian", "streak")


@dataclass(frozen=True)
class CentroidConfig:
    """Parameters of `extract_spots` (the centroider node's parameters, same names).

    detection_sigma: threshold in units of the noise of the PSF-matched detection image;
    binning: detection grid bin factor (1 or 2; 2 is 4x cheaper and splits pairs >= ~4 px);
    min_area/max_area: accepted footprint sizes [full-resolution px]; min_snr: reported spots'
    SNR floor; background_block_px: background mesh size [px]; gain_e_per_adu: for the
    shot-noise term of the covariance; saturation_adu: a spot with a pixel at or above it is
    flagged (0 = the image dtype's maximum); max_spots: keep at most this many (brightest).
    psf_sigma_px: the optics' PSF 1-sigma [px]; sets the fit model, windows, hot-pixel test.
    Shape test (hot pixels, cosmic rays; psf_sigma_px > 0): isolated pixels brighter than a
    PSF allows are replaced by their neighbours' mean first; then a spot is rejected when its
    brightest pixel holds more than max_peak_fraction of its flux, or, at SNR >= shape_min_snr,
    when its narrowest second moment is below min_width_fraction * psf_sigma_px^2 (a star is
    never thinner than the PSF; a cosmic-ray track is).
    method: "auto" (default) = PSF fit for point-like spots, streak model for elongated ones;
    "gaussian" = PSF fit for point-like spots, centre of gravity for streaks; "streak" = streak
    model for every spot; "cog" = centre of gravity; "wcog" = intensity-weighted (squared)
    centre of gravity. Saturated spots always use the centre of gravity.
    split_blends: fit two PSFs jointly when a point-like spot shows a second peak.
    min_smear_px: with a known body rate, predicted smears shorter than this are point-like.
    """

    detection_sigma: float = 4.5
    binning: int = 2
    min_area: int = 2
    max_area: int = 20000
    min_snr: float = 5.0
    background_block_px: int = 32
    gain_e_per_adu: float = 1.0
    saturation_adu: float = 0.0
    max_spots: int = 500
    method: str = "auto"
    psf_sigma_px: float = 1.0
    max_peak_fraction: float = 0.5
    min_width_fraction: float = 0.6
    shape_min_snr: float = 10.0
    split_blends: bool = True
    min_smear_px: float = 1.5

    def __post_init__(self) -> None:
        bad = []
        if not (np.isfinite(self.detection_sigma) and self.detection_sigma > 0):
            bad.append(f"detection_sigma={self.detection_sigma} must be > 0")
        if self.binning not in (1, 2):
            bad.append(f"binning={self.binning} must be 1 or 2")
        if not (1 <= self.min_area <= self.max_area):
            bad.append(f"need 1 <= min_area ({self.min_area}) <= max_area ({self.max_area})")
        if not (np.isfinite(self.min_snr) and self.min_snr >= 0):
            bad.append(f"min_snr={self.min_snr} must be >= 0")
        if not (4 <= self.background_block_px <= 1024):
            bad.append(f"background_block_px={self.background_block_px} must be in [4, 1024]")
        if not (np.isfinite(self.gain_e_per_adu) and self.gain_e_per_adu > 0):
            bad.append(f"gain_e_per_adu={self.gain_e_per_adu} must be > 0")
        if not (self.max_spots >= 1):
            bad.append(f"max_spots={self.max_spots} must be >= 1")
        if not (0 <= self.psf_sigma_px <= 50):
            bad.append(f"psf_sigma_px={self.psf_sigma_px} must be in [0, 50] (0 disables the shape test)")
        if self.method not in CENTROID_METHODS:
            bad.append(f"method={self.method!r} must be one of {CENTROID_METHODS}")
        if self.method in ("auto", "gaussian", "streak") and self.psf_sigma_px <= 0:
            bad.append(f"method {self.method!r} needs psf_sigma_px > 0")
        if not (0 < self.max_peak_fraction <= 1 and 0 <= self.min_width_fraction <= 1 and self.shape_min_snr >= 0):
            bad.append("need 0 < max_peak_fraction <= 1, 0 <= min_width_fraction <= 1, shape_min_snr >= 0")
        if not (np.isfinite(self.min_smear_px) and self.min_smear_px >= 0):
            bad.append(f"min_smear_px={self.min_smear_px} must be >= 0")
        if bad:
            raise ValueError("invalid centroid config: " + "; ".join(bad))

    @property
    def window_half(self) -> int:
        """Half size of a point-spot window [px]: the PSF to 3 sigma (beyond, a
        pixel carries < 1 % of the position information)."""
        return int(max(3, np.ceil(3.0 * max(self.psf_sigma_px, 1.0))))


@dataclass
class _Candidates:
    """Working table of measured detections (one entry per candidate spot)."""

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
    wx: np.ndarray  # intensity-weighted centre of gravity and its covariance
    wy: np.ndarray
    wcov: np.ndarray
    has_window: np.ndarray  # small spots keep their cleaned fit window (n, S, S), top-left pixel
    window: np.ndarray
    window_valid: np.ndarray
    window_col0: np.ndarray
    window_row0: np.ndarray
    peaks: list  # large spots: (K, 2) full-resolution (x, y) of separate peaks (K >= 2: a blend)


def extract_spots(image: np.ndarray, config: CentroidConfig = CentroidConfig(),
                  smear: "SmearModel | None" = None) -> Spots:
    """Detect spots and measure them (see CentroidConfig). `smear`, when given, predicts each
    star's streak from the body rate and exposure: detection uses the matched streak kernel
    and positions come from a fit on the predicted path (mid-exposure, curved arcs included)."""
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {image.shape}")
    if image.dtype.kind not in "uif":
        raise ValueError(f"expected a numeric image, got dtype {image.dtype}")
    height, width = image.shape
    binning = config.binning if min(height, width) >= 16 * config.binning else 1
    saturation = config.saturation_adu or (np.iinfo(image.dtype).max if image.dtype.kind in "ui" else np.inf)
    sigma = max(config.psf_sigma_px, 0.5)
    rate_aided = smear is not None and _typical_smear_px(smear, width, height) >= config.min_smear_px
    det = detect(image, binning=binning, background_block_px=config.background_block_px,
                 detection_sigma=config.detection_sigma, psf_sigma_px=config.psf_sigma_px,
                 min_area=config.min_area, max_area=config.max_area,
                 smear_kernel=_smear_kernel(smear, width, height, sigma, binning) if rate_aided else None)
    frame_values = dict(background_adu=float(np.median(det.background[::8, ::8])), noise_adu=det.noise_adu)
    if det.x.size == 0:
        return Spots.empty(width, height, **frame_values)
    noise, gain = det.noise_adu, config.gain_e_per_adu
    cand = _measure(image, det, config, sigma, find_blends=config.split_blends and not rate_aided)

    # Defects: cleaned-away hot pixels (nothing left) and spots too sharp or too thin for the PSF.
    rejected = np.zeros(cand.x.size, bool)
    if config.psf_sigma_px > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            sharp = cand.peak / cand.flux
        rejected = ((cand.cleaned & (cand.snr < config.min_snr)) | (sharp > config.max_peak_fraction)
                    | ((cand.snr >= config.shape_min_snr) & (cand.minor < config.min_width_fraction * sigma ** 2)))
        rejected &= np.isfinite(cand.x)
    # Streaks spread their signal: their footprint SNR understates what the streak fit recovers,
    # so they pass a lower first cut and face min_snr with the fit's SNR.
    streaky = (rate_aided or (cand.major > _elongation_limit(sigma))) & (config.method in ("auto", "streak"))
    first_cut = np.where(streaky, 0.4 * config.min_snr, config.min_snr)
    local = _local_noise_factor(det, cand.x, cand.y, cand.flux, sigma, gain)
    keep = (~rejected & np.isfinite(cand.x) & np.isfinite(cand.y) & (cand.flux > 0)
            & (cand.snr / np.sqrt(local) >= first_cut) & (cand.area >= config.min_area))
    sel = np.flatnonzero(keep)
    n = sel.size
    x, y, flux, cov = cand.x[sel].copy(), cand.y[sel].copy(), cand.flux[sel].copy(), cand.cov[sel].copy()
    snr = cand.snr[sel].copy()
    flags = np.zeros(n, np.uint32)
    # Clipped spots: their pixels at the clip level carry no shape information, so every fit
    # below leaves them out (`excluded`); a saturated spot no fit describes gets a covariance
    # as wide as the spot.
    clip = _clip_levels(image, det, sel, cand.peak_raw[sel], cand.x[sel], cand.y[sel], saturation, gain)
    saturated = np.isfinite(clip)
    flags[saturated] |= FLAG_SATURATED
    flags[cand.edge[sel]] |= FLAG_EDGE
    length, angle = np.zeros(n), np.zeros(n)
    excluded = _clipped_pixels(image, det, sel[saturated], clip[saturated], sigma) if saturated.any() else None
    fitted = np.zeros(n, bool)  # saturated spots measured by a fit without their clipped pixels
    # Elongated beyond the PSF (second moment of a segment of length L is L^2/12).
    elongated = cand.major[sel] > _elongation_limit(sigma)
    # Several separate peaks with dips between them: stars blended into one footprint, not a streak.
    multi = np.array([len(cand.peaks[i]) >= 2 for i in sel], bool) & ~saturated
    if rate_aided and _rate_aid_disagrees(cand, sel, ~saturated & ~cand.edge[sel] & ~multi, sigma, smear):
        return replace(extract_spots(image, config, None), rate_aid_rejected=True)
    flags[multi] |= FLAG_BLENDED
    extra = []  # further stars split off blends: (x, y, flux, cov, snr, peak[, length, angle, flags])
    if config.method == "wcog":
        x, y, cov = cand.wx[sel].copy(), cand.wy[sel].copy(), cand.wcov[sel].copy()
    # An aperture centre of gravity is biased by the star's sub-pixel phase, beyond its noise
    # term: add that bias's RMS, computed for this PSF and aperture (measure_small's), to the
    # covariance of the spots measured so. A fit below replaces both.
    aperture = np.flatnonzero(cand.has_window[sel])
    phase = cog_phase_bias_rms(sigma, min(max(2.5, 3.0 * sigma), float(config.window_half + 1)),
                               2 if config.method == "wcog" else 1)
    cov[aperture] += phase ** 2 * np.eye(2)
    if config.method in ("cog", "wcog") and multi.any():
        # Two stars in one footprint: a centre of gravity between them, as wide as the spot.
        cov[multi] = _moment_covariance(cand, sel[multi])
    if config.method not in ("cog", "wcog"):
        if config.method == "streak" or (rate_aided and config.method == "auto"):
            as_streak = np.ones(n, bool)
        elif config.method == "auto":
            as_streak = elongated.copy()
        else:  # gaussian: streaks keep the centre of gravity
            as_streak = np.zeros(n, bool)
        as_streak &= ~multi
        as_point = ~as_streak & ~elongated & ~multi
        clipped_point = as_point & saturated
        as_point &= ~saturated
        # In a smeared frame (most well-measured spots are streaks) a spot with several peaks is
        # streaks crossing stars or streaks, which point-PSF fits would misplace: it keeps its
        # centre of gravity with a covariance as wide as the spot itself (its second moments).
        clear = (cand.snr[sel] >= 20) & ~saturated
        smeared_frame = rate_aided or (np.sum(elongated & clear & ~multi) >= max(5, 0.5 * np.sum(clear)))
        if multi.any() and (smeared_frame or not config.split_blends):
            b = np.flatnonzero(multi)
            cov[b] = _moment_covariance(cand, sel[b])
        elif multi.any():
            extra += _fit_blends(image, det, config, sigma, np.flatnonzero(multi), x, y, flux, cov, snr, cand, sel)
        if as_point.any():
            extra += _fit_points(image, det, config, sigma, np.flatnonzero(as_point), x, y, flux, cov, snr, flags,
                                 cand, sel, excluded)
        if clipped_point.any():
            fitted[clipped_point] = _fit_clipped_points(image, det, config, sigma, np.flatnonzero(clipped_point),
                                                        x, y, flux, cov, snr, excluded)
        if as_streak.any():
            extra += _fit_streak_spots(image, det, config, sigma, np.flatnonzero(as_streak), x, y, flux, cov, snr,
                                       flags, length, angle, cand, sel, smear if rate_aided else None, noise, gain,
                                       excluded)
            fitted |= as_streak & ((flags & FLAG_STREAK) != 0)
        # A star clipped in a single pixel has no flat top, but its fit shows it: the model at its
        # brightest pixel exceeds the data there by many sigmas. Those are refitted without it.
        path_fitted = (flags & FLAG_RATE_AIDED) != 0
        probe = np.flatnonzero(~saturated & ~multi & ((as_point & (snr > 0)) | path_fitted))
        level = _undershot_peaks(image, det, sel[probe], x[probe], y[probe], flux[probe],
                                 smear.path(x[probe], y[probe]) if rate_aided and probe.size else None, sigma, gain)
        hit = probe[np.isfinite(level)]
        if hit.size:
            clip[hit], saturated[hit] = level[np.isfinite(level)], True
            flags[hit] |= FLAG_SATURATED
            more = _clipped_pixels(image, det, sel[hit], clip[hit], sigma)
            excluded = more if excluded is None else excluded | more
            points, streaks = hit[~path_fitted[hit]], hit[path_fitted[hit]]
            if points.size:
                fitted[points] = _fit_clipped_points(image, det, config, sigma, points, x, y, flux, cov, snr, excluded)
            if streaks.size:
                extra += _fit_streak_spots(image, det, config, sigma, streaks, x, y, flux, cov, snr, flags, length,
                                           angle, cand, sel, smear, noise, gain, excluded)
                fitted[streaks] = snr[streaks] > 0
    wide = np.flatnonzero(saturated & ~fitted)
    if wide.size:
        cov[wide] = _moment_covariance(cand, sel[wide])
    area, peak = cand.area[sel], cand.peak[sel]
    if extra:
        ex = np.array([e[:3] for e in extra])
        x, y, flux = np.concatenate([x, ex[:, 0]]), np.concatenate([y, ex[:, 1]]), np.concatenate([flux, ex[:, 2]])
        cov = np.concatenate([cov, np.array([e[3] for e in extra])])
        snr = np.concatenate([snr, np.array([e[4] for e in extra])])
        # Point blends carry (x, y, flux, cov, snr, peak); split streaks add (length, angle, flags).
        flags = np.concatenate([flags, np.array([e[8] if len(e) > 8 else FLAG_BLENDED for e in extra], np.uint32)])
        area = np.concatenate([area, np.zeros(len(extra), area.dtype)])
        peak = np.concatenate([peak, np.array([e[5] for e in extra])])
        length = np.concatenate([length, np.array([e[6] if len(e) > 8 else 0.0 for e in extra])])
        angle = np.concatenate([angle, np.array([e[7] if len(e) > 8 else 0.0 for e in extra])])
    # Measurements above used the frame's typical pixel noise; where stray light makes the local
    # noise higher (or lower), scale the SNR and covariance by the local/typical variance ratio.
    local = _local_noise_factor(det, x, y, flux, sigma, gain)
    snr, cov = snr / np.sqrt(local), cov * local[:, None, None]
    # A centre of gravity of a window summing to ~0 can land anywhere: a position outside the
    # image measured nothing in it.
    inside = (x >= -0.5) & (x <= width - 0.5) & (y >= -0.5) & (y <= height - 0.5)
    final = np.flatnonzero((snr >= config.min_snr) & inside)
    order = final[np.argsort(-flux[final], kind="stable")][: config.max_spots]
    return Spots(x=x[order], y=y[order], flux=flux[order], snr=snr[order], cov=cov[order], flags=flags[order],
                 area=area[order].astype(np.int32), peak=peak[order], width=width, height=height,
                 rejected_shape=int(rejected.sum()), streak_length=length[order], streak_angle=angle[order],
                 **frame_values)


def _measure(image: np.ndarray, det: Detections, config: CentroidConfig, sigma: float,
             find_blends: bool = True) -> _Candidates:
    """Aperture (small components) or footprint (large ones) measurements of every detection,
    after hot-pixel cleaning."""
    half = config.window_half + 1  # measuring window: the fit window plus a pixel of room
    size = 2 * half + 1
    big = size + SEARCH_MARGIN  # search window: the spot window is re-centred on the brightest 3x3 sum in it
    height, width = image.shape
    noise, gain = det.noise_adu, config.gain_e_per_adu
    ratio_limit = _hot_pixel_ratio(config, sigma)
    m = det.x.size
    weighted = config.method == "wcog"
    small = ((det.right - det.left) <= big - 2) & ((det.bottom - det.top) <= big - 2)
    out = {k: np.full(m, np.nan) for k in ("x", "y", "flux", "snr", "minor", "major", "angle", "peak", "peak_raw",
                                           "wx", "wy")}
    out["cov"], out["wcov"] = np.full((m, 2, 2), np.nan), np.full((m, 2, 2), np.nan)
    out["edge"], out["cleaned"] = np.zeros(m, bool), np.zeros(m, bool)
    out["window"], out["window_valid"] = np.zeros((m, size, size)), np.zeros((m, size, size), bool)
    out["window_col0"], out["window_row0"] = np.zeros(m, np.int64), np.zeros(m, np.int64)
    idx = np.flatnonzero(small)
    out["has_window"] = small.copy()
    out["peaks"] = [np.zeros((0, 2))] * m
    if idx.size:
        bg = det.background_at(det.x[idx], det.y[idx])
        res = measure_small(image, det.x[idx], det.y[idx], bg, det.top[idx], det.bottom[idx], det.left[idx],
                            det.right[idx], half, SEARCH_MARGIN, float(sigma), float(noise), float(gain),
                            float(ratio_limit), weighted)
        for key, value in zip(("x", "y", "flux", "snr", "minor", "major", "angle", "peak", "peak_raw", "cov", "wx",
                               "wy", "wcov", "edge", "cleaned", "window", "window_valid", "window_col0",
                               "window_row0"), res[:19]):
            out[key][idx] = value
        win, valid, c0, r0 = res[19:]
        # The aperture truncates a short faint streak: footprints wider than it get their
        # elongation (and blend peaks) from the detection footprint too.
        extent = np.maximum(det.right[idx] - det.left[idx], det.bottom[idx] - det.top[idx])
        wide = np.flatnonzero(extent > 2.0 * max(2.5, 3.0 * sigma) + 1.0)
        if wide.size:
            grid_r = np.clip((r0[wide][:, None] + np.arange(big)) // det.binning, 0, det.labels.shape[0] - 1)
            grid_c = np.clip((c0[wide][:, None] + np.arange(big)) // det.binning, 0, det.labels.shape[1] - 1)
            footprint = det.labels[grid_r[:, :, None], grid_c[:, None, :]] == det.label[idx[wide]][:, None, None]
            _footprint_shape(win[wide], footprint & valid[wide], valid[wide], c0[wide], r0[wide], idx[wide], out,
                             det, config, sigma, find_blends, blend_use=footprint & valid[wide])
    large = np.flatnonzero(~small)
    if large.size:
        _measure_large(image, det, config, sigma, large, out, find_blends)
    return _Candidates(area=det.area.astype(np.int64), **out)


def _measure_large(image, det, config, sigma, idx, out, find_blends: bool) -> None:
    """Footprint measurements of the spots too large for a point window (streaks, bright or
    blended stars), batched by window size: the footprint (grown by one detection-grid pixel)
    gives flux, centre of gravity and SNR; its pixels 2 sigma above the noise give the shape."""
    height, width = image.shape
    noise, gain, b = det.noise_adu, config.gain_e_per_adu, det.binning
    ratio_limit = _hot_pixel_ratio(config, sigma)
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
        out["major"][members], out["angle"][members] = shape.major, shape.angle
        out["minor"][members] = np.where(shape.peak >= 10.0 * noise, shape.minor, np.inf)
        out["wx"][members], out["wy"][members], out["wcov"][members] = wmom.x, wmom.y, wmom.cov
        out["peak_raw"][members] = np.where(use, raw, -np.inf).reshape(k.size, -1).max(axis=1)
        out["edge"][members] = ((det.left[members] <= 0) | (det.top[members] <= 0) | (det.right[members] >= width)
                                | (det.bottom[members] >= height))
        out["cleaned"][members] = hit.any(axis=(1, 2))
        _footprint_shape(win, labels & valid, valid, col0, row0, members, out, det, config, sigma, find_blends,
                         blend_use=use)


def _footprint_shape(win, footprint, valid, col0, row0, members, out, det, config, sigma, find_blends, blend_use):
    """Refine the shape of spots `members` from their detection footprint (the matched-filter
    mask, not grown), which traces a faint streak that a threshold or an aperture cuts short:
    the spot is as elongated as the longer measure says; elongated spots get the cross-track
    width test (_streak_width) and, with find_blends, a search for two stars (two_peaks over
    `blend_use`). win, footprint, valid: (n, R, C) windows with top-left pixel (col0, row0)."""
    noise, gain = det.noise_adu, config.gain_e_per_adu
    ridge = aperture_moments(win, footprint, col0, row0, noise, gain, signed_shape=True)
    longer = ridge.major > out["major"][members]
    out["major"][members] = np.where(longer, ridge.major, out["major"][members])
    out["angle"][members] = np.where(longer, ridge.angle, out["angle"][members])
    stretched = np.flatnonzero(out["major"][members] > _elongation_limit(sigma))
    if stretched.size == 0:
        return
    out["minor"][members[stretched]] = np.minimum(out["minor"][members[stretched]], _streak_width(
        win[stretched], footprint[stretched], valid[stretched], out["major"][members[stretched]], noise, sigma,
        det.binning))
    if find_blends:
        box, box_var, maxima = box_sums(win[stretched], blend_use[stretched], gain, noise)
        found, rows, cols = two_peaks(box, box_var, maxima, 3.0 * config.detection_sigma * noise,
                                      max(2.0, 2.0 * sigma))
        for j in np.flatnonzero(found):
            k = stretched[j]
            out["peaks"][members[k]] = np.column_stack([cols[j] + col0[k], rows[j] + row0[k]]).astype(float)


# Flat top: several pixels of a spot at exactly its brightest raw value, a tie that shot noise
# makes improbable (chance below FLAT_TOP_CHANCE), mark a clipped spot (the sensor's full
# well or ADC ceiling, whatever saturation_adu says). Only spots whose brightest pixel is
# FLAT_TOP_MIN_SIGMA noise sigmas above the background are examined (fainter ones cannot be
# clipped by a sensor whose noise is that far below its ceiling). A false flag costs only the
# information of the pixels left out, never a wrong covariance.
FLAT_TOP_MIN_SIGMA = 50.0
FLAT_TOP_CHANCE = 0.01


def _clip_levels(image, det, sel, peak_raw, x, y, configured, gain) -> np.ndarray:
    """Raw level [ADU] from which each spot's pixels are clipped (inf: not saturated): the
    configured saturation level when its brightest raw pixel reaches it, else the value m of
    a flat top in its detection box grown by 2 px: k >= 2 pixels at exactly m, where the
    chance of such a tie is C(near - 1, k - 1) p^(k - 1) < FLAT_TOP_CHANCE, p = 1 ADU times
    the peak density 1 / (sqrt(2 pi) s) of a pixel's value, s = sqrt((m - bg) / gain +
    noise^2) its shot + pixel noise, near = pixels within 2 s of m (a streak's ridge has many
    near the top, a clipped core has only its clipped pixels). sel: detection indices."""
    n = sel.size
    level = np.full(n, np.inf)
    reached = peak_raw >= configured
    level[reached] = configured
    background = det.background_at(np.nan_to_num(x), np.nan_to_num(y))
    bright = np.flatnonzero(~reached & (peak_raw - background >= FLAT_TOP_MIN_SIGMA * det.noise_adu))
    height, width = image.shape
    for k in bright:
        d = sel[k]
        box = image[max(det.top[d] - 2, 0):min(det.bottom[d] + 2, height),
                    max(det.left[d] - 2, 0):min(det.right[d] + 2, width)]
        top = float(box.max())
        ties = int(np.count_nonzero(box == top))
        if ties < 2:
            continue
        spread = np.sqrt(max(top - background[k], 0.0) / gain + det.noise_adu ** 2)
        near = int(np.count_nonzero(box >= top - 2.0 * spread))
        chance = math.comb(near - 1, ties - 1) * (1.0 / (np.sqrt(2.0 * np.pi) * spread)) ** (ties - 1)
        if chance < FLAT_TOP_CHANCE:
            level[k] = top
    return level


# A fitted spot whose model exceeds its brightest raw pixel by more than UNDERSHOOT_SIGMA of
# that pixel's noise has a clipped core (a pixel can only read low when it is clipped).
UNDERSHOOT_SIGMA = 6.0


def _undershot_peaks(image, det, sel, x, y, flux, path, sigma, gain) -> np.ndarray:
    """Clip level [ADU] of fitted spots whose brightest raw pixel (in their detection box grown
    by 2 px) reads UNDERSHOOT_SIGMA below the fitted model there (inf: none): clipped in too
    few pixels for a flat top. Only spots FLAT_TOP_MIN_SIGMA above the background are
    examined. x, y, flux: the fits (N,); path: (N, K, 2) offsets of fits on a predicted path
    (the model is their mean PSF, the fits' approximation), None for point fits (the
    pixel-integrated Gaussian)."""
    from .psf_fit import pixel_integrated_profile

    n = sel.size
    level = np.full(n, np.inf)
    if n == 0:
        return level
    height, width = image.shape
    background = det.background_at(np.nan_to_num(x), np.nan_to_num(y))
    # Brightest raw pixel of each grown box (the only per-spot Python step: boxes differ in size).
    value, row, col = np.full(n, -np.inf), np.zeros(n, np.int64), np.zeros(n, np.int64)
    for k, d in enumerate(sel):
        top, left = max(det.top[d] - 2, 0), max(det.left[d] - 2, 0)
        box = image[top:min(det.bottom[d] + 2, height), left:min(det.right[d] + 2, width)]
        if box.size:
            at = int(np.argmax(box))
            row[k], col[k] = divmod(at, box.shape[1])
            row[k] += top
            col[k] += left
            value[k] = box.flat[at]
    above = value - background
    examined = np.flatnonzero(np.isfinite(flux) & (above >= FLAT_TOP_MIN_SIGMA * det.noise_adu))
    if examined.size == 0:
        return level
    r, c, fx, fy, f = row[examined], col[examined], x[examined], y[examined], flux[examined]
    if path is None:
        px, _ = pixel_integrated_profile(c - 0.5, fx, sigma)
        py, _ = pixel_integrated_profile(r - 0.5, fy, sigma)
        model = f * px * py
    else:
        var_eff = sigma * sigma + 1.0 / 12.0
        dx = (c - fx)[:, None] - path[examined, :, 0]
        dy = (r - fy)[:, None] - path[examined, :, 1]
        model = f * np.mean(np.exp(-0.5 * (dx * dx + dy * dy) / var_eff), axis=1) / (2.0 * np.pi * var_eff)
    noise = np.sqrt(np.maximum(model, 0.0) / gain + det.noise_adu ** 2)
    hit = above[examined] < model - UNDERSHOOT_SIGMA * noise
    level[examined[hit]] = value[examined[hit]]
    return level


def _clipped_pixels(image, det, sel, level, sigma) -> np.ndarray:
    """(H, W) bool: the pixels at or above their spot's clip level `level` [ADU] in the
    detection boxes `sel`, grown by the PSF's reach (any fit reading them leaves them out)."""
    height, width = image.shape
    out = np.zeros(image.shape, bool)
    grow = int(np.ceil(3.0 * sigma)) + 2
    for d, value in zip(sel, level):
        rows = slice(max(det.top[d] - grow, 0), min(det.bottom[d] + grow, height))
        cols = slice(max(det.left[d] - grow, 0), min(det.right[d] + grow, width))
        out[rows, cols] |= image[rows, cols] >= value
    return out


def _moment_covariance(cand, idx) -> np.ndarray:
    """(n, 2, 2) covariance [px^2] as wide as the spots `idx` themselves (their second
    moments): for centres of gravity no noise model describes (blends of streaks, clipped
    spots no fit could measure), so that the identifier gives them little weight."""
    major, minor, theta = cand.major[idx], cand.minor[idx], cand.angle[idx]
    # No positive signal left to take moments of (a spot at the clip level everywhere): as wide
    # as a disc of the spot's area (per-axis variance A / 4 pi), at least one pixel's 1/12.
    disc = np.maximum(np.maximum(cand.area[idx], 1) / (4.0 * np.pi), 1.0 / 12.0)
    major = np.where(np.isfinite(major) & (major > 0), major, disc)
    minor = np.where(np.isfinite(minor) & (minor >= 0), np.minimum(minor, major), major)
    theta = np.where(np.isfinite(theta), theta, 0.0)
    c, s = np.cos(theta), np.sin(theta)
    cov = np.empty((idx.size, 2, 2))
    cov[:, 0, 0] = major * c * c + minor * s * s
    cov[:, 1, 1] = major * s * s + minor * c * c
    cov[:, 0, 1] = cov[:, 1, 0] = (major - minor) * c * s
    return cov


def _fit_clipped_points(image, det, config, sigma, which, x, y, flux, cov, snr, excluded) -> np.ndarray:
    """PSF fit of saturated point-like spots `which` (in place) without their clipped pixels:
    the wings alone fix the centre, and the inverse Fisher information of those pixels is its
    covariance. The window is the point window grown by the clipped core's radius. Returns
    which of them converged (the others keep their centre of gravity)."""
    noise, gain = det.noise_adu, config.gain_e_per_adu
    cx, cy = np.rint(x[which]).astype(np.int64), np.rint(y[which]).astype(np.int64)
    ok = np.zeros(which.size, bool)
    probe = config.window_half
    core, _ = gather_windows(excluded, cx - probe, cy - probe, 2 * probe + 1)
    radius = np.ceil(np.sqrt(core.sum(axis=(1, 2)) / np.pi)).astype(np.int64)
    half_all = config.window_half + radius
    for half in np.unique(half_all):
        k = np.flatnonzero(half_all == half)
        size = 2 * int(half) + 1
        col0, row0 = cx[k] - half, cy[k] - half
        win, valid = _cleaned_windows(image, col0, row0, size, det.background_at(x[which[k]], y[which[k]]), noise,
                                      sigma)
        clipped, _ = gather_windows(excluded, col0, row0, size)
        valid &= clipped == 0
        # The flux is linear in the model: start from the window's sum (the clipped core short).
        flux0 = np.maximum(np.where(valid, win, 0.0).sum(axis=(1, 2)), flux[which[k]])
        fx, fy, ff, fc, good, fv = fit_psf_windows(win, valid, col0, row0, x[which[k]][:, None],
                                                   y[which[k]][:, None], flux0[:, None], sigma, noise, gain)
        good = good[:, 0] & (valid.sum(axis=(1, 2)) > 6)
        t = which[k[good]]
        x[t], y[t], flux[t], cov[t] = fx[good, 0], fy[good, 0], ff[good, 0], fc[good, 0]
        snr[t] = ff[good, 0] / np.sqrt(fv[good, 0])
        ok[k] = good
    return ok


def _elongation_limit(sigma: float) -> float:
    """Largest second moment [px^2] of a point-like spot: 2.5x a pixelated PSF's (a segment of
    length L adds L^2 / 12)."""
    return 2.5 * (sigma ** 2 + 1.0 / 12.0)


def _hot_pixel_ratio(config: "CentroidConfig", sigma: float) -> float:
    """Peak-to-brightest-neighbour ratio above which a pixel is a defect, not starlight
    (twice what the PSF allows); inf (no cleaning) without a PSF."""
    return 2.0 * star_peak_to_neighbour_ratio(sigma) if config.psf_sigma_px > 0 else np.inf


def _streak_width(win, footprint, valid, major, noise, sigma, binning) -> np.ndarray:
    """Stand-in for the narrowest second moment [px^2] of elongated spots, for the width test.

    Second moments of a faint streak are too noisy to tell a PSF-wide streak from a cosmic-ray
    track a pixel wide, so count instead: where the ridge is >= 10 noise sigmas, a PSF of sigma
    >= 1 px puts >= 5-sigma signal on >= ~2.5 pixels across the track per pixel of length, a
    cosmic-ray track on ~1. Returns 0 (fails the width test) for a spot with fewer than 1.8
    such pixels per pixel of length (length from the major moment), else inf (no verdict)."""
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


def _cleaned_windows(image, col0, row0, size, background, noise, sigma):
    """Background-subtracted (n, size, size) windows with hot pixels cleaned; cleaned on windows
    one pixel larger, so that a hot pixel on the border is judged against its true neighbours."""
    raw, valid = gather_windows(image, np.asarray(col0) - 1, np.asarray(row0) - 1, size + 2)
    win, _ = clean_hot_pixels(np.where(valid, raw - np.asarray(background)[:, None, None], 0.0), valid, noise,
                              2.0 * star_peak_to_neighbour_ratio(sigma))
    return win[:, 1:-1, 1:-1], valid[:, 1:-1, 1:-1]


def _fit_points(image, det, config, sigma, which, x, y, flux, cov, snr, flags, cand, sel, excluded=None):
    """Gaussian PSF fit of point-like spots `which` (in place); blends get a joint 2-PSF fit.
    Pixels `excluded` (a neighbour's clipped core; None = none) are left out of the fits.
    Returns the split-off second stars as (x, y, flux, cov, snr, peak) tuples."""
    half = config.window_half
    size = 2 * half + 1
    noise, gain = det.noise_adu, config.gain_e_per_adu
    # Windows measured already (small spots, centred on their peak) are reused, cropped to the
    # fit window around the same centre pixel.
    source = sel[which]
    crop = (cand.window.shape[1] - size) // 2
    win = cand.window[source][:, crop:crop + size, crop:crop + size].copy()
    valid = cand.window_valid[source][:, crop:crop + size, crop:crop + size].copy()
    col0, row0 = cand.window_col0[source] + crop, cand.window_row0[source] + crop
    fresh = np.flatnonzero(~cand.has_window[source])
    if fresh.size:
        col0[fresh] = np.rint(x[which[fresh]]).astype(np.int64) - half
        row0[fresh] = np.rint(y[which[fresh]]).astype(np.int64) - half
        bg = det.background_at(x[which[fresh]], y[which[fresh]])
        win[fresh], valid[fresh] = _cleaned_windows(image, col0[fresh], row0[fresh], size, bg, noise, sigma)
    if excluded is not None:
        clipped, _ = gather_windows(excluded, col0, row0, size)
        valid &= clipped == 0
    blended = np.zeros(which.size, bool)
    extra = []
    if config.split_blends:
        found, pr, pc = secondary_peaks(win, valid, half, config.detection_sigma * 3.0 * noise,
                                        min_separation=max(2.0, 2.0 * sigma), radius=half - 1.5, gain=gain, noise=noise)
        # A second peak that is another detected spot is fitted jointly but not reported twice.
        px, py = col0 + pc, row0 + pr
        others = np.hypot(px[:, None] - x[None, :], py[:, None] - y[None, :])
        others[np.arange(which.size), which] = np.inf
        duplicate = others.min(axis=1) < 2.0 if x.size > 1 else np.zeros(which.size, bool)
        blended = found
        if blended.any():
            b = np.flatnonzero(blended)
            bx0 = np.column_stack([x[which[b]], px[b].astype(float)])
            by0 = np.column_stack([y[which[b]], py[b].astype(float)])
            bf0 = np.column_stack([flux[which[b]], np.maximum(win[b, pr[b], pc[b]] * 2 * np.pi * sigma ** 2, 1.0)])
            fx, fy, ff, fc, ok, fv = fit_psf_windows(win[b], valid[b], col0[b], row0[b], bx0, by0, bf0, sigma, noise,
                                                     gain)
            for j, k in enumerate(b):
                if not ok[j].all():
                    blended[k] = False
                    continue
                t = which[k]
                x[t], y[t], flux[t], cov[t], snr[t] = fx[j, 0], fy[j, 0], ff[j, 0], fc[j, 0], ff[j, 0] / np.sqrt(fv[j, 0])
                flags[t] |= FLAG_BLENDED
                if not duplicate[k]:
                    second_snr = ff[j, 1] / np.sqrt(fv[j, 1])
                    if second_snr >= config.min_snr:
                        extra.append((fx[j, 1], fy[j, 1], ff[j, 1], fc[j, 1], second_snr, float(win[k, pr[k], pc[k]])))
    single = np.flatnonzero(~blended)
    if single.size:
        fx, fy, ff, fc, ok, fv = fit_psf_windows(win[single], valid[single], col0[single], row0[single],
                                                 x[which[single]][:, None], y[which[single]][:, None],
                                                 flux[which[single]][:, None], sigma, noise, gain)
        good = ok[:, 0]
        t = which[single[good]]
        x[t], y[t], flux[t], cov[t] = fx[good, 0], fy[good, 0], ff[good, 0], fc[good, 0]
        snr[t] = ff[good, 0] / np.sqrt(fv[good, 0])
    return extra


def _fit_blends(image, det, config, sigma, which, x, y, flux, cov, snr, cand, sel):
    """Joint fit of one PSF per peak over the footprint window of each blended spot `which`
    (in place for the brightest star); returns the others as (x, y, flux, cov, snr, peak)."""
    noise, gain = det.noise_adu, config.gain_e_per_adu
    margin = int(np.ceil(3.0 * sigma)) + 2
    extra = []
    for t in which:
        peaks = cand.peaks[sel[t]]
        left = int(np.floor(peaks[:, 0].min())) - margin
        top = int(np.floor(peaks[:, 1].min())) - margin
        size = int(max(np.ptp(peaks[:, 0]), np.ptp(peaks[:, 1]))) + 2 * margin + 1
        bg = det.background_at(np.array([peaks[0, 0]]), np.array([peaks[0, 1]]))
        win, valid = _cleaned_windows(image, np.array([left]), np.array([top]), size, bg, noise, sigma)
        amplitude = win[0, (peaks[:, 1] - top).astype(int), (peaks[:, 0] - left).astype(int)]
        flux0 = np.maximum(amplitude * 2.0 * np.pi * sigma ** 2, 1.0)
        fx, fy, ff, fc, ok, fv = fit_psf_windows(win, valid, np.array([left]), np.array([top]), peaks[None, :, 0],
                                                 peaks[None, :, 1], flux0[None], sigma, noise, gain)
        if not ok[0].all():
            continue  # keep the centre of gravity, flagged as a blend
        order = np.argsort(-ff[0])
        first = order[0]
        x[t], y[t], flux[t], cov[t] = fx[0, first], fy[0, first], ff[0, first], fc[0, first]
        snr[t] = ff[0, first] / np.sqrt(fv[0, first])
        for k in order[1:]:
            snr_k = ff[0, k] / np.sqrt(fv[0, k])
            if snr_k >= config.min_snr:
                extra.append((fx[0, k], fy[0, k], ff[0, k], fc[0, k], snr_k, float(amplitude[k])))
    return extra


def _fit_streak_spots(image, det, config, sigma, which, x, y, flux, cov, snr, flags, length, angle, cand, sel,
                      smear, noise, gain, excluded=None) -> list:
    """Streak-model fit of spots `which` (in place): on the predicted path when `smear` is
    given, else a free line segment seeded from the spot's moments; pixels `excluded`
    (clipped; None = none) are left out. On the predicted path, a spot whose fit leaves
    another star's light is refitted with it (_split_merged_streaks); returns the stars split
    off so as extra-spot tuples (x, y, flux, cov, snr, peak, length, angle, flags)."""
    from .streak import fit_streaks, fit_streaks_on_path

    reach = _streak_reach(cand, sel, which, x, y, smear, sigma)
    if smear is not None:
        reach = 2.0 * reach  # room for a merged neighbour's path (a pair's window covers both)
    residual = _streak_residual(image, det, sigma, noise, x[which], y[which], reach)
    extra = []
    if smear is not None:
        path = smear.path(x[which], y[which])
        fit = fit_streaks_on_path(residual, x[which], y[which], flux[which], path, sigma, noise, gain,
                                  excluded=excluded)
        extra_flag = FLAG_STREAK | FLAG_RATE_AIDED
    else:
        length0 = segment_length(cand.major[sel][which], sigma)
        fit = fit_streaks(residual, x[which], y[which], flux[which], length0, cand.angle[sel][which], sigma, noise,
                          gain, excluded=excluded)
        extra_flag = FLAG_STREAK
    good = fit.converged
    t = which[good]
    x[t], y[t], flux[t], cov[t] = fit.x[good], fit.y[good], fit.flux[good], fit.cov[good]
    length[t], angle[t] = fit.length[good], np.nan_to_num(fit.angle[good])
    flags[t] |= extra_flag
    with np.errstate(divide="ignore", invalid="ignore"):
        snr[t] = fit.flux[good] / fit.flux_sigma[good]  # the fit's (matched-filter) SNR
    if smear is not None and good.any():
        extra = _split_merged_streaks(residual, fit, which, path, x, y, flux, cov, snr, flags, config, sigma, noise,
                                      gain, excluded)
    # A spot the streak model could not describe is not reported when it should be a streak
    # (rate aided, or elongated: a fragment or a defect); a point-like one keeps its centroid.
    failed = which[~good]
    elongated = cand.major[sel][failed] > _elongation_limit(sigma)
    snr[failed[elongated | (smear is not None)]] = 0.0
    return extra


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


def _split_merged_streaks(residual, fit, which, path, x, y, flux, cov, snr, flags, config, sigma, noise, gain,
                          excluded) -> list:
    """Several stars on one predicted path (streaks merged into one detection, or a
    neighbour's streak in the window): the one-star fit of such a spot is pulled toward the
    other stars far beyond its covariance. Spots `which` with one-star fit `fit` (path (n, K,
    2)) whose residual holds another star (MERGED_*) are refitted jointly with it, seeded at
    the matched-filter peak of the residual, as long as that helps. When a group wins, its
    first star (the spot's own) replaces the spot (in place, flag BLENDED, covariance of the
    joint fit) and the others are returned as extra-spot tuples unless they are spots
    already (within 2 px) or below min_snr."""
    from .streak import fit_star_groups_on_path, second_source_on_path

    k = np.flatnonzero(fit.converged)
    # One row per spot, one column per star of its group so far (NaN: no such star).
    gx, gy, gf, gs = fit.x[k][:, None], fit.y[k][:, None], fit.flux[k][:, None], fit.flux_sigma[k][:, None]
    gcov = fit.cov[k][:, None]
    chi2 = fit.chi2[k].copy()
    growing = np.ones(k.size, bool)
    for stars in range(1, MERGED_MAX_STARS):
        tried = np.flatnonzero(growing)
        if tried.size == 0:
            break
        sx, sy, sf, found = second_source_on_path(residual, gx[tried, :stars], gy[tried, :stars],
                                                  gf[tried, :stars], path[k[tried]], sigma, noise, gain, excluded)
        # Only a star whose image overlaps the spot's own (its path within MERGED_OVERLAP_SIGMA
        # PSF sigmas of the spot's path somewhere) can pull the fit; others merely share the window.
        offset = np.stack([sx - gx[tried, 0], sy - gy[tried, 0]], axis=1)
        chords = path[k[tried]][:, :, None, :] - path[k[tried]][:, None, :, :]  # (n, K, K, 2): o_a - o_b
        gap = np.min(np.linalg.norm(offset[:, None, None, :] - chords, axis=3), axis=(1, 2))
        seeded = (found >= MERGED_MIN_SNR) & (sf > 0) & (gap <= MERGED_OVERLAP_SIGMA * sigma)
        tried, sx, sy, sf = tried[seeded], sx[seeded], sy[seeded], sf[seeded]
        growing[:] = False
        if tried.size == 0:
            break
        fits = fit_star_groups_on_path(residual, np.column_stack([gx[tried, :stars], sx]),
                                       np.column_stack([gy[tried, :stars], sy]),
                                       np.column_stack([gf[tried, :stars], sf]), path[k[tried]], sigma, noise, gain,
                                       excluded=excluded)
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
    extra = []
    split = np.flatnonzero(np.isfinite(gx[:, 1:]).any(axis=1)) if gx.shape[1] > 1 else np.zeros(0, np.int64)
    for j in split:
        # Star 0 is the spot's own (its window, started from its fit); the others are neighbours.
        t = which[k[j]]
        x[t], y[t], flux[t], cov[t] = gx[j, 0], gy[j, 0], gf[j, 0], gcov[j, 0]
        snr[t] = gf[j, 0] / gs[j, 0]
        flags[t] |= FLAG_BLENDED
        for m in np.flatnonzero(np.isfinite(gx[j]))[1:]:
            star_snr = gf[j, m] / gs[j, m]
            others = np.hypot(np.r_[x, [e[0] for e in extra]] - gx[j, m], np.r_[y, [e[1] for e in extra]] - gy[j, m])
            others[t] = np.inf
            if star_snr >= config.min_snr and not np.any(others < 2.0):  # not a spot (or split-off star) already
                row = int(np.clip(np.rint(gy[j, m]), 0, residual.shape[0] - 1))
                col = int(np.clip(np.rint(gx[j, m]), 0, residual.shape[1] - 1))
                extra.append((gx[j, m], gy[j, m], gf[j, m], gcov[j, m], star_snr, float(residual[row, col]),
                              fit.length[k[j]], np.nan_to_num(fit.angle[k[j]]),
                              FLAG_STREAK | FLAG_RATE_AIDED | FLAG_BLENDED))
    return extra


# Rate-aid check. An aiding rate that disagrees with the image (an estimate lagging an
# acceleration, a mis-scaled or misaligned gyro) makes every path fit lock onto the same end of
# its streak: a bias common to all stars, which no attitude verification can see, with
# covariances as small as for a right aid; the rest of each streak comes out as a further spot.
# The detection footprints show the streaks as they are (the matched filter only smooths
# them), so before any fit the smear vector of each of the AID_CHECK_STREAKS brightest clean
# detections (footprint SNR >= AID_CHECK_MIN_SNR; one peak; not clipped or at the edge; minor
# second moment at most AID_CHECK_MAX_MINOR sigma^2, i.e. not two streaks side by side) is
# taken from its footprint's moments, length sqrt(12 (major - sigma^2 - 1/12)) along the major
# axis, and compared with the predicted one. When at least AID_REJECT_FRACTION of them are
# further from it than AID_TOLERANCE_PX or AID_TOLERANCE_FRACTION of their predicted length (a
# wrong rate moves all of them; streaks merged end to end or crossing others are single
# outliers), the frame is measured without the aid. On rendered frames at 0.3-5 deg/s
# (cross-boresight, roll, mixed) the right rate gives distances of 1-6 % of the length, a 10 %
# wrong one 11-17 %. With fewer than AID_CHECK_MIN_STREAKS such detections the aid is kept
# unchecked (faint fields are where it helps most).
AID_CHECK_STREAKS = 12
AID_CHECK_MIN_STREAKS = 3
AID_CHECK_MIN_SNR = 30.0
AID_CHECK_MAX_MINOR = 1.8
AID_TOLERANCE_PX = 1.0
AID_TOLERANCE_FRACTION = 0.15
AID_REJECT_FRACTION = 0.75


def _rate_aid_disagrees(cand, sel, usable, sigma, smear) -> bool:
    """True when the footprints of the brightest candidates `sel` (of those `usable`: one peak,
    not clipped, not at the edge) are not the smear `smear` predicts (AID_* above)."""
    one_wide = cand.minor[sel] <= AID_CHECK_MAX_MINOR * sigma ** 2  # not two streaks side by side
    snr = cand.snr[sel]
    candidates = np.flatnonzero(usable & one_wide & (snr >= AID_CHECK_MIN_SNR))
    if candidates.size < AID_CHECK_MIN_STREAKS:
        return False
    c = sel[candidates[np.argsort(-snr[candidates], kind="stable")[:AID_CHECK_STREAKS]]]
    predicted = smear.smear_vectors(cand.x[c], cand.y[c])
    # A pixel-integrated PSF's second moment is sigma^2 + 1/12 [px^2].
    length = segment_length(cand.major[c], np.sqrt(sigma ** 2 + 1.0 / 12.0))
    angle = np.nan_to_num(cand.angle[c])
    measured = np.nan_to_num(length)[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    # A footprint has no sense (start or end): compare with the nearer of +-measured.
    distance = np.minimum(np.linalg.norm(measured - predicted, axis=1), np.linalg.norm(measured + predicted, axis=1))
    tolerance = np.maximum(AID_TOLERANCE_PX, AID_TOLERANCE_FRACTION * np.linalg.norm(predicted, axis=1))
    return bool(np.mean(~(distance <= tolerance)) >= AID_REJECT_FRACTION)


def _streak_reach(cand, sel, which, x, y, smear, sigma) -> np.ndarray:
    """Half size [px] of the region each streak fit may read: half the predicted (or measured)
    streak length plus the PSF's reach and slack for the window the fitter builds."""
    if smear is not None:
        half_length = 0.5 * np.linalg.norm(smear.smear_vectors(x[which], y[which]), axis=1)
    else:
        half_length = np.sqrt(np.maximum(np.nan_to_num(3.0 * cand.major[sel][which]), 0.0))  # NaN: no extent
    return half_length * 1.2 + 5.0 * sigma + 4.0


def _streak_residual(image, det, sigma, noise, x, y, reach) -> np.ndarray:
    """Background-subtracted, hot-pixel-cleaned float32 image for the streak fits: the whole
    frame when there are many streaks (two OpenCV passes), else only square regions of half
    size `reach` [px] around (x, y), the rest left at 0 (the fits read nothing else)."""
    height, width = image.shape
    b = det.binning
    ratio_limit = 2.0 * star_peak_to_neighbour_ratio(sigma)
    if x.size > 20:
        full_bg = cv2.resize(det.background, (det.background.shape[1] * b, det.background.shape[0] * b),
                             interpolation=cv2.INTER_NEAREST)
        residual = image.astype(np.float32)
        h, w = min(full_bg.shape[0], height), min(full_bg.shape[1], width)
        residual[:h, :w] -= full_bg[:h, :w]
        residual[h:, :] -= det.background[-1, -1]  # odd sizes: the last row/column
        residual[:h, w:] -= det.background[-1, -1]
        cleaned, _ = clean_hot_pixels(residual[None], np.ones((1,) + residual.shape, bool), noise, ratio_limit)
        return cleaned[0].astype(np.float32)
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


def _local_noise_factor(det: Detections, x, y, flux, sigma, gain) -> np.ndarray:
    """Variance ratio of a spot's measurement under the local pixel noise vs the frame's typical
    one: (F/g + N s_local^2) / (F/g + N s^2), N = 4 pi sigma^2 the PSF's effective pixels."""
    scale = det.noise_scale_at(np.nan_to_num(x), np.nan_to_num(y))
    shot = np.maximum(np.nan_to_num(flux), 0.0) / gain
    pixels = 4.0 * np.pi * sigma ** 2 * det.noise_adu ** 2
    return (shot + pixels * scale ** 2) / (shot + pixels)


def _typical_smear_px(smear: "SmearModel", width: int, height: int) -> float:
    """Largest predicted smear length [px] over a 3x3 grid of field points."""
    gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 3) * (width - 1), np.linspace(0.1, 0.9, 3) * (height - 1))
    return float(np.max(np.linalg.norm(smear.smear_vectors(gx.ravel(), gy.ravel()), axis=1)))


def _smear_kernel(smear: "SmearModel", width: int, height: int, sigma: float, binning: int) -> np.ndarray | None:
    """Matched-filter kernel on the detection grid for a smear that is about the same over the
    field (cross-boresight rates); None when it varies by more than 30 % (roll-dominated)."""
    gx, gy = np.meshgrid(np.linspace(0.1, 0.9, 3) * (width - 1), np.linspace(0.1, 0.9, 3) * (height - 1))
    vectors = smear.smear_vectors(gx.ravel(), gy.ravel()) / binning
    mean = vectors.mean(axis=0)
    if np.max(np.linalg.norm(vectors - mean, axis=1)) > 0.3 * max(np.linalg.norm(mean), 1e-9):
        return None
    s = max(0.5, sigma / binning)
    half = int(np.ceil(0.5 * np.max(np.abs(mean)) + 2.5 * s))
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float64)
    kernel = np.zeros_like(xx)
    steps = max(2, int(np.ceil(np.linalg.norm(mean) * 2)))
    for t in (np.arange(steps) + 0.5) / steps - 0.5:
        kernel += np.exp(-0.5 * ((xx - t * mean[0]) ** 2 + (yy - t * mean[1]) ** 2) / s ** 2)
    return (kernel / kernel.sum()).astype(np.float32)
