# SPDX-License-Identifier: Apache-2.0
"""
identifier: star identification (lost-in-space, then tracking) + attitude and body rate.

Needs the camera model from `camera_info`. Publishes attitude, attitude_with_covariance and
matched_stars with the spots' stamp, only for verified solutions, and angular_velocity once two
solutions are in the rate window; otherwise it publishes nothing, logs why and reports it on
/diagnostics (mode, counters).

The subscription callback only checks and decodes a spots message; a worker thread identifies
it. At most `queue_depth` frames wait (default 3; 1: the worker always takes the newest); the oldest
waiting one is dropped when one more arrives, counted (`frames_dropped_overload`) and logged
(newest frame wins). The tracker works from stamps, so a skipped frame only lengthens its
prediction step.

A lost-in-space solve runs in a second thread. When it ends within `inline_wait_s` its frame is
published as usual; when it takes longer, the frames arriving meanwhile are bridged by
frame-to-frame rotations (Tracker.bridge, seed 004) and the newest one is published, verified,
when the solve ends (delay compensation).

Bad input never stops the node: a malformed spots message is skipped, spots with non-finite
or implausible values are dropped from their frame, and frames that would corrupt the track's
time line (unstamped, stamped in the future, out of order) are dropped; each is counted on
/diagnostics and logged (throttled). A backwards jump beyond `stamp.reset_after_s` restarts
the track instead (a replay or simulation restarted). See docs/RELIABILITY.md.

A managed node (managed_node.py, msg_docs/services.md): `configure` loads the pattern
database and compiles the kernels, `activate` starts identifying, `deactivate` keeps database
and track (spots arriving meanwhile are counted, `frames_ignored_inactive`), `cleanup`
releases them. `~/reset` (std_srvs/Trigger) drops the track: the next frame is identified
lost-in-space.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped, TwistWithCovarianceStamped, Vector3Stamped
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_srvs.srv import Trigger

from ..models.attitude import ARCSEC
from ..models.camera import CameraModel
from ..models.calibration_kernel import warm_up as calibration_warm_up
from ..models.online_calibration import OnlineCalibration, OnlineCalibrationConfig
from ..identify import DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
from ..track.tracking import MODE_LOST, TrackedFrame, Tracker, TrackingConfig
from . import convert
from .camera_info_input import CameraInfoInput
from .diagnostics import Rejections
from .frame_queue import NewestFrame
from .in_orbit import InOrbit
from .managed_node import ManagedNode
from .node_process import exit_node_process, run_node
from .output_flush import flush_publishers
from ..parameter_spec import field_values
from .identifier_parameters import (CALIBRATION_PARAMETERS, DATABASE_PARAMETERS, IDENTIFIER_PARAMETERS,
                                    IDENTIFY_PARAMETERS, TRACKING_PARAMETERS, epoch_from_clock)
from .parameters import declare_parameters, guard_parameter_changes
from .qos import IMAGE_QOS, RESULT_QOS, SPOTS_QOS, overridable
from .smear_aid_input import SmearAidInput
from ..track.stamp_order import STAMP_OK, STAMP_RESET, StampOrder
from .throttled_log import ThrottledLog

# Tunable while running (`ros2 param set`, the specs marked dynamic); the rest is fixed at
# startup (database, algorithm).
RUNTIME_PARAMETERS = {spec.name for spec in IDENTIFIER_PARAMETERS if spec.dynamic}
# The reliable outputs (topic -> attribute), flushed before they go (output_flush.py).
OUTPUT_PUBLISHERS = {"attitude": "pub_attitude", "attitude_with_covariance": "pub_pose", "matched_stars": "pub_matches",
                     "angular_velocity": "pub_rate", "angular_velocity_with_covariance": "pub_rate_cov",
                     "angular_acceleration": "pub_accel"}


@dataclass
class SpotsFrame:
    """A checked, decoded spots message waiting for the worker."""

    stamp_ns: int
    spots: object  # Spots
    camera: CameraModel
    sensor_frame: str
    received: float  # time.perf_counter() at the subscription callback [s]
    time_reset: bool  # this frame (or one it replaced) restarted time: reset the track first


def keep_time_reset(dropped: SpotsFrame, following: SpotsFrame) -> SpotsFrame:
    """Carry a dropped frame's time reset over to the frame after it."""
    following.time_reset = following.time_reset or dropped.time_reset
    return following


class IdentifierNode(ManagedNode):
    def __init__(self) -> None:
        super().__init__("identifier")
        values = declare_parameters(self, IDENTIFIER_PARAMETERS)  # identifier_parameters.py
        algorithm = values["algorithm"]
        self.frame_id = values["frame_id"]
        now_ns = self.get_clock().now().nanoseconds
        epoch = epoch_from_clock(values["database.epoch_jyear"], now_ns * 1e-9)
        db_config = DatabaseConfig(**{**field_values(DATABASE_PARAMETERS, values), "epoch_jyear": epoch},
                                   max_pair_angle_rad=np.radians(values["database.max_pair_angle_deg"]))
        self.config = IdentifyConfig(**field_values(IDENTIFY_PARAMETERS, values))
        self.tracking_enabled = values["tracking.enabled"]
        self.tracking_config = tracking_config = TrackingConfig(**field_values(TRACKING_PARAMETERS, values),
                                                                false_positive_bound=self.config.false_positive_bound)
        calibration_enabled = values["calibration.enabled"]
        online_config = OnlineCalibrationConfig(**field_values(CALIBRATION_PARAMETERS, values))
        self.online_calibration = OnlineCalibration(online_config) if calibration_enabled else None
        self.queue_depth = values["queue_depth"]
        self.inline_wait_s = values["inline_wait_s"]
        self.stamps = StampOrder(lambda: self.get_clock().now().nanoseconds, values["stamp.max_future_s"],
                                 values["stamp.reset_after_s"])
        self.autostart = values["autostart"]

        self.algorithm, self.db_config, self.tracking_config = algorithm, db_config, tracking_config
        self.database = self.identifier = self.tracker = None  # made by configure, released by cleanup
        self.frames = self._worker = None
        self.diag = self.start_diagnostics()
        self.diag.value("algorithm", algorithm)
        self.diag.value("mode", MODE_LOST)
        # Tracker state: the frame worker vs the end of a lost-in-space solve (which finishes in
        # the solve's thread, or inline in the frame worker's: reentrant) vs ~/reset.
        self._lock = threading.RLock()
        self._acquisition = None  # (future, stamp_ns, spots, camera, frame_id, received) of a running solve
        # run_node's shutdown watchdog waits this much longer: a solve running at shutdown ends
        # within its budget (the frame in progress too, up to twice the budget).
        self.shutdown_extra_s = 2.0 * self.config.max_time_s
        self.log = ThrottledLog(self)
        self.reject = Rejections(self.diag, self.log)
        self.in_orbit = InOrbit(self, values, self.diag, self.reject)  # observer, aberration, status (in_orbit.py)
        self.sensor_frame = ""  # the newest spots' frame_id: the status messages' frame
        guard_parameter_changes(self, self.apply_parameters, self.diag, self.log)
        self.camera_info = CameraInfoInput(self, self.diag, self.log, check=self.fov_problem)
        self.smear_aid = SmearAidInput(self.reject)  # what the centroider measured each frame with (smear_aid_input.py)
        self.srv_reset = self.create_service(Trigger, "~/reset", self.on_reset)

    def configure(self) -> None:
        """
        Load (or build) the database, make the identifier and tracker, create topics and workers.

        In order: the pattern database, the identifier and the tracker, compiling their kernels,
        then the topics and the worker threads.
        """
        started = time.perf_counter()
        self.database = load_or_build_database(self.db_config)
        self.identifier = make_identifier(self.algorithm, self.database, self.config)
        self.tracker = Tracker(self.identifier, self.tracking_config)
        # Compiled kernels: ~50 s the first time, then loaded from numba's cache.
        self.tracker.warm_up(CameraModel.from_fov(1024, 1024, np.radians(15.0)))
        if self.online_calibration is not None:
            calibration_warm_up()  # the online refinement's kernel, not at its first estimate
        self.diag.count("database_loads")
        self.get_logger().info(
            f"algorithm {self.algorithm}: {self.database.star_count} guide stars to Hp "
            f"{self.db_config.magnitude_limit} at epoch {self.db_config.epoch_jyear:g}, "
            f"{self.database.pair_a.size} pairs, loaded in "
            f"{time.perf_counter() - started:.2f} s")

        publisher = self.create_lifecycle_publisher
        self.pub_attitude = publisher(QuaternionStamped, "attitude", **overridable(RESULT_QOS))
        self.pub_pose = publisher(PoseWithCovarianceStamped, "attitude_with_covariance", **overridable(RESULT_QOS))
        self.pub_matches = publisher(PointCloud2, "matched_stars", **overridable(RESULT_QOS))
        self.pub_rate = publisher(Vector3Stamped, "angular_velocity", **overridable(RESULT_QOS))
        self.pub_accel = publisher(Vector3Stamped, "angular_acceleration", **overridable(RESULT_QOS))
        self.pub_rate_cov = publisher(TwistWithCovarianceStamped, "angular_velocity_with_covariance",
                                      **overridable(RESULT_QOS))
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lost_in_space")
        self.frames = NewestFrame(self, self.identify_frame, self.diag, self.log, self.queue_depth,
                                  merge=keep_time_reset)
        self.sub_info = self.create_subscription(CameraInfo, "camera_info", self.camera_info.update,
                                                 **overridable(IMAGE_QOS))
        # Before the spots: a frame's aid is published first and should be read first.
        self.sub_aid_rate = self.create_subscription(Vector3Stamped, "smear_aid/angular_velocity",
                                                     self.smear_aid.on_rate, **overridable(SPOTS_QOS))
        self.sub_aid_path = self.create_subscription(PoseWithCovarianceStamped,
                                                     "smear_aid/exposure_path_offset", self.smear_aid.on_path_offset,
                                                     **overridable(SPOTS_QOS))
        self.sub_aid_accel = self.create_subscription(Vector3Stamped, "smear_aid/angular_acceleration",
                                                      self.smear_aid.on_acceleration, **overridable(SPOTS_QOS))
        self.sub_spots = self.create_subscription(PointCloud2, "spots", self.on_spots, **overridable(SPOTS_QOS))
        self.in_orbit.configure()

    def release(self) -> None:
        """
        Undo configure: stop the workers, remove the topics, drop the track and the database.

        Also drop the camera model; the next configure loads the database again.
        """
        if self.frames is not None:
            self.frames.stop()
            self.frames = None
        with self._lock:
            self._acquisition = None  # a solve still running is ignored
        if self._worker is not None:
            self._worker.shutdown(wait=True, cancel_futures=True)
            self._worker = None
        for name in ("sub_info", "sub_aid_rate", "sub_aid_accel", "sub_spots"):
            if getattr(self, name, None) is not None:
                self.destroy_subscription(getattr(self, name))
                setattr(self, name, None)
        self.in_orbit.release()
        flush_publishers(self, {topic: getattr(self, name, None) for topic, name in OUTPUT_PUBLISHERS.items()})
        for name in OUTPUT_PUBLISHERS.values():
            if getattr(self, name, None) is not None:
                self.destroy_lifecycle_publisher(getattr(self, name))
                setattr(self, name, None)
        self.camera_info = CameraInfoInput(self, self.diag, self.log, check=self.fov_problem)
        self.smear_aid.clear()
        with self._lock:
            self.database = self.identifier = self.tracker = None
        self.diag.value("mode", MODE_LOST)

    def on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """
        ~/reset: drop the track (and any lost-in-space solve in progress).

        The next frame is identified lost-in-space.
        """
        with self._lock:
            if self.tracker is None:
                response.success = False
                response.message = f"nothing to reset: the identifier is {self.lifecycle_state} (not configured)"
                self.diag.count("resets_refused")
                return response
            self.tracker.reset()
            self._acquisition = None  # a solve still running is ignored
        self.diag.count("resets")
        self.diag.value("mode", MODE_LOST)
        response.success = True
        response.message = "tracking dropped: the next frame is identified lost-in-space"
        self.get_logger().info(f"~/reset: {response.message}")
        return response

    def fov_problem(self, camera) -> str | None:
        """Why the pattern database cannot serve this camera, or None."""
        diagonal = 2 * camera.half_diagonal_fov_rad
        limit = self.database.config.max_pair_angle_rad
        if diagonal > limit:
            return (f"camera diagonal FOV {np.degrees(diagonal):.2f} deg exceeds database.max_pair_angle_deg "
                    f"{np.degrees(limit):.2f}")
        return None

    def apply_parameters(self, changes: dict) -> str | None:
        """
        Runtime parameter changes (see parameters.guard_parameter_changes).

        The new identification and tracking configurations are built (checked) first, then
        applied together between two frames; a lost-in-space solve running reads them from
        its next step on.
        """
        identify = {spec.field: changes[spec.name] for spec in IDENTIFY_PARAMETERS if spec.name in changes}
        tracking = {spec.field: changes[spec.name] for spec in TRACKING_PARAMETERS if spec.name in changes}
        config = replace(self.config, **identify)
        tracking_config = replace(self.tracking_config, **tracking, false_positive_bound=config.false_positive_bound)
        with self._lock:
            self.config, self.tracking_config = config, tracking_config
            if getattr(self, "identifier", None) is not None:  # built with the database
                self.identifier.config = config
                self.tracker.config = tracking_config
            self.inline_wait_s = changes.get("inline_wait_s", self.inline_wait_s)
            self.tracking_enabled = changes.get("tracking.enabled", self.tracking_enabled)
            self.stamps.max_future_s = changes.get("stamp.max_future_s", self.stamps.max_future_s)
            self.stamps.reset_after_s = changes.get("stamp.reset_after_s", self.stamps.reset_after_s)
            self.shutdown_extra_s = 2.0 * config.max_time_s
        return None

    def on_spots(self, msg: PointCloud2) -> None:
        """Executor thread: count, check the stamp and the message, decode; the worker identifies (identify_frame())."""
        received = time.perf_counter()
        if not self.active:  # inactive: configured, not processing
            self.diag.count("frames_ignored_inactive")
            return
        self.diag.count("frames_received")
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        self.diag.time("input_age", (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9)
        verdict = self.stamps.classify(stamp_ns)
        if verdict not in (STAMP_OK, STAMP_RESET):  # the tracker's prediction and rate need increasing time
            self.reject(f"frames_{verdict}", self.stamps.describe(verdict, stamp_ns) + "; frame dropped")
            return
        camera = self.camera_info.camera
        if camera is None:
            self.diag.count("frames_without_camera_info")
            self.diag.set(DiagnosticStatus.WARN, "waiting for camera_info")
            self.log.warn("no_info", "spots received before any valid camera_info; frame skipped")
            return
        if self.online_calibration is not None:
            camera = self.online_calibration.camera_for(camera)  # the nominal one until an estimate applies
        try:
            spots = convert.cloud_to_spots(msg, camera.width, camera.height)
        except ValueError as exc:
            self.diag.count("frames_rejected")
            self.diag.set(DiagnosticStatus.WARN, f"rejected spots: {exc}")
            self.log.warn("bad_spots", f"rejected spots message: {exc}")
            return
        spots, dropped = convert.drop_invalid_spots(spots)
        if dropped:
            self.reject("spots_dropped_invalid", f"dropped {dropped} spot(s) with non-finite or implausible values "
                        f"(frame {stamp_ns * 1e-9:.6f}); {len(spots)} kept", dropped)
        if verdict == STAMP_RESET:
            self.reject("time_resets", self.stamps.describe(verdict, stamp_ns) + "; track restarted")
        self.diag.time("decode", time.perf_counter() - received)
        self.frames.put(SpotsFrame(stamp_ns, spots, camera, msg.header.frame_id, received, verdict == STAMP_RESET),
                        stamp_ns)

    def identify_frame(self, frame: SpotsFrame) -> None:
        """Worker thread: track or identify the newest frame and publish its attitude."""
        applied = self.smear_aid.applied_for(frame.stamp_ns)
        if applied is not None:
            frame.spots = replace(frame.spots, applied_motion=applied)
            self.diag.count("frames_with_smear_aid")
        elif self.smear_aid.received:  # the centroider states every frame's: this one's was lost
            self.diag.count("frames_without_smear_aid")
        with self._lock:
            self.sensor_frame = frame.sensor_frame
            if frame.time_reset:
                self.tracker.reset()
                self._acquisition = None  # a solve still running for the old time line is ignored
            if len(frame.spots) == 0:  # nothing to identify (an occulted or blank frame)
                self.not_identified(frame.stamp_ns, "too_few_spots", "no spots", frame.spots)
                return
            try:
                self.process(frame.stamp_ns, frame.spots, frame.camera, frame.sensor_frame, frame.received)
            except Exception as exc:  # a defect, not bad input: reported, and the next frame is processed
                self.internal_error(frame.stamp_ns, exc)

    def process(self, stamp_ns: int, spots, camera, sensor_frame: str, received: float) -> None:
        """Track, or start (or bridge during) a lost-in-space solve. Holds the lock."""
        if self._acquisition is not None:
            if not self._acquisition[0].done():
                if self.tracker.bridge(stamp_ns, spots, camera):
                    self.diag.count("frames_bridged")
                else:
                    self.diag.count("frames_not_bridged")
                    self.log.warn("bridge", "a frame during a lost-in-space solve shares too few stars with "
                                  "the previous one; it is not identified")
                return
            self._finish_acquisition()
        if self.tracking_enabled:
            prediction = self.tracker.predict(stamp_ns)
            if prediction is not None:
                tracked = self.tracker.accept_tracked(stamp_ns, spots, camera, prediction)
                if tracked.solved:
                    self.publish(tracked, spots, camera, sensor_frame, received)
                    return
                self.diag.count("tracking_failed")
        else:
            self.tracker.reset()
        self.tracker.begin_acquisition(stamp_ns, spots, camera)
        future = self._worker.submit(self.identifier.identify, spots, camera)
        self._acquisition = (future, stamp_ns, spots, camera, sensor_frame, received)
        try:
            future.result(timeout=self.inline_wait_s)
        except TimeoutError:
            # Still running: it finishes in its own thread when done, unless the next frame sees it first.
            future.add_done_callback(self.on_solve_done)
            return
        self._finish_acquisition()

    def on_solve_done(self, future) -> None:
        """Handle the end of a solve that outlived inline_wait_s (runs in the solve's thread)."""
        with self._lock:
            if self._acquisition is None or self._acquisition[0] is not future:
                return  # already finished by a frame, or dropped by a time reset
            stamp_ns = self._acquisition[1]
            try:
                self._finish_acquisition()
            except Exception as exc:  # a defect: reported, the node keeps running
                if self.context.ok():
                    self.internal_error(stamp_ns, exc)

    def _finish_acquisition(self) -> None:
        future, stamp_ns, spots, camera, sensor_frame, received = self._acquisition
        self._acquisition = None
        try:
            result = future.result()
        except Exception as exc:  # identify() failed: reported; the next frame starts a new solve
            self.tracker.reset()
            self.internal_error(stamp_ns, exc)
            return
        self.diag.value("last_identify_ms", f"{result.elapsed_s * 1e3:.2f}")
        if not result.solved:
            self.tracker.complete_acquisition(result)
            self.not_identified(stamp_ns, result.status, result.reason, spots)
            return
        newest_spots = self.tracker.pending_spots()
        tracked = self.tracker.complete_acquisition(result)
        if tracked is None:
            self.diag.count("bridge_not_verified")
            self.diag.value("mode", MODE_LOST)
            self.log.warn("bridge_failed", "lost-in-space solved an older frame but the bridged attitude was "
                          "not verified on the newest frame")
            return
        self.publish(tracked, newest_spots if tracked.bridged_frames else spots, camera, sensor_frame, received)

    def not_identified(self, stamp_ns: int, status: str, reason: str, spots) -> None:
        self.diag.count(f"not_identified_{status}")
        self.diag.value("mode", MODE_LOST)
        self.diag.set(DiagnosticStatus.WARN, f"not identified: {reason}", last_spot_count=len(spots))
        self.log.warn("unsolved", f"frame {stamp_ns * 1e-9:.3f} not identified: {reason}")
        self.publish_status(stamp_ns, None, None, 0)

    def publish_status(self, stamp_ns: int, mode: str | None, rotation: np.ndarray | None, stars: int,
                       state=None, on_exposure_path: bool = False) -> None:
        """
        Publish the frame's head status (in_orbit.py).

        mode None: no attitude (then the last one, propagated, tells what the head faced); state:
        the observer at the frame (looked up when None); on_exposure_path: the attitude was
        carried to mid-exposure by a gyro's path (TrackedFrame.on_exposure_path).
        """
        tracker, camera = self.tracker, self.camera_info.camera
        if state is None:
            state = self.in_orbit.observer_at(stamp_ns)
        if rotation is None and tracker is not None:
            rotation = tracker.attitude_guess(stamp_ns)
        rate = tracker.rate.angular_velocity if tracker is not None and tracker.rate is not None else None
        report = self.in_orbit.status(stamp_ns, mode, state, rotation, rate,
                                      camera.half_diagonal_fov_rad if camera is not None else None)
        self.in_orbit.publish_status(stamp_ns, report, self.sensor_frame or convert.OPTICAL_FRAME, stars,
                                     on_exposure_path)

    def internal_error(self, stamp_ns: int, exc: Exception) -> None:
        self.diag.count("frames_failed")
        self.diag.value("mode", MODE_LOST)
        self.diag.set(DiagnosticStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}")
        self.log.error("internal", f"frame {stamp_ns * 1e-9:.6f} failed: {type(exc).__name__}: {exc}")

    def publish(self, tracked: TrackedFrame, spots, camera: CameraModel, sensor_frame: str, received: float) -> None:
        result, stamp_ns = tracked.identification, tracked.stamp_ns
        state = self.in_orbit.observer_at(stamp_ns)
        solution = self.in_orbit.corrected(result, spots, camera, state)
        self.pub_attitude.publish(convert.quaternion_msg(solution.quaternion, stamp_ns, self.frame_id))
        self.pub_pose.publish(convert.pose_with_covariance_msg(solution, stamp_ns, self.frame_id))
        self.pub_matches.publish(convert.identification_to_cloud(result, spots, result.magnitude, stamp_ns,
                                                                 self.frame_id, self.camera_info.camera))
        if tracked.rate is not None:
            frame = sensor_frame or convert.OPTICAL_FRAME
            if tracked.rate.angular_acceleration is not None:  # before the rate: the centroider pairs them by stamp
                self.pub_accel.publish(convert.vector3_msg(tracked.rate.angular_acceleration, stamp_ns, frame))
            self.pub_rate.publish(convert.vector3_msg(tracked.rate.angular_velocity, stamp_ns, frame))
            self.pub_rate_cov.publish(convert.rate_with_covariance_msg(tracked.rate, frame))
            sigma_rate = np.degrees(tracked.rate.sigma)
            self.diag.value("last_rate_sigma_deg_s_xyz", f"{sigma_rate[0]:.4f},{sigma_rate[1]:.4f},{sigma_rate[2]:.4f}")
        if self.online_calibration is not None:
            self.refine_camera(spots, result)
        self.diag.count("frames_identified")
        self.diag.count(f"frames_{tracked.mode}")
        self.publish_status(stamp_ns, tracked.mode, solution.rotation, int(result.hip.size), state,
                            tracked.on_exposure_path)
        self.diag.value("mode", tracked.mode)
        latency_s = time.perf_counter() - received
        self.diag.time("processing", latency_s)
        latency_ms = latency_s * 1e3
        sigma = np.sqrt(np.diag(solution.covariance)) / ARCSEC
        self.diag.set(DiagnosticStatus.OK, "identified", last_stars_matched=result.hip.size,
                      last_deep_stars_matched=result.deep_count,
                      last_spot_count=len(spots), last_sigma_arcsec_xyz=f"{sigma[0]:.2f},{sigma[1]:.2f},{sigma[2]:.2f}",
                      last_false_positive_bound=f"{result.false_positive_probability:.1e}",
                      last_processing_ms=f"{latency_ms:.2f}", last_bridged_frames=tracked.bridged_frames,
                      last_gate_px="" if tracked.gate_px is None else f"{tracked.gate_px:.1f}")

    def refine_camera(self, spots, result) -> None:
        """
        Run the online calibration.

        Add a published frame's matches; after a fit report the estimate (and what is applied)
        on /diagnostics.
        """
        nominal = self.camera_info.camera
        if nominal is None:
            return
        estimate = self.online_calibration.add(spots, result, nominal)
        if estimate is None:
            return
        self.diag.count("calibration_fits")
        self.diag.value("calibration_focal_px", f"{estimate.value['f']:.3f}")
        self.diag.value("calibration_focal_sigma_px", f"{estimate.sigma['f']:.3g}")
        self.diag.value("calibration_k1", f"{estimate.value['k1']:.6g}" if "k1" in estimate.fitted else "")
        self.diag.value("calibration_k1_sigma", f"{estimate.sigma['k1']:.3g}" if "k1" in estimate.fitted else "")
        self.diag.value("calibration_residual_rms_px", f"{estimate.residual_rms_px:.3f}")
        self.diag.value("calibration_stars", estimate.stars)
        self.diag.value("calibration_applied", ",".join(self.online_calibration.applied) or "none")

    def destroy_node(self) -> None:
        self.release()
        super().destroy_node()


def main(argv: list[str] | None = None) -> None:
    exit_node_process(run_node(IdentifierNode, argv))


if __name__ == "__main__":
    main()
