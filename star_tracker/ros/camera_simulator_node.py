"""camera_simulator: renders Hipparcos star frames and publishes them with the truth used.

Publishes image_raw (mono16), camera_info, truth/attitude, truth/angular_velocity and
truth/objects, all with the frame's mid-exposure stamp. See msg_docs/.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from ..attitude import matrix_to_quaternion, quaternion_to_matrix, radec_roll_to_matrix
from ..camera import CameraModel
from ..catalog import julian_year_from_unix, load_hipparcos
from ..motion import SampledMotion, motion_from_parameters
from ..render import FalseObjectModel, SensorModel, StarFieldRenderer, frame_seed
from . import convert
from .common import IMAGE_QOS, RESULT_QOS, Diagnostics, ThrottledLog, declare, guard_parameter_changes, run_node


class CameraSimulatorNode(Node):
    def __init__(self) -> None:
        super().__init__("camera_simulator")
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.rate_hz = p("rate_hz", 10.0, "frame rate [Hz]", 0.01, 1000.0)
        self.max_frames = p("max_frames", 0, "stop publishing after this many frames (0 = never)", 0, 10**9)
        self.frame_id = p("frame_id", convert.OPTICAL_FRAME, "frame_id of image_raw, camera_info, truth/objects and truth/angular_velocity")
        self.start_delay_s = p("start_delay_s", 0.0, "wait before the first exposure [s]", 0.0, 3600.0)
        self.max_backlog_frames = p("max_backlog_frames", 5, "frames rendered late before older ones are skipped", 0, 1000)
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
            aperture_diameter_m=p("optics.aperture_diameter_m", 0.03, "entrance pupil diameter [m]", 1e-4, 10.0),
            optical_transmission=p("optics.transmission", 0.8, "optical transmission [-]", 1e-3, 1.0),
            psf_sigma_px=p("optics.psf_sigma_px", 1.0, "Gaussian PSF (defocus) 1-sigma [px]", 0.1, 20.0),
            vignetting_at_corner=p("optics.vignetting_at_corner", 0.1, "light lost at the image corner [-]", 0.0, 0.99),
            photon_flux_hp0=p("sky.photon_flux_hp0", 2.0e10, "photons/s/m^2 in the sensor band from an Hp=0 star", 1e-6, 1e14),
            color_coefficient=p("sky.color_coefficient", 0.0, "instrument magnitude = Hp + c (B-V) [-]", -5.0, 5.0),
            background_e_per_px_s=p("sky.background_e_per_px_s", 400.0, "sky + zodiacal background [e-/px/s]", 0.0, 1e9),
            stray_light_gradient_e_per_px2_s=tuple(p("sky.stray_light_gradient_e_per_px2_s", [0.0, 0.0],
                                                     "linear stray-light gradient in x, y [e-/px/s per px]")),
            exposure_s=p("sensor.exposure_s", 0.1, "exposure time [s]", 1e-6, 10.0),
            pixel_pitch_m=p("sensor.pixel_pitch_m", 13e-6, "pixel pitch [m]", 1e-7, 1e-3),
            quantum_efficiency=p("sensor.quantum_efficiency", 0.6, "quantum efficiency [-]", 1e-3, 1.0),
            dark_e_per_px_s=p("sensor.dark_e_per_px_s", 20.0, "dark current at dark_reference_k [e-/px/s]", 0.0, 1e9),
            dark_reference_k=p("sensor.dark_reference_k", 293.15, "reference temperature of dark_e_per_px_s [K]", 1.0, 500.0),
            dark_doubling_k=p("sensor.dark_doubling_k", 6.0, "dark current doubles every this many kelvin [K]", 0.1, 100.0),
            temperature_k=p("sensor.temperature_k", 293.15, "detector temperature [K]", 1.0, 500.0),
            dsnu_fraction=p("sensor.dsnu_fraction", 0.1, "dark signal non-uniformity, lognormal sigma [-]", 0.0, 5.0),
            prnu_fraction=p("sensor.prnu_fraction", 0.01, "photo-response non-uniformity 1-sigma [-]", 0.0, 0.5),
            hot_pixel_fraction=p("sensor.hot_pixel_fraction", 2e-5, "fraction of hot pixels [-]", 0.0, 0.1),
            hot_pixel_dark_factor=p("sensor.hot_pixel_dark_factor", 200.0, "hot pixel dark current multiple [-]", 0.0, 1e6),
            cosmic_ray_rate_per_cm2_s=p("sensor.cosmic_ray_rate_per_cm2_s", 5.0, "cosmic-ray hit rate [1/cm^2/s]", 0.0, 1e6),
            cosmic_ray_electrons=p("sensor.cosmic_ray_electrons", 3000.0, "mean charge of a hit [e-]", 0.0, 1e9),
            read_noise_e=p("sensor.read_noise_e", 8.0, "read noise 1-sigma [e-]", 0.0, 1e4),
            gain_e_per_adu=p("sensor.gain_e_per_adu", 1.0, "conversion gain [e-/ADU]", 1e-3, 1e4),
            bias_adu=p("sensor.bias_adu", 100.0, "bias offset [ADU]", 0.0, 65535.0),
            full_well_e=p("sensor.full_well_e", 60000.0, "full-well capacity [e-]", 1.0, 1e9),
            adc_bits=p("sensor.adc_bits", 16, "ADC bit depth", 8, 16),
            rolling_shutter_row_time_s=p("sensor.rolling_shutter_row_time_s", 0.0,
                                         "row readout delay of a rolling shutter; 0 = global shutter [s]", 0.0, 1e-2),
            frame_transfer_time_s=p("sensor.frame_transfer_time_s", 0.0, "frame-transfer time; 0 = none [s]", 0.0, 1.0),
            noise=p("sensor.noise", True, "shot and read noise on (false renders expected values)"),
        )
        self.sensor = sensor
        false_objects = FalseObjectModel(
            planets_per_frame=p("false_objects.planets_per_frame", 0, "bright non-catalog points per frame", 0, 100),
            planet_magnitude_range=tuple(p("false_objects.planet_magnitude_range", [-1.0, 2.0], "instrument magnitude range")),
            debris_per_frame=p("false_objects.debris_per_frame", 0, "moving debris streaks per frame", 0, 100),
            debris_magnitude_range=tuple(p("false_objects.debris_magnitude_range", [3.0, 6.0], "instrument magnitude range")),
            debris_speed_px_s=tuple(p("false_objects.debris_speed_px_s", [100.0, 1000.0], "image speed range [px/s]")),
        )
        magnitude_limit = p("sky.magnitude_limit", 7.5, "faintest star rendered [Hp mag]", -2.0, 12.0)
        epoch = p("sky.epoch_jyear", 0.0, "catalog epoch [Julian year]; 0 = the clock's date", 0.0, 2200.0)
        observer_velocity = p("sky.observer_velocity_m_s", [0.0, 0.0, 0.0],
                              "spacecraft velocity in ICRS for stellar aberration [m/s] (Earth orbit ~ 30 km/s)")
        fixed_pattern_seed = p("fixed_pattern_seed", 0, "seed of PRNU, DSNU and hot pixels", 0, 2**31 - 1)
        quaternion = p("attitude.quaternion", [0.0, 0.0, 0.0, 0.0],
                       "initial sensor->ICRS quaternion x, y, z, w; all zero = use RA/Dec/roll")
        ra = np.radians(p("attitude.ra_deg", 80.0, "initial boresight right ascension [deg]", -360.0, 360.0))
        dec = np.radians(p("attitude.dec_deg", 20.0, "initial boresight declination [deg]", -90.0, 90.0))
        roll = np.radians(p("attitude.roll_deg", 0.0, "initial roll about the boresight [deg]", -360.0, 360.0))
        self.profile = p("attitude.profile", "constant_rate",
                         "motion: fixed, constant_rate, slew, tumble, jitter, or external (follow truth_in/ topics)")
        deg = np.radians
        body_rate = deg(p("attitude.body_rate_deg_s", [0.0, 0.0, 0.0],
                          "constant body rate in the sensor frame x, y, z (constant_rate, jitter base) [deg/s]"))
        self.motion_kwargs = {
            "fixed": {},
            "constant_rate": {"body_rate_rad_s": body_rate},
            "slew": {"axis": p("attitude.slew.axis", [1.0, 0.0, 0.0], "slew axis in the sensor frame"),
                     "angle_rad": deg(p("attitude.slew.angle_deg", 10.0, "slew angle [deg]", -3600.0, 3600.0)),
                     "max_rate_rad_s": deg(p("attitude.slew.max_rate_deg_s", 2.0, "coast rate [deg/s]", 1e-6, 90.0)),
                     "accel_rad_s2": deg(p("attitude.slew.accel_deg_s2", 0.5, "acceleration [deg/s^2]", 1e-6, 1000.0)),
                     "t_start": p("attitude.slew.start_s", 2.0, "slew start after the first exposure [s]", 0.0, 1e6)},
            "tumble": {"initial_rate_rad_s": deg(p("attitude.tumble.initial_rate_deg_s", [0.5, 0.2, 1.0],
                                                   "initial body rate [deg/s]")),
                       "inertia_kg_m2": p("attitude.tumble.inertia_kg_m2", [10.0, 12.0, 8.0],
                                          "principal moments about the sensor x, y, z axes [kg m^2]")},
            "jitter": {"body_rate_rad_s": body_rate,
                       "amplitudes_rad": p("attitude.jitter.amplitudes_rad", [2e-5, 2e-5, 1e-5],
                                           "sinusoid amplitudes x, y, z per term, flat (3N) [rad]"),
                       "frequencies_hz": p("attitude.jitter.frequencies_hz", [7.0], "sinusoid frequencies (N) [Hz]"),
                       "phases_rad": p("attitude.jitter.phases_rad", [0.0], "phases: 1, N or 3N values [rad]")},
        }
        if self.profile not in (*self.motion_kwargs, "external"):
            raise ValueError(f"attitude.profile={self.profile!r}: expected one of {sorted([*self.motion_kwargs, 'external'])}")
        if len(distortion) != 5 or len(quaternion) != 4:
            raise ValueError("optics.distortion needs 5 values, attitude.quaternion 4")
        if not np.all(np.isfinite(quaternion)):  # NaN would fall through to RA/Dec/roll unnoticed
            raise ValueError(f"attitude.quaternion={list(quaternion)} must be finite")
        if np.linalg.norm(quaternion) > 0:
            initial = quaternion_to_matrix(np.asarray(quaternion, dtype=float))
        else:
            initial = radec_roll_to_matrix(ra, dec, roll)
        self.initial_rotation = initial
        if self.profile != "external":  # validate now: a bad profile fails at startup, not at the first frame
            motion_from_parameters(self.profile, initial, **self.motion_kwargs[self.profile])
        self.t0_ns: int | None = None  # exposures start at t0 + period; set in start()
        epoch = epoch or julian_year_from_unix(self.get_clock().now().nanoseconds * 1e-9)
        catalog = load_hipparcos().at_epoch(epoch)
        self.renderer = StarFieldRenderer(self.camera, sensor, catalog, magnitude_limit, false_objects,
                                          fixed_pattern_seed, observer_velocity)
        self.period_ns = int(round(1e9 / self.rate_hz))
        if sensor.exposure_s * 1e9 > self.period_ns:
            raise ValueError(f"sensor.exposure_s={sensor.exposure_s} is longer than the frame period {1 / self.rate_hz} s")
        self.frame_index = 0
        blank = p("faults.blank_frames", [-1], "frame indices rendered with the field occulted (no stars, "
                  "e.g. Earth or a baffle): to exercise loss and re-acquisition; -1 = none")
        self.blank_frames = {int(k) for k in blank if int(k) >= 0}

        self.pub_image = self.create_publisher(Image, "image_raw", IMAGE_QOS)
        self.pub_info = self.create_publisher(CameraInfo, "camera_info", IMAGE_QOS)
        self.pub_truth = self.create_publisher(QuaternionStamped, "truth/attitude", RESULT_QOS)
        self.pub_truth_rate = self.create_publisher(Vector3Stamped, "truth/angular_velocity", RESULT_QOS)
        self.pub_truth_objects = self.create_publisher(PointCloud2, "truth/objects", RESULT_QOS)
        self.diag = Diagnostics(self)
        self.log = ThrottledLog(self)
        # Every parameter is read-only: a runtime change is refused with the reason, logged, counted.
        guard_parameter_changes(self, lambda changes: None, self.diag, self.log)
        if self.profile == "external":
            # Truth from a dynamics simulator, on this node's clock (use_sim_time for sim time).
            self.motion = None
            self._external_pending: dict[int, list] = {}
            self.create_subscription(QuaternionStamped, "truth_in/attitude", self.on_external_attitude, RESULT_QOS)
            self.create_subscription(Vector3Stamped, "truth_in/angular_velocity", self.on_external_rate, RESULT_QOS)
        self.timer = None
        if self.wait_for_subscribers:
            self.waiting_timer = self.create_timer(0.05, self.start_when_subscribed)
        else:
            self.start()
        self.get_logger().info(
            f"{width}x{height} px, FOV {fov_x_deg:.2f} deg, {self.rate_hz:g} Hz, exposure {sensor.exposure_s * 1e3:g} ms, "
            f"{len(self.renderer.catalog)} stars to Hp {magnitude_limit}, attitude profile {self.profile}")

    def start(self) -> None:
        """Fix the time origin and start the frame timer. Its ticks fall at now + n*period and
        are never early, so exposures end 1 ms before a tick: the frame is rendered right
        after its exposure, and a late tick only delays it."""
        now_ns = self.get_clock().now().nanoseconds
        delay_ticks = int(np.ceil(self.start_delay_s * 1e9 / self.period_ns))
        self.t0_ns = now_ns + delay_ticks * self.period_ns - 1_000_000
        if self.profile != "external":
            self.motion = motion_from_parameters(self.profile, self.initial_rotation, t0=self.t0_ns * 1e-9,
                                                 **self.motion_kwargs[self.profile])
        self.timer = self.create_timer(self.period_ns * 1e-9, self.on_timer)

    def on_external_attitude(self, msg: QuaternionStamped) -> None:
        self._external_sample(convert.stamp_to_ns(msg.header.stamp), 0, convert.quaternion_from_msg(msg))

    def on_external_rate(self, msg: Vector3Stamped) -> None:
        v = msg.vector
        self._external_sample(convert.stamp_to_ns(msg.header.stamp), 1, np.array([v.x, v.y, v.z]))

    def _external_sample(self, stamp_ns: int, slot: int, value: np.ndarray) -> None:
        """Pair attitude and rate by stamp, then append them to the sampled motion."""
        entry = self._external_pending.setdefault(stamp_ns, [None, None])
        entry[slot] = value
        if entry[0] is None or entry[1] is None:
            if len(self._external_pending) > 100:  # a partner that never came: drop the oldest
                self._external_pending.pop(min(self._external_pending))
                self.diag.count("external_samples_unpaired")
            return
        del self._external_pending[stamp_ns]
        t, q, rate = stamp_ns * 1e-9, entry[0], entry[1]
        try:
            if self.motion is None:
                self.motion = SampledMotion(np.array([t]), q[None], rate[None])
            else:
                self.motion.append(t, q, rate)
            self.diag.count("external_samples")
        except ValueError as exc:
            self.diag.count("external_samples_rejected")
            self.log.warn("external", f"rejected external truth sample at {t:.6f} s: {exc}")

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
        # Frame k's exposure ends at t0 + (k+1) period; its stamp is mid-exposure. Like camera
        # hardware, every exposure is delivered (late if the host was busy); only a backlog
        # beyond max_backlog_frames is skipped, counted and logged.
        now_ns = self.get_clock().now().nanoseconds
        due = (now_ns - self.t0_ns) // self.period_ns  # frames whose exposure has ended
        if self.max_frames:
            due = min(due, self.max_frames)
        backlog = int(due - self.frame_index)
        if backlog > self.max_backlog_frames:
            skipped = backlog - self.max_backlog_frames
            self.diag.count("frames_skipped_overrun", skipped)
            self.get_logger().warning(f"rendering is {backlog} frames behind the {self.rate_hz:g} Hz schedule: "
                                      f"skipped {skipped} frame(s)")
            self.frame_index += skipped
        while self.frame_index < due:
            self.render_and_publish()

    def render_and_publish(self) -> None:
        k = self.frame_index
        stamp_ns = self.t0_ns + (k + 1) * self.period_ns - int(round(self.sensor.exposure_s * 0.5e9))
        started = time.perf_counter()
        try:
            if self.motion is None:
                raise ValueError("no external truth received yet")
            frame = self.renderer.render(self.motion, stamp_ns * 1e-9, frame_seed(self.seed, k))
        except ValueError as exc:  # external truth does not cover this exposure
            self.frame_index += 1
            self.diag.count("frames_skipped_no_attitude")
            self.diag.set(DiagnosticStatus.WARN, f"frame skipped: {exc}")
            self.log.warn("no_attitude", f"frame {k} skipped: {exc}")
            return
        if k in self.blank_frames:  # occulted field: background and noise only, no objects
            frame = self._blank(frame, k)
            self.diag.count("frames_blanked")
        truth = frame.truth
        rendered = time.perf_counter()
        self.pub_image.publish(convert.array_to_image(frame.image, stamp_ns, self.frame_id))
        self.diag.time("image_age", (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9)
        self.pub_info.publish(convert.camera_to_info(self.camera, stamp_ns, self.frame_id))
        self.pub_truth.publish(convert.quaternion_msg(matrix_to_quaternion(truth.rotation), stamp_ns))
        self.pub_truth_rate.publish(convert.vector3_msg(truth.body_rate, stamp_ns, self.frame_id))
        objects = np.zeros(truth.hip.size, convert.TRUTH_OBJECT_DTYPE)
        objects["hip_id"], objects["pixel_x"], objects["pixel_y"] = truth.hip, truth.x, truth.y
        objects["electrons"], objects["kind"] = truth.electrons, truth.kind
        self.pub_truth_objects.publish(convert.records_to_cloud(objects, convert.TRUTH_OBJECT_FIELDS, stamp_ns, self.frame_id))
        self.frame_index += 1
        self.diag.time("render", rendered - started)
        self.diag.time("publish", time.perf_counter() - rendered)
        self.diag.count("frames_published")
        self.diag.set(DiagnosticStatus.OK, "publishing", objects_in_view=truth.hip.size, smear_substeps=frame.substeps)


    def _blank(self, frame, k: int):
        """The frame with the field occulted: its median level plus read noise, nothing in view."""
        rng = np.random.default_rng(frame_seed(self.seed, k) ^ 0x5EED)
        level = float(np.median(frame.image))
        noise = self.sensor.read_noise_e / self.sensor.gain_e_per_adu
        image = np.clip(np.round(rng.normal(level, noise, frame.image.shape)), 0, np.iinfo(frame.image.dtype).max)
        truth = frame.truth
        none = np.zeros(0, bool)
        empty = replace(truth, kind=truth.kind[none], hip=truth.hip[none], x=truth.x[none], y=truth.y[none],
                        electrons=truth.electrons[none], extent_px=truth.extent_px[none])
        return replace(frame, image=image.astype(frame.image.dtype), truth=empty)


def main(argv: list[str] | None = None) -> None:
    sys.exit(run_node(CameraSimulatorNode, argv))


if __name__ == "__main__":
    main()
