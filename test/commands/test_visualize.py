# SPDX-License-Identifier: Apache-2.0
"""Pictures (star_tracker/visualize.py): what is drawn lands where the data says."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from star_tracker import visualize  # noqa: E402
from star_tracker.models.attitude import radec_roll_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402

GREEN = np.array([0x3C, 0xDC, 0x3C]) / 255.0  # identified stars
ORANGE = np.array([0xFF, 0xB0, 0x00]) / 255.0  # residual arrows, image outline


def raster(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3] / 255.0


def colour_near(pixels: np.ndarray, display_xy, colour, radius: int) -> int:
    """Pixels of `colour` within `radius` of a matplotlib display point (origin bottom left)."""
    height = pixels.shape[0]
    x, y = int(round(display_xy[0])), int(round(height - display_xy[1]))
    window = pixels[max(y - radius, 0):y + radius + 1, max(x - radius, 0):x + radius + 1]
    return int(np.sum(np.all(np.abs(window - colour) < 0.12, axis=2)))


def test_solution_figure_circles_the_stars_and_draws_residuals(tmp_path):
    rng = np.random.default_rng(1)
    image = rng.normal(100, 3, (300, 400)).astype(np.float32)
    stars = [(80.0, 60.0, 101), (300.0, 220.0, 202), (200.0, 150.0, 303)]
    for x, y, _ in stars:
        yy, xx = np.mgrid[0:300, 0:400]
        image += 2000 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0)
    matched = [{"x": x, "y": y, "predicted_x": x + 0.2, "predicted_y": y, "hip": h, "magnitude": 3.0}
               for x, y, h in stars]
    unmatched = np.array([[30.0, 250.0]])
    fig = visualize.solution_figure(image, matched, unmatched, "a title", residual_scale=100.0)
    ax = fig.axes[0]
    pixels = raster(fig)
    for x, y, _ in stars:  # a green circle of ~7 px radius around each star, none far away
        centre = ax.transData.transform((x, y))
        assert colour_near(pixels, centre, GREEN, 12) > 10
    assert colour_near(pixels, ax.transData.transform((30.0, 150.0)), GREEN, 5) == 0
    # The residual (0.2 px right) magnified 100x: an orange arrow reaching ~20 px right of the star.
    x, y, _ = stars[1]
    assert colour_near(pixels, ax.transData.transform((x + 15.0, y)), ORANGE, 3) > 0
    assert colour_near(pixels, ax.transData.transform((x, y + 15.0)), ORANGE, 3) == 0
    labels = [t.get_text() for t in ax.texts]
    assert sorted(labels) == ["HIP 101", "HIP 202", "HIP 303"]
    assert any("unmatched spots (1)" == t.get_text() for t in ax.get_legend().get_texts())
    path = visualize.save_figure(fig, tmp_path / "f.png")
    import cv2

    assert cv2.imread(path).shape[1] == 900  # 9 in at 100 dpi


def test_sky_chart_projects_stars_and_the_image_outline(catalog):
    camera = CameraModel.from_fov(1024, 1024, math.radians(15.0))
    rotation = radec_roll_to_matrix(math.radians(83.8), math.radians(-1.0), math.radians(20.0))
    sky = catalog.at_epoch(2026.0)
    alnilam = sky.index_of(26311)  # epsilon Ori, the middle star of Orion's belt
    fig = visualize.sky_chart(sky, rotation, camera, identified_hip=[26311], magnitude_limit=6.0)
    ax = fig.axes[0]
    # The image outline: the field's edges at +-7.5 deg along x through the boresight.
    outline = next(line for line in ax.lines if line.get_label() == "image")
    x, y = outline.get_data()
    assert np.max(x) == pytest.approx(7.5, abs=0.01) and np.min(x) == pytest.approx(-7.5, abs=0.01)
    assert np.max(y) == pytest.approx(7.5, abs=0.01)
    # The identified star is circled where the camera sees it (gnomonic about the boresight).
    body = sky.unit_vectors()[alnilam] @ rotation
    star_xy = (math.degrees(math.atan(body[0] / body[2])), -math.degrees(math.atan(body[1] / body[2])))
    circled = ax.collections[1].get_offsets()
    assert len(circled) == 1 and np.allclose(circled[0], star_xy, atol=1e-6)
    assert colour_near(raster(fig), ax.transData.transform(star_xy), GREEN, 12) > 10
    # Dots: the catalog's stars to Hp 6 inside the chart, the brightest largest.
    dots = ax.collections[0]
    sizes = dots.get_sizes()
    assert len(dots.get_offsets()) > 50 and sizes.max() > 20 * sizes.min()
    assert "identified (1)" in [t.get_text() for t in ax.get_legend().get_texts()]


def test_run_figure_and_run_arrays():
    arcsec = math.radians(1 / 3600)

    def record(k, identified=True):
        error = (0.5 * arcsec * (k + 1), 3.0 * arcsec, 0.0) if identified else None
        return SimpleNamespace(stamp_ns=1_000_000_000 + k * 200_000_000, truth=np.eye(3), error=lambda e=error: e,
                               covariance=np.diag([1.0, 1.0, 4.0]) * arcsec**2 if identified else None,
                               rate=np.radians([0.1, 0.0, 0.0]) if identified else None,
                               truth_rate=np.radians([0.1, 0.0, 0.0]))

    frames = [record(0), record(1), record(2, identified=False), record(3)]
    frames.append(SimpleNamespace(stamp_ns=0, truth=None))  # no truth: left out
    arrays = visualize.run_arrays(frames)
    assert arrays["time_s"] == pytest.approx([0.0, 0.2, 0.4, 0.6])
    assert arrays["cross_boresight_arcsec"][[0, 1, 3]] == pytest.approx([0.5, 1.0, 2.0])
    assert np.isnan(arrays["cross_boresight_arcsec"][2]) and arrays["roll_arcsec"][0] == pytest.approx(3.0)
    assert arrays["sigma_cross_arcsec"][0] == pytest.approx(math.sqrt(2.0))
    assert arrays["sigma_roll_arcsec"][0] == pytest.approx(2.0)
    assert arrays["rate_deg_s"][0] == pytest.approx([0.1, 0.0, 0.0]) and np.isnan(arrays["rate_deg_s"][2]).all()

    fig = visualize.run_figure(**arrays, title="run")
    error_axes, rate_axes = fig.axes
    lines = {line.get_label(): line for line in error_axes.lines}
    assert lines["cross-boresight error"].get_ydata()[3] == pytest.approx(2.0)
    assert lines["3σ roll"].get_ydata()[0] == pytest.approx(6.0)
    assert lines["not identified (1)"].get_xdata() == pytest.approx([0.4])
    rate_lines = {line.get_label(): line for line in rate_axes.lines}
    assert rate_lines["estimated ωx"].get_ydata()[1] == pytest.approx(0.1)
    single = visualize.run_figure(arrays["time_s"], arrays["cross_boresight_arcsec"], arrays["roll_arcsec"])
    assert len(single.axes) == 1  # no rate given: the error panel alone
