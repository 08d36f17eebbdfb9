# SPDX-License-Identifier: Apache-2.0
"""docs/USER_GUIDE.md: its Python example runs as written, its command lines parse."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from star_tracker.commands import COMMANDS

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "USER_GUIDE.md"


def test_python_api_example_runs_and_matches_the_truth(capsys):
    text = GUIDE.read_text()
    code = re.search(r"<!-- python-api-example -->\n```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {}
    exec(compile(code, str(GUIDE), "exec"), namespace)  # noqa: S102 - our own guide
    result = namespace["result"]
    assert result.solved and result.hip.size >= 20
    assert namespace["cross"] < 2.0 and namespace["roll_error"] < 20.0  # arcsec, against the render's truth
    assert (namespace["ra"], namespace["dec"], namespace["roll"]) == pytest.approx((120.0, -30.0, 45.0), abs=1e-3)
    assert np.all(namespace["sigma"] > 0) and namespace["sigma"][2] > namespace["sigma"][0]  # roll is the weak axis
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{result.hip.size} stars, RA 120.0") and out[1].startswith("error vs truth")


def test_every_command_line_of_the_guide_parses():
    import argparse

    parser = argparse.ArgumentParser(prog="star-tracker")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.register(sub)
    ours = set(sub.choices)
    blocks = re.findall(r"```bash\n(.*?)```", GUIDE.read_text(), re.S)
    # Drop comments, a trailing `&` and shell redirections.
    lines = [re.split(r"\s[#>|]", line)[0].strip().rstrip("&").strip() for block in blocks
             for line in block.splitlines()]
    checked = 0
    for line in lines:
        words = shlex.split(line) if line.startswith("star-tracker ") else []
        if len(words) > 1 and words[1] in ours:
            parser.parse_args(words[1:])  # exits (fails the test) on an unknown option or a bad value
            checked += 1
    assert checked >= 12
    # Every subcommand of this package is documented with an example.
    for name in ours:
        assert f"star-tracker {name} " in GUIDE.read_text(), name
