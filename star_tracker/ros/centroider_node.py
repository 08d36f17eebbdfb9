"""centroider: extracts star spots from any mono8/mono16 Image and publishes `spots`.

The spots message carries the image's header unchanged (stamp = mid-exposure). A malformed
image is logged, counted in /diagnostics and skipped; the next good one is processed.
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import Image, PointCloud2

from ..centroid import CentroidConfig, extract_spots
from . import convert
from .common import IMAGE_QOS, SPOTS_QOS, Diagnostics, ThrottledLog, declare, run_node


class CentroiderNode(Node):
    def __init__(self) -> None:
        super().__init__("centroider")
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.config = CentroidConfig(
            detection_sigma=p("detection_sigma", 5.0, "detection threshold [noise sigmas]", 1.0, 100.0),
            min_area=p("min_area", 2, "smallest accepted spot [px]", 1, 10000),
            max_area=p("max_area", 5000, "largest accepted spot [px]", 1, 1000000),
            min_snr=p("min_snr", 5.0, "smallest reported SNR", 0.0, 1e6),
            background_block_px=p("background_block_px", 32, "background mesh size [px]", 4, 1024),
            gain_e_per_adu=p("gain_e_per_adu", 1.0, "sensor gain for the shot-noise term [e-/ADU]", 1e-3, 1e4),
            saturation_adu=p("saturation_adu", 0.0, "saturation level [ADU]; 0 = dtype maximum", 0.0, 1e9),
            max_spots=p("max_spots", 500, "most spots reported per frame (brightest)", 1, 100000),
            method=p("method", "gaussian", "sub-pixel method: gaussian (PSF fit; streaks use cog) or cog (centre of gravity)"),
            psf_sigma_px=p("psf_sigma_px", 1.0, "expected PSF 1-sigma for the shape test; 0 = no shape test [px]", 0.0, 50.0),
            max_peak_fraction=p("max_peak_fraction", 0.5, "reject a spot whose brightest pixel holds more of its flux "
                                                           "(hot pixels) [-]", 0.01, 1.0),
            min_width_fraction=p("min_width_fraction", 0.6, "reject a spot narrower than this x psf_sigma_px^2 "
                                                             "(cosmic rays) [-]", 0.0, 1.0),
            shape_min_snr=p("shape_min_snr", 10.0, "smallest SNR for the width test", 0.0, 1e6),
        )
        self.pub = self.create_publisher(PointCloud2, "spots", SPOTS_QOS)
        self.sub = self.create_subscription(Image, "image_raw", self.on_image, IMAGE_QOS)
        self.diag = Diagnostics(self)
        self.log = ThrottledLog(self)

    def on_image(self, msg: Image) -> None:
        started = time.perf_counter()
        self.diag.count("frames_received")
        try:
            image = convert.image_to_array(msg)
            spots = extract_spots(image, self.config)
        except ValueError as exc:
            self.diag.count("frames_rejected")
            self.diag.set(DiagnosticStatus.WARN, f"rejected frame: {exc}")
            self.log.warn("bad_image", f"rejected image (stamp {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}): {exc}")
            return
        out = convert.spots_to_cloud(spots, convert.stamp_to_ns(msg.header.stamp), msg.header.frame_id)
        out.header = msg.header  # unchanged stamp and frame
        self.pub.publish(out)
        self.diag.count("frames_processed")
        self.diag.count("spots_rejected_shape", spots.rejected_shape)
        self.diag.set(DiagnosticStatus.OK, "ok", last_spot_count=len(spots),
                      last_processing_ms=f"{(time.perf_counter() - started) * 1e3:.2f}",
                      last_noise_adu=f"{spots.noise_adu:.2f}")


def main(argv: list[str] | None = None) -> None:
    sys.exit(run_node(CentroiderNode, argv))


if __name__ == "__main__":
    main()
