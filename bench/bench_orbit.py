# SPDX-License-Identifier: Apache-2.0
"""
In orbit: two heads over a LEO orbit, render -> centroid -> track -> aberration correction -> fusion.

    python -m bench.bench_orbit [--quick] [--jobs J] [--output docs/BENCHMARKS.md]

Scenario (every figure of the section comes from it). A 550 km circular sun-synchronous orbit
(models.orbit, J2 secular drift), ascending node at 10:30 local time on 2027-03-17 00:00 UTC (the
epoch, argument of latitude 0), a nadir-pointing body (sim.attitude_modes.NadirPointingMotion:
+Z nadir, +Y the negative orbit normal, +X along the velocity). Head "a" looks 45 deg from the
zenith toward body -Y (the orbit normal's side), head "b" 45 deg from the zenith toward +Y: 90 deg
apart. On that date the Sun lies 23 deg from head b's boresight at its closest (blinding it for
~13 % of the orbit) and the gibbous Moon crosses head b's field; head a sees neither. The Earth
is fixed in a nadir-pointing body's frame: a head 45 deg from the zenith keeps its lit limb
66 deg away, beyond the 20 deg exclusion, so the orbit never blinds or occults either head by
the Earth; the inertial arcs of part 4 are where the Earth occults and blinds a head.

Frames every FRAME_S of orbit time over one orbital period from START_OFFSET_S after the epoch,
both heads at the same stamps; the default camera (1024 px, 15 deg) and SensorModel (0.1 s
exposure) with every effect of the Environment (sim.spacecraft: the Sun, the Moon, the planets,
aberration with the Earth's + the orbital velocity; Earth occultation and stray light); the
exposure smeared by the true body rate. Per head: extract_spots (rate-aided by the tracker's
rate), Tracker(make_identifier("hybrid")) with TRACKING (the defaults but for a frame every
3 s: coast and rate window 10 s, angular acceleration bound 0.01 deg/s^2, a held nadir
attitude), the attitude corrected for the observer's velocity (identify.aberration_correction,
given the matched rays and covariances: refitted against the apparent directions with the
fit's weights), and the head status track.head_status would publish (the
geometry from the ephemeris, the true position and the tracker's attitude guess). Fusion:
fuse.FusionState with an AlignmentFilter (reference head a; the drift modelled as one harmonic of
the orbital period beside a random walk of DRIFT_PSD), each solved head's matched stars
(head-frame rays, their apparent ICRS directions, the isotropic ray sigma of the centroid
covariance) and its corrected attitude; the body rate is the true one plus a gyro's 1 urad/s
noise. Head b is truly mounted 10" off its nominal mounting plus a 3" sinusoidal drift over the
orbital period (sim.spacecraft.Misalignment).

Parts: (1) availability and wrong attitudes (> WRONG_ARCSEC from the truth: a head against its
own true attitude, the fused body attitude against the true body attitude), and each head's
blinded/occulted intervals against an independent geometry (astropy's builtin ephemeris, get_body
transformed to a GCRS observer at the spacecraft; the Earth's radius by closed form; the nearest
sunlit point of the Earth by a search over the visible disc); (2) fused against single-head error
per body axis; (3) aberration: every REST_EVERY-th frame of head a solved lost-in-space as
rendered (LEO + the Earth's velocity), corrected and uncorrected, and rendered again at zero
velocity (same seed); (4) the Moon and the bright planets in a head's field: ARCS inertial
pointings at them (several dates and Moon phases, random offsets in the field and rolls), each a
tracked sequence that starts as the head rises from behind the Earth; (5) the alignment
filter's estimate of head b against the injected truth; (6) figures. --quick runs three short
windows of the orbit (the Moon's exclusion entered, the Moon in head b's field, the Sun's
exclusion entered), two short arcs and a few aberration frames.

Output: the section of --output, docs/bench_orbit.json beside it, figures orbit_availability.png,
orbit_fused_error.png and orbit_sky.png in images/ beside it.
"""
from __future__ import annotations

import argparse
import concurrent.futures
import datetime as dt
import json
import math
import os
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from star_tracker.centroid import FLAG_SATURATED, CentroidConfig, extract_spots
from star_tracker.commands.bench import report_progress
from star_tracker.fuse import (AlignmentConfig, AlignmentFilter, BodyRate, FusionConfig, FusionState,
                               FusionUnavailable, HeadObservation)
from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
from star_tracker.identify.aberration_correction import corrected_solution
from star_tracker.identify.base import direction_covariance
from star_tracker.models.aberration import aberrate
from star_tracker.models.attitude import ARCSEC, matrix_to_rotation_vector, rotation_vector_to_matrix
from star_tracker.models.camera import CameraModel
from star_tracker.models.catalog import load_hipparcos
from star_tracker.models.ephemeris import load_ephemeris
from star_tracker.models.orbit import KeplerianOrbit, OrbitElements, sun_synchronous_inclination
from star_tracker.models.sky_geometry import ExclusionModel, HeadStatus, earth_occults, head_geometry
from star_tracker.sim.attitude_modes import HeadMounting, NadirPointingMotion, inertial_attitude
from star_tracker.sim.render import KIND_MOON, KIND_PLANET, StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel
from star_tracker.sim.spacecraft import Misalignment, Spacecraft
from star_tracker.track.head_status import head_frame_status
from star_tracker.track.tracking import Tracker, TrackingConfig
from .machine import machine_info, machine_text, utc_now
from .report import write_section

SECTION = "## In orbit: two heads over a LEO orbit"
SEED = 2027
ALTITUDE_M = 550e3
EPOCH_UNIX_S = dt.datetime(2027, 3, 17, tzinfo=dt.timezone.utc).timestamp()
CENTROID = CentroidConfig(sensor_blooms=True)  # the frames bloom (EnvironmentModel.blooming)
LTAN_H = 10.5  # local time of the ascending node [h]
START_OFFSET_S = 600.0  # the frames start here after the epoch: both heads clear
FRAME_S = 3.0
CAMERA = CameraModel.from_fov(1024, 1024, math.radians(15.0))
SENSOR = SensorModel()
MAGNITUDE_LIMIT = 7.5
EXCLUSION = ExclusionModel()  # Sun 30 deg, Moon 25 deg, lit Earth 20 deg, Earth + 100 km of atmosphere
# Head -> body (v_body = M v_head): the boresight 45 deg from the zenith (body -Z) toward body -Y (a), +Y (b).
MOUNTINGS = {"a": HeadMounting(rotation_vector_to_matrix([math.radians(135.0), 0.0, 0.0])),
             "b": HeadMounting(rotation_vector_to_matrix([-math.radians(135.0), 0.0, 0.0]))}
HEADS = tuple(MOUNTINGS)
MISALIGNED = "b"
OFFSET_AXIS = np.array([6.0, -5.0, 6.0]) / np.linalg.norm([6.0, -5.0, 6.0])  # head frame
DRIFT_AXIS = np.array([1.0, 1.0, 1.0]) / math.sqrt(3.0)
OFFSET_ARCSEC, DRIFT_ARCSEC = 10.0, 3.0
WRONG_ARCSEC = 60.0
GYRO_SIGMA_RAD_S = 1e-6
# The alignment filter models the drift as periodic over the orbit (one harmonic of the orbital
# period, docs/FUSION.md § Orbit-periodic drift); its random walk is left for what is not periodic:
# 1e-5 "^2/s lets the estimate wander ~0.24" over an orbit.
DRIFT_PSD = 1e-5 * ARCSEC ** 2
TRACKING = TrackingConfig(max_coast_s=10.0, rate_window_s=10.0, max_angular_acceleration_rad_s2=math.radians(0.01))
REST_EVERY = 10
# Part 4: (target, Moon illuminated fraction wanted or None) x ARC_ROLLS attitudes each.
ARC_TARGETS = (("moon", 0.4), ("moon", 0.6), ("moon", 0.8), ("moon", 0.97), ("venus", None), ("mars", None),
               ("jupiter", None), ("saturn", None))
ARC_ROLLS = 2
ARC_FRAMES, ARC_LEAD = 100, 20  # frames per arc; of them, before the head comes out from the Earth
ARC_MAX_OFFSET_RAD = math.radians(6.0)  # the target this far from the boresight at most
MIN_ELONGATION_RAD = math.radians(45.0)  # a planet's date: this far from the Sun (Venus: its greatest elongation)
# --quick: windows of the orbit's frame grid [s after the epoch] and fewer arcs.
QUICK_WINDOWS_S = ((1830.0, 1900.0), (2280.0, 2340.0), (5250.0, 5320.0))
QUICK_ARCS, QUICK_ARC_FRAMES, QUICK_ARC_LEAD = 2, 30, 10
QUICK_REST_FRAMES = 8
STATUSES = tuple(s.value for s in HeadStatus)
CAUSES = ("occulted", "blinded_sun", "blinded_earth", "blinded_moon")


# ----------------------------------------------------------------------------------- scenario
def orbit() -> KeplerianOrbit:
    """Return the 550 km sun-synchronous orbit, its node at LTAN_H local time at the epoch."""
    sun = load_ephemeris().sun_position(EPOCH_UNIX_S)
    raan = math.atan2(sun[1], sun[0]) + (LTAN_H - 12.0) / 24.0 * 2.0 * math.pi
    return KeplerianOrbit(OrbitElements.circular(ALTITUDE_M, sun_synchronous_inclination(ALTITUDE_M), raan, 0.0,
                                                 EPOCH_UNIX_S))


def misalignment(period_s: float) -> Misalignment:
    """Return head b's true mounting error: 10" offset plus a 3" sinusoid over the orbital period (head frame)."""
    return Misalignment(offset_rad=tuple(OFFSET_ARCSEC * ARCSEC * OFFSET_AXIS),
                        drift_amplitude_rad=tuple(DRIFT_ARCSEC * ARCSEC * DRIFT_AXIS), drift_period_s=period_s,
                        drift_epoch_unix_s=EPOCH_UNIX_S + START_OFFSET_S)


def spacecraft() -> Spacecraft:
    """Return the nadir-pointing spacecraft with heads a and b (b misaligned)."""
    path = orbit()
    return Spacecraft(path, NadirPointingMotion(path), dict(MOUNTINGS), load_ephemeris(),
                      misalignments={MISALIGNED: misalignment(path.period_s)})


def orbit_times(quick: bool) -> tuple[np.ndarray, np.ndarray]:
    """Return the frame indices and UNIX times [s] of the orbit run (--quick: the windows' frames)."""
    period = orbit().period_s
    k = np.arange(int(period // FRAME_S))
    t = EPOCH_UNIX_S + START_OFFSET_S + k * FRAME_S
    if quick:
        offset = t - EPOCH_UNIX_S
        keep = np.zeros(k.size, bool)
        for low, high in QUICK_WINDOWS_S:
            keep |= (offset >= low) & (offset <= high)
        k, t = k[keep], t[keep]
    return k, t


def true_alignment(t: float, period_s: float) -> np.ndarray:
    """Return head b's true mounting correction c [rad] in the fusion's convention (body frame): c = M delta."""
    return MOUNTINGS[MISALIGNED].head_to_body @ misalignment(period_s).angles(t)


# ----------------------------------------------------------------------------------- workers
_CHAIN: dict = {}


def _chain() -> dict:
    """Build (once per process) the renderer, the identifier and the scenario."""
    if not _CHAIN:
        database = load_or_build_database(DatabaseConfig())
        catalog = load_hipparcos().at_epoch(database.config.epoch_jyear)
        lis = make_identifier("hybrid", database)
        Tracker(lis, TRACKING).warm_up(CAMERA)
        _CHAIN.update(lis=lis, renderer=StarFieldRenderer(CAMERA, SENSOR, catalog, magnitude_limit=MAGNITUDE_LIMIT),
                      craft=spacecraft(), ephemeris=load_ephemeris())
    return _CHAIN


def _stamp(t: float) -> int:
    return int(round(t * 1e9))


def _status(tracker: Tracker, stamp_ns: int, mode: str | None, rotation, environment) -> str:
    """Return the status the identifier publishes (track.head_status) from the true position and its attitude."""
    if rotation is None:
        rotation = tracker.attitude_guess(stamp_ns)
    geometry = None
    if rotation is not None:
        geometry = head_geometry(rotation[:, 2], CAMERA.half_diagonal_fov_rad, environment.bodies(), EXCLUSION)
    rate = tracker.rate.angular_velocity if tracker.rate is not None else None
    return head_frame_status(mode, geometry, rate, TRACKING.max_angular_rate_rad_s).status


def _frame_record(frame, environment, tracked, spots, tracker: Tracker, stamp_ns: int, fusion: bool) -> dict:
    """Return what one head did in one frame, with its truth (see run_sequence)."""
    truth, ident = frame.truth, tracked.identification
    env_truth = truth.environment
    record = {"stamp_ns": stamp_ns, "mode": tracked.mode, "spots": len(spots),
              "truth_status": env_truth.head.status.value,
              "flooded": bool(env_truth.blinded), "moon_in_field": bool(np.any(truth.kind == KIND_MOON)),
              "planets_in_field": int(np.count_nonzero(truth.kind == KIND_PLANET)),
              "sun_angle_rad": float(env_truth.head.sun_angle_rad),
              "moon_angle_rad": float(env_truth.head.moon_angle_rad),
              "truth_rotation": truth.rotation, "solved": bool(tracked.solved)}
    rotation = None
    if tracked.solved:
        velocity = environment.observer_velocity_m_s
        si = ident.spot_index
        ray_cov = direction_covariance(CAMERA, spots.x[si], spots.y[si], spots.cov[si])
        corrected = corrected_solution(ident.attitude, ident.star_vectors, velocity, ident.body_vectors, ray_cov)
        rotation = corrected.rotation
        error = matrix_to_rotation_vector(truth.rotation.T @ corrected.rotation)
        record.update(stars=int(ident.hip.size), error=error,
                      error_raw=matrix_to_rotation_vector(truth.rotation.T @ ident.attitude.rotation),
                      nees=float(error @ np.linalg.solve(corrected.covariance, error)),
                      saturated=int(np.count_nonzero(spots.flags[ident.spot_index] & FLAG_SATURATED)))
        if fusion:
            record.update(rotation=corrected.rotation, covariance=corrected.covariance, rays=ident.body_vectors,
                          apparent=aberrate(ident.star_vectors, velocity),
                          sigmas=np.sqrt(0.5 * np.trace(ray_cov, axis1=1, axis2=2)))
    record["status"] = _status(tracker, stamp_ns, tracked.mode if tracked.solved else None, rotation, environment)
    return record


def run_sequence(job: dict) -> dict:
    """
    Track one head through a sequence of frames; return its per-frame records.

    job: kind "orbit" (head, frame indices k, times t) or "arc" (the arc's inertial rotation, times);
    seed. Each record: the tracker's mode, spots, the truth's geometric status (the renderer's
    sky_geometry at the true attitude), flooded (the stray light fills every pixel), the Moon and
    planets on the chip, the status the identifier would publish, and when solved the error of the
    raw and the corrected attitude against the head's own truth (rotation vector, sensor frame
    [rad]) and the fusion's inputs.
    """
    chain = _chain()
    renderer, craft = chain["renderer"], chain["craft"]
    if job["kind"] == "orbit":
        motion, environments = craft.head_motion(job["head"]), craft
    else:
        arc = Spacecraft(craft.orbit, inertial_attitude(np.asarray(job["rotation"])), {"a": HeadMounting(np.eye(3))},
                         chain["ephemeris"])
        motion, environments = arc.head_motion("a"), arc
    tracker = Tracker(chain["lis"], TRACKING)
    records = []
    for k, t in zip(job["k"], job["t"]):
        stamp_ns = _stamp(t)
        environment = environments.environment(t)
        frame = renderer.render(motion, t, frame_seed(job["seed"], int(k)), environment=environment)
        smear = tracker.centroider_aid(stamp_ns, CAMERA, SENSOR.exposure_s)
        spots = extract_spots(frame.image, CENTROID, smear)
        tracked = tracker.process(stamp_ns, spots, CAMERA)
        record = _frame_record(frame, environment, tracked, spots, tracker, stamp_ns, job["kind"] == "orbit")
        record.update(k=int(k), t=float(t))
        records.append(record)
    return {"job": {key: value for key, value in job.items() if key not in ("k", "t")}, "records": records}


def run_rest(job: dict) -> dict:
    """
    Aberration frames: head a's orbit frames solved lost-in-space as rendered and again rendered at zero velocity.

    Per frame: the raw and corrected error of the frame as rendered (LEO + the Earth's
    velocity), the error of the same frame (same seed) rendered with a zero observer velocity,
    and the aberration's predicted displacement of the boresight [rad].
    """
    chain = _chain()
    renderer, craft, lis = chain["renderer"], chain["craft"], chain["lis"]
    motion = craft.head_motion(job["head"])
    records = []
    for k, t in zip(job["k"], job["t"]):
        environment = craft.environment(t)
        velocity = environment.observer_velocity_m_s
        record = {"k": int(k), "t": float(t)}
        for name, env in (("moving", environment), ("rest", replace(environment, observer_velocity_m_s=np.zeros(3)))):
            frame = renderer.render(motion, t, frame_seed(job["seed"], int(k)), environment=env)
            spots = extract_spots(frame.image, CENTROID)
            result = lis.identify(spots, CAMERA)
            if not result.solved:
                continue
            truth = frame.truth.rotation
            record[f"{name}_raw"] = matrix_to_rotation_vector(truth.T @ result.attitude.rotation)
            if name == "moving":
                si = result.spot_index
                ray_cov = direction_covariance(CAMERA, spots.x[si], spots.y[si], spots.cov[si])
                corrected = corrected_solution(result.attitude, result.star_vectors, velocity, result.body_vectors,
                                               ray_cov)
                record["moving_corrected"] = matrix_to_rotation_vector(truth.T @ corrected.rotation)
                composed = corrected_solution(result.attitude, result.star_vectors, velocity)  # C alone
                record["moving_composed"] = matrix_to_rotation_vector(truth.T @ composed.rotation)
                boresight = truth[:, 2]
                record["predicted_rad"] = float(np.arccos(np.clip(aberrate(boresight, velocity) @ boresight, -1, 1)))
        records.append(record)
    return {"job": {key: value for key, value in job.items() if key not in ("k", "t")}, "records": records}


# ----------------------------------------------------------------------------------- part 4: the arcs
def _unit(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, float) / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _arc_date(ephemeris, target: str, fraction: float | None) -> float:
    """Return the first UTC midnight from the epoch on which the target suits an arc (see ARC_TARGETS)."""
    days = EPOCH_UNIX_S + 86400.0 * np.arange(400)
    sun, body = ephemeris.sun_position(days), ephemeris.position(target, days)
    elongation = _angle(_unit(sun), _unit(body))
    if fraction is None:
        ok = elongation > MIN_ELONGATION_RAD
    else:
        ok = (np.abs(ephemeris.moon_illuminated_fraction(days) - fraction) < 0.06) & (elongation > math.radians(50))
    return float(days[int(np.argmax(ok))] if ok.any() else days[int(np.argmax(elongation))])


def _pointing(target_icrs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return a sensor -> ICRS rotation putting target_icrs at a random place within ARC_MAX_OFFSET_RAD, any roll."""
    rho = ARC_MAX_OFFSET_RAD * math.sqrt(rng.uniform(0.05, 1.0))
    phi = rng.uniform(0.0, 2.0 * math.pi)
    sensor = np.array([math.sin(rho) * math.cos(phi), math.sin(rho) * math.sin(phi), math.cos(rho)])
    axis = np.cross(sensor, target_icrs)
    onto = rotation_vector_to_matrix(_unit(axis) * _angle(sensor, target_icrs))  # sensor -> target, shortest
    return rotation_vector_to_matrix(target_icrs * rng.uniform(0.0, 2.0 * math.pi)) @ onto


def arc_jobs(quick: bool) -> list[dict]:
    """
    Return the part-4 sequences: inertial pointings at the Moon and the planets.

    For each target and roll: the date (_arc_date), a random attitude with the target in the
    field (at the date's midnight, seen from the spacecraft), and frames every FRAME_S starting
    ARC_LEAD frames before the head and the target (by sky_geometry) first come out from behind
    the Earth: the head's status no longer occulted or blinded by the lit Earth, the target no
    longer behind the Earth.
    """
    ephemeris, path = load_ephemeris(), orbit()
    rng = np.random.default_rng(SEED + 4)
    frames, lead = (QUICK_ARC_FRAMES, QUICK_ARC_LEAD) if quick else (ARC_FRAMES, ARC_LEAD)
    specs = [(target, fraction, roll) for target, fraction in ARC_TARGETS for roll in range(ARC_ROLLS)]
    if quick:
        specs = [specs[0], specs[[target for target, _, _ in specs].index("jupiter")]]  # the Moon and a planet
    jobs = []
    for index, (target, fraction, roll) in enumerate(specs):
        day = _arc_date(ephemeris, target, fraction)
        r, _ = path.state(day)
        rotation = _pointing(_unit(ephemeris.position(target, day, observer_m=r)), rng)
        scan = day + np.arange(0.0, path.period_s, FRAME_S)
        statuses, behind = [], []
        for t in scan:
            r, _ = path.state(t)
            bodies = (r, ephemeris.sun_position(t), ephemeris.moon_position(t))
            statuses.append(head_geometry(rotation[:, 2], CAMERA.half_diagonal_fov_rad, _bodies(*bodies),
                                          EXCLUSION).status.value)
            target_m = ephemeris.position(target, t, observer_m=r)
            behind.append(bool(earth_occults(_unit(target_m), r, EXCLUSION.limb_radius_m,
                                             np.linalg.norm(target_m))[0]))
        hidden = np.isin(statuses, ("occulted", "blinded_earth")) | np.array(behind)
        out = np.flatnonzero(hidden[:-1] & ~hidden[1:])
        first = int(out[0]) + 1 if out.size else lead
        start = scan[first] - lead * FRAME_S
        k = np.arange(frames)
        jobs.append({"kind": "arc", "index": index, "target": target, "fraction": fraction, "roll": roll,
                     "date": dt.datetime.fromtimestamp(day, dt.timezone.utc).strftime("%Y-%m-%d"),
                     "rotation": rotation.tolist(), "k": k, "t": start + k * FRAME_S, "seed": SEED + 100 + index})
    return jobs


def _bodies(spacecraft_m, sun_m, moon_m):
    from star_tracker.models.sky_geometry import BodyPositions
    return BodyPositions(np.asarray(spacecraft_m, float), np.asarray(sun_m, float), np.asarray(moon_m, float))


# ----------------------------------------------------------------------------------- independent geometry
def astropy_statuses(times: np.ndarray, positions_m: np.ndarray, velocities_m_s: np.ndarray,
                     boresights: np.ndarray) -> dict:
    """
    Return each frame's geometric status from astropy, independently of models.sky_geometry and the DE421 ephemeris.

    The Sun and the Moon: astropy's get_body with its builtin ephemeris (ERFA epv00, moon98),
    transformed to a GCRS observer at the spacecraft's position and velocity. The Earth's limb
    (radius + atmosphere of EXCLUSION) by closed form: its angular radius asin(R_L / |r|) about
    -r. The Sun is eclipsed, the Moon occulted, when its direction lies within that radius. The
    nearest sunlit visible point of the limb sphere: a search over rays from the spacecraft
    across the visible disc (0.5 deg grid, then 0.02 deg about the best), lit where the geocentric
    Sun is above the local horizon. Same precedence as HeadStatus. Returns arrays: status and the
    angles [rad] from the boresight to the Sun, the Moon and the nearest lit Earth point.
    """
    import astropy.units as u
    from astropy.coordinates import GCRS, CartesianRepresentation, get_body, solar_system_ephemeris
    from astropy.time import Time

    obstime = Time(times, format="unix", scale="utc")
    observer = GCRS(obstime=obstime, obsgeoloc=CartesianRepresentation(positions_m.T * u.m),
                    obsgeovel=CartesianRepresentation(velocities_m_s.T * u.m / u.s))
    with solar_system_ephemeris.set("builtin"):
        sun_geo = get_body("sun", obstime)
        sun = _unit(sun_geo.transform_to(observer).cartesian.xyz.to_value(u.m).T)
        moon = _unit(get_body("moon", obstime).transform_to(observer).cartesian.xyz.to_value(u.m).T)
    sun_geocentric = _unit(sun_geo.cartesian.xyz.to_value(u.m).T)
    radius = EXCLUSION.earth_radius_m + EXCLUSION.atmosphere_height_m
    distance = np.linalg.norm(positions_m, axis=1)
    earth = -positions_m / distance[:, None]
    limb = np.arcsin(radius / distance)
    b = _unit(boresights)
    occulted = _angle(b, earth) < limb
    sun_angle, moon_angle = _angle(b, sun), _angle(b, moon)
    eclipsed, moon_hidden = _angle(sun, earth) < limb, _angle(moon, earth) < limb
    lit = np.full(times.size, np.inf)
    near = _angle(b, earth) - limb < EXCLUSION.earth_limb_exclusion_rad + math.radians(1.0)
    for i in np.flatnonzero(near):
        lit[i] = _nearest_lit(b[i], positions_m[i], sun_geocentric[i], radius)
    status = np.full(times.size, HeadStatus.TRACKING_POSSIBLE.value, dtype=object)
    status[~moon_hidden & (moon_angle < EXCLUSION.moon_exclusion_rad)] = HeadStatus.BLINDED_MOON.value
    status[lit < EXCLUSION.earth_limb_exclusion_rad] = HeadStatus.BLINDED_EARTH.value
    status[~eclipsed & (sun_angle < EXCLUSION.sun_exclusion_rad)] = HeadStatus.BLINDED_SUN.value
    status[occulted] = HeadStatus.OCCULTED.value
    return {"status": status.astype(str), "sun_angle_rad": sun_angle, "moon_angle_rad": moon_angle,
            "lit_earth_angle_rad": lit}


def _nearest_lit(boresight: np.ndarray, position_m: np.ndarray, sun_hat: np.ndarray, radius_m: float) -> float:
    """Angle [rad] from the boresight to the nearest sunlit point of the sphere seen from position_m (inf: none)."""
    distance = float(np.linalg.norm(position_m))
    centre = -position_m / distance
    rho_max = math.asin(radius_m / distance)
    helper = np.eye(3)[int(np.argmin(np.abs(centre)))]
    u_axis = _unit(np.cross(centre, helper))
    w_axis = np.cross(centre, u_axis)

    def best(rho: np.ndarray, phi: np.ndarray) -> tuple[float, float, float]:
        rr, pp = np.meshgrid(np.clip(rho, 0.0, rho_max), phi, indexing="ij")
        d = (np.cos(rr)[..., None] * centre + np.sin(rr)[..., None] * (np.cos(pp)[..., None] * u_axis
                                                                       + np.sin(pp)[..., None] * w_axis))
        along = d @ position_m
        s = -along - np.sqrt(np.maximum(along * along - (distance * distance - radius_m * radius_m), 0.0))
        points = position_m + s[..., None] * d
        angle = np.where(points @ sun_hat > 0.0, _angle(d, boresight), np.inf)
        i = np.unravel_index(int(np.argmin(angle)), angle.shape)
        return float(angle[i]), float(rr[i]), float(pp[i])

    coarse = math.radians(0.5)
    angle, rho, phi = best(np.linspace(0.0, rho_max, int(rho_max / coarse) + 2),
                           np.linspace(0.0, 2 * math.pi, int(2 * math.pi / coarse), endpoint=False))
    if not math.isfinite(angle):
        return math.inf
    fine = np.linspace(-2 * coarse, 2 * coarse, 201)
    refined, _, _ = best(rho + fine, phi + fine / max(math.sin(rho), 1e-3))
    return min(angle, refined)


def intervals(mask: np.ndarray) -> list[tuple[int, int]]:
    """Return the runs of True in mask as (first, last) indices, inclusive."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(int)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def compare_intervals(simulated: np.ndarray, predicted: np.ndarray) -> dict:
    """
    Compare the intervals of each cause (CAUSES) in two per-frame status sequences.

    Each interval of one is paired with the interval of the other it overlaps most; an interval
    without a partner counts as unmatched. Returns per cause: the interval counts, the largest
    offset of a paired interval's first or last frame [frames], the unmatched count, and the
    frames whose statuses differ.
    """
    out = {}
    for cause in CAUSES:
        sim, pred = intervals(simulated == cause), intervals(predicted == cause)
        offsets, unmatched = [], 0
        for mine, theirs in ((sim, pred), (pred, sim)):
            for a, b in mine:
                overlap = [(min(b, d) - max(a, c), (c, d)) for c, d in theirs if min(b, d) >= max(a, c)]
                if not overlap:
                    unmatched += 1
                    continue
                c, d = max(overlap)[1]
                offsets += [abs(a - c), abs(b - d)]
        out[cause] = {"simulated": len(sim), "predicted": len(pred), "max_offset_frames": max(offsets, default=0),
                      "unmatched": unmatched,
                      "frames_differing": int(np.sum((simulated == cause) != (predicted == cause)))}
    return out


# ----------------------------------------------------------------------------------- fusion
def fuse(records: dict[str, list[dict]], period_s: float) -> tuple[list[dict], dict]:
    """
    Run the fusion over the orbit: per frame each solved head's observation, then fused_at with the gyro's rate.

    Returns per frame: the heads used, the fused error against the true body attitude (body
    frame rotation vector [rad]), its NEES, head b's alignment estimate error against the
    injected truth [rad] and its NEES; and the fusion's and the filter's counters.
    """
    craft = spacecraft()
    body = craft.body
    alignment = AlignmentFilter(AlignmentConfig(HEADS, drift_psd=DRIFT_PSD, harmonic_period_s=period_s))
    state = FusionState(FusionConfig(HEADS), alignment)
    # The same fusion with head b's true mounting given (no alignment estimate): the geometry's share.
    known = FusionState(FusionConfig(HEADS))
    drift = misalignment(period_s)
    rng = np.random.default_rng(SEED + 5)
    out = []
    for frames in zip(*(records[h] for h in HEADS)):
        t, stamp_ns = frames[0]["t"], frames[0]["stamp_ns"]
        for head, frame in zip(HEADS, frames):
            if frame["solved"]:
                measured = (frame["apparent"], frame["rays"], frame["sigmas"], frame["rotation"], frame["covariance"])
                state.add(HeadObservation(head, stamp_ns, MOUNTINGS[head].head_to_body.T, *measured))
                true_mounting = MOUNTINGS[head].head_to_body
                if head == MISALIGNED:
                    true_mounting = true_mounting @ rotation_vector_to_matrix(drift.angles(t))
                known.add(HeadObservation(head, stamp_ns, true_mounting.T, *measured))
        rate = np.asarray(body.angular_velocity_at(t)) + rng.normal(scale=GYRO_SIGMA_RAD_S, size=3)
        row = {"k": frames[0]["k"], "t": t, "heads": [],
               "saturated": any(f["solved"] and f["saturated"] > 0 for f in frames)}
        truth = body.rotations_at(np.array([t]))[0]
        body_rate = BodyRate(rate, np.eye(3) * GYRO_SIGMA_RAD_S ** 2)
        try:
            fused = state.fused_at(stamp_ns, body_rate)
        except FusionUnavailable:
            fused = None
        if fused is not None:
            error = matrix_to_rotation_vector(truth.T @ fused.rotation)
            row.update(heads=list(fused.heads), error=error,
                       nees=float(error @ np.linalg.solve(fused.covariance, error)))
        try:
            known_fused = known.fused_at(stamp_ns, body_rate)
            row["error_known_alignment"] = matrix_to_rotation_vector(truth.T @ known_fused.rotation)
        except FusionUnavailable:
            pass
        estimate = alignment.estimate(MISALIGNED, stamp_ns)
        alignment_error = estimate.correction - true_alignment(t, period_s)
        row.update(alignment_error=alignment_error,
                   alignment_nees=float(alignment_error @ np.linalg.solve(estimate.covariance, alignment_error)))
        out.append(row)
    out_counters = {"fusion": vars(state.counters).copy(), "alignment": vars(alignment.counters).copy()}
    return out, out_counters


# ----------------------------------------------------------------------------------- summaries
def _arcsec(x) -> np.ndarray:
    return np.asarray(x, float) / ARCSEC


def _rms(x: np.ndarray, axis=0):
    return np.sqrt(np.mean(np.square(x), axis=axis)) if len(x) else np.full(3, np.nan)


def head_summary(records: list[dict], predicted: np.ndarray) -> dict:
    """Availability, wrong attitudes, errors and the intervals against astropy of one head's sequence."""
    solved = [r for r in records if r["solved"]]
    errors = np.array([r["error"] for r in solved]).reshape(-1, 3)
    total = np.linalg.norm(errors, axis=1) / ARCSEC
    truth_status = np.array([r["truth_status"] for r in records])
    reported = np.array([r["status"] for r in records])
    unsolved = ~np.array([r["solved"] for r in records])
    counts = {s: int(np.sum(truth_status == s)) for s in STATUSES}
    return {
        "frames": len(records), "solved": len(solved), "wrong": int(np.sum(total > WRONG_ARCSEC)),
        "max_error_arcsec": float(total.max()) if total.size else None,
        "lost_in_space_frames": int(sum(r["mode"] == "lost_in_space" for r in records)),
        "flooded": int(sum(r["flooded"] for r in records)),
        "cross_rms_arcsec": float(_arcsec(np.sqrt(np.mean(errors[:, :2] ** 2)))) if errors.size else None,
        "roll_rms_arcsec": float(_arcsec(np.sqrt(np.mean(errors[:, 2] ** 2)))) if errors.size else None,
        "truth_status_frames": counts, "astropy_status_frames": {s: int(np.sum(predicted == s)) for s in STATUSES},
        "solved_by_truth_status": {s: int(np.sum((truth_status == s) & ~unsolved)) for s in STATUSES},
        "truth_vs_astropy": compare_intervals(truth_status, predicted),
        "unsolved_frames": int(unsolved.sum()),
        "reported_cause_agrees": int(np.sum(unsolved & (reported == predicted))),
        "reported_unknown_cause": int(np.sum(unsolved & (reported == "lost_in_space"))),
        "nees": _split_mean([r["nees"] for r in solved], [r["saturated"] > 0 for r in solved]),
    }


def _split_mean(values: list, saturated: list) -> dict:
    """Mean of values over frames with a matched saturated spot, without one, and all (with the frame counts)."""
    v, flag = np.asarray(values, float), np.asarray(saturated, bool)
    return {name: {"frames": int(mask.sum()), "mean": float(v[mask].mean()) if mask.any() else None}
            for name, mask in (("saturated", flag), ("unsaturated", ~flag), ("all", np.ones(v.size, bool)))}


def intervals_met(summary: dict) -> bool:
    """Every cause's intervals paired, each boundary within one frame."""
    return all(c["unmatched"] == 0 and c["max_offset_frames"] <= 1 for c in summary["truth_vs_astropy"].values())


def fusion_summary(fused: list[dict], period_s: float, start_t: float) -> dict:
    """Fused availability, wrong attitudes, per-axis errors (two heads / one head / all), alignment error."""
    done = [f for f in fused if f["heads"]]
    errors = np.array([f["error"] for f in done]).reshape(-1, 3)
    total = np.linalg.norm(errors, axis=1) / ARCSEC
    two = np.array([len(f["heads"]) == 2 for f in done], bool)
    saturated = np.array([f["saturated"] for f in done], bool)
    late = np.array([f["t"] >= start_t + period_s / 2 for f in fused], bool)
    align = np.array([f["alignment_error"] for f in fused]).reshape(-1, 3)
    align_nees = np.array([f["alignment_nees"] for f in fused])
    return {
        "frames": len(fused), "fused": len(done), "available_pct": 100.0 * len(done) / max(len(fused), 1),
        "two_heads": int(two.sum()), "one_head": int((~two).sum()), "wrong": int(np.sum(total > WRONG_ARCSEC)),
        "max_error_arcsec": float(total.max()) if total.size else None,
        "rms_two_heads_arcsec": _arcsec(_rms(errors[two])).tolist(),
        "rms_two_heads_known_alignment_arcsec": _arcsec(_rms(np.array(
            [f["error_known_alignment"] for f, ok in zip(done, two) if ok and "error_known_alignment" in f]
        ).reshape(-1, 3))).tolist(),
        "rms_two_heads_unsaturated_arcsec": _arcsec(_rms(errors[two & ~saturated])).tolist(),
        "two_heads_unsaturated": int((two & ~saturated).sum()),
        "rms_one_head_arcsec": _arcsec(_rms(errors[~two])).tolist(),
        "rms_all_arcsec": _arcsec(_rms(errors)).tolist(),
        "nees_two_heads": _split_mean([f["nees"] for f, ok in zip(done, two) if ok], saturated[two]),
        "alignment_late_frames": int(late.sum()),
        "alignment_rms_arcsec": _arcsec(_rms(align[late])).tolist(),
        "alignment_max_arcsec": _arcsec(np.abs(align[late]).max(axis=0)).tolist() if late.any() else None,
        "alignment_nees": float(align_nees[late].mean()) if late.any() else None,
        "alignment_first_arcsec": _arcsec(align[0]).tolist() if len(align) else None,
    }


def per_axis_cross(records: list[dict]) -> float:
    """Return a head's cross-boresight RMS error per axis [arcsec]: sqrt(mean(dx^2 + dy^2) / 2)."""
    errors = np.array([r["error"] for r in records if r["solved"]]).reshape(-1, 3)
    return float(_arcsec(np.sqrt(np.mean(errors[:, :2] ** 2)))) if errors.size else math.nan


def aberration_summary(rest: list[dict]) -> dict:
    """Mean cross-boresight and roll errors as rendered (uncorrected, corrected) and at rest, same frames."""
    keys = ("moving_raw", "moving_composed", "moving_corrected", "rest_raw")
    both = [r for r in rest if all(key in r for key in keys)]
    out = {"frames": len(rest), "solved_all": len(both)}
    for key in keys:
        e = np.array([r[key] for r in both]).reshape(-1, 3)
        out[key] = {"cross_mean_arcsec": float(_arcsec(np.mean(np.hypot(e[:, 0], e[:, 1])))) if e.size else None,
                    "roll_mean_arcsec": float(_arcsec(np.mean(np.abs(e[:, 2])))) if e.size else None,
                    "total_mean_arcsec": float(_arcsec(np.mean(np.linalg.norm(e, axis=1)))) if e.size else None}
    predicted = [r["predicted_rad"] for r in both]
    out["predicted_mean_arcsec"] = float(_arcsec(np.mean(predicted))) if predicted else None
    corrected, at_rest = out["moving_corrected"]["cross_mean_arcsec"], out["rest_raw"]["cross_mean_arcsec"]
    out["ratio"] = corrected / at_rest if corrected is not None and at_rest else None
    out["met"] = bool(out["ratio"] is not None and out["ratio"] <= 1.10)
    return out


def arcs_summary(arcs: list[dict], predicted: list[np.ndarray]) -> dict:
    """Frames with the Moon or a planet in the field (visible, not flooded), solved, wrong; intervals vs astropy."""
    rows, in_field, solved, wrong, transitions = [], 0, 0, 0, []
    for arc, pred in zip(arcs, predicted):
        job, records = arc["job"], arc["records"]
        target_in = np.array([(r["moon_in_field"] if job["target"] == "moon" else r["planets_in_field"] > 0)
                              and not r["flooded"] and r["truth_status"] != "occulted" for r in records])
        ok = np.array([r["solved"] for r in records])
        err = np.array([np.linalg.norm(r["error"]) / ARCSEC if r["solved"] else 0.0 for r in records])
        summary = head_summary(records, pred)
        rows.append({"target": job["target"], "date": job["date"], "fraction": job["fraction"], "roll": job["roll"],
                     "frames": len(records), "in_field": int(target_in.sum()), "solved": int((target_in & ok).sum()),
                     "wrong": int((target_in & (err > WRONG_ARCSEC)).sum()),
                     "wrong_any": int((err > WRONG_ARCSEC).sum()), "intervals_met": intervals_met(summary),
                     "truth_vs_astropy": summary["truth_vs_astropy"],
                     "truth_status_frames": summary["truth_status_frames"]})
        in_field += int(target_in.sum())
        solved += int((target_in & ok).sum())
        wrong += int((err > WRONG_ARCSEC).sum())
        transitions.append(summary)
    return {"arcs": rows, "in_field": in_field, "solved": solved, "unsolved": in_field - solved, "wrong": wrong}


# ----------------------------------------------------------------------------------- figures
COLOURS = {"attitude": "#2ca02c", "no attitude": "#c7c7c7", "wrong": "#d62728",
           "tracking_possible": "#e8f4e8", "blinded_sun": "#ff7f0e", "blinded_earth": "#1f77b4",
           "blinded_moon": "#9467bd", "occulted": "#222222", "two heads": "#1a7f1a", "one head": "#98df8a",
           "none": "#c7c7c7"}


def _runs(values: list) -> list[tuple[int, int, object]]:
    """Return (first index, length, value) of the runs of equal values."""
    runs, start = [], 0
    for i in range(1, len(values) + 1):
        if i == len(values) or values[i] != values[start]:
            runs.append((start, i - start, values[start]))
            start = i
    return runs


def figures(images: Path, records: dict, predicted: dict, fused: list[dict], rest_t0: float) -> list[str]:
    """Draw the availability timeline, the fused and alignment errors against time, and the sky; return the files."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    images.mkdir(parents=True, exist_ok=True)
    written = []
    minutes = (np.array([r["t"] for r in records[HEADS[0]]]) - rest_t0) / 60.0
    step = FRAME_S / 60.0
    rows = []
    for head in HEADS:
        rs = records[head]
        attitude = ["wrong" if r["solved"] and np.linalg.norm(r["error"]) / ARCSEC > WRONG_ARCSEC
                    else "attitude" if r["solved"] else "no attitude" for r in rs]
        rows += [(f"{head}: attitude", attitude), (f"{head}: simulator", [r["truth_status"] for r in rs]),
                 (f"{head}: astropy", list(predicted[head]))]
    rows.append(("fused", ["two heads" if len(f["heads"]) == 2 else "one head" if f["heads"] else "none"
                           for f in fused]))
    fig, ax = plt.subplots(figsize=(11, 4.2))
    for y, (label, values) in enumerate(reversed(rows)):
        for first, length, value in _runs(values):
            ax.broken_barh([(minutes[first] - step / 2, length * step)], (y - 0.4, 0.8), color=COLOURS[value])
    ax.set_yticks(range(len(rows)), [label for label, _ in reversed(rows)])
    ax.set_xlabel("minutes from the first frame")
    ax.set_xlim(minutes[0] - step, minutes[-1] + step)
    used = [key for key in COLOURS if any(key in values for _, values in rows)]
    ax.legend(handles=[Patch(color=COLOURS[key], label=key.replace("_", " ")) for key in used], ncol=5,
              loc="upper center", bbox_to_anchor=(0.5, -0.18), fontsize=8, frameon=False)
    ax.set_title("Availability over one orbit: each head's attitude, its geometric status (simulator, astropy), fused")
    fig.tight_layout()
    written.append(_save(fig, images / "orbit_availability.png"))

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    done = [f for f in fused if f["heads"]]
    t = (np.array([f["t"] for f in done]) - rest_t0) / 60.0
    error = _arcsec([f["error"] for f in done]).reshape(-1, 3)
    one = np.array([len(f["heads"]) == 1 for f in done], bool)
    for first, length, value in _runs(list(one)):
        if value:
            top.axvspan(t[first] - step / 2, t[first + length - 1] + step / 2, color="#eeeeee", lw=0)
    for axis, colour in zip(range(3), ("#1f77b4", "#ff7f0e", "#2ca02c")):
        top.plot(t, error[:, axis], ".", ms=2, color=colour, label=f"body {'xyz'[axis]}")
    top.set_ylabel("fused error [arcsec]")
    top.legend(loc="upper right", fontsize=8, markerscale=4)
    top.set_title("Fused attitude error per body axis (grey: one head only); head b's alignment estimate error")
    align = _arcsec([f["alignment_error"] for f in fused]).reshape(-1, 3)
    ta = (np.array([f["t"] for f in fused]) - rest_t0) / 60.0
    for axis, colour in zip(range(3), ("#1f77b4", "#ff7f0e", "#2ca02c")):
        bottom.plot(ta, align[:, axis], "-", lw=1, color=colour, label=f"body {'xyz'[axis]}")
    bottom.set_ylim(-4, 4)
    bottom.axhline(0, color="k", lw=0.5)
    bottom.set_ylabel("alignment error [arcsec]")
    bottom.set_xlabel("minutes from the first frame")
    bottom.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    written.append(_save(fig, images / "orbit_fused_error.png"))

    written.append(sky_figure(images / "orbit_sky.png", records, plt))
    return written


def _save(fig, path: Path) -> str:
    fig.savefig(path, dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt
    plt.close(fig)
    return str(path)


def _lonlat(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mollweide coordinates of unit vectors: longitude -RA wrapped to (-pi, pi] (RA grows leftward), latitude Dec."""
    v = np.atleast_2d(vectors)
    ra = np.arctan2(v[:, 1], v[:, 0])
    lon = -np.angle(np.exp(1j * ra))
    lat = np.arcsin(np.clip(v[:, 2], -1, 1))
    jump = np.concatenate([[False], np.abs(np.diff(lon)) > math.pi])
    lon, lat = lon.astype(float), lat.astype(float)
    lon[jump], lat[jump] = np.nan, np.nan
    return lon, lat


def _circle(centre: np.ndarray, radius_rad: float) -> np.ndarray:
    centre = _unit(centre)
    helper = np.eye(3)[int(np.argmin(np.abs(centre)))]
    u_axis = _unit(np.cross(centre, helper))
    w_axis = np.cross(centre, u_axis)
    phi = np.linspace(0, 2 * math.pi, 361)
    ring = np.cos(phi)[:, None] * u_axis + np.sin(phi)[:, None] * w_axis
    return math.cos(radius_rad) * centre + math.sin(radius_rad) * ring


def sky_figure(path: Path, records: dict, plt) -> str:
    """Mollweide sky (ICRS): the heads' boresights over the orbit, the Sun's and Moon's exclusion cones, the limb."""
    ephemeris, path_orbit = load_ephemeris(), orbit()
    t = np.array([r["t"] for r in records[HEADS[0]]])
    mid = float(t[len(t) // 2])
    r_mid, _ = path_orbit.state(mid)
    fig = plt.figure(figsize=(10, 5.4))
    ax = fig.add_subplot(111, projection="mollweide")
    for head, colour in zip(HEADS, ("#1f77b4", "#d62728")):
        boresights = np.array([r["truth_rotation"][:, 2] for r in records[head]])
        ax.plot(*_lonlat(boresights), "-", color=colour, lw=1.5, label=f"head {head} boresight")
        ax.plot(*_lonlat(boresights[:1]), "o", color=colour, ms=5)
    sun = _unit(ephemeris.sun_position(mid, observer_m=r_mid))
    moon = _unit(ephemeris.moon_position(mid, observer_m=r_mid))
    ax.plot(*_lonlat(sun), "*", color="#ff7f0e", ms=14, label="Sun (30° exclusion)")
    ax.plot(*_lonlat(_circle(sun, EXCLUSION.sun_exclusion_rad)), "-", color="#ff7f0e", lw=1)
    ax.plot(*_lonlat(moon), "o", color="#9467bd", ms=8, label="Moon (25° exclusion)")
    ax.plot(*_lonlat(_circle(moon, EXCLUSION.moon_exclusion_rad)), "-", color="#9467bd", lw=1)
    radius = EXCLUSION.earth_radius_m + EXCLUSION.atmosphere_height_m
    for i, when in enumerate(t[:: max(len(t) // 4, 1)][:4]):
        r, _ = path_orbit.state(when)
        limb = math.asin(radius / np.linalg.norm(r))
        ax.plot(*_lonlat(_circle(-r, limb)), ":", color="#555555", lw=0.8,
                label="Earth's limb at 4 times" if i == 0 else None)
    ax.grid(True, lw=0.3)
    ax.set_xticks(np.radians([-150, -120, -90, -60, -30, 0, 30, 60, 90, 120, 150]),
                  [f"{(-lon) % 360}°" for lon in range(-150, 151, 30)], fontsize=7)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.04), ncol=3, fontsize=8, frameon=False)
    ax.set_title("The sky over the orbit (ICRS, right ascension growing leftward): boresights and exclusion cones",
                 fontsize=10, pad=18)
    fig.tight_layout()
    return _save(fig, path)


# ----------------------------------------------------------------------------------- report
def _f(x, digits: int = 2) -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def _axes(values, digits: int = 2) -> str:
    return ", ".join(_f(v, digits) for v in values)


def _met(ok: bool) -> str:
    return "**met**" if ok else "**not met**"


def render_markdown(results: dict) -> str:
    """Return the section's Markdown from the results."""
    meta, heads, fusion, aber, arcs = (results[key] for key in ("meta", "heads", "fusion", "aberration", "arcs"))
    goals = results["goals"]
    quick = " (`--quick`: three short windows of the orbit, two short arcs)" if meta["quick"] else ""
    lines = [
        SECTION, "",
        f"Command: `{meta['command']}` from the repository root{quick}. Measured {meta['date']} in "
        f"{meta['elapsed_s'] / 60:.1f} min on {meta['jobs']} worker processes. Machine: {machine_text(meta)}. "
        "Raw results: `docs/bench_orbit.json`.", "",
        f"Scenario: a {ALTITUDE_M / 1e3:.0f} km circular sun-synchronous orbit (inclination "
        f"{meta['inclination_deg']:.2f}°, period {meta['period_s'] / 60:.1f} min), its ascending node at "
        f"{int(LTAN_H)}:{int(60 * (LTAN_H % 1)):02d} local time, epoch 2027-03-17 00:00 UTC; a nadir-pointing body "
        "(+Z nadir, +Y the negative orbit normal); head a looks 45° from the zenith toward body −Y, head b 45° from "
        "the zenith toward +Y (90° apart). On that date the Sun comes within "
        f"{meta['closest_sun_deg']['b']:.0f}° of head b's boresight (its 30° exclusion) and the "
        f"{meta['moon_fraction']:.0%}-lit Moon crosses head b's field; head a's closest approach is "
        f"{meta['closest_sun_deg']['a']:.0f}° to the Sun and {meta['closest_moon_deg']['a']:.0f}° to the Moon. "
        "Nadir pointing holds the Earth still in the heads' frames: its limb stays 66° from both boresights, so "
        "the orbit has no Earth blinding or occultation (the arcs of part 4 have both). "
        f"{meta['frames_per_head']} frames per head, one every {FRAME_S:.0f} s of orbit time from "
        f"{START_OFFSET_S / 60:.0f} min after the epoch; the default camera (1024², 15°) and sensor (0.1 s "
        "exposure, smeared by the true body rate), stars to Hp 7.5, every effect of the environment (the Sun's, "
        "the lit Earth's and the Moon's stray light and blinding, the Moon's disc and blooming, the planets, "
        "Earth occultation, aberration with the Earth's + the orbital velocity). Per head: `extract_spots` "
        "(rate-aided by the tracker), `Tracker(make_identifier(\"hybrid\"))` with coast and rate window 10 s and "
        "an angular-acceleration bound of 0.01°/s² (a frame every 3 s), the attitude corrected for the "
        "observer's velocity (refitted against the apparent directions with the fit's weights), and the status the "
        "identifier publishes (`track.head_status`). Fusion: "
        "`FusionState` with an `AlignmentFilter` (head a the reference; the drift modelled as one harmonic of the "
        f"orbital period beside a random walk of {DRIFT_PSD / ARCSEC ** 2:.1e} arcsec²/s), the gyro rate 1 µrad/s "
        "off. Head b is truly mounted "
        f"{OFFSET_ARCSEC:.0f}\" off nominal plus a {DRIFT_ARCSEC:.0f}\" sinusoid over the orbital period. Wrong: "
        f"more than {WRONG_ARCSEC:.0f}\" from the truth (a head's own true attitude; the true body attitude for "
        "the fused one).", "",
        "| goal | figure | verdict |", "|---|---|---|",
        f"| 1. fused available ≥ 99.5 % of frames, 0 wrong (heads and fused) | {fusion['available_pct']:.2f} % "
        f"({fusion['fused']}/{fusion['frames']}); wrong: head a {heads['a']['wrong']}, head b {heads['b']['wrong']}, "
        f"fused {fusion['wrong']} | {_met(goals['availability'])} |",
        f"| 1. blinded/occulted intervals = astropy's within one frame | orbit: {goals['interval_text']['orbit']}; "
        f"arcs: {goals['interval_text']['arcs']} | {_met(goals['intervals'])} |",
        f"| 2. fused ≤ 1.5 × a single head's cross-boresight error, per body axis (two heads fused; judged "
        f"against head a, the better head) | fused RMS {_axes(fusion['rms_two_heads_arcsec'])}\" (x, y, z) vs "
        f"1.5 × head a's {_f(goals['cross_per_axis']['a'])}\" = {_f(1.5 * goals['cross_per_axis']['a'])}\" (head b: "
        f"1.5 × {_f(goals['cross_per_axis']['b'])}\" = {_f(1.5 * goals['cross_per_axis']['b'])}\"); with head b's "
        f"true mounting given (no alignment estimate) {_axes(fusion['rms_two_heads_known_alignment_arcsec'])}\"; "
        f"the geometry's expectation √((a² + b²)/2) = {_f(goals['geometric_yz'])}\" on y and z | "
        f"{_met(goals['fused_error'])} |",
        f"| 3. corrected error within 10 % of the error at rest | mean cross-boresight: corrected "
        f"{_f(aber['moving_corrected']['cross_mean_arcsec'])}\", at rest {_f(aber['rest_raw']['cross_mean_arcsec'])}\" "
        f"(ratio {_f(aber['ratio'], 3)}); uncorrected {_f(aber['moving_raw']['cross_mean_arcsec'])}\" | "
        f"{_met(aber['met'])} |",
        f"| 4. ≥ 1 000 frames with the Moon or a bright planet in a head's field, 0 wrong | {arcs['in_field']} frames, "
        f"{arcs['solved']} solved, {arcs['unsolved']} unsolved, {arcs['wrong']} wrong | "
        f"{_met(goals['moon_planets'])} |",
        f"| 5. alignment estimate < 1\" within one orbit (RMS per body axis over the last half orbit) | RMS "
        f"{_axes(fusion['alignment_rms_arcsec'])}\", max {_axes(fusion['alignment_max_arcsec'] or [])}\", NEES "
        f"{_f(fusion['alignment_nees'])} | {_met(goals['alignment'])} |",
        "",
    ]
    lines += ["**1. Availability.** Frames per head by the simulator's geometric status (the renderer's, at the "
              "true attitude) and by astropy's, and what the head did:", "",
              "| head | frames | attitude | wrong | max error | lost-in-space solves | flooded | "
              + " | ".join(s.replace("_", " ") + " (sim / astropy / solved)" for s in STATUSES) + " |",
              "|---|---:|---:|---:|---:|---:|---:|" + "---:|" * len(STATUSES)]
    for head in HEADS:
        h = heads[head]
        cells = [f"{h['truth_status_frames'][s]} / {h['astropy_status_frames'][s]} / {h['solved_by_truth_status'][s]}"
                 for s in STATUSES]
        lines.append(f"| {head} | {h['frames']} | {h['solved']} | {h['wrong']} | {_f(h['max_error_arcsec'], 1)}\" | "
                     f"{h['lost_in_space_frames']} | {h['flooded']} | " + " | ".join(cells) + " |")
    lines += ["", "Intervals (simulator against astropy): per cause, intervals in each, the largest offset of a "
              "first or last frame, frames that differ.", "",
              "| sequence | " + " | ".join(c.replace("_", " ") for c in CAUSES) + " |",
              "|---|" + "---|" * len(CAUSES)]
    for name, comparison in results["interval_rows"]:
        lines.append(f"| {name} | " + " | ".join(
            f"{c['simulated']} / {c['predicted']}, ±{c['max_offset_frames']}, {c['frames_differing']}"
            + (f", {c['unmatched']} unpaired" if c["unmatched"] else "") for c in comparison.values()) + " |")
    lines += ["", f"Without an attitude the identifier publishes a cause from its own geometry (the ephemeris, the "
              f"true position, its last attitude propagated): head a {heads['a']['reported_cause_agrees']} and head b "
              f"{heads['b']['reported_cause_agrees']} of their {heads['a']['unsolved_frames']} and "
              f"{heads['b']['unsolved_frames']} frames without an attitude carry astropy's status "
              f"({heads['a']['reported_unknown_cause']} and {heads['b']['reported_unknown_cause']} report no known "
              "cause: lost in space). Fused: "
              f"{fusion['two_heads']} frames from two heads, {fusion['one_head']} from one, "
              f"{fusion['frames'] - fusion['fused']} without; counters {results['fusion_counters']['fusion']}, "
              f"alignment {results['fusion_counters']['alignment']}.", "",
              "![availability](images/orbit_availability.png)", "",
              "**2. Fused against single-head error** (RMS per axis, arcsec):", "",
              "| | x | y | z |", "|---|---:|---:|---:|",
              f"| fused, two heads ({fusion['two_heads']} frames) | "
              + " | ".join(_f(v) for v in fusion["rms_two_heads_arcsec"]) + " |",
              f"| fused, two heads, head b's true mounting given ({fusion['two_heads']} frames) | "
              + " | ".join(_f(v) for v in fusion["rms_two_heads_known_alignment_arcsec"]) + " |",
              f"| fused, one head ({fusion['one_head']} frames) | "
              + " | ".join(_f(v) for v in fusion["rms_one_head_arcsec"]) + " |",
              f"| fused, all ({fusion['fused']} frames) | {' | '.join(_f(v) for v in fusion['rms_all_arcsec'])} |"]
    for head in HEADS:
        h = heads[head]
        lines.append(f"| head {head} alone (sensor frame: cross-boresight per axis, roll) | "
                     f"{_f(goals['cross_per_axis'][head])} | {_f(goals['cross_per_axis'][head])} | "
                     f"{_f(h['roll_rms_arcsec'])} (roll) |")
    nees, fused_nees = {h: heads[h]["nees"] for h in HEADS}, fusion["nees_two_heads"]
    lines += [f"| fused, two heads, no saturated star matched ({fusion['two_heads_unsaturated']} frames) | "
              + " | ".join(_f(v) for v in fusion["rms_two_heads_unsaturated_arcsec"]) + " |", "",
              "Body x is across both boresights; body y and z each lie 45° from both, so with one head they "
              "carry its roll error times cos 45°, and with two they rest on both heads' cross-boresight errors "
              "and on head b's alignment estimate (part 5). NEES (3 when consistent), frames with a matched "
              "saturated star / without / all: "
              + "; ".join(f"head {h} {_f(nees[h]['saturated']['mean'], 1)} ({nees[h]['saturated']['frames']}) / "
                          f"{_f(nees[h]['unsaturated']['mean'], 1)} ({nees[h]['unsaturated']['frames']}) / "
                          f"{_f(nees[h]['all']['mean'], 1)}" for h in HEADS)
              + f"; fused (two heads) {_f(fused_nees['saturated']['mean'], 1)} ({fused_nees['saturated']['frames']}) / "
              f"{_f(fused_nees['unsaturated']['mean'], 1)} ({fused_nees['unsaturated']['frames']}) / "
              f"{_f(fused_nees['all']['mean'], 1)}. Saturated stars bloom in these frames "
              "(`EnvironmentModel.blooming`, on with every environment); with `centroid.sensor_blooms` the "
              "centroider leaves each clipped pixel and the spill above and below its run out of the star's fit "
              "(`centroid/detection/saturation.py`).", "",
              "![fused error](images/orbit_fused_error.png)", "",
              f"**3. Aberration** ({aber['solved_all']} of head a's frames, "
              + ("spread over the windows" if meta["quick"] else f"every {REST_EVERY}th") + ", each solved "
              "lost-in-space as rendered and rendered again at zero velocity with the same seed; mean error, "
              "arcsec):", "",
              "| | cross-boresight | roll | total |", "|---|---:|---:|---:|"]
    for key, label in (("moving_raw", "LEO + Earth velocity, uncorrected"),
                       ("moving_composed", "LEO + Earth velocity, C R_fit alone (no rays given)"),
                       ("moving_corrected", "LEO + Earth velocity, corrected (refit with the fit's weights)"),
                       ("rest_raw", "at rest")):
        a = aber[key]
        lines.append(f"| {label} | {_f(a['cross_mean_arcsec'])} | {_f(a['roll_mean_arcsec'])} | "
                     f"{_f(a['total_mean_arcsec'])} |")
    lines += ["", f"The aberration predicted at the boresight (|aberrate(b, v) − b|, v the Earth's + the orbital "
              f"velocity) averages {_f(aber['predicted_mean_arcsec'])}\" over the same frames. Corrected: "
              "`corrected_solution` given the matched rays and their covariances refits against the apparent "
              "directions with the identifier's weights. Composing the fit with C alone (the unweighted Wahba "
              "rotation of the matched stars onto their apparent places; what it does without the rays) leaves the "
              "aberration's scale about the boresight (~|v|/c) weighted differently from the fit, which matters "
              "whenever a bright, precisely measured star sits off the field's centre.", "",
              "**4. The Moon and the bright planets in the field**: inertial pointings (a random place within 6° "
              "of the boresight, random roll), each a tracked sequence of frames 3 s apart that starts "
              f"{ARC_LEAD if not meta['quick'] else QUICK_ARC_LEAD} frames before the head and its target come out "
              "from behind the Earth (so the arcs also cross Earth occultation and Earth blinding). In field: the "
              "target on the chip, the frame neither occulted nor flooded.", "",
              "| target | date | roll | frames | in field | solved | wrong | intervals = astropy |",
              "|---|---|---:|---:|---:|---:|---:|---|"]
    for row in arcs["arcs"]:
        name = row["target"] + (f" ({row['fraction']:.0%} lit)" if row["fraction"] else "")
        lines.append(f"| {name} | {row['date']} | {row['roll']} | {row['frames']} | {row['in_field']} | "
                     f"{row['solved']} | {row['wrong_any']} | {'yes' if row['intervals_met'] else 'no'} |")
    lines += ["", f"**5. Alignment.** Head b's correction against the injected truth (body frame): after the first "
              f"update {_axes(fusion['alignment_first_arcsec'] or [], 1)}\"; over the last half orbit "
              f"({fusion['alignment_late_frames']} frames) RMS {_axes(fusion['alignment_rms_arcsec'])}\", max "
              f"{_axes(fusion['alignment_max_arcsec'] or [])}\", NEES {_f(fusion['alignment_nees'])} (3 when "
              "consistent).", "", "![sky](images/orbit_sky.png)", ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------- main
def _run_jobs(jobs: list[tuple], workers: int) -> list[dict]:
    """Run (function, job) pairs, in `workers` processes (1: in this one), reporting progress; results in order."""
    results = [None] * len(jobs)
    if workers <= 1:
        for i, (function, job) in enumerate(jobs):
            report_progress(i, len(jobs), job["kind"])
            results[i] = function(job)
    else:
        with concurrent.futures.ProcessPoolExecutor(workers) as pool:
            futures = {pool.submit(function, job): i for i, (function, job) in enumerate(jobs)}
            for done, future in enumerate(concurrent.futures.as_completed(futures)):
                results[futures[future]] = future.result()
                report_progress(done + 1, len(jobs), "sequences")
    return results


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    return value


def _timeline(records: dict, predicted: dict, fused: list[dict]) -> dict:
    """
    Return the orbit's per-frame columns for the JSON.

    t [s, UNIX]; the fused heads; the fused and alignment errors (body frame, arcsec; null
    without a fused attitude); per head its mode, spots, statuses (simulator, astropy, published),
    flooded, Moon in the field, saturated matched stars, and errors (sensor frame, arcsec;
    corrected and raw).
    """
    def arcsec(value):
        return None if value is None else [round(float(x), 3) for x in _arcsec(value)]

    columns = {"t": [round(f["t"], 1) for f in fused], "fused_heads": ["".join(f["heads"]) for f in fused],
               "fused_error_arcsec": [arcsec(f.get("error")) for f in fused],
               "alignment_error_arcsec": [arcsec(f["alignment_error"]) for f in fused]}
    for head in HEADS:
        rs = records[head]
        columns[head] = {"mode": [r["mode"] for r in rs], "spots": [r["spots"] for r in rs],
                         "simulator": [r["truth_status"] for r in rs], "astropy": list(predicted[head]),
                         "published": [r["status"] for r in rs], "flooded": [r["flooded"] for r in rs],
                         "moon_in_field": [r["moon_in_field"] for r in rs],
                         "saturated": [r.get("saturated") for r in rs],
                         "error_arcsec": [arcsec(r["error"]) if r["solved"] else None for r in rs],
                         "raw_error_arcsec": [arcsec(r["error_raw"]) if r["solved"] else None for r in rs]}
    return columns


def _interval_text(summaries: list[dict]) -> tuple[str, bool]:
    worst = max((c["max_offset_frames"] for s in summaries for c in s["truth_vs_astropy"].values()), default=0)
    unpaired = sum(c["unmatched"] for s in summaries for c in s["truth_vs_astropy"].values())
    count = sum(c["simulated"] for s in summaries for c in s["truth_vs_astropy"].values())
    ok = unpaired == 0 and worst <= 1
    return f"{count} intervals, largest offset {worst} frame{'s' if worst != 1 else ''}, {unpaired} unpaired", ok


def dump_json(results: dict) -> str:
    """Return the results as JSON text: indented, the per-frame timeline's columns one a line."""
    marker = "@timeline@"
    text = json.dumps({**results, "timeline": marker}, indent=1)
    timeline = results.get("timeline", {})
    lines = [f"  {json.dumps(key)}: {json.dumps(value, separators=(',', ':'))}" for key, value in timeline.items()]
    columns = ",\n".join(lines)
    return text.replace(json.dumps(marker), "{\n" + columns + "\n }") + "\n"


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark (module docstring); write its section, JSON and figures when --output is given."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="three short windows of the orbit, two short arcs")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: every core)")
    parser.add_argument("--output", type=Path, help=f"write the '{SECTION[3:]}' section of this Markdown file (and "
                        "bench_orbit.json, images/ beside it)")
    parser.add_argument("--images", type=Path, help="figure directory (default: images/ beside --output)")
    args = parser.parse_args(argv)
    started, date = time.perf_counter(), utc_now()
    path = orbit()
    period = path.period_s
    k, times = orbit_times(args.quick)
    rest = (np.linspace(0, k.size - 1, QUICK_REST_FRAMES).astype(int) if args.quick
            else np.arange(0, k.size, REST_EVERY))
    jobs = [(run_sequence, {"kind": "orbit", "head": head, "k": k, "t": times, "seed": SEED + i})
            for i, head in enumerate(HEADS)]
    jobs += [(run_sequence, job) for job in arc_jobs(args.quick)]
    jobs.append((run_rest, {"kind": "rest", "head": HEADS[0], "k": k[rest], "t": times[rest], "seed": SEED}))
    outputs = _run_jobs(jobs, max(1, args.jobs))
    records = {head: outputs[i]["records"] for i, head in enumerate(HEADS)}
    arcs = [o for o in outputs if o["job"]["kind"] == "arc"]
    rest_records = outputs[-1]["records"]

    # Independent geometry.
    r, v = path.state(times)
    predicted = {head: astropy_statuses(times, r, v, np.array([x["truth_rotation"][:, 2] for x in records[head]]))
                 for head in HEADS}
    arc_predicted = []
    for arc in arcs:
        t_arc = np.array([x["t"] for x in arc["records"]])
        ra, va = path.state(t_arc)
        boresight = np.asarray(arc["job"]["rotation"])[:, 2]
        arc_predicted.append(astropy_statuses(t_arc, ra, va, np.tile(boresight, (t_arc.size, 1)))["status"])
    fused, counters = fuse(records, period)

    heads = {head: head_summary(records[head], predicted[head]["status"]) for head in HEADS}
    fusion = fusion_summary(fused, period, times[0])
    aberration = aberration_summary(rest_records)
    moon_planets = arcs_summary(arcs, arc_predicted)
    arc_summaries = [head_summary(a["records"], p) for a, p in zip(arcs, arc_predicted)]
    cross = {head: per_axis_cross(records[head]) for head in HEADS}
    orbit_text, orbit_ok = _interval_text([heads[h] for h in HEADS])
    arcs_text, arcs_ok = _interval_text(arc_summaries)
    goals = {
        "availability": fusion["available_pct"] >= 99.5 and fusion["wrong"] == 0
        and all(heads[h]["wrong"] == 0 for h in HEADS),
        "intervals": orbit_ok and arcs_ok, "interval_text": {"orbit": orbit_text, "arcs": arcs_text},
        "single_cross_arcsec": cross[HEADS[0]], "cross_per_axis": cross,
        # Heads 90 deg apart: each body axis y, z half about one boresight, half about the other,
        # each fixed by the other head's cross-boresight axis.
        "geometric_yz": math.sqrt((cross[HEADS[0]] ** 2 + cross[HEADS[1]] ** 2) / 2.0),
        "fused_error": bool(np.all(np.array(fusion["rms_two_heads_arcsec"]) <= 1.5 * cross[HEADS[0]])),
        "aberration": aberration["met"],
        "moon_planets": moon_planets["in_field"] >= 1000 and moon_planets["wrong"] == 0,
        "alignment": bool(fusion["alignment_rms_arcsec"] and np.all(np.array(fusion["alignment_rms_arcsec"]) < 1.0)),
    }
    ephemeris = load_ephemeris()
    mid = float(times[len(times) // 2])
    meta = {"command": "python -m bench.bench_orbit" + "".join(
                f" {shlex.quote(a)}" for a in (argv if argv is not None else sys.argv[1:])),
            "date": date, "elapsed_s": time.perf_counter() - started, "quick": args.quick, "jobs": max(1, args.jobs),
            "frames_per_head": int(k.size), "period_s": period,
            "inclination_deg": math.degrees(path.elements.inclination_rad),
            "closest_sun_deg": {h: math.degrees(min(x["sun_angle_rad"] for x in records[h])) for h in HEADS},
            "closest_moon_deg": {h: math.degrees(min(x["moon_angle_rad"] for x in records[h])) for h in HEADS},
            "moon_fraction": float(ephemeris.moon_illuminated_fraction(mid, observer_m=path.state(mid)[0])),
            **machine_info()}
    results = {"meta": meta, "goals": goals, "heads": heads, "fusion": fusion, "fusion_counters": counters,
               "aberration": aberration, "arcs": moon_planets,
               "interval_rows": [(f"orbit, head {h}", heads[h]["truth_vs_astropy"]) for h in HEADS]
               + [(f"arc {a['job']['index']}: {a['job']['target']}", s["truth_vs_astropy"])
                  for a, s in zip(arcs, arc_summaries)],
               "timeline": _timeline(records, {h: predicted[h]["status"] for h in HEADS}, fused)}
    images = args.images or (args.output.parent / "images" if args.output else None)
    if images is not None:
        results["figures"] = figures(images, records, {h: predicted[h]["status"] for h in HEADS}, fused, times[0])
    results["meta"]["elapsed_s"] = time.perf_counter() - started
    results = _jsonable(results)
    text = render_markdown(results)
    print(text)
    if args.output is not None:
        write_section(args.output, text)
        (args.output.parent / "bench_orbit.json").write_text(dump_json(results))
    return results


if __name__ == "__main__":
    main()
