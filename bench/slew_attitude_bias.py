# SPDX-License-Identifier: Apache-2.0
"""
The tracked slew of test_tracking, frame by frame: attitude error against its covariance and the acceleration.

    python -m bench.slew_attitude_bias

Renders the slew of test_tracking.test_slew_is_tracked_on_every_frame_with_an_honest_rate (eigen-axis
[0.6, 0.8, 0] in the sensor frame, 2 deg/s^2 up to 2 deg/s, 10 Hz, 0.1 s exposures), tracks it as the test
does (the centroider rate-aided by the tracker's own rate) and prints per frame: the true rate, the
attitude error (sensor axes, arcsec) and its normalized value (error / covariance sigma), the bias a
constant angular acceleration alpha puts on every star's light centroid (alpha T^2 / 24 about alpha's
axis: the time-averaged position, not the mid-exposure one), whether the frame was rate-aided or its aid
rejected, and the rate's normalized error. Diagnosis only: no goal is judged.
"""
from __future__ import annotations

import numpy as np

ARCSEC = np.radians(1.0 / 3600.0)


def main() -> int:
    from star_tracker.centroid import CentroidConfig, extract_spots
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
    from star_tracker.models.attitude import matrix_to_rotation_vector, radec_roll_to_matrix
    from star_tracker.models.camera import CameraModel
    from star_tracker.models.catalog import load_hipparcos
    from star_tracker.sim.motion import SlewMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel
    from star_tracker.track.tracking import Tracker, TrackingConfig

    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    sensor = SensorModel()
    # The sky at the database's epoch, as the tests' `catalog` fixture renders it (test/conftest.py).
    renderer = StarFieldRenderer(camera, sensor, load_hipparcos().at_epoch(DatabaseConfig().epoch_jyear),
                                 magnitude_limit=7.5)
    identifier = make_identifier("hybrid", load_or_build_database(DatabaseConfig()))
    tracker = Tracker(identifier, TrackingConfig(max_angular_acceleration_rad_s2=np.radians(2.0)))
    axis = np.array([0.6, 0.8, 0.0])
    accel = np.radians(2.0)
    motion = SlewMotion(radec_roll_to_matrix(1.4, 0.35, 0.2), axis=axis, angle_rad=np.radians(3.0),
                        max_rate_rad_s=np.radians(2.0), accel_rad_s2=accel, t_start=0.3)
    exposure = sensor.exposure_s
    print("| frame | t s | rate °/s | attitude error x, y, z ″ | error / sigma | alpha T²/24 x, y ″ | aided | aid "
          "rejected | rate error / sigma |")
    print("|---:|---:|---:|---|---|---|:-:|:-:|---|")
    for k in range(30):
        t = 0.05 + 0.1 * k
        frame = renderer.render(motion, t, frame_seed(0, k))
        smear = None if tracker.rate is None else SmearModel(camera, tracker.rate.angular_velocity, exposure)
        spots = extract_spots(frame.image, CentroidConfig(), smear)
        result = tracker.process(int(round(t * 1e9)), spots, camera)
        # The true angular acceleration at mid-exposure, by central differences of the true rate.
        step = 1e-3
        rate_ahead = renderer.render(motion, t + step, frame_seed(0, k)).truth.body_rate
        rate_behind = renderer.render(motion, t - step, frame_seed(0, k)).truth.body_rate
        alpha = (rate_ahead - rate_behind) / (2 * step)
        bias = alpha * exposure ** 2 / 24.0
        attitude = result.identification.attitude
        if attitude is None:
            print(f"| {k} | {t:.2f} | – | – | – | – | – | – | – |")
            continue
        error = matrix_to_rotation_vector(frame.truth.rotation.T @ attitude.rotation)
        sigma = np.sqrt(np.diag(attitude.covariance))
        rate = "–"
        if result.rate is not None:
            rate = ", ".join(f"{v:+.1f}" for v in (result.rate.angular_velocity - frame.truth.body_rate)
                             / result.rate.sigma)
        aided = spots.psf.source == "prior" and spots.psf.reason.startswith("rate-aided")
        print(f"| {k} | {t:.2f} | {np.degrees(np.linalg.norm(frame.truth.body_rate)):.2f} | "
              + ", ".join(f"{v / ARCSEC:+.2f}" for v in error) + " | "
              + ", ".join(f"{v:+.1f}" for v in error / sigma) + " | "
              + ", ".join(f"{v / ARCSEC:+.2f}" for v in bias[:2]) + f" | {'yes' if aided else 'no'} | "
              f"{'yes' if spots.rate_aid_rejected else 'no'} | {rate} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
