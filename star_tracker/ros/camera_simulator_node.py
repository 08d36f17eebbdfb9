"""camera_simulator: renders Hipparcos star frames and publishes them with the truth used.

Publishes image_raw (mono16), camera_info, truth/attitude, truth/angular_velocity and
truth/stars, all with the frame's mid-exposure stamp. See msg_docs/.
"""
from __future__ import annotations

import sys

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from ..attitude import matrix_to_quaternion, quaternion_to_matrix, radec_roll_to_matrix
from ..camera import CameraModel
from ..catalog import julian_year_from_unix, load_hipparcos
from ..motion import ConstantRateMotion
from ..render import SensorModel, StarFieldRenderer
from . import convert
from .common import RESULT_QOS, SENSOR_QOS, Diagnostics, declare, run_node


class CameraSimulatorNode(Node):
    def __init__(self) -> None:
        super().__init__("camera_simulator")
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.rate_hz = p("rate_hz", 10.0, "frame rate [Hz]", 0.01, 1000.0)
        self.max_frames = p("max_frames", 0, "stop publishing after this many frames (0 = never)", 0, 10**9)
        self.frame_id = p("frame_id", convert.OPTICAL_FRAME, "frame_id of image_raw, camera_info, truth/stars and truth/angular_velocity")
        self.start_delay_s = p("start_delay_s", 0.0, "wait before the first exposure [s]", 0.0, 3600.0)
        self.wait_for_subscribers = p("wait_for_subscribers", False,
                                      "begin exposures only once image_raw, camera_info and truth/attitude each "
                                      "have a subscriber (then start_delay_s more): no frame lost to DDS discovery")
        self.seed = p("seed", 0, "noise seed: frame k uses the stream (seed, k)", 0, 2**31 - 1)
        width = p("image.width", 1024, "image width [px]", 16, 8192)
        height = p("image.height", 1024, "image height [px]", 16, 8192)
        fov_x_deg = p("optics.fov_x_deg", 15.0, "horizontal field of view [deg]", 0.5, 120.0)
        distortion = p("optics.distortion", [0.0, 0.0, 0.0, 0.0, 0.0],
                       "Brown-Conrady plumb_bob k1, k2, p1, p2, k3 (published in camera_info)")
        self.camera = CameraModel.from_fov(width, height, np.radians(fov_x_deg), tuple(distortion))
        sensor = SensorModel(
            zero_point_e_per_s=p("sensor.zero_point_e_per_s", 1.0e7, "photo-electrons/s from an Hp=0 star", 1.0, 1e12),
            exposure_s=p("sensor.exposure_s", 0.1, "exposure time [s]", 1e-6, 10.0),
            psf_sigma_px=p("optics.psf_sigma_px", 1.0, "Gaussian PSF 1-sigma [px]", 0.1, 20.0),
            background_e_per_px_s=p("sensor.background_e_per_px_s", 400.0, "sky background [e-/px/s]", 0.0, 1e9),
            dark_e_per_px_s=p("sensor.dark_e_per_px_s", 20.0, "dark current [e-/px/s]", 0.0, 1e9),
            read_noise_e=p("sensor.read_noise_e", 8.0, "read noise 1-sigma [e-]", 0.0, 1e4),
            gain_e_per_adu=p("sensor.gain_e_per_adu", 1.0, "conversion gain [e-/ADU]", 1e-3, 1e4),
            bias_adu=p("sensor.bias_adu", 100.0, "bias offset [ADU]", 0.0, 65535.0),
            full_well_e=p("sensor.full_well_e", 60000.0, "full-well capacity [e-]", 1.0, 1e9),
            adc_bits=p("sensor.adc_bits", 16, "ADC bit depth", 8, 16),
        )
        self.sensor = sensor
        magnitude_limit = p("sky.magnitude_limit", 7.5, "faintest star rendered [Hp mag]", -2.0, 12.0)
        epoch = p("sky.epoch_jyear", 0.0, "catalog epoch [Julian year]; 0 = the clock's date", 0.0, 2200.0)
        quaternion = p("attitude.quaternion", [0.0, 0.0, 0.0, 0.0],
                       "initial sensor->ICRS quaternion x, y, z, w; all zero = use RA/Dec/roll")
        ra = np.radians(p("attitude.ra_deg", 80.0, "initial boresight right ascension [deg]", -360.0, 360.0))
        dec = np.radians(p("attitude.dec_deg", 20.0, "initial boresight declination [deg]", -90.0, 90.0))
        roll = np.radians(p("attitude.roll_deg", 0.0, "initial roll about the boresight [deg]", -360.0, 360.0))
        rate = np.radians(np.asarray(p("attitude.body_rate_deg_s", [0.0, 0.0, 0.0],
                                       "constant body rate in the sensor frame x, y, z [deg/s]"), dtype=float))
        if len(distortion) != 5 or rate.shape != (3,) or len(quaternion) != 4:
            raise ValueError("optics.distortion needs 5 values, attitude.body_rate_deg_s 3, attitude.quaternion 4")
        if not np.all(np.isfinite(rate)) or np.linalg.norm(rate) > np.radians(90.0):
            raise ValueError(f"attitude.body_rate_deg_s={list(np.degrees(rate))} must be finite and below 90 deg/s")
        if np.linalg.norm(quaternion) > 0:
            initial = quaternion_to_matrix(np.asarray(quaternion, dtype=float))
        else:
            initial = radec_roll_to_matrix(ra, dec, roll)

        self.initial_rotation, self.body_rate = initial, rate
        self.t0_ns: int | None = None  # exposures start at t0 + period; set in start()
        epoch = epoch or julian_year_from_unix(self.get_clock().now().nanoseconds * 1e-9)
        catalog = load_hipparcos().at_epoch(epoch)
        self.renderer = StarFieldRenderer(self.camera, sensor, catalog, magnitude_limit)
        self.period_ns = int(round(1e9 / self.rate_hz))
        if sensor.exposure_s * 1e9 > self.period_ns:
            raise ValueError(f"sensor.exposure_s={sensor.exposure_s} is longer than the frame period {1 / self.rate_hz} s")
        self.frame_index = 0

        self.pub_image = self.create_publisher(Image, "image_raw", SENSOR_QOS)
        self.pub_info = self.create_publisher(CameraInfo, "camera_info", SENSOR_QOS)
        self.pub_truth = self.create_publisher(QuaternionStamped, "truth/attitude", RESULT_QOS)
        self.pub_truth_rate = self.create_publisher(Vector3Stamped, "truth/angular_velocity", RESULT_QOS)
        self.pub_truth_stars = self.create_publisher(PointCloud2, "truth/stars", RESULT_QOS)
        self.diag = Diagnostics(self)
        self.timer = None
        if self.wait_for_subscribers:
            self.waiting_timer = self.create_timer(0.05, self.start_when_subscribed)
        else:
            self.start()
        self.get_logger().info(
            f"{width}x{height} px, FOV {fov_x_deg:.2f} deg, {self.rate_hz:g} Hz, exposure {sensor.exposure_s * 1e3:g} ms, "
            f"{len(self.renderer.catalog)} stars to Hp {magnitude_limit}, body rate {np.degrees(rate)} deg/s")

    def start(self) -> None:
        """Fix the time origin and start the frame timer. Its ticks fall at now + n*period and
        are never early, so exposures end 1 ms before a tick: the frame is rendered right
        after its exposure, and a late tick only delays it."""
        now_ns = self.get_clock().now().nanoseconds
        delay_ticks = int(np.ceil(self.start_delay_s * 1e9 / self.period_ns))
        self.t0_ns = now_ns + delay_ticks * self.period_ns - 1_000_000
        self.motion = ConstantRateMotion(self.initial_rotation, self.body_rate, t0=self.t0_ns * 1e-9)
        self.timer = self.create_timer(self.period_ns * 1e-9, self.on_timer)

    def start_when_subscribed(self) -> None:
        publishers = (self.pub_image, self.pub_info, self.pub_truth)
        if all(pub.get_subscription_count() > 0 for pub in publishers):
            self.destroy_timer(self.waiting_timer)
            self.get_logger().info("subscribers connected; starting exposures")
            self.start()
        else:
            self.diag.set(DiagnosticStatus.OK, "waiting for subscribers")

    def on_timer(self) -> None:
        if self.max_frames and self.frame_index >= self.max_frames:
            if self.frame_index == self.max_frames:
                self.get_logger().info(f"published {self.max_frames} frames; idle")
                self.diag.set(DiagnosticStatus.OK, "finished", frames=self.frame_index)
                self.frame_index += 1
            return
        # Frame k's exposure ends at t0 + (k+1) period; its stamp is mid-exposure.
        now_ns = self.get_clock().now().nanoseconds
        due = (now_ns - self.t0_ns) // self.period_ns  # frames whose exposure has ended
        if due < self.frame_index + 1:
            return
        if due > self.frame_index + 1:  # rendering fell behind: skip to the newest frame, count the rest
            skipped = int(due - 1 - self.frame_index)
            if self.max_frames:
                skipped = min(skipped, self.max_frames - self.frame_index)
            self.diag.count("frames_skipped_overrun", skipped)
            self.get_logger().warning(f"rendering is behind the {self.rate_hz:g} Hz schedule: skipped {skipped} frame(s)")
            self.frame_index += skipped
            if self.max_frames and self.frame_index >= self.max_frames:
                return
        k = self.frame_index
        stamp_ns = self.t0_ns + (k + 1) * self.period_ns - int(round(self.sensor.exposure_s * 0.5e9))
        rng = np.random.default_rng([self.seed, k])
        frame = self.renderer.render(self.motion.rotations_at, stamp_ns * 1e-9, self.motion.body_rate, rng)
        truth = frame.truth
        self.pub_image.publish(convert.array_to_image(frame.image, stamp_ns, self.frame_id))
        self.pub_info.publish(convert.camera_to_info(self.camera, stamp_ns, self.frame_id))
        self.pub_truth.publish(convert.quaternion_msg(matrix_to_quaternion(truth.rotation), stamp_ns))
        self.pub_truth_rate.publish(convert.vector3_msg(truth.body_rate, stamp_ns, self.frame_id))
        stars = np.zeros(truth.hip.size, convert.TRUTH_STAR_DTYPE)
        stars["hip_id"], stars["pixel_x"], stars["pixel_y"], stars["electrons"] = truth.hip, truth.x, truth.y, truth.electrons
        self.pub_truth_stars.publish(convert.records_to_cloud(stars, convert.TRUTH_STAR_FIELDS, stamp_ns, self.frame_id))
        self.frame_index += 1
        self.diag.count("frames_published")
        self.diag.set(DiagnosticStatus.OK, "publishing", stars_in_view=truth.hip.size, smear_substeps=frame.substeps)


def main(argv: list[str] | None = None) -> None:
    sys.exit(run_node(CameraSimulatorNode, argv))


if __name__ == "__main__":
    main()
