# SPDX-License-Identifier: Apache-2.0
"""
The PSF estimate's pilot (centroid/psf/pilot.py): a crowded frame's brightest detections measured alone.

On a crowded frame rendered here (not by sim/: pixel-integrated Gaussians by erf, Poisson and
read noise) whose PSF is twice the prior: the pilot must engage, measure a small part of the
detections at the prior, and give exactly the spots and estimate of a full measurement.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.special import erf

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid import frame_measurement
from star_tracker.centroid.psf import pilot as psf_pilot
from star_tracker.centroid.detection.components_kernel import footprint_peaks

SIZE = 2048
STARS = 3000
SIGMA_PX = 2.0  # the true PSF; the centroider's prior is 1 px
HALF = 9  # stamp half size [px]


def crowded_frame(seed: int = 3) -> np.ndarray:
    """Render a SIZE^2 uint16 frame [ADU, gain 1]: STARS Gaussians of 300-300 000 e- (log-uniform), sky 50 e-."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(HALF, SIZE - HALF - 1, STARS)
    y = rng.uniform(HALF, SIZE - HALF - 1, STARS)
    flux = np.exp(rng.uniform(np.log(300.0), np.log(3e5), STARS))
    ix, iy = np.rint(x).astype(int), np.rint(y).astype(int)
    k = np.arange(-HALF, HALF + 1)[None, :]

    def axis(d):
        edge = (k - d[:, None]) / (np.sqrt(2.0) * SIGMA_PX)
        return 0.5 * (erf(edge + 0.5 / (np.sqrt(2.0) * SIGMA_PX)) - erf(edge - 0.5 / (np.sqrt(2.0) * SIGMA_PX)))

    stamps = flux[:, None, None] * axis(y - iy)[:, :, None] * axis(x - ix)[:, None, :]
    light = np.full((SIZE, SIZE), 50.0)
    for s in range(STARS):
        light[iy[s] - HALF:iy[s] + HALF + 1, ix[s] - HALF:ix[s] + HALF + 1] += stamps[s]
    electrons = rng.poisson(light) + rng.normal(0.0, 5.0, light.shape)
    return np.clip(np.rint(electrons + 100.0), 0, 65535).astype(np.uint16)


def test_the_pilot_measures_few_detections_and_changes_nothing(monkeypatch):
    image = crowded_frame()
    config = CentroidConfig(saturation_adu=60000.0)
    measured: list[int] = []
    measure = frame_measurement.measure_candidates

    def counting(image, det, *args, **kwargs):
        measured.append(det.x.size)
        return measure(image, det, *args, **kwargs)

    monkeypatch.setattr(frame_measurement, "measure_candidates", counting)
    crowded = psf_pilot.PILOT_MIN_DETECTIONS
    with_pilot = extract_spots(image, config)
    pilot_sizes = list(measured)
    measured.clear()
    monkeypatch.setattr(psf_pilot, "PILOT_MIN_DETECTIONS", 10 ** 9)
    without = extract_spots(image, config)

    detections_at_prior = measured[0]
    assert detections_at_prior >= crowded, measured  # the frame is crowded enough
    assert len(pilot_sizes) == 2 and pilot_sizes[0] < 0.2 * detections_at_prior, (pilot_sizes, measured)
    assert abs(with_pilot.psf.sigma_px - SIGMA_PX) < 0.1 * SIGMA_PX, with_pilot.psf  # the truth
    assert with_pilot.psf == without.psf
    assert np.array_equal(with_pilot.x, without.x) and np.array_equal(with_pilot.y, without.y)

    # With a running prior (the node's) there is no pilot: the frame is measured whole.
    monkeypatch.setattr(psf_pilot, "PILOT_MIN_DETECTIONS", crowded)
    measured.clear()
    extract_spots(image, config, psf_prior=1.0)
    assert measured[0] == detections_at_prior, measured


def test_footprint_peaks_are_each_footprints_highest_pixel():
    rng = np.random.default_rng(5)
    image = rng.integers(0, 1000, (61, 47)).astype(np.uint16)
    for binning in (1, 2):
        labels, count = ndimage.label(rng.random((61 // binning, 47 // binning)) > 0.6)
        labels = labels.astype(np.int32)
        label = np.arange(1, count + 1, dtype=np.int64)
        rows, cols = np.indices(labels.shape)
        left = np.array([cols[labels == k].min() for k in label]) * binning
        right = np.array([cols[labels == k].max() + 1 for k in label]) * binning
        top = np.array([rows[labels == k].min() for k in label]) * binning
        bottom = np.array([rows[labels == k].max() + 1 for k in label]) * binning
        full = np.kron(labels, np.ones((binning, binning), np.int32))
        expected = ndimage.maximum(image[:full.shape[0], :full.shape[1]], full, label)
        got = footprint_peaks(image, labels, binning, label, left, top, right, bottom)
        assert np.array_equal(got, expected), binning
