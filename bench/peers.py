"""Adapters for peer star-tracker centroiders, for benchmark comparisons only.

Optional dependencies (requirements-bench.txt), never runtime ones:

- tetra3rs (Rust, PyO3): ``tetra3rs.CentroidExtractor.extract`` -- the buffer-reusing form of
  ``tetra3rs.extract_centroids`` (bit-identical results, faster in a frame loop). It returns
  ``Centroid.x, .y`` with the origin at the image centre, +x right, +y down, brightest first.
- cedar-solve (fork of ESA tetra3; module ``tetra3``): ``tetra3.get_centroids_from_image``, the
  pure numpy/scipy extractor. It returns an (N, 2) array of (y, x) with x = y = 0.5 at the centre
  of the top-left pixel, brightest (largest sum) first. (Cedar Detect, the Rust gRPC server
  that ``tetra3.cedar_detect_client`` drives, is not shipped in the wheel and is not used.)

Both adapters take a 2-D image in ADU (uint16 or uint8; any real dtype works), call the peer
with its default settings, and return an (N, 2) float64 array of (x, y) = (column, row) [px] in
this project's convention: (0, 0) at the centre of the top-left pixel, brightest first.
The conversions were checked against simulator truth (mean offset < 0.02 px in x and y).
"""
from __future__ import annotations

import importlib
import threading
import warnings
from importlib import metadata

import numpy as np

_MODULES = {"tetra3rs": "tetra3rs", "cedar-solve": "tetra3"}
_local = threading.local()


def available() -> dict[str, str | None]:
    """{peer name: None if usable, else why not (the import error text)}."""
    out: dict[str, str | None] = {}
    for name, module in _MODULES.items():
        try:
            metadata.version(name)  # `tetra3` could also be a non-cedar install
            importlib.import_module(module)
            out[name] = None
        except Exception as exc:  # noqa: BLE001 - any failure means "not usable", report it
            out[name] = f"{type(exc).__name__}: {exc}"
    return out


def tetra3rs_centroids(image: np.ndarray) -> np.ndarray:
    """tetra3rs centroids of `image` [ADU] as (N, 2) (x, y) [px], (0, 0) = top-left pixel centre.

    Defaults of tetra3rs 0.14: sigma_threshold=5 above a 64-px-block local background, Gaussian
    matched filter sigma 1.5 px for detection, 3..10000 px blobs, max_elongation=3 (drops
    streaks), max_sharpness=0.9 (drops hot pixels), quadratic sub-pixel peak refinement,
    all cores. tetra3rs puts the origin at the image centre, (W/2, H/2) from the top-left
    pixel corner, so x_ours = x + (W - 1) / 2 and y_ours = y + (H - 1) / 2.
    """
    import tetra3rs

    extractor = getattr(_local, "tetra3rs_extractor", None)
    if extractor is None:  # one per thread, as tetra3rs requires
        extractor = _local.tetra3rs_extractor = tetra3rs.CentroidExtractor()
    result = extractor.extract(image)
    h, w = image.shape
    xy = np.array([(c.x, c.y) for c in result.centroids], dtype=np.float64).reshape(-1, 2)
    return xy + [(w - 1) / 2.0, (h - 1) / 2.0]


def cedar_centroids(image: np.ndarray) -> np.ndarray:
    """cedar-solve centroids of `image` [ADU] as (N, 2) (x, y) [px], (0, 0) = top-left pixel centre.

    Defaults of cedar-solve 0.5.1: 25-px local-mean background subtraction, threshold 2x the
    global RMS of the residual, 3x3 binary opening, spots of 5..100 px, no axis-ratio limit,
    intensity-weighted first moments over each thresholded spot (no fixed window). The peer
    converts the image to float32 itself. It returns (y, x) with 0.5 at the top-left pixel
    centre, so swap the columns and subtract 0.5.
    """
    from tetra3 import get_centroids_from_image

    with warnings.catch_warnings():  # cedar-solve uses the deprecated scipy.ndimage.filters
        warnings.simplefilter("ignore", DeprecationWarning)
        yx = np.asarray(get_centroids_from_image(image), dtype=np.float64).reshape(-1, 2)
    return yx[:, ::-1] - 0.5
