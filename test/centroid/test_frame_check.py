# SPDX-License-Identifier: Apache-2.0
"""frame_problem: the reason a frame gave too few spots, judged on frames whose trouble is known."""
import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.centroid.frame_check import frame_problem

SHAPE = (240, 320)


def reason(image):
    return frame_problem(image, extract_spots(image, CentroidConfig()), min_spots=4)


def test_blank_frames():
    assert reason(np.zeros(SHAPE, np.uint16)) == "blank frame: every pixel is 0 ADU (no signal, no noise)"
    assert reason(np.full(SHAPE, np.nan, np.float32)) == "blank frame: no finite pixel"


@pytest.mark.parametrize("dtype, level", [(np.uint8, 255), (np.uint16, 65535)])
def test_saturated_frame(dtype, level):
    image = np.full(SHAPE, level, dtype)
    image[:40] = level // 3
    assert reason(image).startswith(f"saturated frame: 83% of the pixels at the clip level {level} ADU")


def test_hot_pixels_alone_are_named_defects():
    rng = np.random.default_rng(3)
    image = rng.normal(1000.0, 10.0, SHAPE)
    image.flat[rng.choice(image.size, 400, replace=False)] = 60000.0  # isolated single-pixel defects
    text = reason(image.astype(np.uint16))
    assert text.startswith("frame dominated by defects:") and "hot pixels / cosmic rays rejected" in text


def test_plain_noise_has_too_few_stars_and_stars_have_no_problem():
    rng = np.random.default_rng(4)
    noise = rng.normal(1000.0, 10.0, SHAPE)
    assert reason(noise.astype(np.uint16)).startswith("too few stars: 0 star spot(s) found, at least 4 needed")
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]]
    for x, y in ((50.3, 60.7), (200.1, 40.2), (120.6, 180.4), (280.2, 200.9), (30.5, 210.5)):
        noise += 3000.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0)
    assert reason(noise.astype(np.uint16)) is None
