# SPDX-License-Identifier: Apache-2.0
"""
Freed memory kept for reuse (star_tracker/process_memory.py), judged by page faults counted by the kernel.

Each case runs in its own interpreter (the allocator setting is process-wide): a 64 MB array is
allocated, written, freed and allocated and written again; the second round's minor page
faults say whether the freed memory was reused or handed back to the kernel and faulted in
again (at least one fault per 2 MB, with or without transparent huge pages).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import resource, sys
import numpy as np
sys.path.insert(0, {root!r})
if {keep}:
    from star_tracker.process_memory import keep_freed_memory
    assert keep_freed_memory()
def faults_of_one_round():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    block = np.empty(64 << 20, np.uint8)
    block.fill(1)
    del block
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
faults_of_one_round()
print(faults_of_one_round())
"""


def _second_round_faults(keep: bool) -> int:
    result = subprocess.run([sys.executable, "-c", SCRIPT.format(root=str(ROOT), keep=keep)], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return int(result.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc only")
def test_freed_frame_buffers_are_reused_not_faulted_in_again():
    huge_pages = (64 << 20) // (2 << 20)  # the fewest faults that can bring 64 MB in (2 MB transparent huge pages)
    assert _second_round_faults(keep=False) >= huge_pages  # glibc's default: the block went back to the kernel
    assert _second_round_faults(keep=True) < huge_pages / 4
