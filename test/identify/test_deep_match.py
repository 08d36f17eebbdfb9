# SPDX-License-Identifier: Apache-2.0
"""
The deep re-match (identify/deep_match.py): faint stars beyond the guide stars, judged by truth.

Simulated frames know which star made each spot; the real images are judged by
astrometry.net's independent TAN-SIP solutions (reference attitude, .anet.wcs), never by
our own solve.
"""
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from star_tracker.centroid import CentroidConfig, Spots, extract_spots
from star_tracker.identify import IdentifyConfig, make_identifier
from star_tracker.identify.deep_catalog import load_or_build_deep_catalog
from star_tracker.models.attitude import matrix_to_rotation_vector, quaternion_to_matrix
from star_tracker.models.catalog import radec_to_unit, unit_to_radec
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import KIND_STAR, StarFieldRenderer
from star_tracker.sim.sensor import SensorModel

from test_identify import random_rotation, synthetic_scene

ARCSEC = math.radians(1.0 / 3600.0)
REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def error_rad(rotation, truth):
    return float(np.linalg.norm(matrix_to_rotation_vector(truth.T @ rotation)))


def solve_both(database, spots, camera, **config):
    """Return the guide-only and the deep identification of the same spots."""
    results = []
    for deep in (False, True):
        identifier = make_identifier("hybrid", database, IdentifyConfig(deep_match=deep, max_time_s=5.0, **config))
        results.append(identifier.identify(spots, camera))
    return results


def test_deep_rematch_adds_the_faint_stars_without_a_wrong_id(database, nominal_camera, catalog):
    """
    Spots of every star to Hp 8.5 (guide stars to 6.5).

    The deep catalog names the faint ones, every id is the truth's, and the attitude error
    against truth shrinks.
    """
    rng = np.random.default_rng(31)
    errors = {False: [], True: []}
    for _ in range(12):
        truth = random_rotation(rng)
        spots, hip = synthetic_scene(catalog, nominal_camera, truth, rng, noise_px=0.1, magnitude_limit=8.5)
        guide, deep = solve_both(database, spots, nominal_camera)
        assert guide.solved and deep.solved, (guide.reason, deep.reason)
        assert not guide.deep.any()
        np.testing.assert_array_equal(deep.hip, hip[deep.spot_index])  # every id, guide and deep, is right
        faint = ~np.isin(hip, database.hip)
        assert deep.deep_count >= 0.8 * np.count_nonzero(faint), (deep.deep_count, np.count_nonzero(faint), deep.stats)
        # Mostly stars fainter than the guide stars; the others are guide-database outcasts (blends).
        assert np.mean(deep.magnitude[deep.deep] > database.config.magnitude_limit) > 0.9
        assert set(guide.hip) <= set(deep.hip)
        assert deep.false_positive_probability <= guide.false_positive_probability
        for key, result in ((False, guide), (True, deep)):
            errors[key].append(error_rad(result.attitude.rotation, truth))
    assert np.median(errors[True]) < 0.7 * np.median(errors[False]), (np.median(errors[True]) / ARCSEC,
                                                                      np.median(errors[False]) / ARCSEC)


def test_uncatalogued_spots_get_no_deep_identity(database, nominal_camera, catalog):
    """
    Check that false objects of every brightness among the stars are never named.

    The way a deep match could go wrong: a chance catalog star in an uncatalogued spot's gate.
    """
    rng = np.random.default_rng(32)
    for _ in range(8):
        truth = random_rotation(rng)
        spots, hip = synthetic_scene(catalog, nominal_camera, truth, rng, noise_px=0.1, magnitude_limit=8.5)
        n_false = 60
        fx, fy = rng.uniform(0, nominal_camera.width - 1, n_false), rng.uniform(0, nominal_camera.height - 1, n_false)
        flux = 10 ** (-0.4 * rng.uniform(4.0, 10.0, n_false)) * 1e5
        x, y = np.concatenate([spots.x, fx]), np.concatenate([spots.y, fy])
        n = x.size
        mixed = Spots(x, y, np.concatenate([spots.flux, flux]), np.full(n, 50.0), np.tile(np.eye(2) * 0.01, (n, 1, 1)),
                      np.zeros(n, np.uint32), np.full(n, 9, np.int32), np.concatenate([spots.flux, flux]) / 10,
                      nominal_camera.width, nominal_camera.height)
        truth_hip = np.concatenate([hip, np.zeros(n_false, hip.dtype)])
        result = make_identifier("hybrid", database, IdentifyConfig(max_time_s=5.0)).identify(mixed, nominal_camera)
        assert result.solved, result.reason
        np.testing.assert_array_equal(result.hip, truth_hip[result.spot_index])
        assert result.deep_count > 0


def test_one_spot_with_a_runaway_covariance_leaves_the_deep_matches(database, nominal_camera, catalog):
    """
    A spot whose covariance ran away (1e23 px^2, as a singular blend fit once gave) claims no star.

    Its gate would reach every star in the image and make each ambiguous: the deep matches
    with it must be those without it, every id the truth's.
    """
    rng = np.random.default_rng(33)
    for _ in range(4):
        truth = random_rotation(rng)
        spots, hip = synthetic_scene(catalog, nominal_camera, truth, rng, noise_px=0.1, magnitude_limit=8.5)
        clean = make_identifier("hybrid", database, IdentifyConfig(max_time_s=5.0)).identify(spots, nominal_camera)
        cov = spots.cov.copy()
        faint = int(np.argsort(spots.flux)[spots.flux.size // 3])  # no guide star: a deep one or none
        cov[faint] = 1e23 * np.eye(2)
        bad = replace(spots, cov=cov)
        result = make_identifier("hybrid", database, IdentifyConfig(max_time_s=5.0)).identify(bad, nominal_camera)
        assert clean.solved and result.solved, (clean.reason, result.reason)
        np.testing.assert_array_equal(result.hip, hip[result.spot_index])
        assert result.deep_count >= clean.deep_count - 1, (result.deep_count, clean.deep_count, result.stats)
        assert clean.deep_count >= 5


def test_deep_rematch_on_rendered_frames(database, nominal_camera, catalog):
    """
    Rendered, centroided frames (stars to Hp 8.5, noise, PSF).

    Every match, guide or deep, is the star the renderer drew at that spot; the
    cross-boresight error against truth does not grow (the faint stars' centroids are ~5x
    noisier, so they add less than their number suggests) and the published covariance stays
    honest (chi^2 of the error, 3 DOF).
    """
    renderer = StarFieldRenderer(nominal_camera, SensorModel(), catalog.at_epoch(database.config.epoch_jyear),
                                 magnitude_limit=8.5)
    rng = np.random.default_rng(33)
    cross = {False: [], True: []}
    for seed in range(6):
        truth = random_rotation(rng)
        frame = renderer.render(ConstantRateMotion(truth, np.zeros(3)), 0.0, seed)
        spots = extract_spots(frame.image, CentroidConfig())
        guide, deep = solve_both(database, spots, nominal_camera)
        assert guide.solved and deep.solved
        assert deep.deep_count > guide.hip.size
        star = frame.truth.kind == KIND_STAR
        tx, ty, thip = frame.truth.x[star], frame.truth.y[star], frame.truth.hip[star]
        for key, result in ((False, guide), (True, deep)):
            i = result.spot_index
            gap = np.hypot(spots.x[i][:, None] - tx[None], spots.y[i][:, None] - ty[None])
            nearest = np.argmin(gap, axis=1)  # the star behind each spot: the one drawn there (within 1 px)
            assert np.all(gap[np.arange(i.size), nearest] < 1.0)
            np.testing.assert_array_equal(result.hip, thip[nearest])
            error = matrix_to_rotation_vector(truth.T @ result.attitude.rotation)
            assert error @ np.linalg.solve(result.attitude.covariance, error) < 16.27  # chi^2_3, 99.9 %
            cross[key].append(math.hypot(error[0], error[1]))
    rms = {key: float(np.sqrt(np.mean(np.square(values)))) for key, values in cross.items()}
    assert rms[True] <= 1.1 * rms[False], {key: value / ARCSEC for key, value in rms.items()}


def test_the_lens_projection_is_opencvs():
    """
    The compiled re-match's projection (pixel_of) is cv2.projectPoints with K and D, and images what the camera does.

    Pinhole and Brown-Conrady lenses (barrel, pincushion, tangential, k3), rays across and
    beyond the field, behind the camera, and past the radius where the distortion folds back
    (CameraModel.project's mask).
    """
    import cv2

    from star_tracker.identify.deep_match_kernel import pixel_of
    from star_tracker.identify.kernel_records import LensModel
    from star_tracker.models.camera import CameraModel

    rng = np.random.default_rng(8)
    lenses = [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.12, 0.03, 2e-4, -1e-4, 0.0), (0.08, -0.02, 0.0, 0.0, 0.01),
              (-0.3, 0.0, 0.0, 0.0, 0.0)]
    folded = 0
    for distortion in lenses:
        camera = CameraModel.from_fov(1280, 1024, math.radians(20.0), distortion)
        lens = LensModel.of(camera)
        rays = rng.normal(size=(3000, 3)) * [0.4, 0.4, 1.0]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        got = np.array([pixel_of(x, y, z, lens) for x, y, z in rays])
        u, v, imaged = camera.project(rays)
        np.testing.assert_array_equal(got[:, 2].astype(bool), imaged)
        front = rays[:, 2] > 1e-9
        reference, _ = cv2.projectPoints(rays[front], np.zeros(3), np.zeros(3), camera.intrinsic_matrix(),
                                         np.array(distortion, float))
        np.testing.assert_allclose(got[front, :2], reference[:, 0], rtol=1e-10, atol=1e-6)
        folded += np.count_nonzero(front & ~imaged)
    assert folded > 100  # the strong barrel lens folds rays back: they are not imaged


def test_deep_rematch_through_a_distorted_lens_names_the_stars_drawn_there(database, catalog, monkeypatch):
    """
    Rendered frames through a lens with barrel and tangential distortion (stars to Hp 8.5).

    Every match, guide or deep, is the star the renderer drew at that spot, and the faint stars
    are named. Then with a zero cone margin every pass after the first queries its own cone:
    the same answer.
    """
    from star_tracker.identify import deep_match
    from star_tracker.models.camera import CameraModel

    camera = CameraModel.from_fov(1024, 1024, math.radians(20.0), (-0.12, 0.03, 2e-4, -1e-4, 0.0))
    renderer = StarFieldRenderer(camera, SensorModel(), catalog.at_epoch(database.config.epoch_jyear),
                                 magnitude_limit=8.5)
    identifier = make_identifier("hybrid", database, IdentifyConfig(max_time_s=5.0))
    rng = np.random.default_rng(36)
    results = []
    for seed in range(3):
        frame = renderer.render(ConstantRateMotion(random_rotation(rng), np.zeros(3)), 0.0, seed)
        spots = extract_spots(frame.image, CentroidConfig())
        result = identifier.identify(spots, camera)
        assert result.solved, result.reason
        star = frame.truth.kind == KIND_STAR
        i = result.spot_index
        gap = np.hypot(spots.x[i][:, None] - frame.truth.x[star][None], spots.y[i][:, None] - frame.truth.y[star][None])
        nearest = np.argmin(gap, axis=1)
        assert np.all(gap[np.arange(i.size), nearest] < 1.0)
        np.testing.assert_array_equal(result.hip, frame.truth.hip[star][nearest])
        assert result.deep_count > 2 * np.count_nonzero(~result.deep), result.stats
        results.append((spots, result))
    monkeypatch.setattr(deep_match, "CONE_MARGIN_RAD", 0.0)
    for spots, result in results:
        again = identifier.identify(spots, camera)
        np.testing.assert_array_equal(again.hip, result.hip)
        np.testing.assert_array_equal(again.attitude.rotation, result.attitude.rotation)


def test_cone_query_is_every_star_within_the_cone(database):
    # The cell index's cone query against brute force over the whole deep catalog: small, field-
    # sized and hemisphere-wide cones anywhere, the poles and cube edges included.
    from star_tracker.identify.deep_catalog import cone_stars

    catalog = load_or_build_deep_catalog(database.config.magnitude_limit + 2.0, database.config.epoch_jyear,
                                         database.cache_directory)
    cells = catalog.cells
    rng = np.random.default_rng(5)
    axes = np.vstack([rng.normal(size=(150, 3)), np.eye(3), -np.eye(3), [[1, 1, 0], [1, 1, 1], [0, -1, 1]]])
    found = 0
    for axis in axes / np.linalg.norm(axes, axis=1, keepdims=True):
        for half in (1e-3, 0.02, 0.19, 1.0, 2.0):
            chord = 2.0 * math.sin(0.5 * half)
            got = cone_stars(catalog.vectors, cells.cell_start, cells.star_of_cell, cells.centres, cells.reach, axis,
                             chord)
            want = np.flatnonzero(np.sum((catalog.vectors - axis) ** 2, axis=1) <= chord * chord)
            np.testing.assert_array_equal(np.sort(got), want)
            found += want.size
    assert found > 1e6


def test_deep_match_off_changes_nothing(database, nominal_camera, catalog):
    rng = np.random.default_rng(34)
    spots, _ = synthetic_scene(catalog, nominal_camera, random_rotation(rng), rng, magnitude_limit=8.5)
    off = make_identifier("hybrid", database, IdentifyConfig(deep_match=False)).identify(spots, nominal_camera)
    assert off.solved and off.deep_count == 0 and "deep_matches" not in off.stats
    np.testing.assert_array_equal(off.magnitude, database.magnitude[np.searchsorted(database.hip, off.hip)])


def test_deep_catalog_cache_is_validated(tmp_path):
    first = load_or_build_deep_catalog(7.0, 2026.0, tmp_path)
    (cached,) = tmp_path.glob("deep_*.npz")
    assert np.all(first.magnitude <= 7.0) and np.all(np.diff(first.hip) > 0)
    cached.write_bytes(cached.read_bytes()[:-100])  # truncated
    from star_tracker.identify import deep_catalog
    deep_catalog._MEMO.clear()
    again = load_or_build_deep_catalog(7.0, 2026.0, tmp_path)
    np.testing.assert_array_equal(again.hip, first.hip)
    np.testing.assert_allclose(again.vectors, first.vectors, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="deep_magnitude_margin"):
        IdentifyConfig(deep_magnitude_margin=-1.0)


# ------------------------------------------------------------------------------ real images

def real_frame(image_id):
    """(manifest entry, spots, camera of `star-tracker solve`'s default solve) of a corpus image."""
    from star_tracker.commands.images import read_image
    from star_tracker.commands.solve import SolveOptions, solve_spots

    entry = {e["id"]: e for e in json.loads((REALDATA / "MANIFEST.json").read_text())["images"]}[image_id]
    image = read_image(REALDATA / entry["file"])
    pixels = image.pixels
    saturation = 255.0 if "8-bit" in image.description else 0.0
    spots = extract_spots(pixels, CentroidConfig(detection_sigma=4.5, psf_sigma_px=1.0, method="auto", max_spots=150,
                                                 saturation_adu=saturation))
    height, width = pixels.shape
    solved = solve_spots(spots, width, height, fov_deg=entry["fov_h_deg"], options=SolveOptions(max_time_s=5.0))
    assert solved.solved
    return entry, spots, solved


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:The WCS transformation has more axes")  # a WCS file has no image
@pytest.mark.skipif(not (REALDATA / "MANIFEST.json").is_file(), reason="real-image corpus absent")
@pytest.mark.parametrize("image_id,least", [("gran_vega_05sec", 3), ("unh_DSC_0058", 10)])
def test_deep_rematch_on_real_images(image_id, least):
    """
    Check: more stars on a real photograph, the error against astrometry.net's reference does not grow.

    `least`: the deep stars named at least; few on gran_vega_05sec, whose 25 deg JPEG field makes
    wide gates (the frame's chance bound, deep_match.MAX_CHANCE_MATCHES).

    Also astrometry.net's own TAN-SIP solution puts every deep-matched star on its spot (and
    no other deep-catalog star nearer).
    """
    from astropy.io import fits
    from astropy.wcs import WCS

    entry, spots, solved = real_frame(image_id)
    camera, database = solved.camera, solved.database
    guide, deep = solve_both(database, spots, camera, centroid_sigma_floor_px=0.3)
    assert guide.solved and deep.solved
    assert deep.hip.size >= guide.hip.size + least and deep.deep_count >= least
    reference = quaternion_to_matrix(np.array(entry["reference"]["quat_xyzw_sensor_to_icrs"]))
    assert error_rad(deep.attitude.rotation, reference) <= 1.05 * error_rad(guide.attitude.rotation, reference)

    wcs = WCS(fits.getheader(REALDATA / entry["reference"]["wcs_file"]))
    catalog = load_or_build_deep_catalog(database.config.magnitude_limit + IdentifyConfig().deep_magnitude_margin,
                                         database.config.epoch_jyear, database.cache_directory)
    near = catalog.vectors @ reference[:, 2] > math.cos(camera.half_diagonal_fov_rad + 0.02)
    ra, dec = np.degrees(unit_to_radec(catalog.vectors[near]))
    px, py = wcs.all_world2pix(ra, dec, 0, quiet=True)  # 0-based: our pixel convention
    visible = np.isfinite(px) & (px > -5) & (px < camera.width + 5) & (py > -5) & (py < camera.height + 5)
    px, py, hip = px[visible], py[visible], catalog.hip[near][visible]
    for k in np.flatnonzero(deep.deep):
        s = deep.spot_index[k]
        gap = np.hypot(px - spots.x[s], py - spots.y[s])
        nearest = np.argmin(gap)
        # The reference WCS itself misplaces its own matched stars by ~1 px toward the edges: the
        # identity is judged by the nearest star, the distance only against gross errors.
        assert hip[nearest] == deep.hip[k] and gap[nearest] < 3.0, (deep.hip[k], hip[nearest], gap[nearest])
    # astrometry.net's matched stars (.anet.corr, Tycho-2) agree wherever it matched the same spot.
    corr = fits.getdata(REALDATA / entry["reference"]["corr_file"], 1)
    pixel_arcsec = math.degrees(1.0 / camera.fx) * 3600.0
    ours_ra, ours_dec = np.degrees(unit_to_radec(deep.star_vectors))
    for fx, fy, ira, idec in zip(corr["field_x"] - 1, corr["field_y"] - 1, corr["index_ra"], corr["index_dec"]):
        at = np.hypot(spots.x[deep.spot_index] - fx, spots.y[deep.spot_index] - fy) < 1.0
        for k in np.flatnonzero(at):
            separation = math.hypot((ours_ra[k] - ira) * math.cos(math.radians(idec)), ours_dec[k] - idec) * 3600
            # A close double in one spot (e.g. epsilon-1/epsilon-2 Lyr, 208" apart on a 77"/px frame):
            # astrometry.net may have named the other component, which the catalog holds beside ours.
            other = catalog.vectors[near] @ radec_to_unit(np.radians(ira), np.radians(idec))
            component = float(np.max(other)) > math.cos(math.radians(30.0 / 3600)) and separation < 3.0 * pixel_arcsec
            assert separation < 30.0 or component, (deep.hip[k], separation)


def test_deep_pairs_is_the_pairing_rule_by_brute_force():
    # Every (spot, star) pair by brute force under random covariances (elongated, rotated, tiny,
    # a non-finite one that reaches nothing), then the rule of deep_match: a free spot's pair is
    # named when it is its only pair within reach, inside the gate, its star has no other
    # claimant within reach and is not a guide match's; the other free spots with a pair in
    # the gate are ambiguous, those with none within reach uncatalogued.
    from star_tracker.identify.deep_match_kernel import deep_pairs

    rng = np.random.default_rng(21)
    named_total = ambiguous_total = 0
    for trial in range(40):
        n = int(rng.integers(1, 60))
        spots, stars = rng.uniform(0, 200, (n, 2)), rng.uniform(0, 200, (400, 2))
        stars[:5] = spots[:1] + rng.normal(0, 1.0, (5, 2))  # a crowded spot
        stars[5:5 + min(n, 20)] = spots[:min(n, 20)] + rng.normal(0, 0.3, (min(n, 20), 2))  # most spots a star
        angle = rng.uniform(0, np.pi, n)
        major, minor = rng.uniform(0.05, 3.0, n), rng.uniform(0.05, 1.0, n)
        cos, sin = np.cos(angle), np.sin(angle)
        turn = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], 1)
        cov = turn @ (np.stack([major, minor], -1)[:, :, None] ** 2 * np.eye(2)[None]) @ np.transpose(turn, (0, 2, 1))
        if trial % 4 == 0:
            cov[-1] = np.nan
        claimant = rng.uniform(size=n) < 0.9
        free = claimant & (rng.uniform(size=n) < 0.7)
        star_hip = rng.permutation(np.arange(1, 401)).astype(np.int32)
        guide_hip = np.sort(rng.choice(star_hip, 8, replace=False))
        offset = spots[:, None, :] - stars[None, :, :]
        with np.errstate(invalid="ignore"):
            d2_all = np.einsum("nki,nij,nkj->nk", offset, np.linalg.inv(cov), offset)
        pair = (d2_all <= 8.0 ** 2) & claimant[:, None]
        per_spot, per_star = pair.sum(1), pair.sum(0)
        want, ambiguous = [], 0
        for i in np.flatnonzero(free):
            inside = np.flatnonzero(pair[i] & (d2_all[i] <= 4.0 ** 2))
            if inside.size == 0:
                continue
            j = inside[0]
            if per_spot[i] == 1 and per_star[j] == 1 and star_hip[j] not in guide_hip:
                want.append((i, j))
            else:
                ambiguous += 1
        uncatalogued = int(np.count_nonzero(free & (per_spot == 0)))
        spot, star, d2, got_ambiguous, got_uncatalogued = deep_pairs(
            spots[:, 0].copy(), spots[:, 1].copy(), cov, claimant, free, stars[:, 0].copy(), stars[:, 1].copy(),
            star_hip, guide_hip, 8.0, 4.0)
        assert list(zip(spot.tolist(), star.tolist())) == want
        assert np.allclose(d2, d2_all[spot, star], rtol=1e-9)
        assert (got_ambiguous, got_uncatalogued) == (ambiguous, uncatalogued)
        named_total += len(want)
        ambiguous_total += ambiguous
    assert named_total > 100 and ambiguous_total > 10  # the cases were exercised
    empty = deep_pairs(np.zeros(0), np.zeros(0), np.zeros((0, 2, 2)), np.zeros(0, bool), np.zeros(0, bool),
                       stars[:, 0].copy(), stars[:, 1].copy(), star_hip, guide_hip, 8.0, 4.0)
    assert empty[0].size == 0 and empty[3:] == (0, 0)
