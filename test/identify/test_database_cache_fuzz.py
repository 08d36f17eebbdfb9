# SPDX-License-Identifier: Apache-2.0
"""
The pattern-database cache file (star_tracker.identify.database) is never trusted.

Damaged (hypothesis: bit flips, truncation, garbage, empty), consistently tampered with or
unwritable, the database is rebuilt and the same as a fresh one, and the log says so.
"""
from __future__ import annotations

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from star_tracker.models.catalog import load_validated_npz, save_validated_npz  # noqa: E402
from star_tracker.identify import DatabaseConfig  # noqa: E402
from star_tracker.identify import database as database_module  # noqa: E402

from fuzz_support import examples  # noqa: E402


@pytest.fixture(scope="module")
def small_database_files(tmp_path_factory):
    """Return a small pattern database (fast to rebuild), its cache file bytes and its directory."""
    directory = tmp_path_factory.mktemp("pattern_cache")
    config = DatabaseConfig(magnitude_limit=3.5, max_pair_angle_rad=float(np.radians(10.0)))
    reference = database_module.load_or_build_database(config, directory)
    (path,) = directory.glob("pairs_*.npz")
    return config, reference, path, path.read_bytes()


def same_database(a, b) -> bool:
    return all(np.array_equal(getattr(a, n), getattr(b, n)) for n in ("vectors", "hip", "pair_a", "pair_b",
                                                                      "pair_angle"))


@examples(30)
@given(data=st.data())
def test_a_damaged_pattern_cache_is_rebuilt_never_trusted(small_database_files, data, caplog):
    config, reference, path, original = small_database_files
    damage = data.draw(st.sampled_from(["flip", "truncate", "garbage", "empty"]))
    if damage == "flip":
        blob = bytearray(original)
        for offset in data.draw(st.lists(st.integers(0, len(blob) - 1), min_size=1, max_size=4)):
            blob[offset] ^= data.draw(st.integers(1, 255))
    elif damage == "truncate":
        blob = original[:data.draw(st.integers(0, len(original) - 1))]
    elif damage == "garbage":
        blob = data.draw(st.binary(max_size=2000))
    else:
        blob = b""
    path.write_bytes(bytes(blob))
    arrays = load_validated_npz(path)  # a flip in zip metadata may leave the content intact
    intact = arrays is not None and same_database(database_module.database_from_cache(arrays, config), reference)
    caplog.clear()
    loaded = database_module.load_or_build_database(config, path.parent)
    assert same_database(loaded, reference)
    if not intact:
        assert any("rebuilding" in r.getMessage() for r in caplog.records)  # never silently
        assert same_database(database_module.database_from_cache(load_validated_npz(path), config), reference)


def test_a_consistent_but_tampered_pattern_cache_is_rejected(small_database_files, caplog):
    """
    A file with a valid checksum (recomputed by whoever changed it) is still checked.

    Star indices out of range would make the compiled kernels read outside their arrays.
    """
    config, reference, path, original = small_database_files
    path.write_bytes(original)
    arrays = load_validated_npz(path)
    tampered = {
        "pair index out of range": {**arrays, "pair_b": np.where(np.arange(arrays["pair_b"].size) == 0,
                                                                 10**6, arrays["pair_b"]).astype(np.int32)},
        "wrong dtype": {**arrays, "pair_a": arrays["pair_a"].astype(np.int64)},
        "other configuration": {**arrays, "config": np.array(DatabaseConfig().identity())},
        "old format": {k: v for k, v in arrays.items() if k != "format_version"},
        "moved star": {**arrays, "vectors": np.roll(arrays["vectors"], 1, axis=0)},
        "unsorted angles": {**arrays, "pair_angle": arrays["pair_angle"][::-1].copy()},
    }
    for name, content in tampered.items():
        save_validated_npz(path, content)
        assert load_validated_npz(path) is not None  # the checksum alone accepts it
        caplog.clear()
        assert same_database(database_module.load_or_build_database(config, path.parent), reference), name
        assert any("rejected" in r.getMessage() for r in caplog.records), name


def test_an_unwritable_cache_directory_costs_a_rebuild_not_the_database(small_database_files, tmp_path, caplog):
    config, reference, _, _ = small_database_files
    blocked = tmp_path / "not_a_directory"
    blocked.write_text("x")
    database = database_module.load_or_build_database(config, blocked / "sub")
    assert same_database(database, reference)
    assert any("not written" in r.getMessage() for r in caplog.records)
