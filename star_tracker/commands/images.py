# SPDX-License-Identifier: Apache-2.0
"""
Image files for `render` and `solve`.

PNG/TIFF (8/16-bit, grey or colour) through OpenCV, FITS through astropy.io.fits (imported
only for FITS files).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .common import CommandError

FITS_SUFFIXES = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz")
RASTER_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm")


@dataclass(frozen=True)
class LoadedImage:
    """
    pixels: 2-D grey image (uint8/uint16 as stored, float32 for colour or FITS floats).

    Description: e.g. "PNG 8-bit colour 1024x1024 (converted to grey)".
    """

    pixels: np.ndarray
    description: str
    header: dict


def is_fits(path: str | Path) -> bool:
    return str(path).lower().endswith(FITS_SUFFIXES)


def read_image(path: str | Path) -> LoadedImage:
    """
    Read an image as a 2-D array.

    Colour images become grey (the mean of the channels, as float32 to keep the precision of
    the sum); an alpha channel is dropped.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, "No such file", str(path))
    if is_fits(path):
        return _read_fits(path)
    import cv2

    pixels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise CommandError(f"{path}: not an image OpenCV can read (PNG, TIFF, JPEG, ... or FITS by its suffix)")
    kind = path.suffix.lstrip(".").upper() or "image"
    bits = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}.get(pixels.dtype, str(pixels.dtype))
    if pixels.ndim == 3:
        channels = pixels.shape[2]
        colour = pixels[:, :, :3] if channels >= 3 else pixels[:, :, :1]
        # The mean of the channels, summed plane by plane (exact: integers), as np.mean(axis=2)
        # gives it but without its strided reduction (seconds on a 10-Mpx photograph).
        grey = colour[:, :, 0].astype(np.float32)
        for plane in range(1, colour.shape[2]):
            grey += colour[:, :, plane]
        grey /= np.float32(colour.shape[2])
        description = (f"{kind} {bits} {'colour' if channels >= 3 else 'grey+alpha'} {grey.shape[1]}x{grey.shape[0]} "
                       "(converted to grey)")
        pixels = grey
    else:
        description = f"{kind} {bits} grey {pixels.shape[1]}x{pixels.shape[0]}"
    _check_pixels(pixels, path)
    return LoadedImage(pixels, description, {})


def _read_fits(path: Path) -> LoadedImage:
    try:
        from astropy.io import fits
    except ImportError:  # pragma: no cover - astropy is a pinned dependency
        raise CommandError("reading FITS needs astropy (pip install -r requirements.txt)") from None
    try:
        with fits.open(path, memmap=False) as hdus:
            hdu = next((h for h in hdus if getattr(h, "data", None) is not None and h.data.ndim >= 2), None)
            if hdu is None:
                raise CommandError(f"{path}: no image in any HDU of this FITS file")
            data = np.asarray(hdu.data)
            header = {k: hdu.header[k] for k in hdu.header if k and not k.startswith(("COMMENT", "HISTORY"))}
    except OSError as exc:
        raise CommandError(f"{path}: not a readable FITS file ({exc})") from None
    if data.ndim == 3:  # a colour cube (channels first, as FITS stores them): average the planes
        data = data.astype(np.float32).mean(axis=0)
    elif data.ndim > 3:
        raise CommandError(f"{path}: FITS image with {data.ndim} axes; expected 2 (or 3 colour planes)")
    if data.dtype.byteorder not in ("=", "|"):
        data = data.astype(data.dtype.newbyteorder("="))
    if data.dtype.kind == "f":
        data = np.nan_to_num(data.astype(np.float32), nan=float(np.nanmedian(data)))
    _check_pixels(data, path)
    return LoadedImage(data, f"FITS {data.dtype} {data.shape[1]}x{data.shape[0]}", header)


def _check_pixels(pixels: np.ndarray, path: Path) -> None:
    if pixels.ndim != 2 or min(pixels.shape) < 16:
        raise CommandError(f"{path}: image of shape {pixels.shape} is too small (at least 16x16 px)")


def write_image(path: str | Path, image: np.ndarray, header: dict | None = None) -> None:
    """
    Write a uint16 (or uint8) frame losslessly.

    PNG/TIFF through OpenCV, FITS with `header` cards (name -> value or (value, comment)).
    """
    path = Path(path)
    suffix = path.name.lower()
    if path.parent and not path.parent.is_dir():
        raise FileNotFoundError(2, "No such directory", str(path.parent))
    if is_fits(path):
        from astropy.io import fits

        hdu = fits.PrimaryHDU(np.ascontiguousarray(image))
        for key, value in (header or {}).items():
            hdu.header[key] = value
        hdu.writeto(path, overwrite=True)
        return
    if not suffix.endswith((".png", ".tif", ".tiff")):
        raise CommandError(f"{path}: unsupported output format; use .png, .tif/.tiff (16-bit) or .fits")
    import cv2

    if not cv2.imwrite(str(path), image):
        raise CommandError(f"{path}: OpenCV could not write the image")
