# SPDX-License-Identifier: Apache-2.0
"""
The centroiding-time script (bench/corpus_centroid_time.py) and its stage split.

On one real corpus image (skipped where ../shared/realdata is absent): the stages it reports
are parts of the centroiding it times.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench/ is not an installed package
from bench import bench_realdata  # noqa: E402
from bench import corpus_centroid_time as script  # noqa: E402

IMAGE = "ubst_webcam_w1"  # the corpus's smallest frame (640x480): a few ms a run


@pytest.fixture
def corpus() -> Path:
    try:
        return bench_realdata.find_corpus()
    except bench_realdata.CorpusMissing as exc:
        pytest.skip(str(exc))


def test_stages_are_parts_of_the_centroiding(corpus, capsys, monkeypatch):
    """Every stage is timed on a real frame; the stages that do not nest add up to no more than the total."""
    for _, module_name, name in script.STAGES:  # the wrappers are undone after the test
        module = sys.modules.get(module_name) or __import__(module_name, fromlist=[name])
        monkeypatch.setattr(module, name, getattr(module, name))
    # One run: each stage's time lies inside that run's total (medians over runs need not add up).
    script.main(["--corpus", str(corpus), "--repeat", "1", "--stages", IMAGE])
    result = json.loads(capsys.readouterr().out)[IMAGE]
    stages = result["stages"]
    assert set(stages) == {label for label, _, _ in script.STAGES}
    for label in ("detection", "candidate measurement", "PSF estimate", "point fits", "streak fits"):
        assert stages[label] > 0.0, label  # this frame has point-like and elongated spots
    # The free streak fit and the streak residual run inside the streak fits, the rest one after
    # another inside the total (0.01 ms a value of rounding).
    assert stages["free streak fit (compiled)"] + stages["streak residual"] <= stages["streak fits"] + 0.02
    top_level = [label for label in stages if label not in ("free streak fit (compiled)", "streak residual")]
    assert sum(stages[label] for label in top_level) <= result["total"] + 0.06


def test_plain_output_is_one_time_per_image(corpus, capsys):
    script.main(["--corpus", str(corpus), "--repeat", "1", IMAGE])
    times = json.loads(capsys.readouterr().out)
    assert list(times) == [IMAGE] and times[IMAGE] > 0.0
