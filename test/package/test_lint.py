# SPDX-License-Identifier: Apache-2.0
"""
Linters as tests: flake8, pep257 (pydocstyle) and the licence header of every Python file.

flake8 and pydocstyle read their settings from setup.cfg ([flake8]: line length 120;
[pydocstyle]: ament_pep257's default convention). `python test/package/test_lint.py` prints
the files linted, one a line, e.g. `flake8 $(python test/package/test_lint.py)`.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINTED_TREES = ("star_tracker", "test", "bench", "launch", "docs")
LINTED_FILES = ("setup.py",)
SKIPPED_DIRS = {"__pycache__", "build", "install", "log"}

LICENCE_HEADER = "# SPDX-License-Identifier: Apache-2.0"


def linted_files() -> list[str]:
    """Return every .py file the linters and the licence check cover: the linted trees', relative to ROOT, sorted."""
    found = [name for name in LINTED_FILES if (ROOT / name).is_file()]
    for tree in LINTED_TREES:
        for path in (ROOT / tree).rglob("*.py"):
            relative = path.relative_to(ROOT)
            if not SKIPPED_DIRS.intersection(relative.parts[:-1]):
                found.append(relative.as_posix())
    return sorted(found)


def _run(module: str) -> subprocess.CompletedProcess:
    try:
        __import__(module)
    except ImportError:
        pytest.fail(f"{module} is a test dependency (requirements-dev.txt, package.xml): pip install it")
    return subprocess.run([sys.executable, "-m", module, *linted_files()], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # ~12 s on the 2-core machine
def test_flake8():
    result = _run("flake8")
    assert result.returncode == 0, f"flake8 (setup.cfg [flake8]) found:\n{result.stdout}{result.stderr}"


@pytest.mark.slow  # ~11 s
def test_pep257():
    result = _run("pydocstyle")
    assert result.returncode == 0, f"pydocstyle (setup.cfg [pydocstyle]) found:\n{result.stdout}{result.stderr}"


def test_licence_header_on_every_python_file():
    missing = [name for name in linted_files()
               if not (ROOT / name).read_text(encoding="utf-8").startswith(LICENCE_HEADER + "\n")]
    assert not missing, f"first line should be '{LICENCE_HEADER}' in: {missing}"


def test_licence_matches_package_metadata():
    assert "Apache License" in (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert "<license>Apache-2.0</license>" in (ROOT / "package.xml").read_text(encoding="utf-8")
    assert 'license="Apache-2.0"' in (ROOT / "setup.py").read_text(encoding="utf-8")


if __name__ == "__main__":
    print("\n".join(linted_files()))
