# SPDX-License-Identifier: Apache-2.0
"""
The stress campaign through the real nodes: faulty frames into the centroider and identifier processes over DDS.

    python -m star_tracker.campaign.stress_nodes --frames 2000 --seed 1 --output DIR

The centroider and the identifier run as separate processes (star_tracker.ros.pipeline.NodeProcesses,
config/star_tracker.yaml: the shipped parameters) on a private ROS domain. This process plays the
camera: it renders the frames of a seeded plan (stress_faults.py: missions of rest, slews,
tumbles and jitter under hot-pixel and cosmic-ray storms and false objects, with dropped,
duplicated, malformed, bit-flipped, blank frames, stamps jumping back, forward and into the
future, and bad CameraInfo) and publishes each as sensor_msgs/Image with its CameraInfo, then
waits for that frame's outcome before the next (the identifier's `status`, or the centroider's
`spots` for a frame the identifier refuses by its stamp; nothing for a malformed image): the
nodes are never overloaded by design, and the frames' content and stamps do not depend on the
host's speed. The identifier's own rate estimate aids the centroider (`rate_source: topic`, as
shipped).

Every frame must be accounted for: published, or counted on /diagnostics by a named counter
(msg_docs/diagnostics.md). Per node, counter deltas over the run: the centroider's
frames_received = frames sent; frames_received = frames_processed + frames_rejected +
frames_failed + frames_dropped_overload; the identifier's frames_received = the centroider's
frames_processed; and frames_received = frames_identified + the not_identified_* + the stamp,
camera_info, malformed, overload and failure counters. Any difference is a frame lost without a
count (a silent drop). Each attitude is scored against the renderer's truth (wrong: boresight
more than 60" off, or NEES beyond 31.8, 5 sigma of chi^2_3) and each matched star against the
star rendered at its pixel; recovery counts the frames from the end of each stamp jump or dropped
burst to the next attitude. The summary (run_stress_through_nodes) is written to
OUTPUT/summary_nodes.json, each frame's record to OUTPUT/frames_nodes.json, the nodes' logs to
OUTPUT/logs.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import shlex
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .markdown_section import write_between_markers
from .stress_faults import (FAULT_KINDS, FRAME_PERIOD_S, MALFORMED, MISSION_FRAMES, FrameSource, StampRule,
                            StressPlan, plan_stress)

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config" / "star_tracker.yaml"
NODES = ("centroider", "identifier")
STATUS_NAMES = {"centroider": "star_tracker/centroider", "identifier": "star_tracker/identifier"}
FRAME_ID = "star_tracker_optical"
OUTCOME_TIMEOUT_S = 60.0  # a frame's outcome not seen within this: the node is stuck (counted; the run goes on)
STUCK_FRAMES = 3  # this many frames in a row without an outcome end the run (a hung node)
GYRO_SAMPLES = 5  # gyro samples per frame, across its exposure
GYRO_BIAS_DEG_S = 0.02  # each axis's constant bias drawn within +- this [deg/s] (--gyro)
GYRO_NOISE_DEG_S = 0.005  # white noise 1-sigma per sample [deg/s]
WRONG_ARCSEC = 60.0
TRUTH_PX = 3.0  # a matched star is right when the star it is named after was rendered this close (as the campaigns)
GUIDE_MAGNITUDE = 6.5  # the shipped database.magnitude_limit: fainter matched stars come from the deep re-match
# What becomes of a frame the centroider received, and of spots the identifier received.
CENTROIDER_OUTCOMES = ("frames_processed", "frames_rejected", "frames_failed", "frames_dropped_overload")
IDENTIFIER_OUTCOMES = ("frames_identified", "frames_failed", "frames_dropped_overload", "frames_without_camera_info",
                       "frames_rejected", "frames_unstamped", "frames_from_future", "frames_out_of_order",
                       "frames_bridged", "frames_not_bridged")


# ------------------------------------------------------------------------------ the harness's node
class Harness:
    """
    This process's node: publishes image_raw and camera_info, records spots, results, status and /diagnostics.

    Spins in a background thread; `changed` is notified on every message.
    """

    def __init__(self, context):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2

        from ..ros import convert
        from ..ros.pipeline import MONITOR_RESULT_QOS, MONITOR_SENSOR_QOS
        from ..ros.qos import IMAGE_QOS, RATE_INPUT_QOS

        self.convert = convert
        self.node = rclpy.create_node("stress_harness", context=context)
        self.changed = threading.Condition()
        self.spots: dict[int, list[int]] = {}  # stamp -> spot count of each spots message
        self.poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # stamp -> (quaternion xyzw, 3x3 covariance)
        self.matches: dict[int, np.ndarray] = {}
        self.status: dict[int, str] = {}  # stamp -> the identifier's status message
        self.path_frames: set[int] = set()  # stamps of attitudes carried to mid-exposure by a gyro's path (status)
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.diagnostics_seen: dict[str, int] = {}  # status name -> messages received
        n = self.node
        self.pub_image = n.create_publisher(Image, "image_raw", IMAGE_QOS)
        self.pub_info = n.create_publisher(CameraInfo, "camera_info", IMAGE_QOS)
        self.pub_imu = n.create_publisher(Imu, "imu", RATE_INPUT_QOS)
        n.create_subscription(PointCloud2, "spots", self._on_spots, MONITOR_SENSOR_QOS)
        n.create_subscription(PoseWithCovarianceStamped, "attitude_with_covariance", self._on_pose, MONITOR_RESULT_QOS)
        n.create_subscription(PointCloud2, "matched_stars", self._on_matches, MONITOR_RESULT_QOS)
        n.create_subscription(DiagnosticArray, "status", self._on_status, MONITOR_RESULT_QOS)
        n.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(n)
        self._running = True
        self.thread = threading.Thread(target=self._spin, name="stress_harness_spin", daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while self._running:
            self.executor.spin_once(timeout_sec=0.05)

    def _notify(self) -> None:
        with self.changed:
            self.changed.notify_all()

    def _on_spots(self, msg) -> None:
        with self.changed:
            self.spots.setdefault(self.convert.stamp_to_ns(msg.header.stamp), []).append(int(msg.width * msg.height))
            self.changed.notify_all()

    def _on_pose(self, msg) -> None:
        q = msg.pose.pose.orientation
        cov = np.asarray(msg.pose.covariance, float).reshape(6, 6)[3:, 3:]
        with self.changed:
            self.poses[self.convert.stamp_to_ns(msg.header.stamp)] = (np.array([q.x, q.y, q.z, q.w]), cov)
            self.changed.notify_all()

    def _on_matches(self, msg) -> None:
        records = self.convert.cloud_to_records(msg, self.convert.MATCH_FIELDS, self.convert.MATCH_DTYPE).copy()
        with self.changed:
            self.matches[self.convert.stamp_to_ns(msg.header.stamp)] = records
            self.changed.notify_all()

    def _on_status(self, msg) -> None:
        with self.changed:
            stamp = self.convert.stamp_to_ns(msg.header.stamp)
            for status in msg.status:
                self.status[stamp] = status.message
                if any(kv.key == "exposure_path" and kv.value == "true" for kv in status.values):
                    self.path_frames.add(stamp)
            self.changed.notify_all()

    def _on_diagnostics(self, msg) -> None:
        with self.changed:
            for status in msg.status:
                self.diagnostics[status.name] = {kv.key: kv.value for kv in status.values}
                self.diagnostics_seen[status.name] = self.diagnostics_seen.get(status.name, 0) + 1
            self.changed.notify_all()

    def wait(self, seconds: float, until) -> bool:
        """Block until until() (called under the lock) is true, or `seconds` pass; return until()."""
        end = time.monotonic() + seconds
        with self.changed:
            while not until():
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(min(left, 0.5))
            return True

    def counters(self, node: str) -> dict[str, int]:
        """Return the counters of a node's latest /diagnostics (diagnostics.counters_of)."""
        from ..ros.diagnostics import counters_of

        with self.changed:
            values = dict(self.diagnostics.get(STATUS_NAMES[node], {}))
        return counters_of(values)

    def close(self) -> None:
        self._running = False
        self.thread.join(2.0)
        self.executor.remove_node(self.node)
        self.executor.shutdown()
        self.node.destroy_node()


# ------------------------------------------------------------------------------ messages
def bad_camera_info(kind: str, camera, stamp_ns: int):
    """Return a CameraInfo the nodes must refuse (stress_faults.BAD_CAMERA_INFOS)."""
    from ..ros import convert

    info = convert.camera_to_info(camera, stamp_ns, FRAME_ID)
    k = list(info.k)
    if kind == "nan_k":
        k = [math.nan] * 9
    elif kind == "zero_k":
        k = [0.0] * 9
    elif kind == "negative_focal":
        k[0] = k[4] = -k[0]
    elif kind == "wild_distortion":
        info.d = [-50.0, 0.0, 0.0, 0.0, 0.0]
    info.k = [float(v) for v in k]
    return info


class Gyro:
    """
    A rate gyro on the sensor axes: the truth's body rate plus a constant bias and white noise, as sensor_msgs/Imu.

    bias [rad/s] (3,), drawn once per run; noise_rad_s: 1-sigma per sample.
    """

    def __init__(self, seed: int, bias_deg_s: float = GYRO_BIAS_DEG_S, noise_deg_s: float = GYRO_NOISE_DEG_S):
        self.rng = np.random.default_rng([int(seed), 0x6E0])
        self.bias = np.radians(self.rng.uniform(-bias_deg_s, bias_deg_s, 3))
        self.noise = math.radians(noise_deg_s)

    def messages(self, motion, t_s: float, stamp_ns: int, exposure_s: float) -> list:
        """Return GYRO_SAMPLES Imu messages across the exposure centred on t_s [s] (stamped like the frame)."""
        from sensor_msgs.msg import Imu

        from ..ros import convert

        out = []
        for offset in (np.arange(GYRO_SAMPLES) + 0.5) / GYRO_SAMPLES - 0.5:
            rate = (np.asarray(motion.angular_velocity_at(t_s + offset * exposure_s), float) + self.bias
                    + self.rng.normal(0.0, self.noise, 3))
            msg = Imu()
            msg.header.stamp = convert.ns_to_stamp(stamp_ns + int(round(offset * exposure_s * 1e9)))
            msg.header.frame_id = FRAME_ID
            msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(v) for v in rate)
            msg.angular_velocity_covariance = [self.noise ** 2, 0.0, 0.0, 0.0, self.noise ** 2, 0.0, 0.0, 0.0,
                                               self.noise ** 2]
            msg.orientation_covariance[0] = -1.0  # no orientation (REP 145)
            msg.linear_acceleration_covariance[0] = -1.0
            out.append(msg)
        return out


def image_message(image: np.ndarray, fault: str, stamp_ns: int):
    """Return the image_raw message of a frame: mono16, or malformed (MALFORMED) as its fault says."""
    from sensor_msgs.msg import Image

    from ..ros import convert

    if fault == "malformed_empty":
        msg = Image(height=0, width=0, encoding="mono16", step=0)
        msg.header.stamp, msg.header.frame_id = convert.ns_to_stamp(stamp_ns), FRAME_ID
        return msg
    msg = convert.array_to_image(image, stamp_ns, FRAME_ID)
    if fault == "malformed_encoding":
        msg.encoding = "bayer_rggb16"
    elif fault == "malformed_step":
        msg.step = msg.width  # shorter than a mono16 row
    return msg


# ------------------------------------------------------------------------------ scoring
def score_attitude(quaternion: np.ndarray, covariance: np.ndarray, truth_rotation: np.ndarray) -> dict:
    """Boresight and roll error [arcsec] and NEES of a published attitude against the truth."""
    from ..models.attitude import matrix_to_rotation_vector, quaternion_to_matrix

    error = matrix_to_rotation_vector(truth_rotation.T @ quaternion_to_matrix(quaternion))  # sensor frame [rad]
    arcsec = math.degrees(1.0) * 3600.0
    try:
        nees = float(error @ np.linalg.solve(covariance, error))
    except np.linalg.LinAlgError:
        nees = math.inf
    return {"cross_arcsec": math.hypot(error[0], error[1]) * arcsec, "roll_arcsec": abs(error[2]) * arcsec,
            "nees": nees}


def score_matches(records: np.ndarray, truth) -> tuple[int, int, int]:
    """
    Return (matched, wrong guide stars, wrong deep stars) of a frame's matched_stars.

    A star is right when the star it is named after was rendered within TRUTH_PX of its pixel
    (plus half its smear); a wrong one fainter than GUIDE_MAGNITUDE came from the deep re-match.
    """
    from ..sim.render import KIND_STAR

    star = truth.kind == KIND_STAR
    hip, x, y, extent = truth.hip[star], truth.x[star], truth.y[star], truth.extent_px[star]
    wrong_guide = wrong_deep = 0
    for record in records:
        at = np.flatnonzero(hip == int(record["hip_id"]))
        right = at.size > 0 and bool(np.any(np.hypot(x[at] - record["pixel_x"], y[at] - record["pixel_y"])
                                            <= TRUTH_PX + 0.5 * extent[at]))
        if not right:
            if float(record["magnitude"]) > GUIDE_MAGNITUDE:
                wrong_deep += 1
            else:
                wrong_guide += 1
    return int(records.size), wrong_guide, wrong_deep


# ------------------------------------------------------------------------------ the run
def run_stress_through_nodes(frames: int, seed: int, output: Path, progress=None, *, required: tuple[str, ...] = (),
                             mission_frames: tuple[int, int] = MISSION_FRAMES, gyro: bool = False,
                             node_params: dict | None = None) -> dict:
    """
    Run the stress plan of `frames` image messages (seed `seed`) through the centroider and identifier processes.

    Returns the summary (also written to OUTPUT/summary_nodes.json); progress(done, total) is called after
    every frame. required: fault kinds each placed at least once (a short run showing them all);
    mission_frames: (fewest, most) frames of a mission (stress_faults.plan_stress); node_params:
    per node, parameters over config/star_tracker.yaml (none: the shipped ones). gyro: the centroider's
    rate aid from a biased, noisy gyro on `imu` (Gyro; `rate_source: imu`) instead of the identifier's rate.
    """
    import rclpy
    from rclpy.context import Context

    from ..models.catalog import julian_year_from_unix
    from ..ros.middleware import configure_middleware
    from ..ros.pipeline import NodeProcesses, isolated_ros_environment

    output = Path(output)
    output.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    plan = plan_stress(frames, seed, required, mission_frames)
    source = FrameSource(epoch_jyear=julian_year_from_unix(time.time()))  # the sky of the stamps' date
    env = isolated_ros_environment()
    # This process joins the nodes' private domain: localhost discovery and the project's DDS profile.
    saved = {key: os.environ.get(key) for key in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY")}
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    configure_middleware()
    context = Context()
    rclpy.init(args=[], context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    params = {name: dict(values) for name, values in (node_params or {}).items()}
    if gyro:
        params.setdefault("centroider", {})["rate_source"] = "imu"
    nodes = NodeProcesses(env, output / "logs", params, CONFIG, nodes=NODES)
    harness = None
    records: list[dict] = []
    run: dict = {"crashed": {}, "alive_at_end": {}}
    try:
        nodes.start()
        nodes.wait_ready()
        run["timing_s"] = {"nodes_ready": round(time.monotonic() - started, 1)}
        harness = Harness(context)
        try:
            run.update(_drive(plan, source, nodes, harness, records, progress, Gyro(seed) if gyro else None))
        except RuntimeError as exc:  # a node exited, or never answered: the summary says so
            run["error"] = str(exc)[-4000:]
        run["alive_at_end"] = {name: proc.poll() is None for name, proc in nodes.processes.items()}
    finally:
        if harness is not None:
            harness.close()
        run["exit_codes"] = nodes.stop()
        context.try_shutdown()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
    for record in records:  # a run that stopped early leaves them
        record.pop("truth", None)
        record.pop("reference", None)
    logs = {name: path.read_text(errors="replace") for name, path in nodes.log_paths.items()}
    run["tracebacks"] = {name: text.count("Traceback") for name, text in logs.items()}
    summary = summarize(plan, records, run)
    summary["seed"], summary["frames_requested"] = int(seed), int(frames)
    summary["mission_frames"] = list(mission_frames)
    summary["rate_aid"] = "gyro" if gyro else "identifier"
    if gyro:
        summary["gyro"] = {"bias_deg_s": np.degrees(Gyro(seed).bias).tolist(), "noise_deg_s": GYRO_NOISE_DEG_S,
                           "samples_per_frame": GYRO_SAMPLES}
    summary["node_params"] = params
    summary["duration_s"] = round(time.monotonic() - started, 1)
    summary["timing_s"] = {**run.get("timing_s", {}), "frames": run.get("frames_s")}
    (output / "summary_nodes.json").write_text(json.dumps(summary, indent=1, default=_json_default) + "\n")
    (output / "frames_nodes.json").write_text(json.dumps(records, default=_json_default) + "\n")
    return summary


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value).__name__)


def _drive(plan: StressPlan, source: FrameSource, nodes, harness: Harness, records: list[dict], progress,
           gyro: Gyro | None = None) -> dict:
    """Warm up, take the counters' baseline, send every planned frame and wait for its outcome, settle."""
    from ..ros import convert

    h = harness
    if not h.wait(60.0, lambda: h.pub_image.get_subscription_count() > 0 and h.pub_info.get_subscription_count() > 0
                  and all(h.node.count_publishers(t) > 0 for t in ("spots", "status", "attitude_with_covariance",
                                                                   "matched_stars"))):
        raise RuntimeError("the nodes' topics were not discovered within 60 s")
    last_t = max(f.t_s for f in plan.frames)
    base_ns = time.time_ns() - int((last_t + 30.0) * 1e9)  # every planned stamp lies in the past
    good_info = lambda stamp: convert.camera_to_info(source.camera, stamp, FRAME_ID)  # noqa: E731

    # Warm-up (not counted): one frame at rest until the identifier answers it (discovery, first solve).
    first = plan.missions[0]
    warm = source.render(first, first.frames[0])
    for attempt in range(60):
        stamp = base_ns - int(10e9) + attempt * int(FRAME_PERIOD_S * 1e9)
        h.pub_info.publish(good_info(stamp))
        h.pub_image.publish(image_message(warm.image, "", stamp))
        if h.wait(3.0, lambda: stamp in h.status):
            break
        for name in NODES:
            nodes.check_alive(name)
    else:
        raise RuntimeError("the identifier answered no warm-up frame in 180 s")
    baseline = _settle(h, nodes, None)
    began = time.monotonic()

    c_rule, i_rule = StampRule(), StampRule()
    sent = [f for f in plan.frames if f.sent]
    done = 0
    stuck = stuck_in_a_row = 0
    previous = None  # (planned frame, rendered, stamp) of the last frame sent: a duplicate's original
    for mission in plan.missions:
        for f in mission.frames:
            record = {"index": f.index, "mission": f.mission, "motion": mission.motion_kind,
                      "environment": mission.environment, "level": mission.level, "fault": f.fault,
                      "bad_info": f.bad_info, "event": f.event, "sent": f.sent, "copy": f.copy, "t_s": f.t_s}
            records.append(record)
            if not f.sent:
                continue
            if f.copy and previous is not None:
                rendered, stamp = previous[1], previous[2]
            else:
                rendered = source.render(mission, f)
                stamp = (time.time_ns() + int(f.future_s * 1e9) if f.fault == "stamp_future"
                         else base_ns + int(round(f.t_s * 1e9)))
            previous = (f, rendered, stamp)
            now = time.time_ns()
            malformed = f.fault in MALFORMED
            reference, phase, jitter = source.reference(mission, f, rendered.truth)
            record.update(stamp_ns=stamp, c_verdict=c_rule.classify(stamp, now), malformed=malformed,
                          truth=rendered.truth, reference=reference, phase=phase, jitter_arcsec=jitter)
            record["i_verdict"] = "" if malformed else i_rule.classify(stamp, now)
            if gyro is not None and not f.copy and f.fault != "stamp_future":
                for msg in gyro.messages(source.motion(mission), f.t_s, stamp, source.sensor.exposure_s):
                    h.pub_imu.publish(msg)
            h.pub_info.publish(bad_camera_info(f.bad_info, source.camera, stamp) if f.bad_info else good_info(stamp))
            h.pub_image.publish(image_message(rendered.image, f.fault, stamp))
            if malformed:
                h.wait(0.02, lambda: False)
            elif record["i_verdict"] in ("ok", "time_reset"):
                if not h.wait(OUTCOME_TIMEOUT_S, lambda: stamp in h.status):
                    record["timeout"] = True
                    stuck += 1
            elif not h.wait(OUTCOME_TIMEOUT_S, lambda: len(h.spots.get(stamp, ())) > f.copy):
                record["timeout"] = True
                stuck += 1
            stuck_in_a_row = stuck_in_a_row + 1 if record.get("timeout") else 0
            if stuck_in_a_row >= STUCK_FRAMES:
                raise RuntimeError(f"no outcome for {STUCK_FRAMES} frames in a row (frame {f.index}): a node hangs")
            if record.get("timeout"):
                for name in NODES:
                    if nodes.processes[name].poll() is not None:
                        raise RuntimeError(f"{name} exited with {nodes.processes[name].returncode} during the run")
            done += 1
            if progress is not None:
                progress(done, len(sent))
    frames_s = time.monotonic() - began
    final = _settle(h, nodes, baseline, sent=len(sent))
    # What the harness saw per frame.
    for record in records:
        if not record["sent"]:
            continue
        stamp = record["stamp_ns"]
        seen = h.spots.get(stamp, [])
        record["spots_messages"] = len(seen)
        record["spot_count"] = seen[0] if seen else None
        if record["copy"] == 0:
            record["status"] = h.status.get(stamp)
            pose = h.poses.get(stamp)
            if pose is not None and record["fault"] != "stamp_future":
                # An attitude carried to mid-exposure by a gyro's path (its status says so) is judged there.
                on_path = stamp in h.path_frames
                reference = record["truth"].rotation if on_path else record["reference"]
                record.update(score_attitude(pose[0], pose[1], reference), attitude=True, on_path=on_path)
                matches = h.matches.get(stamp)
                if matches is not None:
                    scored = score_matches(matches, record["truth"])
                    record["matched"], record["wrong_guide"], record["wrong_deep"] = scored
            elif pose is not None:
                record["attitude"] = True  # published for a frame stamped in the future: no truth at that stamp
        record.pop("truth", None)
        record.pop("reference", None)
    return {"baseline": baseline, "final": final, "stuck_frames": stuck, "frames_s": round(frames_s, 1)}


def _settle(h: Harness, nodes, baseline: dict | None, sent: int = 0, timeout_s: float = 60.0) -> dict:
    """
    Wait until both nodes' /diagnostics account for what was sent, two fresh messages each; return the counters.

    Without a baseline (the warm-up): until each node's counters balance. With one: until the
    centroider has an outcome for `sent` frames more and the identifier for what the centroider
    published, or timeout_s with no change.
    """
    def outcomes():
        c, i = h.counters("centroider"), h.counters("identifier")
        c_done = sum(c.get(k, 0) for k in CENTROIDER_OUTCOMES)
        i_done = sum(i.get(k, 0) for k in IDENTIFIER_OUTCOMES)
        i_done += sum(v for k, v in i.items() if k.startswith("not_identified_"))
        return c, i, c_done, i_done

    def balanced() -> bool:
        c, i, c_done, i_done = outcomes()
        if baseline is None:
            return c_done == c.get("frames_received", -1) and i_done == i.get("frames_received", -1)
        return (c_done - baseline["c_done"] >= sent
                and i_done - baseline["i_done"] >= c.get("frames_processed", 0) - baseline["centroider"].get(
                    "frames_processed", 0))

    deadline = time.monotonic() + timeout_s
    seen = dict(h.diagnostics_seen)
    while time.monotonic() < deadline:
        fresh = all(h.diagnostics_seen.get(STATUS_NAMES[n], 0) >= seen.get(STATUS_NAMES[n], 0) + 2 for n in NODES)
        if fresh and balanced():
            break
        h.wait(0.5, lambda: False)
        for name in NODES:
            nodes.check_alive(name)
    c, i, c_done, i_done = outcomes()
    return {"centroider": c, "identifier": i, "c_done": c_done, "i_done": i_done}


# ------------------------------------------------------------------------------ the summary
def _deltas(run: dict, node: str) -> dict[str, int]:
    before, after = run["baseline"][node], run["final"][node]
    return {k: after.get(k, 0) - before.get(k, 0) for k in sorted(set(before) | set(after))
            if after.get(k, 0) - before.get(k, 0)}


def summarize(plan: StressPlan, records: list[dict], run: dict) -> dict:
    """Return the run's figures (module docstring) from its frame records and the nodes' counters."""
    sent = [r for r in records if r["sent"]]
    summary: dict = {"frames_planned": len(records), "frames_sent": len(sent),
                     "frames_dropped_before_the_nodes": len(records) - len(sent),
                     "missions": len(plan.missions), "faults": plan.fault_counts(),
                     "motions": _count(m.motion_kind for m in plan.missions),
                     "environments": _count(m.environment for m in plan.missions)}
    if "final" not in run:  # the run stopped before its end
        summary.update(nodes=_node_health(run), error=run.get("error"), passed=False)
        return summary
    c, i = _deltas(run, "centroider"), _deltas(run, "identifier")
    not_identified = {k: v for k, v in i.items() if k.startswith("not_identified_")}
    malformed = sum(r["malformed"] for r in sent)
    bad_infos = sum(bool(r["bad_info"]) for r in sent)
    # Accounting: every frame sent has an outcome counted by each node it reached.
    accounting = {
        "sent_not_received_by_centroider": (len(sent) - c.get("frames_received", 0)
                                            - c.get("frames_ignored_inactive", 0)),
        "centroider_received_without_outcome": c.get("frames_received", 0) - sum(c.get(k, 0)
                                                                                 for k in CENTROIDER_OUTCOMES),
        "processed_not_received_by_identifier": c.get("frames_processed", 0) - i.get("frames_received", 0),
        "identifier_received_without_outcome": i.get("frames_received", 0) - sum(i.get(k, 0)
                                                                                 for k in IDENTIFIER_OUTCOMES)
        - sum(not_identified.values()),
    }
    unaccounted = sum(abs(v) for v in accounting.values())
    expected = {
        "centroider": {"frames_rejected": malformed, "camera_info_rejected": bad_infos,
                       **{f"frames_{v}" if v != "time_reset" else "time_resets": _count_of(sent, "c_verdict", v)
                          for v in ("from_future", "out_of_order", "time_reset")}},
        "identifier": {"camera_info_rejected": bad_infos,
                       **{f"frames_{v}" if v != "time_reset" else "time_resets": _count_of(sent, "i_verdict", v)
                          for v in ("from_future", "out_of_order", "time_reset")}},
    }
    counted = {"centroider": c, "identifier": i}
    mismatches = {f"{node}.{key}": {"expected": value, "counted": counted[node].get(key, 0)}
                  for node, keys in expected.items() for key, value in keys.items()
                  if counted[node].get(key, 0) != value}
    attitudes = [r for r in sent if r.get("cross_arcsec") is not None]
    wrong = [r for r in attitudes if r["cross_arcsec"] > WRONG_ARCSEC or r["nees"] > _nees_5_sigma()]
    nees = np.array([r["nees"] for r in attitudes])
    cross = np.array([r["cross_arcsec"] for r in attitudes])
    roll = np.array([r["roll_arcsec"] for r in attitudes])
    summary.update({
        "centroider": {"spots_published": c.get("frames_processed", 0),
                       "spots_seen": sum(r.get("spots_messages", 0) > r["copy"] for r in sent), "counters": c},
        "identifier": {"attitudes_published": i.get("frames_identified", 0),
                       "attitudes_seen": sum(bool(r.get("attitude")) for r in sent),
                       "status_seen": sum(r.get("status") is not None for r in sent if r["copy"] == 0),
                       "not_identified": not_identified, "counters": i},
        "accounting": {**accounting, "unaccounted": unaccounted,
                       "frames_without_an_outcome_seen": sum(bool(r.get("timeout")) for r in sent),
                       "expected_counters_mismatched": mismatches},
        "bad_camera_info_sent": bad_infos,
        "attitudes": {
            "scored": len(attitudes), "wrong": len(wrong),
            "wrong_frames": [{k: r.get(k) for k in ("index", "mission", "motion", "phase", "fault", "environment",
                                                    "cross_arcsec", "nees", "status")} for r in wrong],
            "nees_mean": float(nees.mean()) if nees.size else None,
            "nees_beyond_5_sigma": int(np.sum(nees > _nees_5_sigma())),
            "cross_arcsec_median": float(np.median(cross)) if cross.size else None,
            "cross_arcsec_max": float(cross.max()) if cross.size else None,
            "roll_arcsec_median": float(np.median(roll)) if roll.size else None,
            "by_mode": _count(r.get("status") for r in attitudes),
            "by_phase": {phase: _phase_figures([r for r in attitudes if r["phase"] == phase])
                         for phase in sorted({r["phase"] for r in attitudes})},
            # Carried to mid-exposure by a gyro's path (the identifier's status says so): judged there.
            "on_exposure_path": _phase_figures([r for r in attitudes if r.get("on_path")]),
        },
        "stars": {"matched": sum(r.get("matched", 0) for r in attitudes),
                  "wrong_guide": sum(r.get("wrong_guide", 0) for r in attitudes),
                  "wrong_deep": sum(r.get("wrong_deep", 0) for r in attitudes)},
        "recovery": recovery(records),
        "identified_by_environment": {env: _rate(sent, lambda r, e=env: r["environment"] == e)
                                      for env in ("nominal", "hot_pixel_storm", "cosmic_ray_storm", "false_objects")},
        "nodes": _node_health(run),
    })
    summary["passed"] = bool(unaccounted == 0 and not summary["accounting"]["frames_without_an_outcome_seen"]
                             and summary["nodes"]["all_alive"] and not wrong
                             and summary["stars"]["wrong_guide"] == 0)
    return summary


def _phase_figures(attitudes: list[dict]) -> dict:
    nees = np.array([r["nees"] for r in attitudes])
    return {"scored": len(attitudes), "beyond_60_arcsec": sum(r["cross_arcsec"] > WRONG_ARCSEC for r in attitudes),
            "nees_beyond_5_sigma": int(np.sum(nees > _nees_5_sigma())),
            "nees_mean": float(nees.mean()) if nees.size else None,
            "nees_median": float(np.median(nees)) if nees.size else None}


def _node_health(run: dict) -> dict:
    codes = run.get("exit_codes", {})
    alive = run.get("alive_at_end", {})
    return {"alive_at_end": alive, "exit_codes": codes, "tracebacks_in_logs": run.get("tracebacks", {}),
            "all_alive": bool(alive) and all(alive.values()) and all(code == 0 for code in codes.values())
            and not any(run.get("tracebacks", {}).values())}


def _rate(sent: list[dict], selected) -> dict:
    frames = [r for r in sent if r["copy"] == 0 and selected(r) and r.get("i_verdict") in ("ok", "time_reset")
              and r.get("fault") != "blank"]
    identified = sum(bool(r.get("attitude")) for r in frames)
    return {"frames": len(frames), "identified": identified}


def _count(values) -> dict:
    counts: dict = {}
    for v in values:
        counts[str(v)] = counts.get(str(v), 0) + 1
    return counts


def _count_of(records, key, value) -> int:
    return sum(r.get(key) == value for r in records)


def _nees_5_sigma() -> float:
    from .presets.scoring import NEES_5_SIGMA

    return NEES_5_SIGMA


def recovery(records: list[dict]) -> dict:
    """
    Frames from the end of each stamp jump or dropped burst to the next attitude, per event kind.

    The count starts at the first frame after the event that the identifier accepts by its stamp
    (1: that frame has an attitude) and runs to the end of the mission (None: not recovered in it);
    an event after which the mission ends before such a frame (stamps jumped back by less than
    stamp.reset_after_s stay out of order until they pass the newest) is not judged, only
    counted. Duplicate copies are not counted.
    """
    by_kind: dict[str, list] = {}
    unjudged: dict[str, int] = {}
    late: list[dict] = []
    frames = [r for r in records if r["sent"] and r["copy"] == 0]
    for n, r in enumerate(frames):
        if not r["event"]:
            continue
        count, result = 0, None
        started = False
        for later in frames[n:]:
            if later["mission"] != r["mission"]:
                break
            started = started or later.get("i_verdict") in ("ok", "time_reset")
            if not started:
                continue
            count += 1
            if later.get("attitude"):
                result = count
                break
        if not started:  # the mission ended before the identifier accepted a stamp again: nothing to recover
            unjudged[r["event"]] = unjudged.get(r["event"], 0) + 1
            continue
        by_kind.setdefault(r["event"], []).append(result)
        if result is None or result > 2:
            late.append({"index": r["index"], "event": r["event"], "frames": result, "mission": r["mission"],
                         "statuses": [x.get("status") or x.get("fault") or x.get("i_verdict")
                                      for x in frames[n:n + 6] if x["mission"] == r["mission"]]})
    kinds = {}
    for kind, values in sorted(by_kind.items()):
        done = [v for v in values if v is not None]
        kinds[kind] = {"events": len(values), "within_2": sum(v <= 2 for v in done),
                       "not_recovered_in_mission": len(values) - len(done), "max": max(done) if done else None,
                       "mean": float(np.mean(done)) if done else None}
    return {"by_event": kinds, "events": sum(k["events"] for k in kinds.values()),
            "within_2": sum(k["within_2"] for k in kinds.values()), "later_or_never": late,
            "mission_ended_before_an_accepted_stamp": unjudged}


# ------------------------------------------------------------------------------ the docs section
BEGIN, END = "<!-- stress_nodes -->", "<!-- /stress_nodes -->"


def render_section(summary: dict, heading: str = "### Stress through the nodes") -> str:
    """Return the docs/RELIABILITY.md section of a run's summary (between BEGIN and END), under `heading`."""
    acc, att, stars, rec = summary["accounting"], summary["attitudes"], summary["stars"], summary["recovery"]
    on_path = att.get("on_exposure_path", {})
    c, i = summary["centroider"]["counters"], summary["identifier"]["counters"]
    nodes = summary["nodes"]
    faults = ", ".join(f"{kind.replace('_', ' ')} {n}" for kind, n in summary["faults"].items())
    phases = "; ".join(f"{phase} {p['nees_beyond_5_sigma']} of {p['scored']} (NEES mean {p['nees_mean']:.1f})"
                       for phase, p in att["by_phase"].items())
    parts = []
    for kind, k in rec["by_event"].items():
        missed = k["not_recovered_in_mission"]
        late = f", {missed} not before the mission ended" if missed else ""
        parts.append(f"{kind.replace('_', ' ')} {k['within_2']} of {k['events']} (max {k['max']}{late})")
    events = "; ".join(parts)
    beyond_60 = sum(p["beyond_60_arcsec"] for p in att["by_phase"].values())
    unjudged = sum(rec.get("mission_ended_before_an_accepted_stamp", {}).values())
    environments = "; ".join(f"{env.replace('_', ' ')} {v['identified']} of {v['frames']}"
                             for env, v in summary["identified_by_environment"].items())
    not_identified = ", ".join(f"{k.removeprefix('not_identified_').replace('_', ' ')} {v}"
                               for k, v in summary["identifier"]["not_identified"].items()) or "none"
    refused = " + ".join(f"{k.removeprefix('frames_').replace('_', ' ')} {i.get(k, 0)}" for k in IDENTIFIER_OUTCOMES
                         if i.get(k, 0) and k != "frames_identified")
    lines = [
        heading,
        "",
        f"Command: `{summary.get('command', '')}` — {summary.get('date', '')}, {summary.get('machine', '')}; "
        f"{summary['duration_s'] / 60:.1f} min. The summary is the run's `summary_nodes.json`, every frame's record "
        "`frames_nodes.json`.",
        "",
        "The centroider and identifier as separate processes (`config/star_tracker.yaml`"
        + (" but `rate_source: imu`: the centroider aided by a gyro on `imu`, bias ("
           + ", ".join(f"{b:+.4f}" for b in summary["gyro"]["bias_deg_s"])
           + f") °/s, noise {summary['gyro']['noise_deg_s']} °/s per sample, "
           f"{summary['gyro']['samples_per_frame']} samples per exposure"
           if summary.get("rate_aid") == "gyro" else " as shipped: the identifier's own rate aids the centroider")
        + "), fed by `star_tracker/campaign/stress_nodes.py`, which renders "
        "each frame (1024², 15°, the simulated camera's sensor, Hipparcos to Hp 7.5 at the stamps' date) and sends "
        "it with its CameraInfo, then waits for that frame's outcome before the next: no overload by design, and "
        "frames and stamps do not depend on the host's speed (the identifier's time budget, `max_time_s`, runs on "
        "the wall clock: a solve timed out is counted, `not_identified_timeout`: "
        f"{i.get('not_identified_timeout', 0)} here). "
        f"{summary['missions']} missions of "
        f"{'-'.join(str(n) for n in summary.get('mission_frames', MISSION_FRAMES))} frames at 10 Hz "
        "(rest, slews ≤ 2 °/s², tumbles ≤ 5 °/s, jitter ≤ 20″ to 20 Hz; half of them under a hot-pixel storm or "
        "cosmic rays at 10× or 100× the simulated camera's, or 1-5 bright false objects, planets and debris), "
        f"seed {summary['seed']}; faults in stress_faults.py.",
        "",
        f"- frames: **{summary['frames_sent']:,} sent** ({summary['frames_dropped_before_the_nodes']} more dropped "
        f"before the nodes). Frames per fault (a dropped burst counts its frames, a sensor storm or false "
        f"objects every frame of their missions): {faults}.",
        f"- every frame accounted for: **{'yes' if acc['unaccounted'] == 0 else 'no'}** "
        f"({acc['unaccounted']} unaccounted, {acc['frames_without_an_outcome_seen']} without an outcome within "
        f"{OUTCOME_TIMEOUT_S:.0f} s). Centroider: {c.get('frames_received', 0):,} received = "
        f"{c.get('frames_processed', 0):,} spots published + {c.get('frames_rejected', 0)} rejected (malformed) + "
        f"{c.get('frames_failed', 0)} failed + {c.get('frames_dropped_overload', 0)} dropped by overload. "
        f"Identifier: {i.get('frames_received', 0):,} received = {i.get('frames_identified', 0):,} attitudes + "
        f"{sum(summary['identifier']['not_identified'].values())} not identified ({not_identified}) + {refused}. "
        f"The counters the faults must move match the plan: "
        f"{'all' if not acc['expected_counters_mismatched'] else acc['expected_counters_mismatched']} "
        f"(camera_info_rejected {c.get('camera_info_rejected', 0)} and {i.get('camera_info_rejected', 0)} for "
        f"{summary['bad_camera_info_sent']} bad CameraInfo; time_resets {i.get('time_resets', 0)}).",
        f"- nodes alive at the end: **{'yes' if nodes['all_alive'] else 'no'}**; exit codes after SIGINT "
        f"{nodes['exit_codes']}; tracebacks in the logs {sum(nodes['tracebacks_in_logs'].values())}.",
        f"- attitudes: {att['scored']:,} scored against the truth (the exposure's mean attitude under jitter, "
        f"unless the identifier's status says a gyro's path carried it to mid-exposure), "
        f"**{att['wrong']} wrong** (boresight > 60″ or NEES > 31.8): {beyond_60} beyond 60″ (boresight error "
        f"median {att['cross_arcsec_median']:.2f}″, max {att['cross_arcsec_max']:.2f}″), {att['nees_beyond_5_sigma']} "
        f"with NEES beyond 31.8; NEES mean {att['nees_mean']:.2f}. NEES beyond 31.8 by motion phase (from the "
        f"truth: the rate changing within the exposure is accelerating): {phases}."
        + (f" Carried to mid-exposure by the gyro's path (`exposure_path: true`): {on_path['scored']:,}, "
           f"{on_path['nees_beyond_5_sigma']} beyond 31.8, NEES mean {on_path['nees_mean']:.2f}."
           if on_path.get("scored") else ""),
        f"- star IDs: {stars['matched']:,} matched stars, **{stars['wrong_guide']} wrong guide stars**, "
        f"{stars['wrong_deep']} wrong deep-catalog stars.",
        f"- recovery (frames from the end of a stamp jump or dropped burst to the next attitude, goal ≤ 2): "
        f"**{rec['within_2']} of {rec['events']}** within 2 ({events})"
        + (f"; {unjudged} more ended their mission while the stamps were still out of order" if unjudged else "")
        + ".",
        f"- identified, frames with stars accepted by their stamp: {environments}.",
        f"- spots the identifier dropped from frames as invalid or duplicate (`spots_dropped_invalid`): "
        f"{i.get('spots_dropped_invalid', 0)}.",
    ]
    return "\n".join(lines) + "\n"


def write_section(path: Path, text: str) -> None:
    """Put `text` between BEGIN and END in the Markdown file at `path` (appended when the markers are absent)."""
    write_between_markers(path, text, BEGIN, END)


# ------------------------------------------------------------------------------ command line
def stamp_summary(summary: dict, command: str, output: Path) -> None:
    """Add the command, the date and the machine to a run's summary and write it to OUTPUT/summary_nodes.json."""
    summary["command"] = command
    summary["date"] = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    summary["machine"] = _machine()
    (Path(output) / "summary_nodes.json").write_text(json.dumps(summary, indent=1, default=_json_default) + "\n")


def _machine() -> str:
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                     if line.startswith("model name"))
    except (OSError, StopIteration):
        model = platform.processor() or "unknown CPU"
    return f"{model}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.platform()}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--frames", type=int, default=2000, help="image messages to send (at least)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--output", type=Path, help="directory for summary_nodes.json, "
                        "frames_nodes.json and the nodes' logs")
    parser.add_argument("--every-fault", action="store_true", help="place every fault kind at least once")
    parser.add_argument("--gyro", action="store_true", help="aid the centroider with a biased, noisy gyro on imu "
                        "(rate_source imu) instead of the identifier's rate")
    parser.add_argument("--docs", type=Path, help="write the figures into this Markdown file (docs/RELIABILITY.md) "
                        f"between {BEGIN} and {END}")
    parser.add_argument("--render", type=Path, nargs="+", help="only write --docs from these summary_nodes.json "
                        "(no run; a second one, a run with --gyro, goes under its own sub-heading)")
    args = parser.parse_args(argv)
    if args.render:
        summaries = [json.loads(path.read_text()) for path in args.render]
        headings = ["### Stress through the nodes"] + ["#### The same plan, the centroider aided by a gyro"] * 9
        text = "\n".join(render_section(summary, heading) for summary, heading in zip(summaries, headings))
        text += ("\nThis section: `python -m star_tracker.campaign.stress_nodes --render OUTPUT/summary_nodes.json "
                 "[a --gyro run's] --docs docs/RELIABILITY.md`.\n")
        print(text)
        if args.docs:
            write_section(args.docs, text)
        return 0
    if args.output is None:
        parser.error("--output is required (unless --render)")

    def progress(done: int, total: int) -> None:
        if done % 100 == 0 or done == total:
            print(f"{done}/{total} frames", flush=True)

    summary = run_stress_through_nodes(args.frames, args.seed, args.output, progress,
                                       required=FAULT_KINDS if args.every_fault else (), gyro=args.gyro)
    stamp_summary(summary, "python -m star_tracker.campaign.stress_nodes " + shlex.join(
        sys.argv[1:] if argv is None else argv), args.output)
    if args.docs and "accounting" in summary:
        write_section(args.docs, render_section(summary))
    print(json.dumps({k: summary[k] for k in ("frames_sent", "accounting", "attitudes", "stars", "nodes", "passed")
                      if k in summary}, indent=1, default=_json_default))
    return 0 if summary.get("passed") else 1


if __name__ == "__main__":
    sys.exit(main())
