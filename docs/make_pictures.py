# SPDX-License-Identifier: Apache-2.0
"""
Regenerate the pictures of README.md's "Pictures" section (docs/images/).

    python docs/make_pictures.py [--output-dir docs/images]

- solve_frame.jpg: `star-tracker solve --plot` on a rendered frame of Orion given a 4 % wrong
  field of view (identified stars, residual vectors, unmatched spots);
- sky_chart.png: the sky chart of that field with the identified stars circled;
- run_attitude_rate.png: attitude error and body rate against time for 20 s of a 20 deg slew
  at up to 2 deg/s, rendered -> centroided -> tracked (the identifier's core, in process).
Everything comes from the simulator: no third-party image is redistributed.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from star_tracker import visualize  # noqa: E402
from star_tracker.models.attitude import attitude_error, quaternion_to_matrix, radec_roll_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.models.catalog import load_hipparcos  # noqa: E402
from star_tracker.commands.__main__ import main as commands  # noqa: E402


def solve_pictures(out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        frame = Path(tmp) / "orion.png"
        assert commands(["render", "--ra", "83.8", "--dec", "-1.0", "--roll", "20", "--rate", "0.05", "0.05", "0",
                         "--seed", "1", "-o", str(frame)]) == 0
        solution_path = Path(tmp) / "solution.json"
        import contextlib
        import io

        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            code = commands(["solve", str(frame), "--fov", "15.6", "--json", "-q", "--plot",
                             str(Path(tmp) / "plot.png")])
        assert code == 0, buffer.getvalue()
        import cv2  # a noisy frame compresses badly as PNG: JPEG at ~1/6 of the size

        cv2.imwrite(str(out / "solve_frame.jpg"), cv2.imread(str(Path(tmp) / "plot.png")),
                    [cv2.IMWRITE_JPEG_QUALITY, 85])
        solution = json.loads(buffer.getvalue())
        solution_path.write_text(buffer.getvalue())
    rotation = quaternion_to_matrix(np.array(solution["quaternion_xyzw"]))
    camera = CameraModel(**{k: solution["camera"][k] for k in ("width", "height", "fx", "fy", "cx", "cy")})
    figure = visualize.sky_chart(load_hipparcos().at_epoch(2026.0), rotation, camera,
                                 [m["hip"] for m in solution["matched"]], magnitude_limit=7.0,
                                 title=f"Orion: the solved field (RA {solution['ra_deg']:.2f}°, "
                                       f"Dec {solution['dec_deg']:+.2f}°), {len(solution['matched'])} stars identified")
    visualize.save_figure(figure, out / "sky_chart.png")


def run_picture(out: Path, rate_hz: float = 5.0, duration_s: float = 20.0) -> None:
    from star_tracker.centroid import extract_spots
    from star_tracker.identify import DatabaseConfig, load_or_build_database, make_identifier
    from star_tracker.track.tracking import Tracker
    from star_tracker.sim.motion import SlewMotion
    from star_tracker.sim.render import StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    camera = CameraModel.from_fov(1024, 1024, math.radians(15.0))
    renderer = StarFieldRenderer(camera, SensorModel(), load_hipparcos().at_epoch(2026.0), magnitude_limit=7.5)
    motion = SlewMotion(radec_roll_to_matrix(math.radians(80.0), math.radians(20.0), 0.0),
                        axis=np.array([0.6, 0.8, 0.0]),
                        angle_rad=math.radians(20.0), max_rate_rad_s=math.radians(2.0),
                        accel_rad_s2=math.radians(0.5), t_start=3.0)
    identifier = make_identifier("hybrid", load_or_build_database(DatabaseConfig()))
    tracker = Tracker(identifier)
    tracker.warm_up(camera)
    n = int(duration_s * rate_hz)
    arrays = {"time_s": np.arange(n) / rate_hz, "cross_boresight_arcsec": np.full(n, np.nan),
              "roll_arcsec": np.full(n, np.nan), "sigma_cross_arcsec": np.full(n, np.nan),
              "sigma_roll_arcsec": np.full(n, np.nan), "rate_deg_s": np.full((n, 3), np.nan),
              "true_rate_deg_s": np.full((n, 3), np.nan)}
    for k, t in enumerate(arrays["time_s"]):
        frame = renderer.render(motion, float(t), frame_seed(0, k))
        arrays["true_rate_deg_s"][k] = np.degrees(frame.truth.body_rate)
        result = tracker.process(int(round(t * 1e9)), extract_spots(frame.image), camera)
        if result.solved:
            attitude = result.identification.attitude
            error = np.degrees(attitude_error(attitude.rotation, frame.truth.rotation)) * 3600
            arrays["cross_boresight_arcsec"][k], arrays["roll_arcsec"][k] = error[0], error[1]
            sigma = np.degrees(np.sqrt(np.diag(attitude.covariance))) * 3600
            arrays["sigma_cross_arcsec"][k], arrays["sigma_roll_arcsec"][k] = math.hypot(sigma[0], sigma[1]), sigma[2]
        if result.rate is not None:
            arrays["rate_deg_s"][k] = np.degrees(result.rate.angular_velocity)
    identified = int(np.isfinite(arrays["cross_boresight_arcsec"]).sum())
    figure = visualize.run_figure(**arrays, title=f"20° slew at up to 2°/s, {rate_hz:g} Hz: {identified}/{n} frames "
                                                  "identified (render → centroid → tracker)")
    visualize.save_figure(figure, out / "run_attitude_rate.png")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--output-dir", type=Path, default=REPO / "docs" / "images")
    args = parser.parse_args(argv)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    solve_pictures(args.output_dir)
    run_picture(args.output_dir)
    for name in ("solve_frame.jpg", "sky_chart.png", "run_attitude_rate.png"):
        path = args.output_dir / name
        print(f"wrote {path} ({path.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
