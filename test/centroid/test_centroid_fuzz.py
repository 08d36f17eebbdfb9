# SPDX-License-Identifier: Apache-2.0
"""
Property-based tests (hypothesis) of spot extraction (star_tracker.centroid) on hostile frames.

Frames as a sensor, a fault or an attacker makes them: spots with finite values, or ValueError
with a message; never another exception. What the identifier node keeps of them (convert.drop_invalid_spots)
is checked too. Defects found by fuzzing are pinned at the end, each with its failing input
(docs/RELIABILITY.md, "Defects found by fuzzing in the core").
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
pytest.importorskip("rclpy")  # convert.drop_invalid_spots lives with the message converters

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.centroid import CENTROID_METHODS, CentroidConfig, extract_spots  # noqa: E402
from star_tracker.centroid.streak.smear import SmearModel  # noqa: E402
from star_tracker.ros import convert  # noqa: E402

from fuzz_support import examples, valid_or_value_error  # noqa: E402


@st.composite
def frames(draw):
    """
    Small images as a sensor, a fault or an attacker makes them.

    Constant (black, saturated), noise, star-like blobs, hot pixels, stripes, with any config
    and sometimes a rate aid.
    """
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    top = np.iinfo(dtype).max
    height, width = draw(st.integers(1, 48)), draw(st.integers(1, 48))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    kind = draw(st.sampled_from(["constant", "noise", "stars", "uniform", "stripes"]))
    level = draw(st.sampled_from([0, 1, 100, top // 2, top - 1, top]))
    image = np.full((height, width), float(level))
    if kind in ("noise", "stars"):
        image += rng.normal(0, draw(st.sampled_from([0.5, 3.0, 30.0])), image.shape)
    if kind == "stars":
        yy, xx = np.mgrid[:height, :width]
        for _ in range(draw(st.integers(1, 6))):
            x0, y0 = rng.uniform(-2, width + 1), rng.uniform(-2, height + 1)
            sigma, amp = rng.uniform(0.3, 3.0), rng.uniform(5, 2 * top)
            image += amp * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * sigma**2))
        image[rng.integers(0, height), rng.integers(0, width)] = top  # a hot pixel
    elif kind == "uniform":
        image = rng.uniform(0, top, image.shape)
    elif kind == "stripes":
        image[:, ::2] = top
    image = np.clip(np.round(image), 0, top).astype(dtype)
    psf = draw(st.sampled_from([0.0, 0.5, 1.0, 2.5]))
    method = draw(st.sampled_from(CENTROID_METHODS if psf > 0 else ("cog", "wcog")))
    min_area = draw(st.integers(1, 5))
    config = CentroidConfig(detection_sigma=draw(st.sampled_from([1.0, 3.0, 4.5, 20.0])),
                            binning=draw(st.sampled_from([1, 2])), min_area=min_area,
                            max_area=draw(st.integers(min_area, 3000)), min_snr=draw(st.sampled_from([0.0, 5.0])),
                            background_block_px=draw(st.sampled_from([4, 8, 32])),
                            saturation_adu=draw(st.sampled_from([0.0, 50.0, float(top)])),
                            max_spots=draw(st.integers(1, 50)), method=method, psf_sigma_px=psf,
                            split_blends=draw(st.booleans()))
    smear = None
    if draw(st.booleans()):
        camera = CameraModel.from_fov(width, height, np.radians(draw(st.floats(1.0, 40.0))))
        omega = np.radians(draw(st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3)))
        smear = SmearModel(camera, omega, draw(st.sampled_from([1e-3, 0.1, 1.0])))
    return image, config, smear


@examples(400)
@given(frames())
@pytest.mark.slow  # ~5 s warm, ~30 s compiling
def test_extract_spots_on_any_frame(frame):
    """
    Spots with finite positions, fluxes and SNRs, or ValueError.

    Covariances and positions outside the image are pinned below as known defects; the
    identifier node drops such spots (convert.drop_invalid_spots), which is checked here too.
    """
    image, config, smear = frame
    spots = valid_or_value_error(extract_spots, image, config, smear)
    if spots is None:
        return
    assert len(spots) <= config.max_spots
    for values in (spots.x, spots.y, spots.flux, spots.snr):
        assert np.all(np.isfinite(values))
    kept, _ = convert.drop_invalid_spots(spots)
    assert np.all(np.isfinite(kept.cov))


@pytest.mark.parametrize("shape", [(1, 1), (1, 4096), (4096, 1), (2, 2), (3, 70000)])
@pytest.mark.parametrize("fill", ["zeros", "saturated", "checker"])
def test_extract_spots_on_degenerate_shapes(shape, fill):
    for dtype in (np.uint8, np.uint16):
        top = np.iinfo(dtype).max
        image = {"zeros": np.zeros(shape, dtype), "saturated": np.full(shape, top, dtype),
                 "checker": (np.indices(shape).sum(0) % 2 * top).astype(dtype)}[fill]
        spots = extract_spots(image, CentroidConfig())
        assert np.all(np.isfinite(spots.x)) and np.all(np.isfinite(spots.cov))
    with pytest.raises(ValueError, match="non-empty 2-D image"):
        extract_spots(np.zeros((0, 5), np.uint16))


# ============================================================================ defects found, fixed
SATURATED_STRIP = np.full((3, 16), 255, np.uint8)  # a fully saturated frame
EXTREME = dict(detection_sigma=1.0, binning=1, min_area=1, min_snr=0.0, split_blends=False)  # allowed parameters


def test_saturated_spot_covariance_is_finite():
    """Found by fuzzing: a saturated spot of ~0 flux got a NaN covariance."""
    spots = extract_spots(SATURATED_STRIP, CentroidConfig(**EXTREME, background_block_px=4, method="cog",
                                                          psf_sigma_px=0.0))
    assert np.all(np.isfinite(spots.cov))


def test_streak_fit_on_a_saturated_frame():
    """
    Found by fuzzing: the streak fit did int(NaN) on this valid frame and refused it.

    The frame is measured: its spot has finite values and lies in the image.
    """
    image = SATURATED_STRIP.copy()
    image[0, 9] = 254
    spots = extract_spots(image, CentroidConfig(**EXTREME, background_block_px=4, method="streak", psf_sigma_px=0.5))
    assert len(spots) >= 1
    for values in (spots.x, spots.y, spots.flux, spots.snr, spots.cov, spots.streak_length, spots.streak_angle):
        assert np.all(np.isfinite(values))
    assert np.all((spots.x > -0.5) & (spots.x < 15.5) & (spots.y > -0.5) & (spots.y < 2.5))


def test_centre_of_gravity_stays_in_the_image():
    """Found by fuzzing: a near-zero-flux centre of gravity landed far outside the image."""
    image = np.random.default_rng(0).integers(0, 256, (19, 42), dtype=np.uint8)
    spots = extract_spots(image, CentroidConfig(**EXTREME, max_area=10, background_block_px=32, max_spots=9,
                                                method="cog", psf_sigma_px=0.0))
    inside = (spots.x > -1) & (spots.x < 42) & (spots.y > -1) & (spots.y < 19)
    assert np.all(inside | (spots.flags != 0))
