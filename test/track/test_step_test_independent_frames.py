# SPDX-License-Identifier: Apache-2.0
"""
The tracker's covariance at rest on frames of the independent renderer (bench/alt_renderer.py).

Hipparcos stars projected by a pinhole at a known attitude, each drawn with the second
renderer's own pixel-integrated Gaussian and detector, `alt.expose` (nothing of star_tracker.sim):
a sequence at rest at 10 Hz, centroided and tracked by the real chain. Two things are judged
against the truth: the published attitude's NEES (an honest covariance: mean 3), and how often
the step test (Tracker._step_covariance: an acceleration step taken from the innovation, each
firing inflating the frame's published covariance along it) fires on a body that does not
move. Its threshold is chi^2_3 at 1 %, but the innovation's expected spread leaves out that the
last attitude is in the rate fit (Tracker._step_covariance), so it fires on about 8 % of the
frames at rest: a margin that covers a slew's first frame, whose step is barely above the noise
(docs/TRACKING.md).
"""
from __future__ import annotations

import numpy as np
import pytest

from bench import alt_renderer as alt
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.identify import make_identifier
from star_tracker.models.attitude import matrix_to_rotation_vector, radec_roll_to_matrix
from star_tracker.track.tracking import MODE_TRACKING, Tracker

FRAMES = 150
FLUX_AT_MAG_4_E = 60000.0  # [e-] a magnitude 4 star's light in one exposure
MAGNITUDE_LIMIT = 7.0


def _field_groups(catalog, camera, rotation):
    """Star fields of the stars imaged at `rotation` (sensor -> ICRS), one per 0.25 mag bin, with their flux [e-]."""
    stars = catalog.brighter_than(MAGNITUDE_LIMIT)
    rays = stars.unit_vectors() @ rotation  # sensor frame: R^T v for every star
    ahead = rays[:, 2] > 0.5
    u, v, _ = camera.project(rays[ahead])
    inside = camera.in_image(u, v, margin=4.0)
    u, v, hp = u[inside], v[inside], stars.hp[ahead][inside]
    groups = []
    bins = np.floor(hp / 0.25)
    for b in np.unique(bins):
        pick = bins == b
        flux = FLUX_AT_MAG_4_E * 10.0 ** (-0.4 * (0.25 * b + 0.125 - 4.0))
        groups.append((alt.StarField.build(alt.GaussianPsf(1.0), u[pick], v[pick]), flux))
    return groups


@pytest.mark.slow  # ~20 s
def test_at_rest_the_tracked_nees_is_honest_and_the_step_test_keeps_its_margin(catalog, database, nominal_camera):
    camera = nominal_camera
    rotation = radec_roll_to_matrix(np.radians(83.0), np.radians(-5.0), np.radians(20.0))  # Orion's belt
    groups = _field_groups(catalog, camera, rotation)
    detector = alt.Detector()
    tracker = Tracker(make_identifier("hybrid", database))
    fired = []
    original = tracker._step_covariance

    def counted(*args, **kwargs):
        step = original(*args, **kwargs)
        if tracker.rate is not None and tracker.rate.angular_acceleration is not None:
            fired.append(step is not None)
        return step

    tracker._step_covariance = counted
    rng = np.random.default_rng(2026)
    nees, modes = [], []
    for k in range(FRAMES):
        signal = sum(alt.star_signal(field_, flux, camera.width, camera.height) for field_, flux in groups)
        image = alt.expose(signal, detector, rng)[0]
        result = tracker.process(int(round((1000.0 + 0.1 * k) * 1e9)), extract_spots(image, CentroidConfig()), camera)
        modes.append(result.mode)
        attitude = result.identification.attitude
        assert result.identification.solved
        error = matrix_to_rotation_vector(rotation.T @ attitude.rotation)
        nees.append(float(error @ np.linalg.solve(attitude.covariance, error)))
    assert modes.count(MODE_TRACKING) == FRAMES - 1
    tested = len(fired)
    assert tested > 0.9 * FRAMES
    # About 8 % (11 of 146 here): the margin is kept on purpose; a spread with the fit's
    # cross-covariances fires on ~2 % (1 of 146 here) and left more slews' first frames beyond
    # 5 sigma (docs/TRACKING.md). Between 3 % and 15 %: either change shows here.
    assert 0.03 * tested <= sum(fired) <= 0.15 * tested, (sum(fired), tested)
    # One pointing: the frames share their stars, so the mean NEES scatters more than 150
    # independent draws would. Here 2.65 (median 1.83, chi^2_3's 2.37: the firings' inflation);
    # 2.2-4.0 refuses a covariance overconfident by a third or inflated on most frames.
    tracked = np.array(nees[1:])
    assert 2.2 < tracked.mean() < 4.0, tracked.mean()
