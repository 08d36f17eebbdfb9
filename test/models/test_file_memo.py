# SPDX-License-Identifier: Apache-2.0
"""In-process reuse of objects loaded from cache files (models/file_memo.py)."""
import os

import numpy as np
import pytest

from star_tracker.models.file_memo import FileMemo, forget_all


def test_an_object_is_reused_only_while_its_file_is_unchanged(tmp_path):
    path = tmp_path / "a.npz"
    path.write_bytes(b"first")
    memo = FileMemo(2)
    memo.put(path, "config A", "loaded A")
    assert memo.get(path, "config A") == "loaded A"
    assert memo.get(path, "config B") is None  # built for something else
    stat = path.stat()
    path.write_bytes(b"other")  # same size, rewritten: read again
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    assert memo.get(path, "config A") is None
    path.unlink()
    assert memo.get(path, "config A") is None
    memo.put(path, "config A", "never stored")  # no file: nothing to key it on
    assert len(memo._items) == 1


def test_the_least_recently_used_object_is_dropped(tmp_path):
    memo = FileMemo(2)
    paths = [tmp_path / f"{name}.npz" for name in "abc"]
    for path in paths:
        path.write_bytes(path.name.encode())
    memo.put(paths[0], "x", 0)
    memo.put(paths[1], "x", 1)
    assert memo.get(paths[0], "x") == 0  # a is now the most recent
    memo.put(paths[2], "x", 2)
    assert memo.get(paths[1], "x") is None and memo.get(paths[0], "x") == 0 and memo.get(paths[2], "x") == 2
    forget_all()  # every memo of the process, this one included
    assert all(memo.get(path, "x") is None for path in paths)
    with pytest.raises(ValueError, match="at least 1"):
        FileMemo(0)


def test_a_database_is_loaded_once_and_read_again_when_its_file_changes(tmp_path, caplog):
    from star_tracker.identify import DatabaseConfig, load_or_build_database

    config = DatabaseConfig(magnitude_limit=4.0, max_pair_angle_rad=np.radians(10.0))
    built = load_or_build_database(config, tmp_path)
    again = load_or_build_database(config, tmp_path)
    assert built.build_seconds > 0 and again.build_seconds == 0.0  # loaded, not built ...
    assert again.vectors is built.vectors and again.pair_a is built.pair_a  # ... from memory, not the file
    assert load_or_build_database(config, tmp_path) is again
    (path,) = tmp_path.glob("pairs_*.npz")
    path.write_bytes(path.read_bytes()[:-100])  # truncated by something else
    with caplog.at_level("WARNING"):
        rebuilt = load_or_build_database(config, tmp_path)
    assert rebuilt.build_seconds > 0 and "rebuilding" in caplog.text  # judged again, not trusted from memory
    assert np.array_equal(rebuilt.hip, built.hip) and np.array_equal(rebuilt.pair_a, built.pair_a)
    assert load_or_build_database(config, tmp_path).vectors is rebuilt.vectors
