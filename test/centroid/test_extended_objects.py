# SPDX-License-Identifier: Apache-2.0
"""
Extended objects and bright saturated stars on frames our simulator did not make.

A real camera's frame holds more than stars: cloud banks lit from below, stray-light
structure. Detected as spots, their summed flux outranked the stars in the brightest-first
patterns; and a bloomed saturated 8-bit star whose flat top fits no streak was dropped, so
the frame's brightest star went missing. Truth: a renderer written here (its own PSF and
noise code, not star_tracker.sim) and, on the real frame, the Hipparcos stars the reference
WCS places on it (../shared/realdata, skipped where absent).
"""
from __future__ import annotations

import json
from math import erf, sqrt

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from test_real_dark_frames import STAR_RADIUS_PX, _corpus, reference_star_pixels


def _pixel_gaussian(shape, x0, y0, sigma, flux):
    """Return a pixel-integrated round Gaussian of `flux` [e-] at (x0, y0) [px] (pixel centres at integers)."""
    h, w = shape
    edges_x, edges_y = np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5
    cdf = np.vectorize(lambda t: 0.5 * (1.0 + erf(t / (sqrt(2.0) * sigma))))
    gx, gy = np.diff(cdf(edges_x - x0)), np.diff(cdf(edges_y - y0))
    return flux * np.outer(gy, gx)


def _frame(seed: int = 4):
    """
    Render 512x512 px: 40 stars (sigma 0.7 px), a close pair, 6 broad blobs (sigma 5-8 px) clear of them.

    Poisson and 4 e- read noise; returns the image, the stars' and the blobs' (x, y) [px].
    """
    rng = np.random.default_rng(seed)
    shape = (512, 512)
    light = np.full(shape, 30.0)
    stars = np.column_stack([rng.uniform(20, 492, 40), rng.uniform(20, 492, 40)])
    flux = rng.uniform(800, 20000, 40)
    pair = np.array([[100.0, 400.0], [104.5, 401.0]])  # 4.6 px apart: one footprint, split as a blend
    # Blobs clear of the stars (a star on a blob is fitted as a blend with the blob's maximum:
    # a known limit, docs/USER_GUIDE.md § 3).
    blobs = np.column_stack([rng.uniform(40, 472, 200), rng.uniform(40, 472, 200)])
    clear = np.hypot(blobs[:, 0, None] - stars[:, 0], blobs[:, 1, None] - stars[:, 1]).min(axis=1) > 35.0
    blobs = blobs[clear][:6]
    for (x, y), f in zip(np.vstack([stars, pair]), np.concatenate([flux, [6000.0, 4000.0]])):
        light += _pixel_gaussian(shape, x, y, 0.7, f)
    for x, y in blobs:
        light += _pixel_gaussian(shape, x, y, rng.uniform(5.0, 8.0), rng.uniform(2.0e4, 6.0e4))
    image = rng.poisson(light) + rng.normal(0.0, 4.0, shape)
    return np.clip(np.rint(image), 0, 65535).astype(np.uint16), np.vstack([stars, pair]), blobs


def _nearest(spots, xy) -> np.ndarray:
    return np.hypot(xy[:, 0, None] - spots.x[None], xy[:, 1, None] - spots.y[None]).min(axis=1)


def test_broad_blobs_are_not_reported_as_stars_and_are_counted():
    image, stars, blobs = _frame()
    spots = extract_spots(image, CentroidConfig())
    assert spots.psf.source == "estimated"
    assert (_nearest(spots, stars) < 1.0).all(), "a star (or the blend's pair) was lost"
    assert (_nearest(spots, blobs) > 4.0).all(), "a blob is reported as a spot"
    assert spots.rejected_extended >= len(blobs)
    # A fixed PSF (the user's) judges alike; a PSF that is only a prior (not estimated) does not.
    fixed = extract_spots(image, CentroidConfig(psf_mode="fixed", psf_sigma_px=0.7))
    assert (_nearest(fixed, blobs) > 4.0).all() and fixed.rejected_extended >= len(blobs)


@pytest.mark.slow
def test_real_frame_keeps_its_bright_stars_above_its_cloud_bank():
    """
    Real frame granasat IMG_007985 (8-bit, Orion above a lit cloud bank): its brightest stars are spots.

    Measured 2026-12-02: before, its brightest star (a bloomed, saturated disc) was dropped, and
    6 of the 16 brightest spots were cloud structures; now none of the 10 brightest are, and
    the frame solves (it did not).
    """
    import argparse

    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import centroid_config
    from star_tracker.models.catalog import load_hipparcos

    corpus = _corpus()
    entry = {e["id"]: e for e in json.loads((corpus / "MANIFEST.json").read_text())["images"]}["gran_IMG_007985"]
    catalog = load_hipparcos().at_epoch(2026.0).brighter_than(3.0)  # Orion's brightest, all saturated here
    star_x, star_y = reference_star_pixels(corpus, entry, catalog)
    sky = star_y < 0.55 * entry["height"]  # the cloud bank fills the lower half
    star_x, star_y = star_x[sky], star_y[sky]
    assert star_x.size >= 5
    image = read_image(corpus / entry["file"])
    defaults = argparse.Namespace(detection_sigma=4.5, psf_sigma=None, max_spots=150)  # `solve`'s
    spots = extract_spots(image.pixels, centroid_config(image.pixels, image.description, defaults))
    near_star = np.hypot(spots.x[:, None] - star_x[None], spots.y[:, None] - star_y[None]).min(axis=1)
    found = np.hypot(star_x[:, None] - spots.x[None], star_y[:, None] - spots.y[None]).min(axis=1)
    assert (found < 2 * STAR_RADIUS_PX).all(), f"reference stars without a spot: {np.sum(found >= 4.0)}"
    assert spots.rejected_extended >= 3
    brightest_above_horizon = spots.y[:10] < 0.55 * entry["height"]
    assert brightest_above_horizon.all(), "cloud structure among the 10 brightest spots"
    assert (near_star[:10] < 2 * STAR_RADIUS_PX).sum() >= star_x.size - 1
