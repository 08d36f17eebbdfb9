# SPDX-License-Identifier: Apache-2.0
"""Renderer and centroider against the simulator's truth."""
import numpy as np
import pytest

from star_tracker.models.attitude import radec_roll_to_matrix
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.sim.motion import ConstantRateMotion
from star_tracker.sim.render import StarFieldRenderer, frame_seed
from star_tracker.sim.sensor import SensorModel


def render(catalog, camera, rate_deg_s=(0.0, 0.0, 0.0), seed=0, sensor=SensorModel(), pointing=(1.4, 0.35, 0.2)):
    renderer = StarFieldRenderer(camera, sensor, catalog, magnitude_limit=7.5)
    motion = ConstantRateMotion(radec_roll_to_matrix(*pointing), np.radians(rate_deg_s))
    return renderer.render(motion, 10.0, frame_seed(0, seed))


def match_to_truth(spots, truth, radius=2.0):
    d = np.hypot(spots.x[:, None] - truth.x[None], spots.y[:, None] - truth.y[None])
    nearest = d.argmin(axis=1)
    return nearest, d[np.arange(len(spots)), nearest] < radius


def isolated(truth, min_separation=12.0):
    d = np.hypot(truth.x[:, None] - truth.x[None], truth.y[:, None] - truth.y[None])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1) > min_separation


def test_same_seed_same_frame(catalog, nominal_camera):
    a = render(catalog, nominal_camera, seed=7).image
    b = render(catalog, nominal_camera, seed=7).image
    c = render(catalog, nominal_camera, seed=8).image
    assert a.dtype == np.uint16 and a.shape == (1024, 1024)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("rate", [(0.0, 0.0, 0.0), (0.3, 0.4, 0.0)])
def test_centroids_match_truth_within_their_covariance(catalog, nominal_camera, rate):
    frame = render(catalog, nominal_camera, rate)
    spots = extract_spots(frame.image, CentroidConfig())
    nearest, ok = match_to_truth(spots, frame.truth)
    alone = isolated(frame.truth)[nearest] & ok & (spots.flags == 0)
    assert alone.sum() >= 40
    ex = spots.x[alone] - frame.truth.x[nearest[alone]]
    ey = spots.y[alone] - frame.truth.y[nearest[alone]]
    bright = spots.snr[alone] > 50
    # Mid-exposure position recovered: constant-rate smear is symmetric about mid-exposure.
    assert np.sqrt(np.mean(ex[bright] ** 2 + ey[bright] ** 2)) < 0.1
    # The reported covariance describes the actual errors (normalized errors ~ unit variance).
    normalized = np.concatenate([ex / np.sqrt(spots.cov[alone, 0, 0]), ey / np.sqrt(spots.cov[alone, 1, 1])])
    assert 0.6 < np.std(normalized) < 1.6


def test_detects_the_stars_that_should_be_seen(catalog, nominal_camera):
    sensor = SensorModel()
    frame = render(catalog, nominal_camera, sensor=sensor)
    spots = extract_spots(frame.image, CentroidConfig())
    truth = frame.truth
    # Expected SNR of each true star inside ~ a 3-sigma PSF aperture.
    pixels = np.pi * (3 * sensor.psf_sigma_px) ** 2
    background_e = (sensor.background_e_per_px_s + sensor.dark_e_per_px_s) * sensor.exposure_s
    snr = truth.electrons / np.sqrt(truth.electrons + pixels * (background_e + sensor.read_noise_e ** 2))
    inside = (truth.x > 5) & (truth.x < 1018) & (truth.y > 5) & (truth.y < 1018)
    want = (snr >= 10) & inside & isolated(truth, 6.0)
    d = np.hypot(truth.x[want][:, None] - spots.x[None], truth.y[want][:, None] - spots.y[None])
    found = d.min(axis=1) < 1.5
    assert want.sum() >= 30
    assert found.mean() >= 0.98


def test_photometry_matches_expected_electrons(catalog, nominal_camera):
    sensor = SensorModel(gain_e_per_adu=2.0)
    frame = render(catalog, nominal_camera, sensor=sensor)
    spots = extract_spots(frame.image, CentroidConfig(gain_e_per_adu=2.0))
    nearest, ok = match_to_truth(spots, frame.truth)
    use = ok & isolated(frame.truth, 15.0)[nearest] & (spots.snr > 30) & (spots.flags == 0)
    ratio = spots.flux[use] * sensor.gain_e_per_adu / frame.truth.electrons[nearest[use]]
    # The footprint captures nearly all of the PSF: flux within a few percent of truth.
    assert use.sum() >= 10
    assert 0.85 < np.median(ratio) < 1.02


def test_star_free_frame_gives_no_spots(catalog, nominal_camera):
    sensor = SensorModel(photon_flux_hp0=1e-3)  # stars far below the noise
    frame = render(catalog, nominal_camera, sensor=sensor, seed=3)
    assert len(extract_spots(frame.image, CentroidConfig())) <= 1


def test_bad_images_are_rejected_clearly():
    with pytest.raises(ValueError, match="2-D"):
        extract_spots(np.zeros((0, 5), np.uint16))
    with pytest.raises(ValueError, match="2-D"):
        extract_spots(np.zeros((4, 4, 3), np.uint8))
    flat = extract_spots(np.full((64, 64), 1000, np.uint16))
    assert len(flat) == 0


def test_hot_pixels_and_cosmic_rays_are_never_reported_as_stars(catalog, nominal_camera):
    from star_tracker.sim.render import KIND_COSMIC_RAY, KIND_HOT_PIXEL

    sensor = SensorModel(hot_pixel_fraction=1e-4, hot_pixel_dark_factor=2000.0, cosmic_ray_rate_per_cm2_s=60.0,
                         dsnu_fraction=0.1, prnu_fraction=0.01)
    stars_found = stars_wanted = tracks_reported = tracks_total = 0
    for k in range(3):
        frame = render(catalog, nominal_camera, sensor=sensor, seed=20 + k)
        t = frame.truth
        spots = extract_spots(frame.image, CentroidConfig())
        assert spots.rejected_shape > 20  # ~100 hot pixels and ~10 cosmic rays per frame
        star = t.kind == 0
        defect = (t.kind == KIND_HOT_PIXEL) | (t.kind == KIND_COSMIC_RAY)
        d_star = np.hypot(spots.x[:, None] - t.x[star][None], spots.y[:, None] - t.y[star][None]).min(axis=1)

        def on(kind, extra=0.0):
            sel = t.kind == kind
            reach = 2.0 + extra * t.extent_px[sel][None]
            return (np.hypot(spots.x[:, None] - t.x[sel][None], spots.y[:, None] - t.y[sel][None]) < reach).any(axis=1)
        # A spot on a hot pixel is always a star that happens to be there too. Cosmic-ray tracks
        # with SNR >= 10 away from the edge are rejected too (fainter tracks are a known gap).
        assert np.all(d_star[on(KIND_HOT_PIXEL)] < 2.0)
        strong_track = on(KIND_COSMIC_RAY, 0.5) & (spots.snr >= 10) & (spots.flags == 0)
        tracks_reported += int(np.sum(d_star[strong_track] >= 2.0))
        tracks_total += int(np.sum(t.kind == KIND_COSMIC_RAY))
        # Stars are still found: SNR >= 10 stars with no other object within 10 px (closer ones
        # blend into one spot; splitting blends is separate work) and no defect within 20 px.
        pixels = np.pi * 9.0
        snr = t.electrons[star] / np.sqrt(t.electrons[star] + pixels * (4.2 + 420 * 0.1 + 64))
        clear = ~(np.hypot(t.x[star][:, None] - t.x[defect][None],
                           t.y[star][:, None] - t.y[defect][None]) < 20).any(axis=1)
        want = (snr >= 10) & isolated(t, 10.0)[star] & clear & (t.x[star] > 5) & (t.x[star] < 1018) \
            & (t.y[star] > 5) & (t.y[star] < 1018)
        d = np.hypot(t.x[star][want][:, None] - spots.x[None], t.y[star][want][:, None] - spots.y[None]).min(axis=1)
        stars_found += int(np.sum(d < 1.5))
        stars_wanted += int(want.sum())
    assert stars_found >= 0.99 * stars_wanted
    # Measured on 8 frames: 70 of 80 tracks with SNR >= 10 rejected; allow at most 15 % through.
    assert tracks_total >= 20 and tracks_reported <= 0.15 * tracks_total


def test_gaussian_fit_reaches_its_covariance_and_beats_cog(catalog, nominal_camera):
    frame = render(catalog, nominal_camera, seed=31)
    t = frame.truth
    results = {}
    for method in ("cog", "gaussian"):
        spots = extract_spots(frame.image, CentroidConfig(method=method))
        nearest, ok = match_to_truth(spots, t)
        use = ok & isolated(t, 12.0)[nearest] & (spots.flags == 0) & (spots.snr > 10) & (t.kind[nearest] == 0)
        ex = spots.x[use] - t.x[nearest[use]]
        ey = spots.y[use] - t.y[nearest[use]]
        results[method] = (ex, ey, spots.cov[use])
    ex, ey, cov = results["gaussian"]
    assert ex.size >= 60
    # The fit's covariance describes its errors: normalized errors have unit variance.
    normalized = np.concatenate([ex / np.sqrt(cov[:, 0, 0]), ey / np.sqrt(cov[:, 1, 1])])
    assert 0.8 < np.std(normalized) < 1.25 and abs(np.mean(normalized)) < 0.2
    # And it is more accurate than the centre of gravity on the same stars.
    rms = {m: np.sqrt(np.mean(r[0] ** 2 + r[1] ** 2)) for m, r in results.items()}
    assert rms["gaussian"] < 0.8 * rms["cog"]


def test_gaussian_fit_survives_a_degenerate_spot_in_the_batch():
    from star_tracker.centroid import PsfStart, fit_gaussian_psf

    yy, xx = np.mgrid[0:64, 0:64]
    image = 1000 * np.exp(-((xx - 20.3) ** 2 + (yy - 30.7) ** 2) / 2) / (2 * np.pi)
    # Second spot: no signal at all (singular information for its position).
    x, y, _, cov, ok = fit_gaussian_psf(image, PsfStart(np.array([20.0, 45.0]), np.array([31.0, 10.0]),
                                                        np.array([900.0, 0.0])), 1.0, 1.0, 1.0)
    assert abs(x[0] - 20.3) < 1e-3 and abs(y[0] - 30.7) < 1e-3 and ok[0]
    assert not ok[1] or cov[1, 0, 0] > 1e6  # flagged, or honestly uninformative


def test_compiled_psf_fit_is_the_numpy_fit(catalog, nominal_camera, monkeypatch):
    from gaussian_fit_reference import use_numpy_fits

    frame = render(catalog, nominal_camera, seed=41)
    compiled = extract_spots(frame.image, CentroidConfig())
    use_numpy_fits(monkeypatch)
    reference = extract_spots(frame.image, CentroidConfig())
    assert len(compiled) == len(reference) >= 50
    assert np.allclose(compiled.x, reference.x, atol=1e-9) and np.allclose(compiled.y, reference.y, atol=1e-9)
    assert np.allclose(compiled.cov, reference.cov, rtol=1e-9, atol=1e-15)
    assert np.allclose(compiled.snr, reference.snr, rtol=1e-9)
    assert np.array_equal(compiled.flags, reference.flags)
