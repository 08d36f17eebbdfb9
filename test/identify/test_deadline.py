# SPDX-License-Identifier: Apache-2.0
"""
The identification budget's clocks (identify/deadline.py).

"cpu" counts only this process's work, so a solve does the same search however busy the host
is; "wall" counts elapsed time.
"""
import subprocess
import sys

import pytest

from star_tracker.identify import IdentifyConfig
from star_tracker.identify.deadline import Deadline


WAITING = """
import time
from star_tracker.identify.deadline import Deadline
wall, cpu = Deadline(0.05, "wall"), Deadline(0.05, "cpu")
time.sleep(0.2)  # another process holding the CPU looks like this to us
print(wall.passed(), cpu.passed(), cpu.remaining_s() > 0.0 > wall.remaining_s())
"""


def test_waiting_spends_wall_time_but_not_cpu_time():
    # In a fresh process: the test worker's own leftover threads (a previous test's executor)
    # count as this process's CPU time and passed the cpu deadline during the sleep.
    out = subprocess.run([sys.executable, "-c", WAITING], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "False", "True"], out


def test_working_spends_cpu_time():
    cpu = Deadline(0.02, "cpu")
    spins = 0
    while not cpu.passed():
        spins += 1
    assert spins > 0 and cpu.remaining_s() <= 0.0


def test_unknown_clock_is_refused():
    with pytest.raises(ValueError, match="budget clock 'sundial'"):
        Deadline(1.0, "sundial")
    with pytest.raises(ValueError, match="budget_clock='sundial' must be one of"):
        IdentifyConfig(budget_clock="sundial")
