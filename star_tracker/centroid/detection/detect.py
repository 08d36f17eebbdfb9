# SPDX-License-Identifier: Apache-2.0
"""
Detection: background, noise, thresholding and connected components.

Works on the image binned `binning` x `binning` (mean of the block, OpenCV INTER_AREA): a
2x2 bin keeps a PSF of sigma >= 1 px well sampled, loses little sensitivity, and makes the
whole-frame work 4x cheaper. Positions are measured later on the full-resolution pixels.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import cv2
import numpy as np

from .components_kernel import component_stats

MAD_TO_SIGMA = 1.4826


class BackgroundPlane(NamedTuple):
    """
    The background near each of n spots as a plane: level [ADU] at (x, y) [px] and slopes [ADU/px].

    A stray-light ramp left in a spot's window (its background taken as one level) pulls the
    centroid toward the bright side: 0.014 px for a 30,000 e- star on a 20,000 e- background
    that changes by half of itself across the half diagonal, 0.07 px at 6,000 e-. Windows
    subtract the plane instead (over_window).
    """

    x: np.ndarray
    y: np.ndarray
    level: np.ndarray
    slope_x: np.ndarray
    slope_y: np.ndarray

    def over_window(self, col0: np.ndarray, row0: np.ndarray, size: int) -> np.ndarray:
        """Return the plane over (n, size, size) windows whose top-left pixels are (col0, row0) [ADU]."""
        steps = np.arange(size, dtype=float)
        dx = np.asarray(col0, float)[:, None] + steps - self.x[:, None]
        dy = np.asarray(row0, float)[:, None] + steps - self.y[:, None]
        return (self.level[:, None, None] + self.slope_x[:, None, None] * dx[:, None, :]
                + self.slope_y[:, None, None] * dy[:, :, None])


# Half the span [binned px] of the central differences that give the background's slopes: within
# one piece of the bilinear tile map (tiles are background_block_px / binning wide).
SLOPE_HALF_SPAN = 2.0
# A slope is kept when it exceeds this many of its standard errors (slope_noise). Without the
# test the tile medians' noise tilts every window a little: on flat backgrounds the centroids
# scattered up to ~3 % more (bench_psf_range).
SLOPE_SIGNIFICANCE = 3.0
TILE_SAMPLES = 64  # background_and_noise's samples per tile (at most 8 x 8)


def slope_noise(pixel_noise: np.ndarray, block_px: int) -> np.ndarray:
    """Return the standard error [ADU/px] of a slope between two neighbouring tiles' medians of pixel_noise [ADU]."""
    median_noise = 1.2533 * np.asarray(pixel_noise, float) / np.sqrt(TILE_SAMPLES)  # the median's efficiency
    return np.sqrt(2.0) * median_noise / float(block_px)


def background_plane(background: np.ndarray, binning: int, x: np.ndarray, y: np.ndarray,
                     slope_floor: np.ndarray | float = 0.0) -> BackgroundPlane:
    """
    Return the binned background map [ADU] as a plane at each full-resolution position (x, y) [px].

    Level: the map bilinearly interpolated there (binned pixel j's centre is full-resolution
    j binning + (binning - 1) / 2). Slopes [ADU/px]: central differences of that interpolation
    over +-SLOPE_HALF_SPAN binned pixels; a slope whose size is below slope_floor [ADU/px] is 0.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    u = (x - 0.5 * (binning - 1)) / binning
    v = (y - 0.5 * (binning - 1)) / binning
    d = SLOPE_HALF_SPAN
    level = _bilinear(background, u, v)
    slope_x = (_bilinear(background, u + d, v) - _bilinear(background, u - d, v)) / (2.0 * d * binning)
    slope_y = (_bilinear(background, u, v + d) - _bilinear(background, u, v - d)) / (2.0 * d * binning)
    slope_x = np.where(np.abs(slope_x) > slope_floor, slope_x, 0.0)
    slope_y = np.where(np.abs(slope_y) > slope_floor, slope_y, 0.0)
    return BackgroundPlane(x, y, level, slope_x, slope_y)


def _bilinear(grid: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of grid at column u, row v (clamped to the grid)."""
    h, w = grid.shape
    u, v = np.clip(u, 0.0, w - 1.0), np.clip(v, 0.0, h - 1.0)
    c, r = np.minimum(u.astype(np.int64), max(w - 2, 0)), np.minimum(v.astype(np.int64), max(h - 2, 0))
    fu, fv = u - c, v - r
    c1, r1 = np.minimum(c + 1, w - 1), np.minimum(r + 1, h - 1)
    top = grid[r, c] * (1.0 - fu) + grid[r, c1] * fu  # float64: fu is (gathering first, not the map converted)
    bottom = grid[r1, c] * (1.0 - fu) + grid[r1, c1] * fu
    return top * (1.0 - fv) + bottom * fv


@dataclass(frozen=True)
class Detections:
    """
    Connected components of the thresholded, PSF-matched image (M of them).

    label: each component's value in `labels`; left, top, right, bottom: bounding box on the
    full-resolution image [px] (right/bottom exclusive); x, y: footprint centroid [px]; area:
    footprint size on the full-resolution
    grid [px]; labels: component label image on the binned grid (0 = background);
    background: background on the binned grid [ADU]; noise_adu: 1-sigma full-resolution pixel
    noise [ADU]; binning: bin factor of the detection grid; noise_scale: local pixel noise over
    noise_adu on the binned grid (stray light raises it where it is bright).
    """

    label: np.ndarray
    left: np.ndarray
    top: np.ndarray
    right: np.ndarray
    bottom: np.ndarray
    x: np.ndarray
    y: np.ndarray
    area: np.ndarray
    labels: np.ndarray
    background: np.ndarray
    noise_adu: float
    binning: int
    noise_scale: np.ndarray | None = None

    def take(self, index: np.ndarray) -> "Detections":
        """Return the detections `index` (their labels unchanged; the frame's grids shared)."""
        return replace(self, label=self.label[index], left=self.left[index], top=self.top[index],
                       right=self.right[index], bottom=self.bottom[index], x=self.x[index], y=self.y[index],
                       area=self.area[index])

    def noise_scale_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Local pixel noise / noise_adu [-] at full-resolution positions (1 where unknown)."""
        if self.noise_scale is None:
            return np.ones(np.shape(x))
        h, w = self.noise_scale.shape
        col = np.clip((np.asarray(x) / self.binning).astype(np.int64), 0, w - 1)
        row = np.clip((np.asarray(y) / self.binning).astype(np.int64), 0, h - 1)
        return self.noise_scale[row, col].astype(float)

    def background_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Background [ADU] at full-resolution positions (nearest detection-grid pixel)."""
        h, w = self.background.shape
        col = np.clip((np.asarray(x) / self.binning).astype(np.int64), 0, w - 1)
        row = np.clip((np.asarray(y) / self.binning).astype(np.int64), 0, h - 1)
        return self.background[row, col].astype(float)

    def background_plane_at(self, x: np.ndarray, y: np.ndarray, block_px: int) -> "BackgroundPlane":
        """
        Return the background's level and slopes at full-resolution positions (background_plane).

        block_px: the background tiles' size [px]. A slope within SLOPE_SIGNIFICANCE standard
        errors of zero is the tile medians' noise, not a gradient: it is taken as 0.
        """
        noise = self.noise_adu * self.noise_scale_at(x, y)
        return background_plane(self.background, self.binning, x, y, SLOPE_SIGNIFICANCE * slope_noise(noise, block_px))


def bin_image(image: np.ndarray, binning: int) -> np.ndarray:
    """
    Mean over binning x binning blocks (trailing rows/columns that do not fill a block are dropped).

    Integer images stay integer (rounded mean), others become float32.
    """
    if image.dtype.kind == "f" and image.dtype != np.float32:
        image = image.astype(np.float32)
    elif image.dtype.kind in "ui" and image.dtype not in (np.uint8, np.uint16):
        image = np.clip(image, 0, 65535).astype(np.uint16)
    if binning == 1:
        return image
    h, w = (image.shape[0] // binning), (image.shape[1] // binning)
    return cv2.resize(image[:h * binning, :w * binning], (w, h), interpolation=cv2.INTER_AREA)


def robust_sigma(values: np.ndarray) -> float:
    """
    1.4826 x median absolute deviation: the Gaussian sigma, ignoring outliers (stars).

    On coarsely quantised data (noise below ~0.7 ADU, most samples equal to the median) the MAD
    is 0: then the standard deviation clipped at 3 sigma about the median (stars and hot pixels
    clipped away, the quantisation's 1/12 ADU^2 left in for the caller).
    """
    values = np.asarray(values, dtype=np.float32).ravel()
    if values.size == 0:
        return 0.0
    mid = values.size // 2
    med = np.partition(values, mid)[mid]
    dev = np.abs(values - med)
    mad = float(MAD_TO_SIGMA * np.partition(dev, mid)[mid])
    return mad if mad > 0 else clipped_sigma(values, float(med))


def clipped_sigma(values: np.ndarray, centre: float, rounds: int = 10) -> float:
    """
    Return the standard deviation of `values` about their own mean.

    Keeping those within 3 sigma of the running mean (starting from `centre`), iterated:
    robust to stars and hot pixels, and unbiased by where the quantisation steps fall
    relative to the mean.
    """
    kept = values[np.isfinite(values)].astype(np.float64)
    if kept.size == 0:
        return 0.0
    # Start from the interquartile range, at least half a quantisation step (it is 0 or 1 here).
    low, high = np.percentile(kept, [25.0, 75.0])
    mean, sigma = centre, max(0.7413 * float(high - low), 0.5)
    for _ in range(rounds):
        inside = kept[np.abs(kept - mean) <= 3.0 * sigma + 1e-9]
        if inside.size < 2:
            break
        mean, sigma = float(np.mean(inside)), float(np.std(inside))
    return sigma


def estimate_background(image: np.ndarray, block: int) -> np.ndarray:
    """Smooth background [same units] (see background_and_noise)."""
    return background_and_noise(image, block)[0]


def background_and_noise(image: np.ndarray, block: int, smooth_tiles: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """
    Smooth background and pixel-noise maps [same units].

    The median and the robust sigma (MAD) of each block x block tile (at most 8x8 samples on
    a regular sub-grid), bilinearly interpolated back to full size. Robust to stars; follow
    stray-light gradients (whose shot noise raises the local noise). smooth_tiles 3: each
    tile's background is the median over its 3x3 tiles (background_tiles: stars as wide as a
    tile).
    """
    h, w = image.shape
    block = max(2, min(block, h, w))
    step = max(1, block // 8)
    sub = image[::step, ::step]
    b = max(1, block // step)
    ph, pw = -sub.shape[0] % b, -sub.shape[1] % b
    if ph or pw:
        sub = np.pad(sub, ((0, ph), (0, pw)), mode="reflect" if min(sub.shape) > 1 else "edge")
    ty, tx = sub.shape[0] // b, sub.shape[1] // b
    tiles = np.ascontiguousarray(sub.reshape(ty, b, tx, b).transpose(0, 2, 1, 3)).reshape(ty * tx, b * b)
    mid = (b * b) // 2
    medians = np.partition(tiles, mid, axis=1)[:, mid].astype(np.float32)
    # Local noise: each tile's MAD, smoothed over 3x3 tiles (64 samples alone scatter by ~10 %).
    spread = np.partition(np.abs(tiles.astype(np.float32) - medians[:, None]), mid, axis=1)[:, mid]
    spread = cv2.blur((MAD_TO_SIGMA * spread).reshape(ty, tx).astype(np.float32), (3, 3),
                      borderType=cv2.BORDER_REPLICATE)
    grid = medians.reshape(ty, tx)
    if smooth_tiles > 1 and min(ty, tx) >= smooth_tiles:
        grid = cv2.medianBlur(grid, smooth_tiles)
    full = cv2.resize(grid, (tx * block, ty * block), interpolation=cv2.INTER_LINEAR)
    noise = cv2.resize(spread, (tx * block, ty * block), interpolation=cv2.INTER_LINEAR)
    return full[:h, :w], noise[:h, :w]


# A star whose aperture (radius 3 sigma) covers at least this share of a background tile biases
# its flux and centre by the tile median's noise, summed coherently over the aperture: its
# background is smoothed over 3x3 tiles (measured on defocused annulus stars, sigma 3 px, 32 px
# tiles: 2 of 189 SNR >= 10 stars lost to it). Real cameras' backgrounds vary on the tile scale,
# so narrower PSFs keep single tiles.
WIDE_STAR_TILE_SHARE = 0.25


def background_tiles(psf_sigma_px: float, block_px: int) -> int:
    """Return how many tiles across (1 or 3) stars of 1-sigma psf_sigma_px [px] take their background over."""
    aperture = np.pi * (3.0 * psf_sigma_px) ** 2
    return 3 if aperture >= WIDE_STAR_TILE_SHARE * block_px ** 2 else 1


@dataclass(frozen=True)
class DetectionGround:
    """
    What detection computes before the PSF enters, shared by a frame's measurements at several widths.

    residual: the binned image minus its background [ADU, float32, binned grid]; background,
    local_noise: the background and local pixel-noise maps there [ADU]; noise: 1-sigma
    full-resolution pixel noise [ADU]; binning: the bin factor.
    """

    residual: np.ndarray
    background: np.ndarray
    local_noise: np.ndarray
    noise: float
    binning: int


def detection_ground(image: np.ndarray, binning: int, background_block_px: int,
                     smooth_tiles: int = 1) -> DetectionGround:
    """
    Bin `image`, estimate its background and noise: DetectionGround.

    background_and_noise (smooth_tiles: see there; background_tiles) and robust_sigma.
    """
    binned = bin_image(image, binning)
    background, local_noise = background_and_noise(binned, max(2, background_block_px // binning), smooth_tiles)
    residual = cv2.subtract(binned, background, dtype=cv2.CV_32F) if binned.dtype != np.float32 else binned - background
    sample = residual[::3, ::3] if residual.size > 40000 else residual
    sigma_binned = robust_sigma(sample)
    quantization = 1.0 / 12.0 if binned.dtype.kind in "ui" else 0.0
    # White pixel noise: the mean of binning^2 pixels has 1/binning of its sigma.
    noise = binning * float(np.sqrt(max(sigma_binned ** 2 - quantization, 0.25 * sigma_binned ** 2)))
    if not np.isfinite(noise) or noise <= 0:
        noise = max(float(np.std(residual)) * binning, 1e-3)  # flat or quantized image: fall back
    return DetectionGround(residual, background, local_noise, noise, binning)


class DetectionSettings(NamedTuple):
    """
    How a frame is detected.

    binning: the detection grid's bin factor; background_block_px: the background mesh [px];
    detection_sigma: the threshold [noise sigmas]; psf_sigma_px: the PSF 1-sigma of the matched
    filter [px] (0: 1 px); min_area, max_area: a detection's footprint [px].
    """

    binning: int
    background_block_px: int
    detection_sigma: float
    psf_sigma_px: float
    min_area: int
    max_area: int


def detect(image: np.ndarray, settings: DetectionSettings, smear_kernel: np.ndarray | None = None,
           ground: DetectionGround | None = None) -> Detections:
    """
    Threshold the PSF-matched residual at detection_sigma x its own robust noise.

    smear_kernel: when the body rate is known, a kernel on the detection grid (unit sum)
    matching the predicted streak; it replaces the PSF-sized Gaussian (matched filter).
    ground: detection_ground(image, binning, background_block_px) when already computed (a
    frame measured at several PSF widths), else computed here.
    """
    binning, background_block_px, detection_sigma, psf_sigma_px, min_area, max_area = settings
    if ground is None:
        ground = detection_ground(image, binning, background_block_px)
    residual, background, local_noise, noise = ground.residual, ground.background, ground.local_noise, ground.noise
    # Matched filter: the PSF on the binned grid, widened by the star's unknown phase within a
    # bin (found best on simulated frames: 99 % of SNR-9 stars at 4.5 sigma, 0 false per frame).
    psf = psf_sigma_px if psf_sigma_px > 0 else 1.0
    psf_sigma_binned = float(np.sqrt((psf / binning) ** 2 + 0.25 * (binning - 1)))
    if smear_kernel is not None:
        smoothed = cv2.filter2D(residual, cv2.CV_32F, smear_kernel, borderType=cv2.BORDER_REFLECT)
    else:
        size = 2 * int(np.ceil(2.0 * psf_sigma_binned)) + 1
        smoothed = cv2.GaussianBlur(residual, (size, size), psf_sigma_binned)
    smooth_noise = robust_sigma(smoothed[::3, ::3] if smoothed.size > 40000 else smoothed) or noise
    # Threshold in units of the local noise: the global figure scaled by the local/median ratio.
    typical = float(np.median(local_noise[::4, ::4]))
    noise_scale = np.clip(local_noise / typical, 0.25, 16.0) if typical > 0 else np.ones_like(local_noise)
    mask = (smoothed > (detection_sigma * smooth_noise) * noise_scale).view(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    bl, bt, br, bb, area_b, cx_b, cy_b = component_stats(labels, count)
    area = area_b[1:] * binning * binning
    keep = np.flatnonzero((area >= min_area) & (area <= max_area)) + 1
    left, top = bl[keep] * binning, bt[keep] * binning
    right, bottom = br[keep] * binning, bb[keep] * binning
    centroids = np.column_stack([cx_b, cy_b])
    # Edge of the last (partial) block: extend boxes that touch the binned grid's border.
    right = np.where(right >= labels.shape[1] * binning, image.shape[1], right)
    bottom = np.where(bottom >= labels.shape[0] * binning, image.shape[0], bottom)
    centre = centroids[keep] * binning + 0.5 * (binning - 1)
    return Detections(label=keep, left=left, top=top, right=right, bottom=bottom,
                      x=centre[:, 0], y=centre[:, 1], area=area[keep - 1], labels=labels, background=background,
                      noise_adu=noise, binning=binning, noise_scale=noise_scale)
