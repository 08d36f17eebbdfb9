# SPDX-License-Identifier: Apache-2.0
import numpy as np
import pytest

from star_tracker.models.catalog import load_hipparcos, load_validated_npz, cache_dir, radec_to_unit, unit_to_radec

ARCSEC = np.radians(1 / 3600)


@pytest.fixture
def catalog(hipparcos):
    """Return the catalogue as loaded (J1991.25), not conftest's sky at the database epoch."""
    return hipparcos


def test_full_catalog_is_loaded(catalog):
    assert len(catalog) > 117_000
    assert np.all(np.isfinite(catalog.ra)) and np.all(np.isfinite(catalog.dec)) and np.all(np.isfinite(catalog.hp))


def test_sirius_and_vega_are_where_they_belong(catalog):
    # Independent reference: SIMBAD ICRS J2000 coordinates; ours propagated from J1991.25.
    j2000 = catalog.at_epoch(2000.0)
    references = {32349: (101.287155, -16.716116), 91262: (279.234733, 38.783689)}  # Sirius, Vega
    for hip, (ra_deg, dec_deg) in references.items():
        i = catalog.index_of(hip)
        ours = radec_to_unit(j2000.ra[i], j2000.dec[i])
        theirs = radec_to_unit(np.radians(ra_deg), np.radians(dec_deg))
        assert np.arccos(min(1.0, ours @ theirs)) < 0.5 * ARCSEC, hip
    assert catalog.hp[catalog.index_of(32349)] < -1.0  # the brightest star in the sky
    assert 0.0 < catalog.hp[catalog.index_of(91262)] < 0.2


def test_proper_motion_moves_barnards_star(catalog):
    barnard = catalog.index_of(87937)  # the largest proper motion, ~10.4"/yr
    later = catalog.at_epoch(catalog.epoch_jyear + 10.0)
    moved = np.arccos(np.clip(radec_to_unit(catalog.ra[barnard], catalog.dec[barnard])
                              @ radec_to_unit(later.ra[barnard], later.dec[barnard]), -1, 1))
    expected = 10.0 * np.hypot(catalog.pm_ra[barnard], catalog.pm_dec[barnard])
    assert 100 * ARCSEC < moved < 110 * ARCSEC
    assert abs(moved - expected) < 0.01 * ARCSEC * 100


def test_unit_vector_round_trip():
    rng = np.random.default_rng(0)
    ra, dec = rng.uniform(0, 2 * np.pi, 100), rng.uniform(-1.5, 1.5, 100)
    ra2, dec2 = unit_to_radec(radec_to_unit(ra, dec))
    assert np.allclose(ra, ra2, atol=1e-12) and np.allclose(dec, dec2, atol=1e-12)


def test_corrupt_cache_is_detected_and_rebuilt(catalog):
    cached = sorted(cache_dir().glob("hip2_*.npz"))
    assert cached, "loading the catalog writes a cache file"
    path = cached[0]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    assert load_validated_npz(path) is None
    import star_tracker.models.catalog as module

    module._CATALOG_MEMO.clear()
    reloaded = load_hipparcos()
    assert np.array_equal(reloaded.hip, catalog.hip)
    assert load_validated_npz(path) is not None


def test_a_checksum_valid_cache_that_is_not_a_catalog_is_rebuilt(catalog):
    # A file with a valid checksum but the wrong columns, dtype or shapes (written by other code,
    # or tampered and re-checksummed) must not reach StarCatalog: it is rebuilt from hip2.dat.
    import star_tracker.models.catalog as module

    path = sorted(cache_dir().glob("hip2_*.npz"))[0]
    columns = {name: getattr(catalog, name) for name in ("hip", "ra", "dec", "pm_ra", "pm_dec", "hp", "b_v")}
    for tampered in ({**columns, "extra": columns["ra"]}, {**columns, "hip": columns["hip"].astype(np.int64)},
                     {**columns, "ra": columns["ra"][:-1]}):
        module.save_validated_npz(path, tampered)
        assert load_validated_npz(path) is not None  # the checksum alone passes it
        module._CATALOG_MEMO.clear()
        reloaded = load_hipparcos()
        assert np.array_equal(reloaded.hip, catalog.hip) and np.array_equal(reloaded.ra, catalog.ra)
        assert sorted(load_validated_npz(path)) == sorted(columns)  # rewritten as a catalog
