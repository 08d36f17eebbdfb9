# SPDX-License-Identifier: Apache-2.0
"""
`colcon build` of the star_tracker ament_python package, and the layout `ros2 run` uses.

Real build, real processes, no mocks:

* runs ``python -m colcon build`` (the interpreter running pytest) on the repository, with
  the build/install/log bases inside a pytest tmp dir, and checks nothing lands in the repo;
* checks the install layout `ros2 run star_tracker <exe>` relies on (executables in
  ``lib/star_tracker``, the ament index marker, ``share/star_tracker/package.xml``) and that
  the ament index and ``install/setup.sh`` resolve it;
* starts each installed node executable with the environment ``install/setup.sh`` would give
  (PYTHONPATH + AMENT_PREFIX_PATH), on a random ROS domain restricted to localhost, waits
  until its lifecycle ``~/get_state`` answers ``active`` (autostart), sends SIGINT and expects
  exit code 0 within 15 s.

Set STAR_TRACKER_REPO to build another checkout (default: the repo containing this file); the
build is test/conftest.py's session fixture `colcon_workspace`.
"""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PACKAGE = "star_tracker"
DIST_NAME = "star-tracker"  # setuptools' normalised name used by the generated entry scripts
NODE_EXECUTABLES = ("camera_simulator", "centroider", "identifier")
SITE_PACKAGES = f"lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages"

READY_TIMEOUT_S = 120
SHUTDOWN_TIMEOUT_S = 15


def _tail(path: Path, chars: int = 6000) -> str:
    try:
        text = path.read_text(errors="replace")
    except FileNotFoundError:
        return "<no output file>"
    return text[-chars:] if text else "<no output>"


def _prepend(env: dict[str, str], var: str, entry: Path) -> None:
    parts = [str(entry)] + [p for p in env.get(var, "").split(os.pathsep) if p]
    env[var] = os.pathsep.join(parts)


def _default_signals() -> None:
    # A pytest started from a non-interactive shell may inherit SIGINT as ignored; the node
    # must see a normal SIGINT, as it does under a terminal or `ros2 launch`.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _is_inside(path: str | Path, root: Path) -> bool:
    return Path(path).resolve().is_relative_to(root.resolve())


@pytest.fixture(scope="module")
def prefix(colcon_workspace) -> Path:
    """
    Return the package's install prefix, install/star_tracker (colcon's isolated layout).

    The build is the session's (test/conftest.py colcon_workspace, shared with test_ros2_cli.py).
    """
    return colcon_workspace / "install" / PACKAGE


@pytest.fixture(scope="module")
def node_env(prefix, tmp_path_factory) -> dict[str, str]:
    """Return what `source install/setup.sh` gives, plus an isolated localhost-only ROS domain."""
    env = os.environ.copy()
    _prepend(env, "PYTHONPATH", prefix / SITE_PACKAGES)
    _prepend(env, "AMENT_PREFIX_PATH", prefix)
    from star_tracker.ros.domain_ids import private_domain_ids  # this run's share of the private ids (conftest)

    env["ROS_DOMAIN_ID"] = str(random.randint(*private_domain_ids()))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; would fight the setting above
    if not env.get("STAR_TRACKER_CACHE"):
        env["STAR_TRACKER_CACHE"] = str(tmp_path_factory.mktemp("star_tracker_cache"))
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


def test_install_layout_matches_ros2_run(prefix):
    missing = []
    for name in NODE_EXECUTABLES:
        exe = prefix / "lib" / PACKAGE / name
        if not (exe.is_file() and os.access(exe, os.X_OK)):
            missing.append(str(exe))
            continue
        shebang = exe.read_text(errors="replace").splitlines()[0]
        assert shebang.startswith("#!"), f"{exe} has no shebang: {shebang!r}"
        interpreter = Path(shebang[2:].split()[0])
        # The executables must run with the interpreter that built them (this venv).
        assert interpreter.parent == Path(sys.executable).parent, (
            f"{exe} runs {interpreter}, expected an interpreter in {Path(sys.executable).parent}"
        )
    assert not missing, f"missing or non-executable: {missing}"

    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    assert marker.is_file(), f"ament index marker missing: {marker}"
    assert (prefix / "share" / PACKAGE / "package.xml").is_file()

    # A real (copied) install, not a --symlink-install egg-link into the source tree.
    init = prefix / SITE_PACKAGES / PACKAGE / "__init__.py"
    assert init.is_file() and not init.is_symlink(), f"package not installed at {init}"


def test_ament_index_and_setup_sh_resolve_the_package(prefix, monkeypatch):
    packages = pytest.importorskip("ament_index_python.packages")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    # `ros2 run star_tracker X` = get_package_prefix + lib/star_tracker/X.
    assert Path(packages.get_package_prefix(PACKAGE)).resolve() == prefix.resolve()
    libexec = Path(packages.get_package_prefix(PACKAGE)) / "lib" / PACKAGE
    found = {p.name for p in libexec.iterdir() if p.is_file() and os.access(p, os.X_OK)}
    assert set(NODE_EXECUTABLES) <= found, f"{libexec} holds only {sorted(found)}"

    # Sourcing the workspace's setup.sh exports the site-packages dir and the prefix.
    script = '. "$1/setup.sh" >/dev/null && printf "%s\\n%s\\n" "$PYTHONPATH" "$AMENT_PREFIX_PATH"'
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")}
    out = subprocess.run(
        ["sh", "-c", script, "sh", str(prefix.parent)], env=env, capture_output=True,
        text=True, timeout=60, check=True,
    ).stdout.splitlines()
    assert str(prefix / SITE_PACKAGES) in out[0].split(os.pathsep), out
    assert str(prefix) in out[1].split(os.pathsep), out


# Resolve an executable exactly as the generated entry script does (distribution metadata ->
# console_scripts entry point -> module), without starting the node.
_RESOLVE = textwrap.dedent(
    """
    import importlib.metadata, importlib.util, json, sys
    dist = importlib.metadata.distribution(sys.argv[1])
    (ep,) = [e for e in dist.entry_points
             if e.group == "console_scripts" and e.name == sys.argv[2]]
    spec = importlib.util.find_spec(ep.module)
    pkg = importlib.util.find_spec(sys.argv[3])
    print(json.dumps({"dist": str(dist.locate_file("")), "module": ep.module,
                      "module_file": spec.origin if spec else None,
                      "package_file": pkg.origin if pkg else None}))
    """
)


@pytest.mark.parametrize("executable", NODE_EXECUTABLES)
def test_installed_node_runs_from_install_tree_and_stops_on_sigint(
        executable, prefix, node_env, tmp_path):
    exe = prefix / "lib" / PACKAGE / executable
    assert exe.is_file(), f"{exe} not installed"

    # cwd = tmp_path so that '' on sys.path cannot pick up the source tree.
    resolved = subprocess.run(
        [sys.executable, "-c", _RESOLVE, DIST_NAME, executable, PACKAGE], cwd=tmp_path,
        env=node_env, capture_output=True, text=True, timeout=120, check=False,
    )
    if resolved.returncode:
        pytest.fail(f"cannot resolve {executable} from {prefix}:\n{resolved.stderr[-4000:]}")
    info = json.loads(resolved.stdout.strip().splitlines()[-1])
    for key in ("dist", "module_file", "package_file"):
        assert info[key] and _is_inside(info[key], prefix), (
            f"{executable}: {key} = {info[key]} is not inside the install tree {prefix}"
        )

    log_path = tmp_path / f"{executable}.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [str(exe)], cwd=tmp_path, env=node_env, stdin=subprocess.DEVNULL, stdout=log,
            stderr=subprocess.STDOUT, start_new_session=True, preexec_fn=_default_signals,
        )
    try:
        from star_tracker.ros.lifecycle_client import wait_for_state

        def alive(_name):
            if proc.poll() is not None:
                pytest.fail(f"{executable} exited with {proc.returncode} before it was active"
                            f":\n{_tail(log_path)}")

        try:  # readiness is the lifecycle state, not a log line
            wait_for_state(node_env, [executable], "active", READY_TIMEOUT_S, check=alive)
        except TimeoutError as exc:
            pytest.fail(f"{executable}: {exc}:\n{_tail(log_path)}")
        assert proc.poll() is None, f"{executable} exited right after activating:\n{_tail(log_path)}"

        proc.send_signal(signal.SIGINT)
        try:
            returncode = proc.wait(timeout=SHUTDOWN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            returncode = None
        if returncode is None:
            pytest.fail(f"{executable} still running {SHUTDOWN_TIMEOUT_S} s after SIGINT:\n"
                        f"{_tail(log_path)}")
        assert returncode == 0, f"{executable} exited with {returncode} on SIGINT:\n{_tail(log_path)}"
        assert "Traceback" not in log_path.read_text(errors="replace"), (
            f"{executable} printed a traceback:\n{_tail(log_path)}"
        )
    finally:
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)  # its own session: the node and any children
            except ProcessLookupError:
                pass
            proc.wait(timeout=30)
