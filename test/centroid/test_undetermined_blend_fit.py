# SPDX-License-Identifier: Apache-2.0
"""
A joint fit that leaves a star undetermined is no blend (point_fits._determined).

Found on a real frame: unh_DSC_0060 centroided at a PSF sigma of 2.85-2.89 px (the estimate
moves there with the stars it is made from) had one spot whose 2-PSF fit gave its second star
no light; the singular joint covariance put the first star's position variance at 1e23 px^2,
its deep-catalog match gate took in every star of the image, every deep match became
ambiguous, and the solve kept 90 of its ~140 stars. The undetermined split is now refitted
as a single star.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid.psf.point_fits import _determined
from star_tracker.centroid.psf.gaussian_fit import PsfFit

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import corpus as bench  # noqa: E402

IMAGE_ID = "unh_DSC_0060"
ARCMIN = math.radians(1.0 / 60.0)


def _fit(flux, cov) -> PsfFit:
    flux = np.asarray(flux, float)[None]
    cov = np.asarray(cov, float)[None]
    zeros = np.zeros_like(flux)
    return PsfFit(zeros, zeros, flux, cov, np.ones_like(flux, bool), np.ones_like(flux))


def test_a_star_without_light_or_with_an_unbounded_position_is_undetermined():
    tight = 0.01 * np.eye(2)
    assert _determined(_fit([3607.0, 250.0], [tight, tight]), 19).tolist() == [True]
    assert _determined(_fit([3607.0, 0.0], [tight, tight]), 19).tolist() == [False]
    assert _determined(_fit([3607.0, 250.0], [1e23 * np.eye(2), tight]), 19).tolist() == [False]
    assert _determined(_fit([3607.0, 250.0], [np.full((2, 2), np.nan), tight]), 19).tolist() == [False]
    assert _determined(_fit([3607.0, 250.0], [(19.0 ** 2 + 1.0) * np.eye(2), tight]), 19).tolist() == [False]


def _corpus_image():
    try:
        return bench.load_corpus(bench.find_corpus(), [IMAGE_ID])[0]
    except (bench.CorpusMissing, IndexError):
        pytest.skip(f"real-image corpus or {IMAGE_ID} absent (../shared/realdata)")


@pytest.mark.slow
@pytest.mark.parametrize("psf_sigma", ["2.79", "2.89"])
def test_real_frame_keeps_its_stars_at_either_psf_width(psf_sigma):
    # Judged against the same image solved at its own PSF estimate: the defect kept 64 % of the
    # stars (90 of ~140); how many faint stars the deep re-match may name is its own rule's.
    image = _corpus_image()
    code, own, _, err = bench.run_solve_command(bench.solve_argv(image))
    assert code == 0, err[-300:]
    code, record, _, err = bench.run_solve_command(bench.solve_argv(image) + ["--psf-sigma", psf_sigma])
    assert code == 0, err[-300:]
    assert len(record["matched"]) >= 0.9 * len(own["matched"]) >= 90, \
        f"{len(record['matched'])} stars matched at sigma {psf_sigma} px, {len(own['matched'])} at its own estimate"
    boresight, _ = bench.attitude_errors(_rotation(record), image.reference)
    assert boresight < ARCMIN


def _rotation(record: dict) -> np.ndarray:
    from star_tracker.models.attitude import quaternion_to_matrix

    return quaternion_to_matrix(np.asarray(record["quaternion_xyzw"], float))
