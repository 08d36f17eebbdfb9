# SPDX-License-Identifier: Apache-2.0
"""
camera_simulator: renders Hipparcos star frames and publishes them with the truth used.

Publishes image_raw (mono16), camera_info, truth/attitude, truth/angular_velocity and
truth/objects, all with the frame's mid-exposure stamp. See msg_docs/.

Timing, like a camera: frame k is delivered when its exposure has ended (the last row's, under
a rolling shutter), the frame transfer is done and `sensor.readout_s` has passed. Motion known
in advance (every profile but `external`) lets the node render a frame while the previous one
is out, so the render costs no latency; external truth arrives over topics, so those frames
are rendered at their delivery time.

A managed node (managed_node.py): `configure` loads the catalog and creates the topics,
`activate` starts the exposures; `deactivate` stops them and a later `activate` resumes the
same time line (the frames of the inactive time are skipped and counted).
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from ..models.attitude import matrix_to_quaternion
from ..models.catalog import julian_year_from_unix, load_hipparcos
from ..sim.motion import SampledMotion
from ..sim.render import StarFieldRenderer, frame_seed
from . import convert
from ..parameter_spec import field_values
from .camera_simulator_orbit import orbit_setup_from
from .camera_simulator_parameters import (CAMERA_SIMULATOR_PARAMETERS, SENSOR_PARAMETERS, attitude_from, camera_from,
                                          false_objects_from, sensor_from, sky_from)
from .camera_simulator_world import CameraWorld
from .managed_node import ManagedNode
from .node_process import exit_node_process, run_node
from .output_flush import flush_publishers
from .parameters import declare_parameters, guard_parameter_changes
from .qos import IMAGE_QOS, RESULT_QOS, TRUTH_INPUT_QOS, overridable
from .throttled_log import ThrottledLog

# A catalog propagated this close to the first exposure's date is kept (proper motions of ~1"/yr
# move a star by < 3 mas a day); further, start() propagates it again.
CATALOG_EPOCH_TOLERANCE_JYEAR = 1.0 / 365.25


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
    truth_odometry: Odometry | None
    objects_in_view: int
    substeps: int
    ready_ns: int


class CameraSimulatorNode(ManagedNode):
    def __init__(self) -> None:
        super().__init__("camera_simulator")
        values = declare_parameters(self, CAMERA_SIMULATOR_PARAMETERS)  # camera_simulator_parameters.py
        self._read_output(values)
        self.camera, fov_x_deg = camera_from(values)
        self.sensor = sensor_from(values)
        readout_s = values["sensor.readout_s"]
        false_objects = false_objects_from(values)
        self.sky = sky = sky_from(values)
        attitude = attitude_from(values)
        self.profile, self.initial_rotation, self.motion_kwargs = attitude.profile, attitude.initial_rotation, \
            attitude.motion_kwargs
        self.t0_ns: int | None = None  # exposures start at t0 + period; set in start()
        self.sky, self.false_objects = sky, false_objects
        # The orbit, the head's mounting and the environment (checked at configure).
        self.world = CameraWorld(orbit_setup_from(values), self.profile)
        self._set_up_schedule(readout_s)
        blank = values["faults.blank_frames"]
        self.blank_frames = {int(k) for k in blank if int(k) >= 0}
        self.autostart = values["autostart"]

        self.fov_x_deg = fov_x_deg
        self.renderer = None  # made by configure, released by cleanup
        self.timer = self.waiting_timer = self._sync_timer = None
        self.diag = self.start_diagnostics()
        self.log = ThrottledLog(self)
        # Only the sensor settings are dynamic (apply_parameters); a change to a read-only one is refused.
        guard_parameter_changes(self, self.apply_parameters, self.diag, self.log)

    def configure(self) -> None:
        """Load the catalog and build the renderer, then create the topics."""
        sky, sensor = self.sky, self.sensor
        now_s = self.clock_s()
        self.world.configure(now_s)  # a bad orbit/mounting: refused here
        # The catalog's epoch: sky.epoch_jyear, else the clock's date now, made the first exposure's
        # by start() (a sim clock may not have ticked yet, or may run at another date).
        self.renderer = self._renderer(sky.epoch_jyear or julian_year_from_unix(now_s or time.time()))
        self._create_interfaces()
        self.get_logger().info(
            f"{self.camera.width}x{self.camera.height} px, FOV {self.fov_x_deg:.2f} deg, {self.rate_hz:g} Hz, "
            f"exposure {sensor.exposure_s * 1e3:g} ms, "
            f"frames delivered {self.delivery_offset_ns * 1e-6:g} ms after the exposure's nominal end "
            f"({'rendered ahead' if self.render_ahead else 'rendered at delivery'}), "
            f"{len(self.renderer.catalog)} stars to Hp {sky.magnitude_limit} at epoch "
            f"{self.renderer.catalog.epoch_jyear:.4f}, attitude profile {self.profile}"
            f"{self.world.describe()}")

    def clock_s(self) -> float | None:
        """Return the node's clock [s] (UNIX time), None while a sim clock (use_sim_time) has not ticked yet."""
        now_ns = self.get_clock().now().nanoseconds
        return now_ns * 1e-9 if now_ns > 0 else None

    def _renderer(self, epoch_jyear: float) -> StarFieldRenderer:
        """Return the renderer with the catalog propagated to epoch_jyear [Julian year]."""
        sky = self.sky
        return StarFieldRenderer(self.camera, self.sensor, load_hipparcos().at_epoch(epoch_jyear), sky.magnitude_limit,
                                 self.false_objects, sky.fixed_pattern_seed, sky.observer_velocity_m_s,
                                 environment_model=self.world.environment_model)

    def activate(self) -> None:
        """
        First activation: start the exposures (once subscribed, with wait_for_subscribers).

        Later ones resume the same time line: frames that fell in the inactive time are skipped.
        """
        if self.t0_ns is not None:
            self.resume()
        elif self.wait_for_subscribers:
            self.waiting_timer = self.create_timer(0.05, self.start_when_subscribed)
        else:
            self.start()

    def deactivate(self) -> None:
        """Stop the frame timers; nothing is rendered or published until activate."""
        for name in ("timer", "waiting_timer", "_sync_timer"):
            if getattr(self, name) is not None:
                self.destroy_timer(getattr(self, name))
                setattr(self, name, None)
        self.cancel_call()
        self.pending = None

    def destroy_node(self) -> None:
        """
        Flush the truth topics, then destroy the node.

        Reliable truth still unacknowledged when the process exits is lost, while its
        best-effort image has gone out: an attitude downstream without its truth
        (output_flush.flush_publishers: bounded, the outcome logged).
        """
        self._flush_truth()
        super().destroy_node()

    def _flush_truth(self) -> None:
        flush_publishers(self, {"truth/attitude": getattr(self, "pub_truth", None),
                                "truth/angular_velocity": getattr(self, "pub_truth_rate", None),
                                "truth/objects": getattr(self, "pub_truth_objects", None),
                                "truth/odometry": getattr(self, "pub_truth_odometry", None)})

    def release(self) -> None:
        """
        Undo configure: timers, topics (the truth flushed first), renderer and catalog.

        The next activation starts a new time line from frame 0.
        """
        self.deactivate()
        self._flush_truth()
        for name in ("pub_image", "pub_info", "pub_truth", "pub_truth_rate", "pub_truth_objects", "pub_truth_odometry"):
            if getattr(self, name, None) is not None:
                self.destroy_lifecycle_publisher(getattr(self, name))
                setattr(self, name, None)
        for name in ("sub_truth_attitude", "sub_truth_rate", "sub_truth_odometry"):
            if getattr(self, name, None) is not None:
                self.destroy_subscription(getattr(self, name))
                setattr(self, name, None)
        self.renderer = None
        self.world.release()
        self.t0_ns, self.frame_index = None, 0
        self.render_times.clear()

    def _read_output(self, values: dict) -> None:
        """Read what is published and when: rate, frame count, frame_id, start, backlog, noise seed."""
        self.rate_hz, self.max_frames, self.frame_id = values["rate_hz"], values["max_frames"], values["frame_id"]
        self.start_delay_s, self.max_backlog_frames = values["start_delay_s"], values["max_backlog_frames"]
        self.wait_for_subscribers, self.seed = values["wait_for_subscribers"], values["seed"]
        self.sync_exposures = values["sync_exposures"]

    def apply_parameters(self, changes: dict) -> str | None:
        """
        Runtime sensor changes (see parameters.guard_parameter_changes).

        The new SensorModel is built (checked) first; the renderer is rebuilt with it (the
        fixed pattern is drawn from the same seed: unchanged; ~0.2 s for 1024 x 1024 px, so a
        frame due meanwhile is delivered late, counted as frames_rendered_late) and a frame
        rendered ahead is dropped, so the next frame delivered is exposed with the new
        settings.
        """
        sensor = replace(self.sensor, **field_values(SENSOR_PARAMETERS, changes))
        if sensor.exposure_s * self.rate_hz > 1.0:
            return f"sensor.exposure_s={sensor.exposure_s} is longer than the frame period {1 / self.rate_hz} s"
        renderer = getattr(self, "renderer", None)
        if renderer is not None:  # (not yet built: it will be with self.sensor)
            self.renderer = StarFieldRenderer(self.camera, sensor, renderer.catalog, self.sky.magnitude_limit,
                                              renderer.false_objects, self.sky.fixed_pattern_seed,
                                              self.sky.observer_velocity_m_s, renderer.max_substep_px,
                                              environment_model=self.world.environment_model)
        self.sensor = sensor
        self.pending = None
        return None

    def _set_up_schedule(self, readout_s: float) -> None:
        """Set up the frame period, when frames are delivered, and the render-ahead state."""
        self.period_ns = int(round(1e9 / self.rate_hz))
        if self.sensor.exposure_s * 1e9 > self.period_ns:
            raise ValueError(f"sensor.exposure_s={self.sensor.exposure_s} is longer than the frame period "
                             f"{1 / self.rate_hz} s")
        # Frame k's middle row ends its exposure at t0 + (k+1) period; the last row ends
        # last_row_ns later, and the frame is delivered delivery_offset_ns after the middle row.
        self.last_row_ns = int(round(abs(self.sensor.rolling_shutter_row_time_s) * (self.camera.height - 1) / 2 * 1e9))
        self.delivery_offset_ns = self.last_row_ns + int(round((self.sensor.frame_transfer_time_s + readout_s) * 1e9))
        self.render_ahead = self.profile != "external"  # external truth may not cover an exposure yet
        self.pending: PreparedFrame | None = None  # the next frame, rendered ahead of its delivery
        self.render_times = deque(maxlen=20)  # recent render durations [s]: how early to start the next
        self._frame_timer = None  # one-shot: start the next render, or an early tick's retry
        self.frame_index = 0

    def _create_interfaces(self) -> None:
        """Create the publishers (lifecycle: silent unless active) and (external profile) the truth input."""
        publisher = self.create_lifecycle_publisher
        self.pub_image = publisher(Image, "image_raw", **overridable(IMAGE_QOS))
        self.pub_info = publisher(CameraInfo, "camera_info", **overridable(IMAGE_QOS))
        self.pub_truth = publisher(QuaternionStamped, "truth/attitude", **overridable(RESULT_QOS))
        self.pub_truth_rate = publisher(Vector3Stamped, "truth/angular_velocity", **overridable(RESULT_QOS))
        self.pub_truth_objects = publisher(PointCloud2, "truth/objects", **overridable(RESULT_QOS))
        self.pub_truth_odometry = publisher(Odometry, "truth/odometry", **overridable(RESULT_QOS)) \
            if self.world.orbiting else None
        if self.world.external_orbit:  # the spacecraft's state from a user's own propagator
            self.sub_truth_odometry = self.create_subscription(Odometry, "truth_in/odometry", self.on_external_odometry,
                                                               **overridable(TRUTH_INPUT_QOS))
        if self.profile == "external":
            # Truth from a dynamics simulator, on this node's clock (use_sim_time for sim time).
            # Taken in every configured state: it is the world's motion, needed when frames resume.
            self.motion = None
            self._external_pending: dict[int, list] = {}
            self.sub_truth_attitude = self.create_subscription(QuaternionStamped, "truth_in/attitude",
                                                               self.on_external_attitude,
                                                               **overridable(TRUTH_INPUT_QOS))
            self.sub_truth_rate = self.create_subscription(Vector3Stamped, "truth_in/angular_velocity",
                                                           self.on_external_rate, **overridable(TRUTH_INPUT_QOS))

    def start(self) -> None:
        """
        Fix the time origin and start the frame timer.

        Its ticks fall at now + n*period and are never early; frame k is delivered on a tick, t0
        + (k+1) period + delivery_offset_ns, and t0 is at least start_delay_s after now. With
        sync_exposures every stamp (mid-exposure) is a multiple of the period: the ticks start that much later.
        """
        now_ns = self.get_clock().now().nanoseconds
        delay_ticks = int(np.ceil((self.start_delay_s * 1e9 + self.delivery_offset_ns) / self.period_ns))
        self.t0_ns = now_ns + delay_ticks * self.period_ns - self.delivery_offset_ns
        # Synchronised: the stamps (mid-exposure, t0 + (k+1) period - exposure/2) on the period grid.
        half_exposure_ns = int(round(self.sensor.exposure_s * 0.5e9))
        shift_ns = (half_exposure_ns - self.t0_ns) % self.period_ns if self.sync_exposures else 0
        self.t0_ns += shift_ns
        epoch = julian_year_from_unix(self.t0_ns * 1e-9)
        if not self.sky.epoch_jyear and abs(epoch - self.renderer.catalog.epoch_jyear) > CATALOG_EPOCH_TOLERANCE_JYEAR:
            self.renderer = self._renderer(epoch)  # the stars' proper motions to the first exposure's date
            self.get_logger().info(f"catalog propagated to the first exposure's epoch {epoch:.4f}")
        if self.profile != "external":
            self.motion = self.world.body_motion(self.profile, self.initial_rotation, self.t0_ns * 1e-9,
                                                 self.motion_kwargs)
        if shift_ns:
            self._sync_timer = self.create_timer(shift_ns * 1e-9, self._start_synced)
        else:
            self._start_timer(now_ns)

    def _start_synced(self) -> None:
        """Start the periodic timer at the first tick on the synchronised grid (sync_exposures)."""
        self.destroy_timer(self._sync_timer)
        self._sync_timer = None
        self._start_timer(self.get_clock().now().nanoseconds)

    def resume(self) -> None:
        """
        Resume when activated again.

        The same t0 and motion (the attitude went on meanwhile); the frames due while inactive,
        or too soon to expose fully, are skipped (frames_skipped_inactive).
        """
        now_ns = self.get_clock().now().nanoseconds
        delivered = (now_ns - self.t0_ns - self.delivery_offset_ns) // self.period_ns  # frames due by now
        following = max(self.frame_index, int(delivered) + 1)
        self.diag.count("frames_skipped_inactive", following - self.frame_index)
        self.frame_index = following
        self._start_timer(now_ns)

    def _start_timer(self, now_ns: int) -> None:
        """Start the periodic frame timer, and the render-ahead of frame frame_index."""
        self.timer = self.create_timer(self.period_ns * 1e-9, self.on_timer)
        self.timer.timer_period_ns = self.period_ns  # exact: seconds -> ns may round down, and ticks drift early
        if self.render_ahead:  # the first frame is rendered a period before its delivery, like every frame at first
            self.call_at(self.delivery_ns(self.frame_index) - self.period_ns, now_ns)

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

    def on_external_odometry(self, msg: Odometry) -> None:
        """Keep the spacecraft's state from truth_in/odometry (GCRS position and velocity), counting bad ones."""
        try:
            self.world.add_state(msg)
            self.diag.count("external_states")
        except ValueError as exc:
            self.diag.count("external_states_rejected")
            self.log.warn("external_odometry", f"rejected truth_in/odometry: {exc}")

    def start_when_subscribed(self) -> None:
        publishers = (self.pub_image, self.pub_info, self.pub_truth)
        if all(pub.get_subscription_count() > 0 for pub in publishers):
            self.destroy_timer(self.waiting_timer)
            self.waiting_timer = None
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
        """
        How long before its delivery a frame's render starts [ns].

        1.5 x the slowest of the recent renders + 3 ms, at most a period (i.e. as soon as the
        previous frame is out).
        """
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
            environment, state = self.world.environment(stamp_ns)
            frame = self.renderer.render(self.world.head_motion(self.motion), stamp_ns * 1e-9, frame_seed(self.seed, k),
                                         environment=environment)
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
            truth_odometry=None if state is None else convert.odometry_msg(state[0], state[1], stamp_ns),
            ready_ns=self.get_clock().now().nanoseconds)
        if truth.environment is not None:
            self.diag.value("head_geometry", truth.environment.head.status.value)
            self.diag.count(f"frames_{truth.environment.head.status.value}")
        self.diag.time("render", rendered - started)
        self.diag.time("convert", time.perf_counter() - rendered)
        return prepared

    def publish(self, frame: "PreparedFrame") -> None:
        started = time.perf_counter()
        # The truth first: whoever has the image has been sent its truth (reliable; destroy_node
        # flushes it on exit), so no attitude downstream lacks the truth it was made from.
        self.pub_truth.publish(frame.truth)
        self.pub_truth_rate.publish(frame.truth_rate)
        self.pub_truth_objects.publish(frame.truth_objects)
        if frame.truth_odometry is not None and self.pub_truth_odometry is not None:
            self.pub_truth_odometry.publish(frame.truth_odometry)
        self.pub_image.publish(frame.image)
        now_ns = self.get_clock().now().nanoseconds
        self.diag.time("image_age", (now_ns - frame.stamp_ns) * 1e-9)
        self.diag.time("delivery_delay", (now_ns - self.exposure_end_ns(frame.index)) * 1e-9)
        if self.render_ahead and frame.ready_ns > self.delivery_ns(frame.index):
            self.diag.count("frames_rendered_late")
        self.pub_info.publish(frame.info)
        self.diag.time("publish", time.perf_counter() - started)
        self.diag.count("frames_published")
        self.diag.set(DiagnosticStatus.OK, "publishing", objects_in_view=frame.objects_in_view,
                      smear_substeps=frame.substeps)

    def _blank(self, frame, k: int):
        """Return the frame with the field occulted: its median level plus read noise, nothing in view."""
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
    exit_node_process(run_node(CameraSimulatorNode, argv))


if __name__ == "__main__":
    main()
