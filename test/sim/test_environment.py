# SPDX-License-Identifier: Apache-2.0
"""
Frames rendered with an Environment against independent geometry.

The stars missing behind the Earth are those astropy puts within the Earth's disc (+
atmosphere); stray light rises toward the exclusion angle and floods the frame inside it;
the Moon's disc has its apparent radius in pixels, its lit side toward the Sun, saturates and
blooms along columns only with blooming on; the environment's planets land at their
projected positions with their flux; per-frame aberration; with no environment (or one that
does nothing) the frame is bit-identical.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import CartesianRepresentation, SkyCoord

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.models.sky_geometry import MOON_RADIUS_M, HeadStatus, head_geometry
from star_tracker.sim.apparent_directions import SPEED_OF_LIGHT_M_S
from star_tracker.sim.body_brightness import SUN_V_MAGNITUDE, moon_magnitude
from star_tracker.sim.environment import Environment, EnvironmentModel
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import KIND_MOON, KIND_PLANET, KIND_STAR, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel

AU_M = 1.495978707e11
MOON_DISTANCE_M = 3.844e8
LEO_M = 6_378_137.0 + 500e3
POINTING = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.3)
BORESIGHT, IMAGE_X, IMAGE_Y = POINTING[:, 2], POINTING[:, 0], POINTING[:, 1]
AT_REST = ConstantRateMotion(POINTING, np.zeros(3))
QUIET = SensorModel(noise=False)


def toward(a: np.ndarray, b: np.ndarray, angle_rad: float) -> np.ndarray:
    """Return the unit vector angle_rad from unit a, in the plane of a and b, toward b."""
    t = b - (b @ a) * a
    return math.cos(angle_rad) * a + math.sin(angle_rad) * t / np.linalg.norm(t)


def quiet_environment(**changes) -> Environment:
    """Return an environment that shows nothing: the Earth behind the head, the Sun and the Moon behind the aperture."""
    spacecraft = LEO_M * BORESIGHT
    values = dict(spacecraft_position_m=spacecraft, spacecraft_velocity_m_s=np.zeros(3),
                  sun_position_m=spacecraft + AU_M * toward(-BORESIGHT, IMAGE_X, 0.3),
                  moon_position_m=spacecraft + MOON_DISTANCE_M * toward(-BORESIGHT, IMAGE_Y, 0.5),
                  observer_velocity_m_s=np.zeros(3))
    return Environment(**{**values, **changes})


def renderer(catalog, camera, sensor=QUIET, **kwargs) -> StarFieldRenderer:
    return StarFieldRenderer(camera, sensor, catalog, magnitude_limit=kwargs.pop("limit", 7.0), **kwargs)


def sky(vectors) -> SkyCoord:
    x, y, z = np.asarray(vectors, dtype=float).reshape(-1, 3).T
    return SkyCoord(CartesianRepresentation(x, y, z, unit=u.m), frame="icrs")


def saturated_adu(sensor: SensorModel) -> int:
    return int(min(sensor.bias_adu + sensor.full_well_e / sensor.gain_e_per_adu + 0.5, sensor.max_adu))


def test_without_an_environment_or_with_one_that_shows_nothing_the_frame_is_the_same(catalog, nominal_camera):
    sensor = SensorModel(hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=20.0)
    r = renderer(catalog, nominal_camera, sensor, observer_velocity_m_s=(1e4, -2e4, 5e3))
    motion = ConstantRateMotion(POINTING, np.radians([0.3, 0.2, 0.1]))
    plain = r.render(motion, 2.0, frame_seed(3, 1))
    none = r.render(motion, 2.0, frame_seed(3, 1), environment=None)
    nothing = r.render(motion, 2.0, frame_seed(3, 1),
                       environment=quiet_environment(observer_velocity_m_s=np.array([1e4, -2e4, 5e3])))
    assert np.array_equal(plain.image, none.image) and none.truth.environment is None
    assert np.array_equal(plain.image, nothing.image)
    for name in ("kind", "hip", "x", "y", "electrons", "extent_px"):
        assert np.array_equal(getattr(plain.truth, name), getattr(nothing.truth, name))
    assert nothing.truth.environment.head.status == HeadStatus.TRACKING_POSSIBLE
    assert nothing.truth.environment.stray_light_e == (0.0, 0.0, 0.0)


def test_the_stars_behind_the_earth_are_those_within_its_disc(catalog, nominal_camera):
    # The limb 3 deg below the boresight, the Sun behind the Earth (the spacecraft in its shadow, the Earth dark).
    limb_radius_m = EnvironmentModel().exclusion.limb_radius_m
    rho = math.asin(limb_radius_m / LEO_M)
    earth = toward(BORESIGHT, IMAGE_Y, rho + math.radians(3.0))
    spacecraft = -LEO_M * earth
    behind_earth = spacecraft + 1e11 * toward(earth, IMAGE_Y, 0.01)  # a planet hidden by the Earth
    env = quiet_environment(spacecraft_position_m=spacecraft, sun_position_m=AU_M * earth,
                            moon_position_m=spacecraft + MOON_DISTANCE_M * toward(-BORESIGHT, IMAGE_X, 0.5),
                            planet_positions_m=[behind_earth], planet_magnitudes=[0.0])
    r = renderer(catalog, nominal_camera, limit=7.5)
    without = r.render(AT_REST, 1.0, 0).truth
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    truth = frame.truth
    assert truth.environment.head.status == HeadStatus.TRACKING_POSSIBLE
    assert truth.environment.head.sun_eclipsed and not np.isfinite(truth.environment.head.lit_earth_angle_rad)
    stars_before = without.hip[without.stars()]
    separation = sky(np.column_stack([np.cos(catalog.dec) * np.cos(catalog.ra), np.cos(catalog.dec)
                                      * np.sin(catalog.ra), np.sin(catalog.dec)])[
        np.searchsorted(catalog.hip, stars_before)]).separation(sky(earth)[0]).to_value(u.rad)
    behind = set(stars_before[separation < rho])
    assert len(behind) >= 10 and len(stars_before) - len(behind) >= 10
    assert set(stars_before) - set(truth.hip[truth.stars()]) == behind
    assert behind <= set(truth.environment.occulted_hip)
    assert not np.any(truth.kind == KIND_PLANET)
    # Behind the (dark) Earth the frame holds no star light: only the static level.
    on_earth = nominal_camera.project((POINTING.T @ toward(BORESIGHT, IMAGE_Y, math.radians(5.0)))[None])
    x, y = int(round(on_earth[0][0])), int(round(on_earth[1][0]))
    assert np.ptp(frame.image[y - 30:y + 30, x - 200:x + 200]) <= 1


@pytest.fixture(scope="module")
def sun_frames(catalog, nominal_camera):
    """Frames with the Sun at decreasing angles from the boresight, toward image +x: {angle_deg: (frame, env)}."""
    r = renderer(catalog, nominal_camera, limit=6.0)
    frames = {}
    for angle in (85.0, 70.0, 55.0, 45.0, 38.0, 33.0, 30.5, 29.5, 20.0, 5.0):
        sun_direction = toward(BORESIGHT, IMAGE_X, math.radians(angle))
        env = quiet_environment(sun_position_m=LEO_M * BORESIGHT + AU_M * sun_direction)
        frames[angle] = r.render(AT_REST, 1.0, 0, environment=env), sun_direction
    return r.render(AT_REST, 1.0, 0), frames


def test_stray_light_rises_toward_the_sun_exclusion_angle_and_blinds_inside_it(sun_frames, nominal_camera):
    plain, frames = sun_frames
    sensor, model = QUIET, EnvironmentModel()
    centre = (slice(462, 562), slice(462, 562))
    levels = []
    for angle, (frame, sun_direction) in frames.items():
        theta = sky(BORESIGHT).separation(sky(sun_direction)).to_value(u.rad)[0]
        added = np.median(frame.image[centre].astype(float) - plain.image[centre])
        head = frame.truth.environment.head
        if theta >= model.exclusion.sun_exclusion_rad:
            # PST (theta / 30 deg)^-8 times the Sun's electrons on a pixel's share of the aperture.
            pst = model.pst_at_exclusion * (theta / model.exclusion.sun_exclusion_rad) ** -model.pst_exponent
            sun_e = sensor.zero_point_e_per_s * sensor.exposure_s * 10 ** (-0.4 * SUN_V_MAGNITUDE)  # colour term 0
            expected = sun_e * pst * sensor.pixel_pitch_m ** 2 / (math.pi * (sensor.aperture_diameter_m / 2) ** 2)
            if expected * (1 + model.stray_light_gradient) < model.stray_light_floor_e:
                expected = 0.0
            assert added == pytest.approx(expected, rel=0.02, abs=1.0)
            assert head.status == HeadStatus.TRACKING_POSSIBLE and not frame.truth.environment.blinded
            assert np.mean(frame.image == saturated_adu(sensor)) < 1e-4
        else:
            # Blinded: every pixel at the full well, no star to be seen.
            assert head.status == HeadStatus.BLINDED_SUN and frame.truth.environment.blinded
            assert np.all(frame.image == saturated_adu(sensor))
        levels.append(added)
    assert np.all(np.diff(levels) >= 0) and levels[0] < 5.0 and levels[5] > 1000.0


def test_stray_light_is_brighter_on_the_side_toward_the_source(sun_frames):
    plain, frames = sun_frames
    frame, _ = frames[33.0]
    added = frame.image.astype(float) - plain.image
    right, left = np.median(added[:, 900:]), np.median(added[:, :124])
    top, bottom = np.median(added[:124]), np.median(added[900:])
    assert right > 1.5 * left > 0 and abs(top - bottom) < 0.02 * right


@pytest.mark.parametrize("above_limb_deg, blinded", [(15.0, True), (25.0, False)])
def test_the_lit_earth_blinds_within_its_limb_exclusion_angle(catalog, nominal_camera, above_limb_deg, blinded):
    # The Sun overhead the spacecraft (the Earth below it in daylight), the limb toward image +y.
    model = EnvironmentModel()
    rho = math.asin(model.exclusion.limb_radius_m / LEO_M)
    earth = toward(BORESIGHT, IMAGE_Y, rho + math.radians(above_limb_deg))
    spacecraft = -LEO_M * earth
    env = quiet_environment(spacecraft_position_m=spacecraft, sun_position_m=-AU_M * earth,
                            moon_position_m=spacecraft + MOON_DISTANCE_M * toward(-BORESIGHT, IMAGE_X, 0.5))
    r = renderer(catalog, nominal_camera, limit=5.0)
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    truth = frame.truth.environment
    assert truth.head.lit_earth_angle_rad == pytest.approx(math.radians(above_limb_deg), abs=math.radians(0.1))
    if blinded:
        assert truth.head.status == HeadStatus.BLINDED_EARTH and truth.blinded
        assert np.all(frame.image == saturated_adu(QUIET))
    else:
        assert truth.head.status == HeadStatus.TRACKING_POSSIBLE and not truth.blinded
        added = frame.image.astype(float) - r.render(AT_REST, 1.0, 0).image
        bottom, top = np.median(added[900:]), np.median(added[:124])
        assert truth.stray_light_e[1] > 100.0 and bottom > 1.5 * top > 0  # brighter toward the Earth


def moon_environment(offset_rad: float, sun_direction: np.ndarray, fraction=None, image_offset=IMAGE_X):
    """Return (environment, Moon's direction): the Moon offset_rad toward image_offset, the Sun along sun_direction."""
    spacecraft = LEO_M * BORESIGHT
    moon_direction = toward(BORESIGHT, image_offset, offset_rad)
    return quiet_environment(moon_position_m=spacecraft + MOON_DISTANCE_M * moon_direction,
                             sun_position_m=spacecraft + AU_M * sun_direction,
                             moon_illuminated_fraction=fraction), moon_direction


def moon_light(frame, plain, cx: float, cy: float) -> np.ndarray:
    """Return the Moon's own light [e-] (gain 1): the frame less the plain one, less the glow about the disc."""
    added = frame.image.astype(float) - plain.image
    yy, xx = np.mgrid[0:added.shape[0], 0:added.shape[1]]
    distance = np.hypot(xx - cx, yy - cy)
    glow = np.median(added[(distance > 30) & (distance < 40)])  # the Moon's stray light about its disc
    return np.where(distance < 30, added - glow, 0.0)


def test_the_moon_has_its_apparent_radius_and_its_centre_where_projected(catalog, nominal_camera):
    # A dim optic (the Moon under the full well) and a full Moon: the Sun behind the spacecraft.
    sensor = SensorModel(noise=False, aperture_diameter_m=1e-4)
    env, moon_direction = moon_environment(0.03, -BORESIGHT, fraction=1.0)
    r = renderer(catalog, nominal_camera, sensor)
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    truth = frame.truth
    moon = truth.kind == KIND_MOON
    assert moon.sum() == 1 and frame.image.max() < saturated_adu(sensor)
    added = moon_light(frame, r.render(AT_REST, 1.0, 0), truth.x[moon][0], truth.y[moon][0])
    plateau = np.median(added[added > 0.5 * added.max()])
    radius_px = math.sqrt(np.count_nonzero(added > 0.5 * plateau) / math.pi)
    distance = MOON_DISTANCE_M
    expected = math.asin(MOON_RADIUS_M / distance) * nominal_camera.fx  # ~17.6 px (0.26 deg at 15 deg / 1024 px)
    assert radius_px == pytest.approx(expected, abs=0.3)
    projected = cv2.projectPoints((POINTING.T @ moon_direction)[None], np.zeros(3), np.zeros(3),
                                  nominal_camera.intrinsic_matrix(), np.zeros(5))[0].reshape(2)
    assert truth.x[moon][0] == pytest.approx(projected[0], abs=1e-6)
    assert truth.y[moon][0] == pytest.approx(projected[1], abs=1e-6)
    # Its electrons: a full Moon's magnitude through the sensor's radiometry, all of it on the chip.
    full = sensor.zero_point_e_per_s * sensor.exposure_s * 10 ** (-0.4 * (moon_magnitude(1.0, distance)))
    assert truth.electrons[moon][0] == pytest.approx(full, rel=0.01)
    assert added.sum() == pytest.approx(full, rel=0.01)
    assert truth.environment.moon_radius_px == pytest.approx(expected, rel=1e-3)
    # No star is listed under the disc.
    stars = truth.stars()
    assert np.all(np.hypot(truth.x[stars] - truth.x[moon], truth.y[stars] - truth.y[moon]) > expected - 1.0)


@pytest.mark.parametrize("sun_image_angle_deg", [0.0, 135.0, 250.0])
def test_the_moon_lit_side_faces_the_sun(catalog, nominal_camera, sun_image_angle_deg):
    sensor = SensorModel(noise=False, aperture_diameter_m=1e-4)
    a = math.radians(sun_image_angle_deg)
    across = math.cos(a) * IMAGE_X + math.sin(a) * IMAGE_Y
    sun_direction = toward(BORESIGHT, across, math.radians(90.0))  # a half Moon, lit toward `across`
    env, _ = moon_environment(0.02, sun_direction, image_offset=-IMAGE_Y)
    r = renderer(catalog, nominal_camera, sensor, limit=3.0)
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    truth = frame.truth
    cx, cy = truth.x[truth.kind == KIND_MOON][0], truth.y[truth.kind == KIND_MOON][0]
    added = moon_light(frame, r.render(AT_REST, 1.0, 0), cx, cy)
    yy, xx = np.mgrid[0:added.shape[0], 0:added.shape[1]]
    weights = added
    offset = np.array([np.sum(weights * (xx - cx)), np.sum(weights * (yy - cy))]) / weights.sum()
    # A uniformly lit half disc's centroid lies 4 r / (3 pi) from the centre, toward the Sun.
    radius_px = truth.environment.moon_radius_px
    assert np.linalg.norm(offset) == pytest.approx(4 * radius_px / (3 * math.pi), rel=0.05)
    turn = (math.degrees(math.atan2(offset[1], offset[0])) - sun_image_angle_deg + 180.0) % 360.0 - 180.0
    assert abs(turn) < 2.0
    dark = int(round(cx - 0.6 * radius_px * math.cos(a))), int(round(cy - 0.6 * radius_px * math.sin(a)))
    assert added[dark[1], dark[0]] < 0.01 * added.max()


@pytest.mark.parametrize("blooming", [True, False])
def test_the_moon_saturates_and_blooms_along_its_columns_only_when_on(catalog, nominal_camera, blooming):
    sensor = SensorModel(noise=False)
    env, _ = moon_environment(0.03, -BORESIGHT)
    r = renderer(catalog, nominal_camera, sensor, limit=3.0, environment_model=EnvironmentModel(blooming=blooming))
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    truth = frame.truth
    moon = truth.kind == KIND_MOON
    cx, cy = int(round(truth.x[moon][0])), int(round(truth.y[moon][0]))
    radius = truth.environment.moon_radius_px
    full = saturated_adu(sensor)
    assert np.all(frame.image[cy - 10:cy + 11, cx - 10:cx + 11] == full)  # the disc itself saturates
    far_in_column = frame.image[[cy - int(radius) - 100, cy + int(radius) + 100], cx]
    beside = frame.image[cy - 10:cy + 11, cx + int(radius) + 6]  # a column clear of the disc and its PSF
    assert np.all(beside < sensor.bias_adu + 100)
    if blooming:
        assert np.all(far_in_column == full)
        # The excess runs to both ends of the columns through the disc's centre.
        assert np.all(frame.image[:, cx] == full)
    else:
        assert np.all(far_in_column < sensor.bias_adu + 100)


def test_planets_land_at_their_projected_positions_with_their_flux(catalog, nominal_camera):
    spacecraft = LEO_M * BORESIGHT
    directions = [toward(BORESIGHT, IMAGE_X, 0.05), toward(BORESIGHT, -IMAGE_Y + IMAGE_X, 0.08)]
    magnitudes = [1.0, 2.5]
    env = quiet_environment(planet_positions_m=[spacecraft + d * 2e11 for d in directions],
                            planet_magnitudes=magnitudes)
    r = renderer(catalog, nominal_camera, limit=4.0)
    frame = r.render(AT_REST, 1.0, 0, environment=env)
    added = frame.image.astype(float) - r.render(AT_REST, 1.0, 0).image
    truth = frame.truth
    planets = np.flatnonzero(truth.kind == KIND_PLANET)
    assert planets.size == 2 and np.all(truth.hip[planets] == 0)
    projected, _ = cv2.projectPoints(np.array(directions) @ POINTING, np.zeros(3), np.zeros(3),
                                     nominal_camera.intrinsic_matrix(), np.zeros(5))
    for index, (x, y), magnitude in zip(planets, projected[:, 0], magnitudes):
        assert truth.x[index] == pytest.approx(x, abs=1e-6) and truth.y[index] == pytest.approx(y, abs=1e-6)
        electrons = QUIET.zero_point_e_per_s * QUIET.exposure_s * 10 ** (-0.4 * magnitude)
        assert truth.electrons[index] == pytest.approx(electrons, rel=1e-9)
        xi, yi = int(round(x)), int(round(y))
        assert added[yi - 7:yi + 8, xi - 7:xi + 8].sum() == pytest.approx(electrons, rel=0.01)


def test_aberration_follows_the_environment_velocity(catalog, nominal_camera):
    r = renderer(catalog, nominal_camera, limit=5.0, observer_velocity_m_s=(0.0, 2e5, 0.0))  # ignored with one
    velocity = 30_000.0 * IMAGE_X
    still = r.render(AT_REST, 1.0, 0, environment=quiet_environment()).truth
    moving = r.render(AT_REST, 1.0, 0, environment=quiet_environment(observer_velocity_m_s=velocity)).truth
    assert still.stars().sum() >= 5 and np.array_equal(still.hip, moving.hip)
    # First order: directions tilt toward the velocity by beta sin(theta), ~ beta fx px near the centre.
    shift = moving.x[moving.stars()] - still.x[still.stars()]
    assert np.allclose(shift, 30_000.0 / SPEED_OF_LIGHT_M_S * nominal_camera.fx, rtol=0.05)
    assert np.allclose(moving.y[moving.stars()], still.y[still.stars()], atol=0.02)
    geometric = renderer(catalog, nominal_camera, limit=5.0, environment_model=EnvironmentModel(aberration=False))
    assert np.array_equal(geometric.render(AT_REST, 1.0, 0, environment=quiet_environment(
        observer_velocity_m_s=velocity)).truth.x, still.x)
    assert np.all(still.kind[still.stars()] == KIND_STAR)


def test_the_truth_geometry_is_sky_geometry_at_mid_exposure(catalog, nominal_camera):
    env, _ = moon_environment(0.03, -BORESIGHT)
    frame = renderer(catalog, nominal_camera, limit=3.0).render(AT_REST, 1.0, 0, environment=env)
    head = frame.truth.environment.head
    expected = head_geometry(BORESIGHT, nominal_camera.half_diagonal_fov_rad, env.bodies(),
                             EnvironmentModel().exclusion)
    assert head.status == expected.status == HeadStatus.BLINDED_MOON and head.moon_in_field
    assert head.moon_angle_rad == expected.moon_angle_rad == pytest.approx(0.03, abs=1e-9)
