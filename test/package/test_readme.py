# SPDX-License-Identifier: Apache-2.0
"""The README's Python examples run as written and solve the frames they make."""
import re
from pathlib import Path

import numpy as np

from star_tracker.models.attitude import attitude_error

README = Path(__file__).resolve().parents[2] / "README.md"


def python_blocks() -> list[str]:
    section = re.search(r"## Python API without ROS\n(.*?)\n## ", README.read_text(), re.S).group(1)
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_readme_python_examples_run_and_solve(capsys):
    first, own_spots = python_blocks()
    namespace: dict = {}
    exec(compile(first, str(README), "exec"), namespace)  # noqa: S102 - our own README
    assert namespace["result"].solved
    assert capsys.readouterr().out.startswith("solved")
    exec(compile(own_spots, str(README), "exec"), namespace)  # noqa: S102
    assert len(namespace["own"].x) == 40
    assert capsys.readouterr().out.strip() == "solved"
    result = namespace["own_result"]
    assert result.hip.size >= 30
    _, _, total = attitude_error(result.attitude.rotation, namespace["frame"].truth.rotation)
    assert total < np.radians(5.0 / 3600.0)
