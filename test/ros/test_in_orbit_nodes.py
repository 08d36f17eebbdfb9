# SPDX-License-Identifier: Apache-2.0
"""
The three nodes in orbit, over DDS: the camera on a spacecraft, the identifier fed its odometry.

1. A nadir-pointing spacecraft on a 550 km sun-synchronous orbit, the camera mounted 45 deg off
   zenith (head.mounting_quaternion): the camera publishes truth/odometry (the orbit's state);
   the identifier, fed it (observer.source odometry), publishes attitudes within an arcsecond of
   the truth across the boresight: corrected for the ~30" of aberration at LEO + the Earth's speed, which an
   identifier without the odometry leaves in (judged on the same frames, with the truth).
2. The camera slews from 50 deg off the Sun to 10 deg off it: once the Sun's stray light blinds
   it, the identifier's status says blinded_sun (predicted from the ephemeris, the odometry and
   its last attitude propagated), not lost_in_space.
3. A malformed orbit (a TLE with a bad checksum): the camera refuses to configure and says why.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402

from star_tracker.models.attitude import (attitude_error, matrix_to_quaternion, radec_roll_to_matrix,  # noqa: E402
                                          rotation_vector_to_matrix)
from star_tracker.models.ephemeris import load_ephemeris  # noqa: E402
from star_tracker.ros import convert  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, TrackerMonitor  # noqa: E402
from star_tracker.ros.qos import RESULT_QOS  # noqa: E402
from test_integration import REPO, ros_graph  # noqa: E402,F401  the isolated-domain fixture

ARCSEC = math.radians(1.0 / 3600.0)
ZENITH_45 = [float(x) for x in matrix_to_quaternion(rotation_vector_to_matrix(np.array([math.radians(135.0), 0, 0])))]


class OrbitMonitor(TrackerMonitor):
    """The tracker monitor plus truth/odometry and the identifier's status, by stamp."""

    def __init__(self):
        super().__init__(name="orbit_monitor")
        self.odometry: dict[int, np.ndarray] = {}
        self.status: dict[int, dict] = {}
        self.create_subscription(Odometry, "truth/odometry", self._on_odometry, RESULT_QOS)
        self.create_subscription(DiagnosticArray, "status", self._on_status, RESULT_QOS)

    def _on_odometry(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        self.odometry[convert.stamp_to_ns(msg.header.stamp)] = np.array([p.x, p.y, p.z])

    def _on_status(self, msg: DiagnosticArray) -> None:
        entry = msg.status[0]
        values = {kv.key: kv.value for kv in entry.values}
        self.status[convert.stamp_to_ns(msg.header.stamp)] = {"message": entry.message, **values}


def run(env, tmp_path, camera: dict, identifier: dict, until, seconds: float = 90.0):
    monitor = OrbitMonitor()
    params = {"camera_simulator": {"start_delay_s": 1.0, "wait_for_subscribers": True, "rate_hz": 4.0, **camera},
              "identifier": identifier}
    remaps = {"identifier": {"odometry": "truth/odometry"}}
    nodes = NodeProcesses(env, tmp_path / "logs", params, REPO / "config" / "star_tracker.yaml", remaps=remaps)
    try:
        nodes.start()
        nodes.wait_ready(timeout_s=120)
        assert monitor.spin_for(seconds, until=lambda: until(monitor)), (monitor.status, nodes.log_paths)
    finally:
        codes = nodes.stop()
        monitor.destroy_node()
    logs = {name: path.read_text() for name, path in nodes.log_paths.items()}
    assert codes == {"camera_simulator": 0, "centroider": 0, "identifier": 0}, logs
    assert not any("Traceback" in text for text in logs.values()), logs
    return monitor


def errors(monitor) -> list[tuple[float, float]]:
    """Return (cross-boresight, roll) errors [rad] of every frame with an attitude and its truth."""
    return [attitude_error(f.attitude, f.truth)[:2] for f in monitor.frames.values()
            if f.attitude is not None and f.truth is not None]


@pytest.mark.integration
@pytest.mark.slow
def test_in_orbit_the_attitude_is_corrected_for_aberration(ros_graph, tmp_path):  # noqa: F811
    camera = {"orbit.model": "kepler", "attitude.profile": "nadir", "head.mounting_quaternion": ZENITH_45}
    corrected = run(ros_graph, tmp_path / "odometry", camera, {"observer.source": "odometry"},
                    until=lambda m: len(errors(m)) >= 12)
    assert len(corrected.odometry) >= 12
    r = next(iter(corrected.odometry.values()))
    assert 6_900e3 < np.linalg.norm(r) < 6_960e3  # 550 km above the equatorial radius (circular)
    cross, roll = np.array(errors(corrected)).T
    assert np.median(cross) < 1.5 * ARCSEC, cross / ARCSEC  # ~0.6" measured
    assert np.median(roll) < 10 * ARCSEC, roll / ARCSEC  # ~2" measured: 30 tracked stars in a 15 deg field
    assert all(s["message"] in ("tracking", "lost_in_space") for s in corrected.status.values())
    plain = run(ros_graph, tmp_path / "plain", camera, {"observer.source": "none"},
                until=lambda m: len(errors(m)) >= 6)
    uncorrected = np.array(errors(plain))[:, 0]
    assert np.median(uncorrected) > 10 * ARCSEC, uncorrected / ARCSEC  # the aberration left in (~30" here)


def slew_toward_the_sun(start_off_deg: float, end_off_deg: float) -> dict:
    """
    Camera parameters: an inertial boresight start_off_deg from the Sun, slewing toward it to end_off_deg.

    The spacecraft starts above the subsolar point (its orbit's node at the Sun's right
    ascension, its argument of latitude at the Sun's declination): the Earth, ~67 deg wide
    from 550 km, lies opposite the Sun, far from the field. The boresight comes from the side
    of the Sun away from the Moon, at least start_off_deg + the Sun-Moon angle from it.
    """
    sun = load_ephemeris().sun_position(time.time())
    sun /= np.linalg.norm(sun)
    sun_ra, sun_dec = math.atan2(sun[1], sun[0]), math.asin(sun[2])
    inclination = math.radians(97.6)
    orbit = {"orbit.model": "kepler", "orbit.sun_synchronous": False, "orbit.inclination_deg": 97.6,
             "orbit.raan_deg": math.degrees(sun_ra),
             "orbit.true_anomaly_deg": math.degrees(math.asin(math.sin(sun_dec) / math.sin(inclination)))}
    # The slew comes from the side away from the Moon: around new moon the Moon lies within ~40 deg
    # of the Sun, and a path across it reported the Moon (blinded_moon) before the Sun.
    moon = load_ephemeris().moon_position(time.time())
    side = -(moon - (moon @ sun) * sun)
    side /= np.linalg.norm(side)
    boresight = math.cos(math.radians(start_off_deg)) * sun + math.sin(math.radians(start_off_deg)) * side
    ra, dec = math.atan2(boresight[1], boresight[0]), math.asin(boresight[2])
    rotation = radec_roll_to_matrix(ra, dec, 0.0)
    axis_icrs = np.cross(boresight, sun)  # turning the boresight about this axis brings it to the Sun
    axis = rotation.T @ (axis_icrs / np.linalg.norm(axis_icrs))
    return {**orbit, "attitude.profile": "slew", "attitude.ra_deg": math.degrees(ra),
            "attitude.dec_deg": math.degrees(dec), "attitude.roll_deg": 0.0,
            "attitude.slew.axis": [float(x) for x in axis],
            "attitude.slew.angle_deg": start_off_deg - end_off_deg, "attitude.slew.max_rate_deg_s": 2.0,
            "attitude.slew.accel_deg_s2": 1.0, "attitude.slew.start_s": 4.0}


@pytest.mark.integration
@pytest.mark.slow
def test_a_head_turned_at_the_sun_reports_blinded_sun(ros_graph, tmp_path):  # noqa: F811
    camera = slew_toward_the_sun(50.0, 10.0)

    def blinded(monitor) -> bool:
        return sum(s["message"] == "blinded_sun" for s in monitor.status.values()) >= 3

    monitor = run(ros_graph, tmp_path, camera, {"observer.source": "odometry"}, until=blinded, seconds=120.0)
    statuses = [s for _, s in sorted(monitor.status.items())]
    first = next(i for i, s in enumerate(statuses) if s["message"] == "blinded_sun")
    assert any(s["attitude"] == "true" for s in statuses[:first])  # it tracked before the Sun came near
    for s in statuses[first:]:
        assert s["attitude"] == "false" and s["message"] == "blinded_sun"
        assert float(s["sun_angle_rad"]) < math.radians(30.0)


@pytest.mark.integration
def test_a_bad_orbit_leaves_the_camera_unconfigured_and_says_why(ros_graph, tmp_path):  # noqa: F811
    params = {"camera_simulator": {"autostart": False, "orbit.model": "tle",
                                   "orbit.tle_line1": "1 25544U 98067A   26335.5 bad",
                                   "orbit.tle_line2": "2 25544  51.6 0 0 0 0 15.5 0"}}
    nodes = NodeProcesses(ros_graph, tmp_path / "logs", params, REPO / "config" / "star_tracker.yaml",
                          nodes=("camera_simulator",))
    try:
        nodes.start()
        nodes.wait_ready()  # a camera started alone is not waited for: its process may still be importing
        assert nodes.get_state("camera_simulator") == "unconfigured"
        assert not nodes.change_state("camera_simulator", "configure")
        assert nodes.get_state("camera_simulator") == "unconfigured"
    finally:
        nodes.stop()
    log = nodes.log_paths["camera_simulator"].read_text()
    assert "69-character TLE line" in log, log
