# SPDX-License-Identifier: Apache-2.0
"""
Stars whose footprint merged with a cosmic-ray track, refitted with the frame's own PSF.

fit_blends fits such a star jointly with the track's peaks using the round Gaussian (or takes
its own pixels' centre of gravity when the track pulls the fit). Where the frame's stars are
not Gaussian (a defocused ring, wings, astigmatism) that misplaces them: ring stars of SNR
~150 beside tracks came out 0.03-0.1 px off, 2-7x their Cramer-Rao bound, while the frame's
other stars were fitted with its template. Here each such star's point window, the pixels
nearer a track peak than the star left out, is fitted with the model the frame's single stars
were fitted with.
"""
from __future__ import annotations

import numpy as np

from ..psf.empirical import fit_empirical
from ..psf.point_fits import cleaned_windows
from ..windows import PsfStart, PsfWindows, gather_windows
from ..records import FitContext, SpotRows

MAX_SHIFT_PX = 1.0  # a refit moving the star farther than this from the blend fit is not taken


def refit_beside_tracks(context: FitContext, peaks: dict, spots: SpotRows, psf, excluded: np.ndarray | None
                        ) -> SpotRows:
    """
    Refit the stars of blends with tracks with `psf` (any model with sample(dx, dy)).

    peaks: spot row -> ((K, 2) the blend's peaks x, y [px], (K,) bool: which are track
    peaks); rows whose star was dropped (SNR 0) are skipped. excluded: (H, W) bool pixels no
    fit may use (clipped), or None. A refit that converges within MAX_SHIFT_PX replaces the
    row's position, flux, covariance and SNR.
    """
    rows = np.array([t for t in peaks if spots.snr[t] > 0], np.int64)
    if rows.size == 0:
        return spots
    half = context.window_half
    size = 2 * half + 1
    x0, y0 = spots.x[rows], spots.y[rows]
    col0, row0 = np.rint(x0).astype(np.int64) - half, np.rint(y0).astype(np.int64) - half
    win, valid = cleaned_windows(context, col0, row0, size, x0, y0)
    if excluded is not None:
        clipped, _ = gather_windows(excluded, col0, row0, size)
        valid &= clipped == 0
    cols = col0[:, None, None] + np.arange(size)[None, None, :]
    lines = row0[:, None, None] + np.arange(size)[None, :, None]
    for k, t in enumerate(rows):
        positions, track = peaks[int(t)]
        star_d2 = (cols[k] - x0[k]) ** 2 + (lines[k] - y0[k]) ** 2
        for px, py in positions[track]:
            valid[k] &= star_d2 <= (cols[k] - px) ** 2 + (lines[k] - py) ** 2
    x, y, flux, cov, flux_var, ok = fit_empirical(psf, PsfWindows(win, valid, col0, row0),
                                                  PsfStart(x0, y0, spots.flux[rows]), context.noise, context.gain)
    ok &= np.hypot(x - x0, y - y0) <= MAX_SHIFT_PX
    take = np.flatnonzero(ok)
    if take.size == 0:
        return spots
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = flux[take] / np.sqrt(flux_var[take])
    return spots.with_values(rows[take], x=x[take], y=y[take], flux=flux[take], cov=cov[take], snr=snr)
