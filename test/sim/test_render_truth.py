# SPDX-License-Identifier: Apache-2.0
"""
The renderer's truth listing (FrameTruth) against what it was asked to draw.

Objects grouped in the documented order, each group's count, positions and signal within the
false-object and sensor parameters, hot pixels at the fixed pattern's positions with their dark
charge.
"""
from __future__ import annotations

import numpy as np

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import (KIND_COSMIC_RAY, KIND_DEBRIS, KIND_HOT_PIXEL, KIND_PLANET, KIND_STAR,
                                     FalseObjectModel, StarFieldRenderer, frame_seed)
from star_tracker.sim.sensor import SensorModel

POINTING = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.3)
RATE = np.radians([0.3, 0.2, 0.1])  # rad/s, sensor frame


def test_truth_lists_every_group_as_drawn(catalog, nominal_camera):
    sensor = SensorModel(hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=40.0, vignetting_at_corner=0.2)
    false_objects = FalseObjectModel(planets_per_frame=3, planet_magnitude_range=(0.0, 1.0), debris_per_frame=4,
                                     debris_magnitude_range=(4.0, 5.0), debris_speed_px_s=(200.0, 400.0))
    r = StarFieldRenderer(nominal_camera, sensor, catalog.at_epoch(2026.0), magnitude_limit=7.0,
                          false_objects=false_objects, fixed_pattern_seed=3)
    motion = ConstantRateMotion(POINTING, RATE)
    width = nominal_camera.width
    assert r.hot_pixels.size > 0
    cosmic_rays = 0
    for k in range(4):
        stamp = 2.0 + 0.1 * k
        t = r.render(motion, stamp, frame_seed(21, k)).truth
        assert t.stamp_s == stamp and np.allclose(t.rotation, motion.rotation_at(stamp), atol=1e-12)
        assert np.allclose(t.body_rate, RATE, atol=1e-15)
        # Stars, then planets, debris, cosmic rays, hot pixels; only stars carry a HIP number.
        assert np.all(np.diff(t.kind) >= 0)
        stars = t.kind == KIND_STAR
        assert stars.sum() > 20 and np.all(np.isin(t.hip[stars], catalog.hip)) and np.all(t.hip[~stars] == 0)
        # Planets and debris start inside the image, so every one is listed.
        planets, debris = t.kind == KIND_PLANET, t.kind == KIND_DEBRIS
        assert planets.sum() == 3 and debris.sum() == 4
        for group, (bright, faint) in ((planets, (0.0, 1.0)), (debris, (4.0, 5.0))):
            assert np.all(nominal_camera.in_image(t.x[group], t.y[group]))
            # Light collected through the vignetting: at most 20 % lost at the corner.
            assert np.all(t.electrons[group] <= sensor.star_electrons(bright) * (1 + 1e-9))
            assert np.all(t.electrons[group] >= 0.8 * sensor.star_electrons(faint) * (1 - 1e-9))
        assert np.all((t.extent_px[debris] >= 200.0 * sensor.exposure_s) & (t.extent_px[debris] <= 400.0
                                                                            * sensor.exposure_s))
        cosmic = t.kind == KIND_COSMIC_RAY
        cosmic_rays += cosmic.sum()
        assert np.all((t.extent_px[cosmic] >= 1.0) & (t.extent_px[cosmic] <= 15.0))
        # Hot pixels: the fixed pattern's, at their pixel centres, with their dark charge (no vignetting).
        hot = t.kind == KIND_HOT_PIXEL
        assert np.array_equal(t.x[hot], r.hot_pixels % width) and np.array_equal(t.y[hot], r.hot_pixels // width)
        assert np.array_equal(t.electrons[hot], r.static_e.reshape(-1)[r.hot_pixels].astype(float))
        assert np.all(t.extent_px[hot] == 0.0)
    assert cosmic_rays > 0


def test_jitter_is_sampled_finely_enough_that_the_image_holds_the_exposures_mean(catalog, nominal_camera):
    # 5" of jitter at 5 Hz on a slow drift moves a star < 1 px: sampled by its extent alone it
    # got 2 sub-steps, whose mean missed the exposure's by ~0.1 px (5"), the NEES of its frames 11.
    from star_tracker.sim.motion import JitterMotion
    from star_tracker.sim.render import MAX_AVERAGE_ERROR_PX

    r = StarFieldRenderer(nominal_camera, SensorModel(), catalog.at_epoch(2026.0), magnitude_limit=6.0)
    arcsec = np.pi / (180.0 * 3600.0)
    for amplitude, frequency in ((5.0, 5.0), (20.0, 20.0)):
        motion = JitterMotion(ConstantRateMotion(POINTING, np.radians([0.1, -0.05, 0.0])),
                              np.full((1, 3), amplitude * arcsec), np.array([frequency]), 0.7)
        stamp = 1.03
        rot_mid = motion.rotation_at(stamp)
        offsets = r._substep_offsets(motion, stamp, rot_mid)
        sampled = r._probe_paths(motion.rotations_at(stamp + offsets), rot_mid).mean(axis=1)
        fine = r._probe_paths(motion.rotations_at(stamp + (np.arange(4000) + 0.5) / 4000 * 0.1 - 0.05),
                              rot_mid).mean(axis=1)
        assert offsets.size > 2
        assert np.max(np.linalg.norm(sampled - fine, axis=1)) < 2 * MAX_AVERAGE_ERROR_PX
    # At rest one sub-step, as before.
    assert r._substep_offsets(ConstantRateMotion(POINTING, np.zeros(3)), 1.0, POINTING).size == 1
