# SPDX-License-Identifier: Apache-2.0
"""
attitude_fusion: every optical head's matched stars in one body attitude (star_tracker/fuse, docs/FUSION.md).

Each head is a namespace relative to this node's (parameter `heads`) holding one
camera_simulator + centroider + identifier; `mounting.<head>` is its sensor frame's orientation
in the body frame. Per head the node subscribes to `<head>/camera_info` (the model that turns
the matched stars' pixels into head-frame rays), `<head>/attitude_with_covariance` (the head's
own solution, paired with its matched stars by exact stamp: the alignment filter's input),
`<head>/matched_stars` and, with `body_rate.source: heads`, `<head>/angular_velocity_with_covariance`
(turned to the body frame); with `body_rate.source: topic` it subscribes to `body_rate`. With
`observer.source: odometry` it subscribes to `odometry` (observer_input.py) and fits the rays to
the stars' apparent places (aberrated by the spacecraft's velocity), as the identifiers correct
theirs.

When a head's solution is accepted the node fuses at that solution's stamp (the head's
mid-exposure stamp) once the heads in step (those of the last fusion, and any whose solution
of the last fused stamp came late) have reported that stamp too, or a newer one, or
`fusion.max_wait_s` has passed (fuse/schedule.py: synchronised heads are fused at their
own exposures, not a frame period apart). It fuses every head whose latest solution lies
within `fusion.stale_after_s`, each brought to the stamp with the body rate
(FusionState.fused_at), and publishes `attitude`, `attitude_with_covariance` and
`fusion_status` with that stamp, and `alignment/<head>` after each alignment update. A
solution stamped at or before the last fused stamp joins the next fusion instead (counted:
fusions_skipped_older), so the outputs' stamps increase.

A head's solution that cannot be used is counted per head on /diagnostics, logged (throttled),
reported in the next fusion_status and left out, and the fusion goes on with the other heads:
malformed, in another frame, without camera_info yet, too few stars, out of order (the core's
screening); a head that stops publishing goes stale and is used again when it comes back
(counted as re-admitted). A managed node (managed_node.py): `configure` checks the parameters
(an empty head list, a mounting that is not a unit quaternion, ...: refused with the reason, the
node stays unconfigured) and creates the topics; `activate` starts fusing.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped, TwistWithCovarianceStamped
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header

from ..fuse import AlignmentFilter, BodyRate, FusedAttitude, FusionState, FusionUnavailable, HeadObservation
from ..models.matrix_checks import covariance_problem, rate_problem
from ..fuse.schedule import FusionSchedule
from ..models.aberration import aberrate
from ..models.attitude import ARCSEC, matrix_to_quaternion, normalize_quaternion, quaternion_to_matrix, \
    rotation_vector_to_matrix
from ..models.camera import CameraModel
from . import convert
from .attitude_fusion_parameters import HEADS, FusionSettings, fusion_parameters, fusion_settings
from .diagnostics import Rejections
from .managed_node import ManagedNode
from .node_process import exit_node_process, run_node
from .observer_input import ObserverInput
from .output_flush import flush_publishers
from .parameters import declare_parameters, guard_parameter_changes
from .qos import IMAGE_QOS, RATE_INPUT_QOS, RESULT_QOS, overridable
from .throttled_log import ThrottledLog

POSES_KEPT = 10  # per head: attitude_with_covariance messages waiting for their matched_stars
QUATERNION_NORM_TOLERANCE = 1e-6  # largest | |q| - 1 | of a head attitude taken as a rotation

# What a head's last fusion_status says.
CONTRIBUTING = "contributing"
STALE = "stale"
NO_SOLUTION = "no solution"
MISSING_CAMERA_INFO = "missing camera_info"
EXCLUDED = "excluded"
MISSING_CAMERA_INFO_KIND = "missing_camera_info"  # the refusal kind (a per-head counter's name)


# ----------------------------------------------------------------------------- conversion (ROS-free records)
def head_rays(stars: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Return the (M, 3) head-frame unit rays of matched stars (MATCH_DTYPE records) through the camera model."""
    return camera.pixel_to_ray(stars["pixel_x"].astype(float), stars["pixel_y"].astype(float))


class HeadSolution(NamedTuple):
    """observation: what the fusion gets of one head's frame; outliers: matched stars left out (residual > max)."""

    observation: HeadObservation
    outliers: int


def apparent_catalog(catalog: np.ndarray, velocity_m_s: np.ndarray | None) -> np.ndarray:
    """
    Return the stars' apparent directions for an observer at velocity_m_s [m/s] (barycentric, ICRS axes).

    catalog: (N, 3) astrometric unit vectors (matched_stars x, y, z). velocity None: unchanged.
    Rows that are not finite unit vectors are left as they are (the fusion's screening counts them).
    """
    if velocity_m_s is None or not np.any(velocity_m_s):
        return catalog
    with np.errstate(invalid="ignore"):
        good = np.all(np.isfinite(catalog), axis=1) & (np.abs(np.linalg.norm(catalog, axis=1) - 1.0) <= 1e-6)
    apparent = catalog.copy()
    if np.any(good):
        apparent[good] = aberrate(catalog[good], velocity_m_s)
    return apparent


def head_solution(head: str, stamp_ns: int, mounting: np.ndarray, stars: np.ndarray, camera: CameraModel,
                  max_residual_sigma: float, head_attitude: tuple[np.ndarray, np.ndarray] | None = None,
                  velocity_m_s: np.ndarray | None = None) -> HeadSolution:
    """
    Return one head's observation from its matched_stars records, camera model and own attitude.

    Rays from the pixels (head_rays), catalog vectors from x, y, z (moved to their apparent
    places when the observer's barycentric velocity_m_s [m/s, ICRS axes] is given, so the fused
    attitude is the true one), each ray's sigma from `sigma`; a star whose residual exceeds
    max_residual_sigma of its sigma is left out (the identifier's fit left it out as an outlier).
    head_attitude: (head -> ICRS rotation, its head-frame covariance [rad^2]) of the same frame,
    or None. Stars with non-finite or bad values stay in: the fusion's screening leaves them out
    and counts them.
    """
    sigma = stars["sigma"].astype(float)
    with np.errstate(invalid="ignore"):
        outlier = stars["residual"].astype(float) > max_residual_sigma * sigma
    keep = ~outlier
    catalog = apparent_catalog(np.column_stack([stars["x"], stars["y"], stars["z"]]).astype(float), velocity_m_s)
    rotation, covariance = head_attitude if head_attitude is not None else (None, None)
    observation = HeadObservation(head, int(stamp_ns), mounting, catalog[keep], head_rays(stars[keep], camera),
                                  sigma[keep], rotation, covariance)
    return HeadSolution(observation, int(np.count_nonzero(outlier)))


def pose_attitude(msg: PoseWithCovarianceStamped) -> tuple[np.ndarray, np.ndarray]:
    """
    Return (rotation, covariance) of an attitude_with_covariance message: child -> parent, rotation block [rad^2].

    ValueError when the quaternion is not of unit norm (within QUATERNION_NORM_TOLERANCE) or the
    rotation block is not a symmetric positive definite covariance.
    """
    o = msg.pose.pose.orientation
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(norm) or abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f"orientation {list(q)} is not a unit quaternion")
    covariance = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[3:, 3:]
    problem = covariance_problem(covariance)
    if problem:
        raise ValueError(f"rotation covariance [rad^2] is {problem}")
    return quaternion_to_matrix(normalize_quaternion(q)), covariance


def twist_body_rate(msg: TwistWithCovarianceStamped, mounting: np.ndarray | None = None) -> BodyRate:
    """
    Return the body rate of an angular_velocity_with_covariance (or body_rate) message.

    mounting: the head's body -> head rotation M when the rate is in that head's frame
    (omega_body = M^T omega_head, P_body = M^T P M); None when it is in the body frame already.
    ValueError for a rate that is not 3 finite values or an angular block that is not a covariance.
    """
    w = msg.twist.twist.angular
    rate = np.array([w.x, w.y, w.z], dtype=float)
    covariance = np.asarray(msg.twist.covariance, dtype=float).reshape(6, 6)[3:, 3:]
    problem = rate_problem(rate, covariance)
    if problem:
        raise ValueError(problem)
    if mounting is None:
        return BodyRate(rate, covariance)
    return BodyRate(mounting.T @ rate, mounting.T @ covariance @ mounting)


def correction_msg(correction: np.ndarray, covariance: np.ndarray, stamp_ns: int,
                   body_frame_id: str) -> PoseWithCovarianceStamped:
    """
    Return an alignment/<head> message: the head's mounting correction c [rad] as a rotation of the body frame.

    orientation: the quaternion of exp([c]x) (a turn by |c| about c, body axes); the rotation
    block of the covariance: c's [rad^2], body axes; the position block unknown (-1).
    """
    msg = PoseWithCovarianceStamped()
    msg.header = Header(stamp=convert.ns_to_stamp(stamp_ns), frame_id=body_frame_id)
    o = msg.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in matrix_to_quaternion(rotation_vector_to_matrix(correction)))
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = cov[2, 2] = -1.0
    cov[3:, 3:] = covariance
    msg.pose.covariance = [float(v) for v in cov.ravel()]
    return msg


def arcsec_xyz(vector: np.ndarray) -> str:
    return ",".join(f"{v / ARCSEC:.3f}" for v in vector)


# ----------------------------------------------------------------------------- the node
@dataclass
class HeadInput:
    """
    One head as the node follows it.

    name; mounting: body -> head (3, 3); camera: the latest valid camera_info model (None
    before one); poses: stamp [ns] -> the head's own (rotation, covariance) waiting for its
    matched_stars; refusal_kind, refusal: why its latest solution did not reach the fusion
    ("" once one is accepted); contributing: in the last fusion; contributed: in one at least.
    """

    name: str
    mounting: np.ndarray
    camera: CameraModel | None = None
    camera_key: tuple | None = None
    poses: dict = field(default_factory=dict)
    refusal_kind: str = ""
    refusal: str = ""
    contributing: bool = False
    contributed: bool = False


class HeadState(NamedTuple):
    """state: CONTRIBUTING, STALE, NO_SOLUTION, MISSING_CAMERA_INFO or EXCLUDED; reason: why, in words ("" if used)."""

    state: str
    reason: str


def head_state(head: HeadInput, used: bool, dropped_reason: str) -> HeadState:
    """Return what a fusion made of a head: used, or left out and why (the core's reason, the node's refusal)."""
    if used:
        return HeadState(CONTRIBUTING, "")
    if head.refusal_kind == MISSING_CAMERA_INFO_KIND:
        return HeadState(MISSING_CAMERA_INFO, head.refusal)
    if head.refusal_kind:
        if head.refusal in dropped_reason:  # the core's reason names its own rejections
            return HeadState(EXCLUDED, dropped_reason)
        return HeadState(EXCLUDED, f"{head.refusal}; {dropped_reason}" if dropped_reason else head.refusal)
    if dropped_reason.startswith("no observation"):
        return HeadState(NO_SOLUTION, dropped_reason)
    return HeadState(STALE, dropped_reason.removeprefix("stale: "))


class AttitudeFusionNode(ManagedNode):
    def __init__(self) -> None:
        super().__init__("attitude_fusion")
        heads = declare_parameters(self, [HEADS])["heads"] or []
        self.values = {"heads": heads, **declare_parameters(self, fusion_parameters(heads)[1:])}
        self.autostart = self.values["autostart"]
        self.settings: FusionSettings | None = None  # made by configure (checked), dropped by cleanup
        self.state: FusionState | None = None
        self.heads: dict[str, HeadInput] = {}
        self.rate: tuple[int, BodyRate, str] | None = None  # (stamp [ns], body rate, where from)
        self.schedule = FusionSchedule()
        self.wait_timer = None  # runs while a fusion waits for the other heads' solutions of its stamp
        self.subscriptions_made: list = []
        self.publishers_made: dict[str, object] = {}
        self.diag = self.start_diagnostics()
        self.log = ThrottledLog(self)
        self.reject = Rejections(self.diag, self.log)
        self.observer = ObserverInput(self, self.values, self.diag, self.reject)
        guard_parameter_changes(self, lambda changes: None, self.diag, self.log)  # all read-only: rclpy refuses

    # --- lifecycle ---
    def configure(self) -> None:
        """Check the parameters together (ValueError with the reason), make the fusion and the topics."""
        settings = self.settings = fusion_settings(self.values)
        self.state = FusionState(settings.fusion,
                                 AlignmentFilter(settings.alignment) if settings.alignment is not None else None)
        self.heads = {name: HeadInput(name, settings.mountings[name]) for name in settings.heads}
        self.rate = None
        self.schedule.reset()
        self.observer.configure()
        publisher = self.create_lifecycle_publisher
        self.publishers_made = {
            "attitude": publisher(QuaternionStamped, "attitude", **overridable(RESULT_QOS)),
            "attitude_with_covariance": publisher(PoseWithCovarianceStamped, "attitude_with_covariance",
                                                  **overridable(RESULT_QOS)),
            "fusion_status": publisher(DiagnosticArray, "fusion_status", **overridable(RESULT_QOS)),
        }
        if settings.alignment is not None:
            for name in settings.alignment.heads[1:]:
                self.publishers_made[f"alignment/{name}"] = publisher(PoseWithCovarianceStamped, f"alignment/{name}",
                                                                      **overridable(RESULT_QOS))
        subscribe = self.create_subscription
        for head in self.heads.values():
            # The head's attitude first: the executor takes ready messages in this order, and the
            # identifier publishes a frame's attitude before its matched stars.
            self.subscriptions_made += [
                subscribe(CameraInfo, f"{head.name}/camera_info", lambda msg, h=head: self.on_camera_info(h, msg),
                          **overridable(IMAGE_QOS)),
                subscribe(PoseWithCovarianceStamped, f"{head.name}/attitude_with_covariance",
                          lambda msg, h=head: self.on_head_attitude(h, msg), **overridable(RESULT_QOS)),
                subscribe(PointCloud2, f"{head.name}/matched_stars", lambda msg, h=head: self.on_matched_stars(h, msg),
                          **overridable(RESULT_QOS))]
            if settings.rate_source == "heads":
                self.subscriptions_made.append(subscribe(
                    TwistWithCovarianceStamped, f"{head.name}/angular_velocity_with_covariance",
                    lambda msg, h=head: self.on_rate(msg, h), **overridable(RATE_INPUT_QOS)))
        if settings.rate_source == "topic":
            self.subscriptions_made.append(subscribe(TwistWithCovarianceStamped, "body_rate",
                                                     lambda msg: self.on_rate(msg, None),
                                                     **overridable(RATE_INPUT_QOS)))
        self.diag.value("heads", ",".join(settings.heads))
        self.diag.value("alignment_reference", settings.alignment.heads[0] if settings.alignment else "off")
        self.diag.value("body_rate_source", settings.rate_source)
        mountings = "; ".join(f"{name}: boresight along body {np.round(m[2], 6).tolist()}"
                              for name, m in settings.mountings.items())
        self.get_logger().info(f"heads {', '.join(settings.heads)} ({mountings}); alignment "
                               f"{'reference ' + settings.alignment.heads[0] if settings.alignment else 'off'}; "
                               f"body rate: {settings.rate_source}")

    def release(self) -> None:
        """Undo configure: remove the topics (outputs flushed first), drop the fusion and the heads."""
        self.cancel_wait()
        self.schedule.reset()
        for subscription in self.subscriptions_made:
            self.destroy_subscription(subscription)
        self.subscriptions_made = []
        self.observer.release()
        flush_publishers(self, self.publishers_made)
        for publisher in self.publishers_made.values():
            self.destroy_lifecycle_publisher(publisher)
        self.publishers_made = {}
        self.settings = self.state = None
        self.heads = {}

    def destroy_node(self) -> None:
        self.release()
        super().destroy_node()

    # --- inputs ---
    def on_camera_info(self, head: HeadInput, msg: CameraInfo) -> None:
        """Take a head's camera model when it changes; an invalid one is counted and ignored (the last good stays)."""
        key = (msg.width, msg.height, tuple(msg.k), tuple(msg.d), msg.distortion_model)
        if key == head.camera_key:
            return
        try:
            camera = convert.info_to_camera(msg)
        except ValueError as exc:
            self.reject(f"{head.name}.camera_info_rejected", f"{head.name}: rejected camera_info: {exc}")
            return
        head.camera, head.camera_key = camera, key
        self.get_logger().info(f"{head.name}: camera model {camera.width}x{camera.height} px, fx={camera.fx:.2f} px")

    def on_head_attitude(self, head: HeadInput, msg: PoseWithCovarianceStamped) -> None:
        """Keep a head's own attitude until its frame's matched_stars arrive (the newest POSES_KEPT)."""
        if not self.active:
            return
        try:
            attitude = pose_attitude(msg)
        except ValueError as exc:
            self.reject(f"{head.name}.head_attitude_rejected",
                        f"{head.name}: attitude_with_covariance not used: {exc}")
            return
        head.poses[convert.stamp_to_ns(msg.header.stamp)] = attitude
        while len(head.poses) > POSES_KEPT:
            head.poses.pop(min(head.poses))

    def on_rate(self, msg: TwistWithCovarianceStamped, head: HeadInput | None) -> None:
        """Keep the newest body rate sample (a head's, turned to the body frame, or body_rate's)."""
        if not self.active:
            return
        origin = f"{head.name}/angular_velocity_with_covariance" if head else "body_rate"
        if head is None and msg.header.frame_id != self.settings.body_frame_id:
            self.reject("rate_samples_rejected", f"body_rate in frame {msg.header.frame_id!r}, not the body frame "
                        f"{self.settings.body_frame_id!r}: not used")
            return
        try:
            rate = twist_body_rate(msg, head.mounting if head else None)
        except ValueError as exc:
            self.reject("rate_samples_rejected", f"{origin} not used: {exc}")
            return
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        if self.rate is not None and stamp_ns <= self.rate[0]:
            self.diag.count("rate_samples_older")  # another head's rate is newer
            return
        self.diag.count("rate_samples")
        self.rate = (stamp_ns, rate, origin)

    def on_matched_stars(self, head: HeadInput, msg: PointCloud2) -> None:
        """Check a head's solution, add it to the fusion as an observation, and fuse at its stamp when accepted."""
        if not self.active:
            self.diag.count("solutions_ignored_inactive")
            return
        started = time.perf_counter()
        self.diag.count(f"{head.name}.solutions_received")
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        attitude = head.poses.pop(stamp_ns, None)
        for older in [stamp for stamp in head.poses if stamp < stamp_ns]:  # their matched stars never came
            del head.poses[older]
        try:
            stars = convert.cloud_to_records(msg, convert.MATCH_FIELDS, convert.MATCH_DTYPE)
        except ValueError as exc:
            self.refuse(head, "malformed", f"matched_stars rejected: {exc}")
            return
        if msg.header.frame_id != self.settings.frame_id:
            self.refuse(head, "wrong_frame", f"matched_stars in frame {msg.header.frame_id!r}, not "
                        f"{self.settings.frame_id!r}")
            return
        if head.camera is None:
            self.refuse(head, MISSING_CAMERA_INFO_KIND, "no valid camera_info yet: its pixels cannot be turned "
                        "into rays")
            return
        velocity = self.observer.velocity(self.observer.state_at(stamp_ns))
        solution = head_solution(head.name, stamp_ns, head.mounting, stars, head.camera,
                                 self.settings.max_residual_sigma, attitude, velocity)
        if solution.outliers:
            self.diag.count("stars_left_out_outlier", solution.outliers)
        if attitude is None:
            self.diag.count(f"{head.name}.without_head_attitude")
        if self.schedule.pending_ns is not None and stamp_ns > self.schedule.pending_ns:
            self.fuse_now(self.schedule.expire())  # a newer solution: the waiting one is as complete as it gets
        excluded_before = self.state.counters.excluded_stars
        admission = self.state.add(solution.observation)
        if self.state.counters.excluded_stars > excluded_before:
            self.diag.count("stars_left_out_invalid", self.state.counters.excluded_stars - excluded_before)
        if not admission.accepted:
            self.refuse(head, admission.rejection, admission.detail)
            return
        head.refusal_kind = head.refusal = ""
        self.diag.count(f"{head.name}.solutions_accepted")
        if self.schedule.is_old(stamp_ns):
            self.diag.count("fusions_skipped_older")  # it joins the next fusion
            return
        latest = {name: obs.stamp_ns for name in self.heads if (obs := self.state.latest(name)) is not None}
        awaited = (self.schedule.awaited(latest, [h.name for h in self.heads.values() if h.contributing])
                   if self.settings.max_wait_s > 0 else [])
        for stamp in self.schedule.add(stamp_ns, latest, awaited):
            self.fuse_now(stamp)
        self.arm_wait()
        self.diag.time("fusion", time.perf_counter() - started)

    def fuse_now(self, stamp_ns: int) -> None:
        """Fuse at stamp_ns; a failure is a defect, reported, and the next solution is fused."""
        try:
            self.fuse(stamp_ns)
        except Exception as exc:  # a defect, not bad input
            self.diag.count("fusions_failed")
            self.diag.set(DiagnosticStatus.ERROR, f"internal error: {type(exc).__name__}: {exc}")
            self.log.error("internal", f"fusion at {stamp_ns * 1e-9:.6f} s failed: {type(exc).__name__}: {exc}")

    def arm_wait(self) -> None:
        """Run the wait timer while a fusion is pending (fusion.max_wait_s), stop it otherwise."""
        if self.schedule.pending_ns is None:
            self.cancel_wait()
        elif self.wait_timer is None:
            self.wait_timer = self.create_timer(self.settings.max_wait_s, self.on_wait_over)

    def cancel_wait(self) -> None:
        if self.wait_timer is not None:
            self.destroy_timer(self.wait_timer)
            self.wait_timer = None

    def on_wait_over(self) -> None:
        """fusion.max_wait_s passed without every awaited head's solution: fuse with what came (counted)."""
        self.cancel_wait()
        stamp = self.schedule.expire()
        if stamp is not None and self.active:
            self.diag.count("fusions_after_wait")
            self.fuse_now(stamp)

    def refuse(self, head: HeadInput, kind: str, detail: str) -> None:
        """Count, log and remember why a head's solution did not reach the fusion (reported in fusion_status)."""
        head.refusal_kind, head.refusal = kind, detail
        self.reject(f"{head.name}.{kind}", f"{head.name}: {detail}; left out")

    # --- the fusion ---
    def rate_at(self, stamp_ns: int) -> tuple[BodyRate, str]:
        """Return the body rate for a fusion at stamp_ns and where it comes from (in words)."""
        settings = self.settings
        if settings.rate_source == "none":
            return BodyRate.at_rest(), "none: a body at rest"
        if self.rate is not None:
            dt = (stamp_ns - self.rate[0]) * 1e-9  # positive: the rate is older than the stamp
            if abs(dt) <= settings.rate_max_age_s:
                return self.rate[1], f"{self.rate[2]}, dt {dt:+.3f} s"
        self.diag.count("fusions_without_rate")
        sigma = settings.unknown_rate_sigma
        return BodyRate(np.zeros(3), np.eye(3) * sigma ** 2), f"unknown: none within {settings.rate_max_age_s} s " \
            f"(zero, 1-sigma {sigma} rad/s)"

    def fuse(self, stamp_ns: int) -> None:
        """Fuse every fresh head at stamp_ns, publish the attitude, the status and new alignment estimates."""
        rate, rate_origin = self.rate_at(stamp_ns)
        alignment = self.state.alignment
        updates = alignment.counters.updates if alignment else 0
        try:
            fused = self.state.fused_at(stamp_ns, rate)
        except FusionUnavailable as exc:
            self.reject("fusions_unavailable", f"no fused attitude at {stamp_ns * 1e-9:.6f} s: {exc}")
            self.publish_status(stamp_ns, None, exc.dropped, rate_origin)
            self.mirror_core_counters()
            return
        frame_id = self.settings.frame_id
        self.publishers_made["attitude"].publish(convert.quaternion_msg(fused.quaternion, stamp_ns, frame_id))
        self.publishers_made["attitude_with_covariance"].publish(
            convert.pose_with_covariance_msg(fused, stamp_ns, frame_id))
        states = self.publish_status(stamp_ns, fused, fused.dropped, rate_origin)
        if alignment is not None and alignment.counters.updates > updates:
            self.publish_alignment(stamp_ns)
        self.diag.count("fusions_published")
        self.mirror_core_counters()
        sigma = np.sqrt(np.diag(fused.covariance))
        self.diag.value("last_heads_used", ",".join(fused.heads))
        self.diag.value("last_stamp_ns", stamp_ns)
        self.diag.value("last_sigma_arcsec_xyz", arcsec_xyz(sigma))
        self.diag.value("last_rate", rate_origin)
        left_out = {name: s for name, s in states.items() if s.state != CONTRIBUTING}
        if left_out:
            self.diag.set(DiagnosticStatus.WARN, f"fused {', '.join(fused.heads)}; " + "; ".join(
                f"{name} {s.state}" for name, s in left_out.items()))
        else:
            self.diag.set(DiagnosticStatus.OK, f"fused {', '.join(fused.heads)}")

    def publish_status(self, stamp_ns: int, fused: FusedAttitude | None, dropped: dict[str, str],
                       rate_origin: str) -> dict[str, HeadState]:
        """Publish fusion_status (one status per head, then the fused one); count each head's outcome; return them."""
        states, statuses = {}, []
        for name, head in self.heads.items():
            used = fused is not None and name in fused.heads
            state = states[name] = head_state(head, used, dropped.get(name, ""))
            if used:
                self.diag.count(f"{name}.contributed")
                if head.contributed and not head.contributing:
                    self.diag.count(f"{name}.readmitted")
                    self.get_logger().info(f"{name}: contributing again")
                head.contributed = True
            elif dropped.get(name, "").startswith("stale"):  # excluded or not, its latest accepted one is stale
                self.diag.count(f"{name}.stale")
            head.contributing = used
            self.diag.value(f"{name}.state", state.state)
            statuses.append(self.head_status(head, state, stamp_ns, fused))
        statuses.append(self.fused_status(fused, dropped, rate_origin))
        msg = DiagnosticArray()
        msg.header = Header(stamp=convert.ns_to_stamp(stamp_ns), frame_id=self.settings.body_frame_id)
        msg.status = statuses
        self.publishers_made["fusion_status"].publish(msg)
        return states

    def head_status(self, head: HeadInput, state: HeadState, stamp_ns: int,
                    fused: FusedAttitude | None) -> DiagnosticStatus:
        """Return one head's DiagnosticStatus of a fusion (msg_docs/fusion_status.md)."""
        values = {"state": state.state, "reason": state.reason}
        latest = self.state.latest(head.name)
        if latest is not None:
            values["solution_stamp_ns"] = str(latest.stamp_ns)
            values["offset_s"] = f"{(stamp_ns - latest.stamp_ns) * 1e-9:+.6f}"  # dt: positive when older
        residual = fused.residuals.get(head.name) if fused is not None else None
        if residual is not None:
            values.update(stars=str(residual.stars), rms_residual_arcsec=f"{residual.rms_residual_rad / ARCSEC:.3f}",
                          chi2=f"{residual.chi2:.1f}", offset_arcsec_xyz=arcsec_xyz(residual.offset),
                          offset_sigma_arcsec_xyz=arcsec_xyz(np.sqrt(np.diag(residual.offset_covariance))))
        alignment = self.state.alignment
        if alignment is not None:
            estimate = alignment.estimate(head.name, stamp_ns)
            values.update(alignment_arcsec_xyz=arcsec_xyz(estimate.correction),
                          alignment_sigma_arcsec_xyz=arcsec_xyz(np.sqrt(np.diag(estimate.covariance))))
        level = DiagnosticStatus.OK if state.state == CONTRIBUTING else DiagnosticStatus.WARN
        message = state.state + (f": {state.reason}" if state.reason else "")
        return DiagnosticStatus(level=level, name=f"head/{head.name}", message=message, hardware_id=head.name,
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def fused_status(self, fused: FusedAttitude | None, dropped: dict[str, str], rate_origin: str) -> DiagnosticStatus:
        """Return the fused attitude's DiagnosticStatus of a fusion (msg_docs/fusion_status.md)."""
        if fused is None:
            return DiagnosticStatus(level=DiagnosticStatus.ERROR, name="fused", hardware_id="attitude_fusion",
                                    message="no fused attitude", values=[
                                        KeyValue(key="heads_used", value=""), KeyValue(key="rate", value=rate_origin)])
        stars = sum(r.stars for r in fused.residuals.values())
        values = {"heads_used": ",".join(fused.heads), "stars": str(stars),
                  "sigma_arcsec_xyz": arcsec_xyz(np.sqrt(np.diag(fused.covariance))),
                  "chi2": f"{fused.chi2:.1f}", "degrees_of_freedom": str(2 * stars - 3), "rate": rate_origin}
        level = DiagnosticStatus.WARN if dropped else DiagnosticStatus.OK
        message = f"fused {len(fused.heads)} of {len(self.heads)} heads"
        return DiagnosticStatus(level=level, name="fused", message=message, hardware_id="attitude_fusion",
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def publish_alignment(self, stamp_ns: int) -> None:
        """Publish every non-reference head's mounting correction on alignment/<head> (after an update)."""
        alignment = self.state.alignment
        for name in alignment.config.heads[1:]:
            estimate = alignment.estimate(name)
            self.publishers_made[f"alignment/{name}"].publish(
                correction_msg(estimate.correction, estimate.covariance, stamp_ns, self.settings.body_frame_id))
            self.diag.value(f"{name}.alignment_arcsec_xyz", arcsec_xyz(estimate.correction))
            self.diag.value(f"{name}.alignment_sigma_arcsec_xyz", arcsec_xyz(np.sqrt(np.diag(estimate.covariance))))

    def mirror_core_counters(self) -> None:
        """Show the fusion core's own counters (fusion.*) and the alignment filter's (alignment.*) on /diagnostics."""
        for key, value in vars(self.state.counters).items():
            self.diag.value(f"fusion.{key}", value)
        if self.state.alignment is not None:
            for key, value in vars(self.state.alignment.counters).items():
                self.diag.value(f"alignment.{key}", value)


def main(argv: list[str] | None = None) -> None:
    exit_node_process(run_node(AttitudeFusionNode, argv))


if __name__ == "__main__":
    main()
