"""identifier: lost-in-space star identification + QUEST attitude from `spots`.

Needs the camera model from `camera_info`. Publishes attitude, attitude_with_covariance and
matched_stars with the spots' stamp, only for verified solutions; otherwise it publishes
nothing, logs why and reports it on /diagnostics.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, PointCloud2

from ..attitude import ARCSEC
from ..camera import CameraModel
from ..identify import ALGORITHMS, DEFAULT_ALGORITHM, DatabaseConfig, IdentifyConfig, load_or_build_database, make_identifier
from . import convert
from .common import IMAGE_QOS, RESULT_QOS, SPOTS_QOS, CameraInfoInput, Diagnostics, ThrottledLog, declare, run_node


class IdentifierNode(Node):
    def __init__(self) -> None:
        super().__init__("identifier")
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        algorithm = p("algorithm", DEFAULT_ALGORITHM, f"identification algorithm: one of {sorted(ALGORITHMS)}")
        self.frame_id = p("frame_id", convert.ICRS_FRAME, "parent frame of the published attitude")
        db_config = DatabaseConfig(
            magnitude_limit=p("database.magnitude_limit", 6.5, "faintest guide star [Hp mag]", -2.0, 12.0),
            max_pair_angle_rad=np.radians(p("database.max_pair_angle_deg", 22.0,
                                            "largest stored star separation; >= the camera's diagonal FOV [deg]", 0.1, 90.0)),
            epoch_jyear=p("database.epoch_jyear", 2026.0, "epoch of guide-star positions [Julian year]", 1900.0, 2200.0),
        )
        self.config = IdentifyConfig(
            max_pattern_spots=p("max_pattern_spots", 12, "brightest spots used to form patterns", 3, 100),
            sigma_multiplier=p("sigma_multiplier", 3.0, "pattern tolerance [sigmas]", 0.1, 20.0),
            angle_tolerance_floor_rad=p("angle_tolerance_floor_rad", 2.0e-5, "added angle tolerance [rad]", 0.0, 0.01),
            centroid_sigma_floor_px=p("centroid_sigma_floor_px", 0.05, "smallest spot 1-sigma [px]", 1e-4, 10.0),
            match_radius_px=p("match_radius_px", 1.5, "verification match radius [px]", 0.01, 50.0),
            false_positive_bound=p("false_positive_bound", 1.0e-6, "largest accepted chance-match probability", 1e-30, 0.5),
            max_time_s=p("max_time_s", 0.5, "time budget per frame [s]", 1e-3, 60.0),
        )
        started = time.perf_counter()
        self.database = load_or_build_database(db_config)
        self.identifier = make_identifier(algorithm, self.database, self.config)
        if hasattr(self.identifier, "warm_up"):  # compiled kernels: ~50 s the first time, then cached
            self.identifier.warm_up(CameraModel.from_fov(1024, 1024, np.radians(15.0)))
        self.get_logger().info(
            f"algorithm {algorithm}: {self.database.star_count} guide stars to Hp {db_config.magnitude_limit}, "
            f"{self.database.pair_a.size} pairs, loaded in {time.perf_counter() - started:.2f} s")

        self.pub_attitude = self.create_publisher(QuaternionStamped, "attitude", RESULT_QOS)
        self.pub_pose = self.create_publisher(PoseWithCovarianceStamped, "attitude_with_covariance", RESULT_QOS)
        self.pub_matches = self.create_publisher(PointCloud2, "matched_stars", RESULT_QOS)
        self.diag = Diagnostics(self)
        self.diag.values["algorithm"] = algorithm
        self.log = ThrottledLog(self)
        self.camera_info = CameraInfoInput(self, self.diag, self.log, check=self.fov_problem)
        self.sub_info = self.create_subscription(CameraInfo, "camera_info", self.camera_info.update, IMAGE_QOS)
        self.sub_spots = self.create_subscription(PointCloud2, "spots", self.on_spots, SPOTS_QOS)

    def fov_problem(self, camera) -> str | None:
        """Why the pattern database cannot serve this camera, or None."""
        diagonal = 2 * camera.half_diagonal_fov_rad
        limit = self.database.config.max_pair_angle_rad
        if diagonal > limit:
            return (f"camera diagonal FOV {np.degrees(diagonal):.2f} deg exceeds database.max_pair_angle_deg "
                    f"{np.degrees(limit):.2f}")
        return None

    def on_spots(self, msg: PointCloud2) -> None:
        self.diag.count("frames_received")
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        camera = self.camera_info.camera
        if camera is None:
            self.diag.count("frames_without_camera_info")
            self.diag.set(DiagnosticStatus.WARN, "waiting for camera_info")
            self.log.warn("no_info", "spots received before any valid camera_info; frame skipped")
            return
        try:
            spots = convert.cloud_to_spots(msg, camera.width, camera.height)
        except ValueError as exc:
            self.diag.count("frames_rejected")
            self.diag.set(DiagnosticStatus.WARN, f"rejected spots: {exc}")
            self.log.warn("bad_spots", f"rejected spots message: {exc}")
            return
        result = self.identifier.identify(spots, camera)
        self.diag.values["last_identify_ms"] = f"{result.elapsed_s * 1e3:.2f}"
        if not result.solved:
            self.diag.count(f"not_identified_{result.status}")
            self.diag.set(DiagnosticStatus.WARN, f"not identified: {result.reason}", last_spot_count=len(spots))
            self.log.warn("unsolved", f"frame {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d} not identified: {result.reason}")
            return
        solution = result.attitude
        self.pub_attitude.publish(convert.quaternion_msg(solution.quaternion, stamp_ns, self.frame_id))
        self.pub_pose.publish(convert.pose_with_covariance_msg(solution, stamp_ns, self.frame_id))
        magnitudes = self.database.magnitude[np.searchsorted(self.database.hip, result.hip)]  # hip is sorted
        self.pub_matches.publish(convert.identification_to_cloud(result, spots, magnitudes, stamp_ns, self.frame_id))
        self.diag.count("frames_identified")
        sigma = np.sqrt(np.diag(solution.covariance)) / ARCSEC
        self.diag.set(DiagnosticStatus.OK, "identified", last_stars_matched=result.hip.size,
                      last_spot_count=len(spots), last_sigma_arcsec_xyz=f"{sigma[0]:.2f},{sigma[1]:.2f},{sigma[2]:.2f}",
                      last_false_positive_bound=f"{result.false_positive_probability:.1e}")


def main(argv: list[str] | None = None) -> None:
    sys.exit(run_node(IdentifierNode, argv))


if __name__ == "__main__":
    main()
