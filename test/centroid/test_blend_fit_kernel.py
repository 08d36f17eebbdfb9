# SPDX-License-Identifier: Apache-2.0
"""
The compiled blend fit (centroid/psf/blend_fit_kernel.py) against the numpy reference and the truth.

Blends of 2-4 stars rendered here (pixel-integrated Gaussians by erf, Gaussian read noise):
the compiled fit must converge where the numpy fit does and agree with it (to 1e-6 px where
every star is determined); where the stars are 3 PSF sigmas apart or more, it must find the
true positions within 5 of its own sigmas. A star with no signal must end unconverged (or
honestly uninformative), never raise.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erf

from star_tracker.centroid.psf.gaussian_fit import fit_psf_windows
from star_tracker.centroid.windows import PsfStart, PsfWindows

from gaussian_fit_reference import fit_psf_numpy

NOISE = 3.0  # [ADU], gain 1


def blend(rng: np.random.Generator, stars: int, size: int, sigma: float):
    """Return (window (size, size) [ADU], true x, y [px in the window], flux [ADU]) of `stars` Gaussians."""
    x, y = rng.uniform(3.5, size - 4.5, stars), rng.uniform(3.5, size - 4.5, stars)
    flux = rng.uniform(2e3, 5e4, stars)
    edges, scale = np.arange(size) - 0.5, np.sqrt(2.0) * sigma
    px = 0.5 * (erf((edges[None] + 1.0 - x[:, None]) / scale) - erf((edges[None] - x[:, None]) / scale))
    py = 0.5 * (erf((edges[None] + 1.0 - y[:, None]) / scale) - erf((edges[None] - y[:, None]) / scale))
    light = np.einsum("k,ki,kj->ij", flux, py, px)
    return light + rng.normal(0.0, NOISE, light.shape), x, y, flux


def both_fits(windows: PsfWindows, start: PsfStart, sigma: float):
    return fit_psf_windows(windows, start, sigma, NOISE, 1.0), fit_psf_numpy(windows, start, sigma, NOISE, 1.0, 10)


@pytest.mark.parametrize("stars", [2, 3, 4])
def test_compiled_blend_fit_is_the_numpy_fit_and_finds_the_stars(monkeypatch, stars):
    rng = np.random.default_rng(stars)
    checked = determined = resolved = 0
    for trial in range(40):
        sigma = rng.uniform(0.7, 2.2)
        size = int(rng.integers(12, 22))
        window, x, y, flux = blend(rng, stars, size, sigma)
        valid = rng.random((1, size, size)) > (0.05 if trial % 2 else 0.0)  # some windows miss a few pixels
        left, top = float(rng.integers(0, 900)), float(rng.integers(0, 900))
        windows = PsfWindows(np.where(valid, window[None], 0.0), valid, np.array([left]), np.array([top]))
        start = PsfStart((left + x + rng.normal(0.0, 0.5, stars))[None], (top + y + rng.normal(0.0, 0.5, stars))[None],
                         (flux * rng.uniform(0.5, 2.0, stars))[None])
        compiled, reference = both_fits(windows, start, sigma)
        assert np.array_equal(compiled.converged, reference.converged)
        if not compiled.converged.all():
            continue
        checked += 1
        # The same solution. Only the summation order differs; a blend whose stars are all
        # determined (each position sigma < 0.1 px) agrees to 1e-6 px, while one a star of which
        # the data cannot place (stars a pixel apart) can stop anywhere within the stopping rule's
        # 1 % of a sigma of its optimum, as either path does.
        sigma_x, sigma_y = np.sqrt(reference.cov[..., 0, 0]), np.sqrt(reference.cov[..., 1, 1])
        tolerance = 1e-6 if max(sigma_x.max(), sigma_y.max()) < 0.1 else 1e-2
        assert np.all(np.abs(compiled.x - reference.x) <= tolerance * np.maximum(sigma_x, 1.0))
        assert np.all(np.abs(compiled.y - reference.y) <= tolerance * np.maximum(sigma_y, 1.0))
        assert np.all(np.abs(compiled.flux - reference.flux) <= tolerance * np.sqrt(reference.flux_var))
        if tolerance < 1e-2:  # and the same information matrix at the solution
            assert np.allclose(compiled.cov, reference.cov, rtol=1e-6, atol=0.0)
            assert np.allclose(compiled.flux_var, reference.flux_var, rtol=1e-6)
            determined += 1
        separation = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :]) + np.eye(stars) * size
        if separation.min() < 3.0 * sigma:
            continue  # stars closer than that can be fitted as fewer (either path): no truth to judge by
        resolved += 1
        # Each true star found by one fitted star within 5 sigma (the fit may order them differently).
        for k in range(stars):
            dx, dy = compiled.x[0] - (left + x[k]), compiled.y[0] - (top + y[k])
            sigma_pos = np.sqrt(compiled.cov[0, :, 0, 0] + compiled.cov[0, :, 1, 1])
            assert np.min(np.hypot(dx, dy) / sigma_pos) < 5.0
    assert checked >= 30 and determined >= 10 and resolved >= 3


def test_a_star_without_signal_ends_unconverged_without_raising(monkeypatch):
    rng = np.random.default_rng(9)
    window, x, y, _ = blend(rng, 1, 15, 1.2)
    windows = PsfWindows(window[None], np.ones((1, 15, 15), bool), np.zeros(1), np.zeros(1))
    # The second star is started in a corner where there is only noise, with no flux.
    start = PsfStart(np.array([[x[0], 2.0]]), np.array([[y[0], 2.0]]), np.array([[2e4, 0.0]]))
    compiled, _ = both_fits(windows, start, 1.2)
    assert compiled.converged[0, 0] and abs(compiled.x[0, 0] - x[0]) < 0.05
    assert not compiled.converged[0, 1] or compiled.cov[0, 1, 0, 0] > 1.0
