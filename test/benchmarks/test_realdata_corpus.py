# SPDX-License-Identifier: Apache-2.0
"""
Every image of the real-image corpus solved by the `solve` command at its defaults.

The corpus is ../shared/realdata (MANIFEST.json); only the manifest's approximate field is
given; each solve is judged against the image's reference pointing (the astrometry.net solve, or the
dense re-fit where the manifest has one: bench/corpus.py).

Two claims per image: a solve is never a wrong one (within 5' of the reference: a false match
lands degrees away), and issue 17's goal, solved within 1'. Images that miss the goal today are
listed with the reason measured; they are strict xfails, so an image that starts meeting it
fails the run until it is taken off the list. Skipped where the corpus is absent.
"""
from __future__ import annotations

import math
import sys
from functools import lru_cache
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import corpus as bench  # noqa: E402

ARCMIN = math.radians(1.0 / 60.0)
WRONG_SOLVE_RAD = 5.0 * ARCMIN  # beyond this a solve is a false identification, not an inaccurate one

# Images short of the 1' goal at defaults, with the cause measured (docs/BENCHMARKS.md § Real images).
# The boresight is judged against the manifest's dense re-fit where it has one (bench/corpus.py):
# the five wide-field images whose few-star astrometry.net reference was 0.9-2.3' off are judged
# against it, and are within 1'.
KNOWN_SHORT = {
    # No reference and not solved by any solver in the benchmark (tetra3rs, cedar-solve neither;
    # astrometry.net, blind on the image, not in 2 400 s of CPU).
    "openstartracker_img1": "not solved: no pattern matched, no stepped field identified",
    # No reference to 1' exists for these two: astrometry.net on the image itself moves its own
    # centre by more than that between SIP orders 2-4.
    "gran_IMG_007985": "1.5-2.2' off with 41-46 stars (the peers 84-88\" off with 15-22); astrometry.net on the image "
                       "itself (80-102 matches, mostly in its top half) moves its centre 170-174\" between SIP orders: "
                       "not settled",
    "ubst_webcam_w1": "1-2.3' off; astrometry.net on the image itself (34-43 matches) moves its centre 91-212\" "
                      "between SIP orders: not settled",
}


def _corpus_ids() -> list[str]:
    try:
        return [image.id for image in bench.load_corpus(bench.find_corpus())]
    except bench.CorpusMissing:
        return []


CORPUS_IDS = _corpus_ids()


@lru_cache(maxsize=None)
def _image(image_id: str) -> bench.CorpusImage:
    return bench.load_corpus(bench.find_corpus(), [image_id])[0]


@lru_cache(maxsize=None)
def _solve(image_id: str) -> tuple[int, dict | None, str]:
    """(exit code, --json document, stderr) of `star-tracker solve IMG --fov F --json` at defaults."""
    code, record, _, err = bench.run_solve_command(bench.solve_argv(_image(image_id)))
    return code, record, err


def _ids_or_skip() -> list:
    return CORPUS_IDS or [pytest.param("absent", marks=pytest.mark.skip(reason="real-image corpus absent "
                                                                        "(../shared/realdata)"))]


def _goal_params() -> list:
    if not CORPUS_IDS:
        return _ids_or_skip()
    return [pytest.param(i, marks=pytest.mark.xfail(strict=True, reason=KNOWN_SHORT[i])) if i in KNOWN_SHORT else i
            for i in CORPUS_IDS]


def test_known_short_list_names_corpus_images():
    if not CORPUS_IDS:
        pytest.skip("real-image corpus absent (../shared/realdata)")
    assert set(KNOWN_SHORT) <= set(CORPUS_IDS)


@pytest.mark.slow
@pytest.mark.parametrize("image_id", _ids_or_skip())
def test_real_image_never_solves_wrong(image_id):
    code, record, err = _solve(image_id)
    assert code in (0, 1), f"{image_id}: exit code {code}: {err.strip()[-300:]}"
    assert record is not None and record.get("solved") == (code == 0)
    if code == 1:
        assert record.get("status"), f"{image_id}: an unsolved image says why"
        return
    image = _image(image_id)
    assert len(record["matched"]) >= 4
    if image.reference is not None:
        boresight, _ = bench.attitude_errors(_rotation(record), image.reference)
        assert boresight < WRONG_SOLVE_RAD, f"{image_id}: {boresight / ARCMIN:.1f}' from the reference"


@pytest.mark.slow
@pytest.mark.parametrize("image_id", _goal_params())
def test_real_image_solved_within_one_arcminute(image_id):
    code, record, _ = _solve(image_id)
    assert code == 0, f"{image_id}: not solved ({(record or {}).get('status')})"
    image = _image(image_id)
    if image.reference is not None:
        boresight, _ = bench.attitude_errors(_rotation(record), image.reference)
        assert boresight <= ARCMIN, f"{image_id}: {boresight / ARCMIN:.2f}' from the reference"


@pytest.mark.slow
@pytest.mark.parametrize("image_id", _ids_or_skip())
def test_real_image_camera_is_fitted_to_the_stars_it_is_reported_with(image_id):
    # A refinement round whose identification lost a marginal match once kept the previous round's
    # camera, fitted to 98 of unh_DSC_0059's 142 reported stars (k2 and the principal point unfitted).
    code, record, _ = _solve(image_id)
    calibration = (record or {}).get("camera", {}).get("calibration")
    if code != 0 or calibration is None:
        pytest.skip(f"{image_id}: not solved or no camera refined")
    assert calibration["stars"] >= 0.9 * len(record["matched"]), (calibration, len(record["matched"]))


@pytest.mark.slow
@pytest.mark.skipif("gran_IMG_007985" not in CORPUS_IDS, reason="real-image corpus absent (../shared/realdata)")
def test_stars_under_cloud_texture_are_matched():
    # A cloud bank's elongated blobs pointing every way crowded the stars out of the spot list:
    # 19 stars matched, tetra3rs 22 (the best peer, docs/BENCHMARKS.md § Real images). `solve`
    # centroids again with the texture ranked last (centroid/detection/texture.py) and keeps that solve.
    code, record, _ = _solve("gran_IMG_007985")
    assert code == 0 and record["texture_last"], (record or {}).get("reason")
    assert len(record["matched"]) >= 22


def _rotation(record: dict):
    import numpy as np

    from star_tracker.models.attitude import quaternion_to_matrix

    return quaternion_to_matrix(np.asarray(record["quaternion_xyzw"], float))


# Real photographs with only an approximate field given (3-4 % off): the scale-free patterns
# find it (identify/scale_free.py).
APPROXIMATE_FIELD_CASES = [("gran_vega_05sec", 0.96), ("oresat_capture_2022_09_25", 1.03), ("lost_img_7660", 0.97)]


@pytest.mark.slow
@pytest.mark.parametrize("image_id, hint_factor", APPROXIMATE_FIELD_CASES if CORPUS_IDS else
                         [pytest.param("absent", 1.0, marks=pytest.mark.skip(reason="real-image corpus absent"))])
def test_real_image_with_an_approximate_field(image_id, hint_factor):
    image = _image(image_id)
    argv = ["solve", str(image.path), "--fov", f"{image.fov_h_deg * hint_factor:g}", "--json", "--quiet"]
    code, record, _, err = bench.run_solve_command(argv)
    assert code == 0, f"{image_id}: {(record or {}).get('reason')} {err[-200:]}"
    patterns = record["attempts"][0]
    assert patterns["search"] == "patterns" and patterns["fields_deg"]
    assert patterns["fields_deg"][0] == pytest.approx(image.fov_h_deg, rel=1e-2)  # the manifest's (edge to edge)
    boresight, _ = bench.attitude_errors(_rotation(record), image.reference)
    assert boresight <= 2.5 * ARCMIN  # lost_img_7660's wide lens: 1.4' without a distortion model
