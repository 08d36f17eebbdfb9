# SPDX-License-Identifier: Apache-2.0
"""bench/campaign_trials.py's conversion of a kind's table back into the records a benchmark summarizes."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pyarrow as pa

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from bench.campaign_trials import engine_line, errors, records  # noqa: E402


def test_list_columns_come_back_as_arrays_and_ragged_ones_as_object_arrays():
    table = pa.table({"task": pa.array([0, 1]), "error": pa.array(["", "ValueError: bad frame"]),
                      "snr": pa.array([[5.0, 7.5], None], pa.list_(pa.float64())),
                      "vectors": pa.array([[[1.0, 2.0, 3.0], None], [[0.0, 0.0, 1.0]]],
                                          pa.list_(pa.list_(pa.float64())))})
    first, second = records(table)
    np.testing.assert_array_equal(first["snr"], [5.0, 7.5])
    assert second["snr"] is None
    assert first["vectors"].dtype == object and first["vectors"][1] is None
    assert first["vectors"][0] == [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(second["vectors"], [[0.0, 0.0, 1.0]])
    assert errors(table) == ["task 1: ValueError: bad frame"]


def test_the_engine_line_says_where_the_trials_ran():
    run = {"trials_run": 40, "threads": 2, "scheduler": "tcp://127.0.0.1:1234", "utilization": 0.93}
    assert engine_line(run) == "trials on the campaign engine: 40 on 2 worker(s) at tcp://127.0.0.1:1234, 93 % busy"
