"""camera_simulator: renders Hipparcos star frames and publishes them with the truth used.

Publishes image_raw (mono16), camera_info, truth/attitude, truth/angular_velocity and
truth/objects, all with the frame's mid-exposure stamp. See msg_docs/.

Timing, like a camera: frame k is delivered when its exposure has ended (the last row's, under
a rolling shutter), the frame transfer is done and `sensor.readout_s` has passed. Motion known
in advance (every profile but `external`) lets the node render a frame while the previous one
is out, so the render costs no latency; external truth arrives over topics, so those frames
are rendered at their delivery time.
"""
from __future__ import annotations

import sys
import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from ..models.attitude import matrix_to_quaternion, quaternion_to_matrix, radec_roll_to_matrix
from ..models.camera import CameraModel
from ..models.catalog import julian_year_from_unix, load_hipparcos
from ..sim.motion import SampledMotion, motion_from_parameters
from ..sim.render import FalseObjectModel, SensorModel, StarFieldRenderer, frame_seed
from . import convert
from .diagnostics import Diagnostics
from .node_process import run_node
from .parameters import declare, guard_parameter_changes
from .qos import IMAGE_QOS, RESULT_QOS
from .throttled_log import ThrottledLog


@dataclass
class PreparedFrame:
    """A rendered frame's messages, ready to publish at its delivery time (node clock, ns)."""

    index: int
    stamp_ns: int
    image: Image
    info: CameraInfo
    truth: QuaternionStamped
    truth_rate: Vector3Stamped
    truth_objects: PointCloud2
    objects_in_view: int
    substeps: int
    ready_ns: int


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
        readout_s = p("sensor.readout_s", 0.0,
                      "readout: a frame is published this long after its exposure (the last row's, under a rolling "
                      "shutter) and frame transfer ended; 0 = at once [s]", 0.0, 10.0)
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
        # Frame k's middle row ends its exposure at t0 + (k+1) period; the last row ends
        # last_row_ns later, and the frame is delivered delivery_offset_ns after the middle row.
        self.last_row_ns = int(round(abs(sensor.rolling_shutter_row_time_s) * (height - 1) / 2 * 1e9))
        self.delivery_offset_ns = self.last_row_ns + int(round((sensor.frame_transfer_time_s + readout_s) * 1e9))
        self.render_ahead = self.profile != "external"  # external truth may not cover an exposure yet
        self.pending: PreparedFrame | None = None  # the next frame, rendered ahead of its delivery
        self.render_times = deque(maxlen=20)  # recent render durations [s]: how early to start the next
        self._frame_timer = None  # one-shot: start the next render, or an early tick's retry
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
            f"frames delivered {self.delivery_offset_ns * 1e-6:g} ms after the exposure's nominal end "
            f"({'rendered ahead' if self.render_ahead else 'rendered at delivery'}), "
            f"{len(self.renderer.catalog)} stars to Hp {magnitude_limit}, attitude profile {self.profile}")

    def start(self) -> None:
        """Fix the time origin and start the frame timer. Its ticks fall at now + n*period and
        are never early; frame k is delivered on a tick, t0 + (k+1) period + delivery_offset_ns,
        and t0 is at least start_delay_s after now."""
        now_ns = self.get_clock().now().nanoseconds
        delay_ticks = int(np.ceil((self.start_delay_s * 1e9 + self.delivery_offset_ns) / self.period_ns))
        self.t0_ns = now_ns + delay_ticks * self.period_ns - self.delivery_offset_ns
        if self.profile != "external":
            self.motion = motion_from_parameters(self.profile, self.initial_rotation, t0=self.t0_ns * 1e-9,
                                                 **self.motion_kwargs[self.profile])
        self.timer = self.create_timer(self.period_ns * 1e-9, self.on_timer)
        self.timer.timer_period_ns = self.period_ns  # exact: seconds -> ns may round down, and ticks drift early
        if self.render_ahead:  # frame 0 is rendered a period before its delivery, like every frame at first
            self.call_at(self.delivery_ns(0) - self.period_ns, now_ns)

    def delivery_ns(self, k: int) -> int:
        """When frame k may be published: its exposure and frame transfer ended, then the readout [ns]."""
        return self.t0_ns + (k + 1) * self.period_ns + self.delivery_offset_ns

    def exposure_end_ns(self, k: int) -> int:
        """When frame k's last row ended its exposure [ns]."""
        return self.t0_ns + (k + 1) * self.period_ns + self.last_row_ns

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
        # Like camera hardware, every frame is delivered (late if the host was busy); only a
        # backlog beyond max_backlog_frames is skipped, counted and logged.
        now_ns = self.get_clock().now().nanoseconds
        due = (now_ns - self.t0_ns - self.delivery_offset_ns) // self.period_ns  # frames deliverable now
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
            self.publish_next()
        if not self.render_ahead or (self.max_frames and self.frame_index >= self.max_frames):
            return
        # Render the next frame ahead, just in time for its delivery: late enough to leave the
        # CPU to the nodes processing the previous frame, early enough to be ready.
        k = self.frame_index
        now_ns = self.get_clock().now().nanoseconds
        if self.pending is None or self.pending.index != k:
            start_ns = self.delivery_ns(k) - self.render_lead_ns()
            if start_ns > now_ns:
                self.call_at(start_ns, now_ns)
                return
            self.pending = self.prepare(k)
            if self.pending is None:  # could not be rendered (counted): it will not be published
                self.frame_index += 1
                return
            now_ns = self.get_clock().now().nanoseconds
        wait_ns = self.delivery_ns(k) - now_ns
        if wait_ns <= 0:  # rendered late: out at once (the periodic tick it missed comes right back for the next)
            self.publish_next()
        elif wait_ns < 1_000_000:  # an early tick (not expected): a tick of its own
            self.call_at(self.delivery_ns(k), now_ns)

    def render_lead_ns(self) -> int:
        """How long before its delivery a frame's render starts [ns]: 1.5 x the slowest of the
        recent renders + 3 ms, at most a period (i.e. as soon as the previous frame is out)."""
        if not self.render_times:
            return self.period_ns
        return min(self.period_ns, int((1.5 * max(self.render_times) + 0.003) * 1e9))

    def call_at(self, at_ns: int, now_ns: int) -> None:
        """on_timer() once more at at_ns (node clock), in place of any such call pending."""
        self.cancel_call()
        self._frame_timer = self.create_timer((at_ns - now_ns + 1000) * 1e-9, self.on_call)

    def cancel_call(self) -> None:
        if self._frame_timer is not None:
            self._frame_timer.cancel()
            self.destroy_timer(self._frame_timer)
            self._frame_timer = None

    def on_call(self) -> None:
        self.cancel_call()
        self.on_timer()

    def publish_next(self) -> None:
        """Publish frame frame_index (rendered ahead, or now) and move on; the caller knows it is due."""
        k = self.frame_index
        frame = self.pending if self.pending is not None and self.pending.index == k else self.prepare(k)
        self.pending = None
        self.frame_index += 1
        if frame is not None:
            self.publish(frame)

    def prepare(self, k: int) -> "PreparedFrame | None":
        """Render frame k and build its messages; None when it cannot be rendered (counted)."""
        stamp_ns = self.t0_ns + (k + 1) * self.period_ns - int(round(self.sensor.exposure_s * 0.5e9))
        started = time.perf_counter()
        try:
            if self.motion is None:
                raise ValueError("no external truth received yet")
            frame = self.renderer.render(self.motion, stamp_ns * 1e-9, frame_seed(self.seed, k))
        except ValueError as exc:  # external truth does not cover this exposure
            self.diag.count("frames_skipped_no_attitude")
            self.diag.set(DiagnosticStatus.WARN, f"frame skipped: {exc}")
            self.log.warn("no_attitude", f"frame {k} skipped: {exc}")
            return None
        if k in self.blank_frames:  # occulted field: background and noise only, no objects
            frame = self._blank(frame, k)
            self.diag.count("frames_blanked")
        rendered = time.perf_counter()
        self.render_times.append(rendered - started)
        truth = frame.truth
        objects = np.zeros(truth.hip.size, convert.TRUTH_OBJECT_DTYPE)
        objects["hip_id"], objects["pixel_x"], objects["pixel_y"] = truth.hip, truth.x, truth.y
        objects["electrons"], objects["kind"] = truth.electrons, truth.kind
        prepared = PreparedFrame(
            index=k, stamp_ns=stamp_ns, objects_in_view=int(truth.hip.size), substeps=frame.substeps,
            image=convert.array_to_image(frame.image, stamp_ns, self.frame_id),
            info=convert.camera_to_info(self.camera, stamp_ns, self.frame_id),
            truth=convert.quaternion_msg(matrix_to_quaternion(truth.rotation), stamp_ns),
            truth_rate=convert.vector3_msg(truth.body_rate, stamp_ns, self.frame_id),
            truth_objects=convert.records_to_cloud(objects, convert.TRUTH_OBJECT_FIELDS, stamp_ns, self.frame_id),
            ready_ns=self.get_clock().now().nanoseconds)
        self.diag.time("render", rendered - started)
        self.diag.time("convert", time.perf_counter() - rendered)
        return prepared

    def publish(self, frame: "PreparedFrame") -> None:
        started = time.perf_counter()
        self.pub_image.publish(frame.image)
        now_ns = self.get_clock().now().nanoseconds
        self.diag.time("image_age", (now_ns - frame.stamp_ns) * 1e-9)
        self.diag.time("delivery_delay", (now_ns - self.exposure_end_ns(frame.index)) * 1e-9)
        if self.render_ahead and frame.ready_ns > self.delivery_ns(frame.index):
            self.diag.count("frames_rendered_late")
        self.pub_info.publish(frame.info)
        self.pub_truth.publish(frame.truth)
        self.pub_truth_rate.publish(frame.truth_rate)
        self.pub_truth_objects.publish(frame.truth_objects)
        self.diag.time("publish", time.perf_counter() - started)
        self.diag.count("frames_published")
        self.diag.set(DiagnosticStatus.OK, "publishing", objects_in_view=frame.objects_in_view,
                      smear_substeps=frame.substeps)

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
