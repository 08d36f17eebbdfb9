# SPDX-License-Identifier: Apache-2.0
"""
The camera simulator against physics.

Photometry, geometry, smear, noise, distortion, shutter effects, aberration and truth. Each
test compares with an independent model.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import (KIND_COSMIC_RAY, KIND_DEBRIS, KIND_HOT_PIXEL, KIND_PLANET, KIND_STAR,
                                     SPEED_OF_LIGHT_M_S, FalseObjectModel, StarFieldRenderer, frame_seed)
from star_tracker.sim.sensor import SensorModel
from star_tracker.ros import convert

POINTING = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.3)
QUIET = SensorModel(noise=False, read_noise_e=0.0)


def renderer(catalog, camera, sensor=SensorModel(), limit=7.0, **kwargs):
    return StarFieldRenderer(camera, sensor, catalog.at_epoch(2026.0), magnitude_limit=limit, **kwargs)


def electrons_above_static(frame, r):
    """Image back in electrons with the known static level (sky, dark) removed."""
    return (frame.image.astype(float) - r.sensor.bias_adu) * r.sensor.gain_e_per_adu - r.static_e


def isolated(truth, distance):
    d = np.hypot(truth.x[:, None] - truth.x[None], truth.y[:, None] - truth.y[None])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1) > distance


def inside(truth, camera, margin):
    return ((truth.x > margin) & (truth.x < camera.width - 1 - margin)
            & (truth.y > margin) & (truth.y < camera.height - 1 - margin))


def test_photometry_matches_expected_electrons_within_shot_noise(catalog, nominal_camera):
    sensor = SensorModel(gain_e_per_adu=2.0, read_noise_e=8.0)
    r = renderer(catalog, nominal_camera, sensor)
    frame = r.render(ConstantRateMotion(POINTING, np.zeros(3)), 5.0, frame_seed(1, 0))
    residual = electrons_above_static(frame, r)
    t = frame.truth
    use = t.stars() & isolated(t, 20) & inside(t, nominal_camera, 10) & (t.electrons < 2e5)
    half = 7  # aperture +-7 px: > 99.99 % of a sigma = 1 px PSF
    normalized = []
    for x, y, expected in zip(t.x[use], t.y[use], t.electrons[use]):
        r0, c0 = int(round(y)), int(round(x))
        box = (slice(r0 - half, r0 + half + 1), slice(c0 - half, c0 + half + 1))
        measured = residual[box].sum()
        variance = expected + np.sum(r.static_e[box]
                                     + sensor.read_noise_e ** 2) + residual[box].size * sensor.gain_e_per_adu ** 2 / 12
        normalized.append((measured - expected) / np.sqrt(variance))
    normalized = np.array(normalized)
    assert normalized.size >= 30
    assert np.all(np.abs(normalized) < 3.0)  # every isolated star within 3 sigma of shot noise
    assert abs(normalized.mean()) < 0.5 and 0.6 < normalized.std() < 1.4


def test_geometry_matches_opencv_projection():
    from star_tracker.models.catalog import load_hipparcos

    camera = CameraModel(1024, 1024, 3889.0, 3885.0, 515.2, 508.7, (-0.15, 0.08, 2e-4, -3e-4, 0.0))
    info = convert.camera_to_info(camera, 0, "star_tracker_optical")  # what the node publishes
    k, d = np.asarray(info.k).reshape(3, 3), np.asarray(info.d)
    catalog = load_hipparcos().at_epoch(2026.0)
    r = StarFieldRenderer(camera, QUIET, catalog, magnitude_limit=7.0)
    frame = r.render(ConstantRateMotion(POINTING, np.zeros(3)), 5.0, 0)
    residual = electrons_above_static(frame, r)
    t = frame.truth
    use = t.stars() & isolated(t, 20) & inside(t, camera, 10) & (t.electrons > 3000)
    stars = catalog.subset(np.isin(catalog.hip, t.hip[use]))
    sensor_rays = stars.unit_vectors() @ frame.truth.rotation  # ICRS -> sensor
    expected, _ = cv2.projectPoints(sensor_rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, d)
    expected = dict(zip(stars.hip, expected.reshape(-1, 2)))
    errors = []
    for hip, x, y in zip(t.hip[use], t.x[use], t.y[use]):
        r0, c0 = int(round(y)), int(round(x))
        rows, cols = np.mgrid[r0 - 7:r0 + 8, c0 - 7:c0 + 8]
        w = residual[r0 - 7:r0 + 8, c0 - 7:c0 + 8]
        centroid = np.array([np.sum(w * cols), np.sum(w * rows)]) / w.sum()
        errors.append(np.hypot(*(centroid - expected[hip])))
    assert len(errors) >= 20
    assert max(errors) < 0.02  # rendered centroids = OpenCV projection with the published K, D


def streak_moments(residual, x, y, half):
    r0, c0 = int(round(y)), int(round(x))
    rows, cols = np.mgrid[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1].astype(float)
    w = np.clip(residual[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1], 0, None)
    mx, my = np.sum(w * cols) / w.sum(), np.sum(w * rows) / w.sum()
    cov = np.cov(np.vstack([cols.ravel() - mx, rows.ravel() - my]), aweights=w.ravel(), bias=True)
    return np.array([mx, my]), cov, (cols, rows, w)


def test_straight_smear_length(catalog, nominal_camera):
    rate = np.radians(3.0)  # about +X: stars streak along the image's y axis
    exposure = 0.1
    r = renderer(catalog, nominal_camera, QUIET, limit=6.5)
    frame = r.render(ConstantRateMotion(POINTING, np.array([rate, 0.0, 0.0])), 5.0, 0)
    residual = electrons_above_static(frame, r)
    t = frame.truth
    expected_length = rate * exposure * nominal_camera.fy  # |omega_perp| T f at the centre
    assert 15 < expected_length < 25
    near_centre = np.hypot(t.x - nominal_camera.cx, t.y - nominal_camera.cy) < 250
    use = t.stars() & isolated(t, 45) & near_centre & (t.electrons > 2000)
    assert use.sum() >= 2
    sigma2 = r.sensor.psf_sigma_px ** 2 + 1.0 / 12.0  # PSF convolved with the pixel
    for x, y in zip(t.x[use], t.y[use]):
        centre, cov, _ = streak_moments(residual, x, y, 22)
        length = np.sqrt(12.0 * (cov[1, 1] - sigma2))  # uniform line: variance L^2/12
        scale = 1.0 + ((x - nominal_camera.cx) ** 2 + (y - nominal_camera.cy) ** 2) / nominal_camera.fy ** 2
        assert abs(length / (expected_length * scale) - 1.0) < 0.02
        assert abs(cov[0, 0] - sigma2) < 0.05  # no spread across the streak
        assert np.hypot(*(centre - [x, y])) < 0.05  # centre = mid-exposure position


def test_roll_smear_draws_arcs_about_the_boresight(catalog, nominal_camera):
    roll_rate = np.radians(150.0)  # 15 degrees of roll in 0.1 s: arcs with measurable curvature
    r = renderer(catalog, nominal_camera, QUIET, limit=5.5)
    frame = r.render(ConstantRateMotion(POINTING, np.array([0.0, 0.0, roll_rate])), 5.0, 0)
    residual = electrons_above_static(frame, r)
    t = frame.truth
    radius = np.hypot(t.x - nominal_camera.cx, t.y - nominal_camera.cy)
    use = t.stars() & isolated(t, 120) & inside(t, nominal_camera, 80) & (radius > 200) & (radius < 450) \
        & (t.electrons > 3000)
    assert use.sum() >= 2
    sigma2 = r.sensor.psf_sigma_px ** 2 + 1.0 / 12.0
    for x, y, rad in zip(t.x[use], t.y[use], radius[use]):
        arc = roll_rate * 0.1 * rad
        _, _, (cols, rows, w) = streak_moments(residual, x, y, int(arc / 2) + 8)
        # Polar coordinates about the boresight (principal point).
        rho = np.hypot(cols - nominal_camera.cx, rows - nominal_camera.cy)
        phi = np.unwrap(np.arctan2(rows - nominal_camera.cy, cols - nominal_camera.cx).ravel()).reshape(rho.shape)
        mean_rho = np.sum(w * rho) / w.sum()
        var_rho = np.sum(w * (rho - mean_rho) ** 2) / w.sum()
        mean_phi = np.sum(w * phi) / w.sum()
        var_phi = np.sum(w * (phi - mean_phi) ** 2) / w.sum()
        # Centred on the boresight: the distance from it stays constant along the whole arc, so
        # its spread is the PSF's alone (a straight streak of this length would add
        # ~(L^2/8r)^2 * 4/45 ~ 0.3-1 px^2).
        assert abs(mean_rho - rad) < 0.1
        assert abs(var_rho - sigma2) < 0.06
        # Arc length = roll angle x radius (uniform in angle: variance (omega T)^2 / 12).
        swept = np.sqrt(12.0 * (var_phi - sigma2 / rad ** 2))
        assert abs(swept / (roll_rate * 0.1) - 1.0) < 0.02


def test_photon_transfer_curve(catalog, nominal_camera):
    gain, read = 2.0, 8.0
    means, variances = [], []
    for level in (100.0, 1e3, 1e4, 1e5, 3e5):  # background [e-/px/s]; T = 0.1 s
        sensor = SensorModel(background_e_per_px_s=level, dark_e_per_px_s=0.0, gain_e_per_adu=gain, read_noise_e=read)
        r = StarFieldRenderer(nominal_camera, sensor, catalog, magnitude_limit=-5.0)  # no stars
        motion = ConstantRateMotion(POINTING, np.zeros(3))
        a = r.render(motion, 1.0, frame_seed(3, 0)).image.astype(float)
        b = r.render(motion, 1.0, frame_seed(3, 1)).image.astype(float)
        means.append(0.5 * (a.mean() + b.mean()) - sensor.bias_adu)
        variances.append(np.var(a - b) / 2.0)  # the difference removes any fixed pattern
    means, variances = np.array(means), np.array(variances)
    # Photon transfer: var = mean / gain + (read / gain)^2 + 1/12 (ADU quantization), within 5 %.
    model = means / gain + (read / gain) ** 2 + 1.0 / 12.0
    assert np.all(np.abs(variances / model - 1.0) < 0.05)
    slope, intercept = np.polyfit(means, variances, 1)
    assert abs(slope * gain - 1.0) < 0.05
    # The intercept is read noise^2 + quantization; the fit's own uncertainty there is ~0.1 ADU^2.
    assert abs(intercept - ((read / gain) ** 2 + 1 / 12)) < 0.05 * (read / gain) ** 2 + 0.2
    # Beyond full well the signal clips: the variance collapses.
    sensor = SensorModel(background_e_per_px_s=1e6, gain_e_per_adu=gain, read_noise_e=read)
    saturated = StarFieldRenderer(nominal_camera, sensor, catalog, magnitude_limit=-5.0).render(
        ConstantRateMotion(POINTING, np.zeros(3)), 1.0, 7).image
    assert np.all(saturated == round(sensor.full_well_e / gain + sensor.bias_adu))


def test_distortion_round_trip_through_camera_info():
    camera = CameraModel(1280, 960, 2500.0, 2498.0, 641.0, 478.5, (-0.2, 0.12, 5e-4, -4e-4, -0.03))
    back = convert.info_to_camera(convert.camera_to_info(camera, 0, "star_tracker_optical"))
    rng = np.random.default_rng(4)
    u, v = rng.uniform(0, 1279, 2000), rng.uniform(0, 959, 2000)
    u2, v2, _ = camera.project(back.pixel_to_ray(u, v))
    assert np.max(np.hypot(u2 - u, v2 - v)) < 1e-3


def test_every_spot_is_traceable_to_truth(catalog, nominal_camera):
    sensor = SensorModel(dsnu_fraction=0.1, prnu_fraction=0.01, hot_pixel_fraction=2e-5, hot_pixel_dark_factor=2000.0,
                         cosmic_ray_rate_per_cm2_s=40.0, vignetting_at_corner=0.1)
    false_objects = FalseObjectModel(planets_per_frame=2, debris_per_frame=2)
    r = renderer(catalog, nominal_camera, sensor, limit=8.0, false_objects=false_objects)
    kinds_seen = set()
    for k in range(3):
        frame = r.render(ConstantRateMotion(POINTING, np.radians([0.3, 0.2, 0.0])), 5.0 + k, frame_seed(5, k))
        t = frame.truth
        spots = extract_spots(frame.image,
                              CentroidConfig(min_area=1, psf_sigma_px=0.0, method="cog"))  # every defect too
        # A spot belongs to an object if it lies on the object's track (+ a few px for blends).
        d = np.hypot(spots.x[:, None] - t.x[None], spots.y[:, None] - t.y[None])
        reach = 3.0 + 0.5 * t.extent_px[None, :]
        owned = d <= reach
        # Or a blend: on the segment between two objects less than 12 px apart (shape test off,
        # so a hot pixel next to a star is measured with it).
        close = np.hypot(t.x[:, None] - t.x[None], t.y[:, None] - t.y[None]) < 12.0
        pair_sum = d[:, :, None] + d[:, None, :]
        blend = ((pair_sum <= np.hypot(t.x[:, None] - t.x[None], t.y[:, None] - t.y[None])[None] + 1.0)
                 & close[None]).any(axis=(1, 2))
        traceable = owned.any(axis=1) | blend
        assert traceable.all(), spots.take(np.flatnonzero(~traceable))
        kinds_seen |= set(t.kind[np.argmin(np.where(owned, d, np.inf), axis=1)].tolist())
    assert {KIND_STAR, KIND_PLANET, KIND_DEBRIS, KIND_COSMIC_RAY, KIND_HOT_PIXEL} <= kinds_seen


def test_rolling_shutter_delays_rows(catalog, nominal_camera):
    row_time = 50e-6  # 51 ms from the first to the last row
    rate = np.array([np.radians(1.0), 0.0, 0.0])
    sensor = SensorModel(noise=False, read_noise_e=0.0, rolling_shutter_row_time_s=row_time)
    r = renderer(catalog, nominal_camera, sensor, limit=6.5)
    motion = ConstantRateMotion(POINTING, rate)
    frame = r.render(motion, 5.0, 0)
    residual = electrons_above_static(frame, r)
    t = frame.truth
    use = t.stars() & isolated(t, 25) & inside(t, nominal_camera, 15) & (t.electrons > 3000)
    assert use.sum() >= 10
    k, d = nominal_camera.intrinsic_matrix(), np.asarray(nominal_camera.distortion)
    shifts = []
    star_vectors = catalog.at_epoch(2026.0)
    for hip, x, y in zip(t.hip[use], t.x[use], t.y[use]):
        centre, _, _ = streak_moments(residual, x, y, 9)
        # Independent: the star's direction seen at its row's mid-exposure time.
        i = star_vectors.index_of(int(hip))
        v_icrs = star_vectors.unit_vectors()[i]
        delay = (centre[1] - (nominal_camera.height - 1) / 2) * row_time
        ray = v_icrs @ motion.rotation_at(5.0 + delay)
        expected, _ = cv2.projectPoints(ray.reshape(1, 1, 3), np.zeros(3), np.zeros(3), k, d)
        assert np.hypot(*(centre - expected.ravel())) < 0.05
        global_ray = v_icrs @ motion.rotation_at(5.0)
        global_px, _ = cv2.projectPoints(global_ray.reshape(1, 1, 3), np.zeros(3), np.zeros(3), k, d)
        shifts.append(centre[1] - global_px.ravel()[1])
    assert np.ptp(shifts) > 2.0  # the shutter visibly skews the field (~3.4 px top to bottom)


def test_frame_transfer_smear(catalog, nominal_camera):
    transfer = 5e-3
    # Fine ADC steps: the smear is ~1 e-/px and must not be rounded away.
    sensor = SensorModel(noise=False, read_noise_e=0.0, frame_transfer_time_s=transfer, gain_e_per_adu=0.05)
    r = renderer(catalog, nominal_camera, sensor, limit=3.5)
    frame = r.render(ConstantRateMotion(POINTING, np.zeros(3)), 5.0, 0)
    residual = electrons_above_static(frame, r)
    t = frame.truth
    brightest = np.argmax(np.where(t.stars(), t.electrons, 0))
    col = int(round(t.x[brightest]))
    row = int(round(t.y[brightest]))
    far_rows = np.abs(np.arange(nominal_camera.height) - row) > 30
    column_excess = residual[far_rows, col - 6:col + 7].sum(axis=1).mean()
    expected = t.electrons[brightest] * transfer / (sensor.exposure_s * nominal_camera.height)
    assert abs(column_excess / expected - 1.0) < 0.05


def test_aberration_shift(catalog, nominal_camera):
    velocity = 30_000.0 * radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)[:, 0]  # along image +x
    still = renderer(catalog, nominal_camera, QUIET, limit=5.0).render(ConstantRateMotion(POINTING, np.zeros(3)), 5.0,
                                                                       0)
    moving = renderer(catalog, nominal_camera, QUIET, limit=5.0, observer_velocity_m_s=velocity).render(
        ConstantRateMotion(POINTING, np.zeros(3)), 5.0, 0)
    a, b = still.truth, moving.truth
    common = np.intersect1d(a.hip[a.stars()], b.hip[b.stars()])
    ia = np.searchsorted(a.hip[a.stars()], common)
    ib = np.searchsorted(b.hip[b.stars()], common)
    shift = np.column_stack([b.x[b.stars()][ib] - a.x[a.stars()][ia], b.y[b.stars()][ib] - a.y[a.stars()][ia]])
    # First-order aberration: directions tilt toward the velocity by beta sin(theta).
    expected_px = 30_000.0 / SPEED_OF_LIGHT_M_S * nominal_camera.fx
    direction = POINTING.T @ (velocity / np.linalg.norm(velocity))
    along = shift @ direction[:2] / np.linalg.norm(direction[:2])
    assert common.size >= 5
    assert np.allclose(along, expected_px, rtol=0.05)


@pytest.mark.parametrize("rate", [0.0, 400.0])
def test_cosmic_ray_count_follows_the_rate(catalog, nominal_camera, rate):
    sensor = SensorModel(cosmic_ray_rate_per_cm2_s=rate)
    r = StarFieldRenderer(nominal_camera, sensor, catalog, magnitude_limit=-5.0)
    counts = [np.sum(r.render(ConstantRateMotion(POINTING, np.zeros(3)), 1.0,
                              frame_seed(9, k)).truth.kind == KIND_COSMIC_RAY)
              for k in range(20)]
    expected = rate * (1024 * 13e-4) ** 2 * sensor.exposure_s
    assert abs(np.mean(counts) - expected) <= 4 * np.sqrt(max(expected, 1e-9) / 20) + 1e-9


def test_background_vignetting_gradient_dark_and_adc_levels(nominal_camera, catalog):
    """Star-free, noise-free frames: every static term at the level its formula gives."""
    cam = nominal_camera
    base = dict(noise=False, read_noise_e=0.0, background_e_per_px_s=4000.0, dark_e_per_px_s=100.0,
                gain_e_per_adu=0.25, bias_adu=200.0)

    def level(**changes):
        sensor = SensorModel(**{**base, **changes})
        frame = StarFieldRenderer(cam, sensor, catalog, magnitude_limit=-5.0).render(
            ConstantRateMotion(POINTING, np.zeros(3)), 1.0, 0)
        return (frame.image.astype(float) - sensor.bias_adu) * sensor.gain_e_per_adu  # electrons

    t = 0.1
    flat = level()
    assert np.allclose(flat, (4000.0 + 100.0) * t, atol=0.13)  # within ADC rounding (0.125 e-)
    # Vignetting: 1 - a r^2 / r_corner^2 on the sky light only (dark current is not light).
    vignetted = level(vignetting_at_corner=0.2)
    assert vignetted[0, 0] == pytest.approx(4000.0 * t * (1 - 0.2 * 2 * 511.5 ** 2 / (2 * 512.0 ** 2)) + 100.0 * t,
                                            abs=0.13)
    assert vignetted[512, 512] == pytest.approx(flat[512, 512], abs=0.13)
    # Stray-light gradient: linear in x and y about the image centre.
    graded = level(stray_light_gradient_e_per_px2_s=(2.0, -1.0))
    assert graded[300, 1000] - graded[300, 100] == pytest.approx(2.0 * 900 * t, abs=0.3)
    assert graded[1000, 400] - graded[100, 400] == pytest.approx(-1.0 * 900 * t, abs=0.3)
    # Dark current doubles every dark_doubling_k kelvin.
    warm = level(temperature_k=293.15 + 12.0)
    assert np.mean(warm - flat) == pytest.approx(100.0 * t * (2 ** 2 - 1), abs=0.05)
    # A 12-bit ADC saturates at 4095 ADU.
    sensor = SensorModel(noise=False, background_e_per_px_s=1e6, adc_bits=12, full_well_e=1e6)
    image = StarFieldRenderer(cam, sensor, catalog, magnitude_limit=-5.0).render(
        ConstantRateMotion(POINTING, np.zeros(3)), 1.0, 0).image
    assert image.max() == 4095 and np.all(image == 4095)


def test_rendered_star_directions_are_erfas_apparent_places(catalog, nominal_camera):
    """The renderer's star directions for an observer at LEO + Earth speed are ERFA's eraAb places to < 0.05"."""
    import erfa

    velocity = np.array([-29_800.0, 7_600.0, 2_100.0])  # the Earth's barycentric velocity + an orbit's, ICRS
    moving = renderer(catalog, nominal_camera, QUIET, limit=5.0, observer_velocity_m_s=velocity)
    astrometric = catalog.brighter_than(5.0).unit_vectors()
    speed = np.linalg.norm(velocity)
    # eraAb(pnat, v [c], s [au], bm1): s = 1 au and sqrt(1 - |v|^2) as for an Earth-bound observer.
    beta = velocity / SPEED_OF_LIGHT_M_S
    reference = erfa.ab(astrometric, beta, 1.0, np.sqrt(1.0 - (speed / SPEED_OF_LIGHT_M_S) ** 2))
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    error = np.degrees(np.arccos(np.clip(np.sum(moving.star_vectors * reference, axis=1), -1, 1))) * 3600.0
    shift = np.degrees(np.arccos(np.clip(np.sum(astrometric * reference, axis=1), -1, 1))) * 3600.0
    assert shift.max() > 20.0  # the aberration itself is ~31"
    assert error.max() < 0.05, error.max()
