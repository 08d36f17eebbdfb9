# SPDX-License-Identifier: Apache-2.0
"""
centroider: extracts star spots from any mono8/mono16 Image and publishes `spots`.

The spots message carries the image's header unchanged (stamp = mid-exposure). A malformed
image is logged, counted in /diagnostics and skipped; the next good one is processed. Frames
with no signal, a saturated background, or a stamp out of order or from the future are still
measured (the centroider keeps no state between frames) but counted and logged; the
identifier decides what to do with their stamps (docs/RELIABILITY.md).

Overload: the subscription callback only checks and decodes an image; a worker thread measures
it. At most `queue_depth` images wait (default 3; 1: the worker always takes the newest); the
oldest waiting one is dropped when one more arrives, counted (`frames_dropped_overload`) and
logged: newest frame wins, latency stays bounded.

Rate aid (optional, never required): with `exposure_time_s` > 0, a camera model from
`camera_info` and a body rate (`rate_source`, settable at runtime: the `angular_velocity`
topic (Vector3Stamped), the `imu` topic (sensor_msgs/Imu from a gyro, rotated by
`gyro.mounting_quaternion`), or the `angular_velocity_rad_s` parameter; see rate_input.py),
each star's smear over the exposure is predicted; detection uses the matched streak filter
and positions come from a fit on the predicted (possibly curved) path. Each measured frame's
aid, as applied, goes out before its spots, stamped as them: `smear_aid/angular_velocity`
(aided frames), `smear_aid/exposure_path_offset` (frames whose streaks were fitted on a gyro's
path within the exposure) and `smear_aid/angular_acceleration` (every frame; zero when the
positions are exposure averages), so the identifier knows what each frame measured even when
the rate it sent arrived frames late (msg_docs/smear_aid.md).

A managed node (managed_node.py): `configure` compiles the kernels and creates the topics,
`activate` starts measuring; images arriving while inactive are counted
(`frames_ignored_inactive`) and dropped.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped, Vector3Stamped
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2

from ..centroid import CentroidConfig, extract_spots
from ..centroid.psf.running_prior import RunningPsf
from ..centroid.warm_up import warm_up
from ..centroid.streak.smear import SmearModel
from . import convert, image_cdr
from .camera_info_input import CameraInfoInput
from .diagnostics import Rejections
from .frame_queue import NewestFrame
from .managed_node import ManagedNode
from .node_process import exit_node_process, run_node
from .output_flush import flush_publishers
from ..parameter_spec import field_values
from .centroider_parameters import CENTROIDER_PARAMETERS, RATE_SOURCES
from .parameters import declare_parameters, guard_parameter_changes
from .qos import IMAGE_QOS, RATE_INPUT_QOS, SPOTS_QOS, overridable
from .rate_input import RateInput
from ..track.stamp_order import STAMP_OK, STAMP_RESET, StampOrder
from .throttled_log import ThrottledLog

RATE_TOPICS = {"topic": "angular_velocity", "imu": "imu"}  # rate_source -> the input it reads
# Tunable while running (`ros2 param set`, the specs marked dynamic), checked together as a
# CentroidConfig; the rest is fixed at startup.
RUNTIME_PARAMETERS = {spec.name for spec in CENTROIDER_PARAMETERS if spec.dynamic}


class CentroiderNode(ManagedNode):
    def __init__(self) -> None:
        super().__init__("centroider")
        values = declare_parameters(self, CENTROIDER_PARAMETERS)  # centroider_parameters.py
        self.config = CentroidConfig(**field_values(CENTROIDER_PARAMETERS, values))
        self.exposure_s = values["exposure_time_s"]
        self.rate_source = values["rate_source"]
        rate_param = values["angular_velocity_rad_s"]
        self.queue_depth = values["queue_depth"]
        self.max_rate_age_s = values["max_rate_age_s"]
        self.stamps = StampOrder(lambda: self.get_clock().now().nanoseconds, values["stamp.max_future_s"],
                                 values["stamp.reset_after_s"])
        # The gyro's mounting (read-only): its vectors are rotated into the sensor frame.
        self.rate_input = RateInput(lambda counter, text: self.reject(counter, text),
                                    list(values["gyro.mounting_quaternion"]), values["gyro.frame_id"],
                                    values["gyro.noise_rad_s"])
        problems = []
        if self.rate_source not in RATE_SOURCES:
            problems.append(f"rate_source={self.rate_source!r} must be one of {RATE_SOURCES}")
        if len(rate_param) != 3 or not np.all(np.isfinite(rate_param)):
            problems.append(f"angular_velocity_rad_s={list(rate_param)} must be 3 finite values")
        if problems:
            raise ValueError("; ".join(problems))
        self.rate_param = np.asarray(rate_param, float)
        self.psf = RunningPsf()  # the last frames' PSF estimate: the next frame's prior
        self.autostart = values["autostart"]

        self.frames = None  # the worker: made by configure, released by cleanup
        self.diag = self.start_diagnostics()
        self.log = ThrottledLog(self)
        self.reject = Rejections(self.diag, self.log)
        guard_parameter_changes(self, self.apply_parameters, self.diag, self.log)
        self.camera_info = CameraInfoInput(self, self.diag, self.log)

    def configure(self) -> None:
        """Compile the kernels, then create the topics and the worker thread."""
        warm_up()  # compile the kernels before the first frame (~25 s the first time, then cached: ~0.4 s)
        self.pub = self.create_lifecycle_publisher(PointCloud2, "spots", **overridable(SPOTS_QOS))
        self.pub_aid_rate = self.create_lifecycle_publisher(Vector3Stamped, "smear_aid/angular_velocity",
                                                            **overridable(SPOTS_QOS))
        self.pub_aid_path = self.create_lifecycle_publisher(PoseWithCovarianceStamped,
                                                            "smear_aid/exposure_path_offset", **overridable(SPOTS_QOS))
        self.pub_aid_accel = self.create_lifecycle_publisher(Vector3Stamped, "smear_aid/angular_acceleration",
                                                             **overridable(SPOTS_QOS))
        self.frames = NewestFrame(self, self.measure, self.diag, self.log, self.queue_depth)
        # Raw: the CDR bytes, read in place (image_cdr.py): a frame dropped for a newer one costs no copy.
        self.sub = self.create_subscription(Image, "image_raw", self.on_image, **overridable(IMAGE_QOS), raw=True)
        self.sub_info = self.create_subscription(CameraInfo, "camera_info", self.camera_info.update,
                                                 **overridable(IMAGE_QOS))
        # Both rate inputs always exist: rate_source (runtime) picks one per frame.
        self.sub_rate = self.create_subscription(Vector3Stamped, "angular_velocity", self.rate_input.on_vector3,
                                                 **overridable(RATE_INPUT_QOS))
        self.sub_imu = self.create_subscription(Imu, "imu", self.rate_input.on_imu, **overridable(RATE_INPUT_QOS))
        # The identifier's angular acceleration, stamped as its angular_velocity (rate_input.motion_for_frame).
        self.sub_accel = self.create_subscription(Vector3Stamped, "angular_acceleration",
                                                  self.rate_input.on_acceleration, **overridable(RATE_INPUT_QOS))

    def release(self) -> None:
        """
        Undo configure: stop the worker, remove the topics, forget what was received.

        Forget the camera model, the latest rate and the PSF estimate.
        """
        if self.frames is not None:
            self.frames.stop()  # the frame in progress is finished and published
            self.frames = None
        flush_publishers(self, {"spots": getattr(self, "pub", None)})
        for name in ("sub", "sub_info", "sub_rate", "sub_imu", "sub_accel"):
            if getattr(self, name, None) is not None:
                self.destroy_subscription(getattr(self, name))
                setattr(self, name, None)
        for name in ("pub", "pub_aid_rate", "pub_aid_accel"):
            if getattr(self, name, None) is not None:
                self.destroy_lifecycle_publisher(getattr(self, name))
                setattr(self, name, None)
        self.camera_info = CameraInfoInput(self, self.diag, self.log)
        self.rate_input.clear()
        self.psf.reset()

    def apply_parameters(self, changes: dict) -> str | None:
        """Runtime parameter changes, all or none (see parameters.guard_parameter_changes)."""
        config = replace(self.config, **{k: v for k, v in changes.items() if k in self.config.__dataclass_fields__})
        rate = np.asarray(changes.get("angular_velocity_rad_s", self.rate_param), float)
        if rate.shape != (3,) or not np.all(np.isfinite(rate)):
            return f"angular_velocity_rad_s={list(rate)} must be 3 finite values"
        rate_source = changes.get("rate_source", self.rate_source)
        if rate_source not in RATE_SOURCES:
            return f"rate_source={rate_source!r} must be one of {RATE_SOURCES}"
        if (config.psf_mode, config.psf_sigma_px) != (self.config.psf_mode, self.config.psf_sigma_px):
            self.psf.reset()  # a new prior or mode: start from it
        self.config, self.rate_param, self.rate_source = config, rate, rate_source
        self.exposure_s = changes.get("exposure_time_s", self.exposure_s)
        self.max_rate_age_s = changes.get("max_rate_age_s", self.max_rate_age_s)
        self.stamps.max_future_s = changes.get("stamp.max_future_s", self.stamps.max_future_s)
        self.stamps.reset_after_s = changes.get("stamp.reset_after_s", self.stamps.reset_after_s)
        return None

    def smear_for(self, stamp_ns: int, width: int, height: int) -> SmearModel | None:
        """Return the smear prediction for an image, or None when exposure, camera or rate is unknown."""
        camera = self.camera_info.camera
        source = self.rate_source  # read once: it may change meanwhile
        if self.exposure_s <= 0 or source == "none" or camera is None:
            return None
        if (camera.width, camera.height) != (width, height):
            return None
        alpha = None
        if source == "parameter":
            omega = self.rate_param
        else:
            motion = self.rate_input.motion_for_frame(RATE_TOPICS[source], stamp_ns, self.exposure_s,
                                                      self.max_rate_age_s)
            if motion is None:
                return None
            omega, alpha = motion  # the identifier's acceleration, else successive samples' slope
            samples = self.rate_input.around_exposure(RATE_TOPICS[source], stamp_ns, self.exposure_s)
            if samples is not None:  # a gyro: the path it measured within the exposure, when not smooth
                return SmearModel(camera, omega, self.exposure_s, alpha).with_exposure_path(*samples)
        return SmearModel(camera, omega, self.exposure_s, alpha)

    def on_image(self, raw: bytes) -> None:
        """Executor thread: count, read the serialized image in place, check it; the worker measures it (measure())."""
        received = time.perf_counter()
        if not self.active:  # inactive: configured, not processing
            self.diag.count("frames_ignored_inactive")
            return
        self.diag.count("frames_received")
        try:
            msg = image_cdr.parse_image(raw)
        except ValueError as exc:
            self.reject_image("(not readable)", exc)
            return
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        self.diag.time("input_age", (self.get_clock().now().nanoseconds - stamp_ns) * 1e-9)
        verdict = self.stamps.classify(stamp_ns)
        if verdict != STAMP_OK:  # measured all the same: counted for whoever reads /diagnostics
            self.reject("time_resets" if verdict == STAMP_RESET else f"frames_{verdict}",
                        self.stamps.describe(verdict, stamp_ns))
        try:
            image = convert.image_to_array(msg)  # a view of the bytes received
        except ValueError as exc:
            self.reject_image(f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}", exc)
            return
        self.diag.time("decode", time.perf_counter() - received)
        self.frames.put((image, msg.header, stamp_ns), stamp_ns)

    def reject_image(self, stamp: str, exc: Exception) -> None:
        """Count and report an image that cannot be measured; the next one is."""
        self.diag.count("frames_rejected")
        self.diag.set(DiagnosticStatus.WARN, f"rejected frame: {exc}")
        self.log.warn("bad_image", f"rejected image (stamp {stamp}): {exc}")

    def measure(self, item) -> None:
        """Worker thread: extract the spots of one decoded image and publish them."""
        image, header, stamp_ns = item
        started = time.perf_counter()
        try:
            smear = self.smear_for(stamp_ns, image.shape[1], image.shape[0])
            spots = extract_spots(image, self.config, smear, psf_prior=self.psf.prior, prior_rings=self.psf.rings)
            self.psf.update(spots.psf)
        except ValueError as exc:
            self.diag.count("frames_rejected")
            self.diag.set(DiagnosticStatus.WARN, f"rejected frame: {exc}")
            self.log.warn("bad_image", f"rejected image (stamp {header.stamp.sec}.{header.stamp.nanosec:09d}): {exc}")
            return
        except Exception as exc:  # a defect, not bad input: reported, and the next frame is processed
            self.diag.count("frames_failed")
            self.diag.set(DiagnosticStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}")
            self.log.error("internal", f"frame {stamp_ns * 1e-9:.6f} failed: {type(exc).__name__}: {exc}")
            return
        out = convert.spots_to_cloud(spots, stamp_ns, header.frame_id)
        out.header = header  # unchanged stamp and frame
        self.publish_applied_motion(spots.applied_motion, stamp_ns, header.frame_id)
        self.pub.publish(out)
        processing_s = time.perf_counter() - started
        self.diag.time("processing", processing_s)
        self.diag.count("frames_processed")
        if smear is not None and spots.rate_aid_rejected:
            self.diag.count("frames_rate_aid_rejected")
            omega = np.degrees(smear.angular_velocity_rad_s)
            self.log.warn("rate_aid_rejected",
                          f"frame {stamp_ns * 1e-9:.6f}: the streaks disagree with the aiding rate "
                          f"({omega[0]:.3f}, {omega[1]:.3f}, {omega[2]:.3f}) deg/s; measured without it")
        elif smear is not None:
            self.diag.count("frames_rate_aided")
            if smear.exposure_path is not None:
                self.diag.count("frames_on_gyro_path")
        self.diag.count("spots_rejected_shape", spots.rejected_shape)
        self.diag.count("spots_rejected_extended", spots.rejected_extended)
        problem = self.content_problem(image, spots)
        self.diag.set(DiagnosticStatus.WARN if problem else DiagnosticStatus.OK, problem or "ok",
                      last_spot_count=len(spots),
                      last_processing_ms=f"{processing_s * 1e3:.2f}",
                      last_noise_adu=f"{spots.noise_adu:.2f}",
                      rate_aided=str(smear is not None and not spots.rate_aid_rejected),
                      rate_source=self.rate_source,
                      psf_fit_model=spots.fit_model or "-",
                      **psf_values(spots.psf))

    def publish_applied_motion(self, applied, stamp_ns: int, frame_id: str) -> None:
        """Publish the frame's smear aid as applied, before its spots (joined by stamp); the acceleration last."""
        if applied.angular_velocity_rad_s is not None:
            self.pub_aid_rate.publish(convert.vector3_msg(applied.angular_velocity_rad_s, stamp_ns, frame_id))
        if applied.exposure_path_offset_rad is not None:
            self.pub_aid_path.publish(convert.path_offset_msg(applied.exposure_path_offset_rad,
                                                              applied.exposure_path_offset_covariance, stamp_ns,
                                                              frame_id))
        alpha = applied.angular_acceleration_rad_s2
        self.pub_aid_accel.publish(convert.vector3_msg(np.zeros(3) if alpha is None else alpha, stamp_ns, frame_id))

    def content_problem(self, image: np.ndarray, spots) -> str | None:
        """
        Count and log a frame with no signal or a saturated background.

        No signal: every pixel equal (lens cap, dead sensor); saturated background: Sun, Earth
        limb, overexposure. None for a usable frame.
        """
        saturation = self.config.saturation_adu or np.iinfo(image.dtype).max
        if spots.background_adu >= saturation:
            self.reject("frames_saturated", f"saturated frame: background {spots.background_adu:.0f} ADU "
                        f">= saturation {saturation:.0f} ADU")
            return "saturated frame"
        if len(spots) == 0 and image.min() == image.max():
            self.reject("frames_no_signal", f"frame without signal: every pixel reads {image.flat[0]} ADU")
            return "frame without signal"
        return None

    def destroy_node(self) -> None:
        self.release()
        super().destroy_node()


def psf_values(psf) -> dict:
    """Return the /diagnostics values of a frame's PsfEstimate (msg_docs/diagnostics.md)."""
    if psf is None:
        return {}
    return {"psf_sigma_px": f"{psf.sigma_px:.3f}", "psf_sigma_uncertainty_px": f"{psf.sigma_uncertainty_px:.3f}",
            "psf_elongation": f"{psf.elongation:.3f}", "psf_stars": psf.stars, "psf_source": psf.source,
            "psf_applied_sigma_px": f"{psf.applied_sigma_px:.3f}", "psf_annular": psf.annular,
            "psf_reason": psf.reason or "-"}


def main(argv: list[str] | None = None) -> None:
    exit_node_process(run_node(CentroiderNode, argv))


if __name__ == "__main__":
    main()
