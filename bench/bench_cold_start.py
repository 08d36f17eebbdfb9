# SPDX-License-Identifier: Apache-2.0
"""
Cold start: process start -> first identified frame on a fresh install.

Each case starts from a fresh clone (`git clone` of the repository's HEAD) and empty caches
(STAR_TRACKER_CACHE and XDG_CACHE_HOME in a temp dir, no NUMBA_CACHE_DIR: numba's default,
the cache beside the installed modules), installs it the way a user does, then starts the
three installed node executables at once (the real commands, the installed
config/star_tracker.yaml) on a private localhost DDS domain and waits for the first attitude
within 60 arcsec of the simulator's truth. Then it does the same again on the now warm install
(second start). Cases:

* colcon: `python -m colcon build` (the running interpreter, as test_colcon_install does);
* colcon, no install compile: the same with STAR_TRACKER_SKIP_INSTALL_COMPILE=1, i.e. the
  kernels compile at the first start (the install step skipped);
* pip: a fresh venv, `pip install -r requirements.txt` (not timed: the dependencies), then
  `pip install <clone>` (timed).

    python -m bench.bench_cold_start --output docs/BENCHMARKS.md [--only colcon,pip]
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .machine import cpu_model
from .report import write_section

REPO = Path(__file__).resolve().parents[1]
NODES = ("camera_simulator", "centroider", "identifier")
CASES = ("colcon", "colcon-no-install-compile", "pip")
FIRST_DOMAIN_ID = 223  # 223-226: this benchmark's private DDS domains
CORRECT_RAD = math.radians(60.0 / 3600.0)  # an identified frame: attitude within 60 arcsec of truth
GOAL_S = 10.0  # [s] goal: process start -> first identified frame
SITE = f"lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages"
# "[INFO] [1764650000.123456789] [centroider]: ready" -> the wall time of the ready line
READY_RE = re.compile(r"\[(\d+\.\d+)\] \[[^\]]*\]: ready\b")


def run(cmd: list[str], env: dict[str, str], cwd: Path, log: Path, timeout_s: float = 3600.0) -> float:
    """Run `cmd` to completion (output to `log`); return its wall time [s]; raise on failure."""
    started = time.perf_counter()
    with open(log, "w") as out:
        code = subprocess.run(cmd, env=env, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                              timeout=timeout_s).returncode
    if code != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited with {code}:\n{log.read_text()[-4000:]}")
    return time.perf_counter() - started


def fresh_environment(tmp: Path) -> dict[str, str]:
    """Return this process's environment with empty caches in `tmp` (what a new user has)."""
    env = dict(os.environ)
    for name in ("NUMBA_CACHE_DIR", "STAR_TRACKER_SKIP_INSTALL_COMPILE", "PYTHONPATH", "AMENT_PREFIX_PATH",
                 "COLCON_DEFAULTS_FILE"):
        env.pop(name, None)
    env["STAR_TRACKER_CACHE"] = str(tmp / "cache" / "star_tracker")
    env["XDG_CACHE_HOME"] = str(tmp / "cache")  # numba's user-wide fallback too
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


def install_colcon(clone: Path, tmp: Path, env: dict[str, str]) -> tuple[float, dict[str, str], Path, Path]:
    """
    Run a colcon build of `clone`.

    Returns (install wall time [s], the node environment, the directory of the executables,
    the installed config file).
    """
    env = dict(env, COLCON_HOME=str(tmp / "colcon_home"))
    seconds = run([sys.executable, "-m", "colcon", "--log-base", str(tmp / "log"), "build", "--base-paths",
                   str(clone), "--build-base", str(tmp / "build"), "--install-base", str(tmp / "install"),
                   "--event-handlers", "console_direct+"], env, tmp, tmp / "install.log")
    prefix = tmp / "install" / "star_tracker"
    node_env = dict(env, PYTHONPATH=str(prefix / SITE), AMENT_PREFIX_PATH=str(prefix))
    return seconds, node_env, prefix / "lib" / "star_tracker", prefix / "share" / "star_tracker" / "config" / \
        "star_tracker.yaml"


def install_pip(clone: Path, tmp: Path, env: dict[str, str]) -> tuple[float, dict[str, str], Path, Path]:
    """Make a fresh venv, its dependencies (not timed), then `pip install <clone>` (timed)."""
    venv = tmp / "venv"
    run([sys.executable, "-m", "venv", str(venv)], env, tmp, tmp / "venv.log")
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    run(pip + ["-r", str(clone / "requirements.txt")], env, tmp, tmp / "requirements.log")
    seconds = run(pip + [str(clone)], env, tmp, tmp / "install.log")
    return seconds, dict(env), venv / "bin", venv / "share" / "star_tracker" / "config" / "star_tracker.yaml"


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a running process [s] (/proc/PID/stat), None when gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def first_identified(bin_dir: Path, config: Path, env: dict[str, str], domain_id: int, logs: Path,
                     timeout_s: float) -> dict:
    """
    Start the three node executables at once.

    Return the seconds from their start to the first attitude within CORRECT_RAD of truth
    (None if none within timeout_s), to each node's `ready` line, and the frames seen by then.
    """
    import rclpy
    from geometry_msgs.msg import QuaternionStamped

    from star_tracker.models.attitude import attitude_error, quaternion_to_matrix
    from star_tracker.ros import convert
    from star_tracker.ros.middleware import configure_middleware
    from star_tracker.ros.pipeline import MONITOR_RESULT_QOS

    env = dict(env, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("ROS_LOCALHOST_ONLY", None)
    configure_middleware(env)
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE")
                       if k in env})
    rclpy.init(domain_id=domain_id)
    monitor = rclpy.create_node("cold_start_monitor")
    truth, attitude = {}, {}
    arrival = {}
    monitor.create_subscription(QuaternionStamped, "truth/attitude", lambda m: truth.__setitem__(
        convert.stamp_to_ns(m.header.stamp), quaternion_to_matrix(convert.quaternion_from_msg(m))), MONITOR_RESULT_QOS)

    def on_attitude(m):
        ns = convert.stamp_to_ns(m.header.stamp)
        attitude[ns] = quaternion_to_matrix(convert.quaternion_from_msg(m))
        arrival[ns] = time.time()

    monitor.create_subscription(QuaternionStamped, "attitude", on_attitude, MONITOR_RESULT_QOS)
    logs.mkdir(parents=True, exist_ok=True)
    processes = {}
    started = time.time()
    for name in NODES:
        with open(logs / f"{name}.log", "w") as log:
            processes[name] = subprocess.Popen([str(bin_dir / name), "--ros-args", "--params-file", str(config)],
                                               env=env, stdout=log, stderr=subprocess.STDOUT,
                                               stdin=subprocess.DEVNULL, start_new_session=True)
    first, cpu = None, {}
    try:
        while time.time() - started < timeout_s and first is None:
            rclpy.spin_once(monitor, timeout_sec=0.05)
            for ns in sorted(attitude):
                if ns in truth and attitude_error(attitude[ns], truth[ns])[2] < CORRECT_RAD:
                    first = arrival[ns] - started
                    cpu = {name: cpu_seconds(p.pid) for name, p in processes.items()}
                    break
            if any(p.poll() is not None for p in processes.values()):
                break
    finally:
        for proc in processes.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in processes.values():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        monitor.destroy_node()
        rclpy.shutdown()
    ready = {}
    for name in NODES:
        found = READY_RE.search((logs / f"{name}.log").read_text(errors="replace"))
        ready[name] = float(found.group(1)) - started if found else None
    return {"first_identified_s": first, "ready_s": ready, "cpu_s_at_first_identified": cpu,
            "attitudes": len(attitude), "frames": len(truth),
            "exit_codes": {name: p.returncode for name, p in processes.items()}}


def measure(case: str, repo: Path, domain_id: int, timeout_s: float, keep: Path | None) -> dict:
    """One case: clone, install (timed), first start, second start."""
    with tempfile.TemporaryDirectory(prefix=f"cold_start_{case}_") as name:
        tmp = Path(keep / case) if keep else Path(name)
        tmp.mkdir(parents=True, exist_ok=True)
        env = fresh_environment(tmp)
        clone = tmp / "src" / "star_tracker"
        subprocess.run(["git", "clone", "--quiet", str(repo), str(clone)], check=True)
        commit = subprocess.run(["git", "-C", str(clone), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
        if case == "colcon-no-install-compile":
            env["STAR_TRACKER_SKIP_INSTALL_COMPILE"] = "1"
        install = install_pip if case == "pip" else install_colcon
        install_s, node_env, bin_dir, config = install(clone, tmp, env)
        compiled = sum(1 for _ in (bin_dir.parent.parent if case != "pip" else tmp / "venv").rglob("*.nbi"))
        starts = [first_identified(bin_dir, config, node_env, domain_id, tmp / f"run{k}", timeout_s) for k in (1, 2)]
        return {"case": case, "commit": commit, "install_s": install_s, "cache_index_files_installed": compiled,
                "first_start": starts[0], "second_start": starts[1]}


def seconds(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f}"


def cpu_text(cpu: dict) -> str:
    return ", ".join(seconds(cpu.get(name)) for name in NODES) if cpu else "–"


def report(results: list[dict], elapsed_s: float, command: str) -> str:
    labels = {"colcon": "`colcon build`", "colcon-no-install-compile":
              "`colcon build`, STAR_TRACKER_SKIP_INSTALL_COMPILE=1 (kernels compile at the first start)",
              "pip": "fresh venv, `pip install <clone>`"}
    lines = ["## Cold start", "",
             f"Command: `{command}` — {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {cpu_model()}, "
             f"{os.cpu_count()} cores (`nproc`), Python {platform.python_version()}, {platform.platform()}; "
             f"{elapsed_s:.0f} s. Commit {results[0]['commit'] if results else '?'}. "
             "Raw numbers: `docs/bench_cold_start.json`.", "",
             "Each case: a fresh `git clone`, empty caches (STAR_TRACKER_CACHE, XDG_CACHE_HOME in a temp dir; no "
             "NUMBA_CACHE_DIR), the install timed, then the three installed node executables started at once with "
             "the installed `config/star_tracker.yaml` on a private localhost DDS domain: seconds from their start "
             "to each node's `ready` line and to the first attitude within 60\" of truth (the first identified "
             f"frame; goal ≤ {GOAL_S:g} s), and each node's CPU time by then (user + system: what the start "
             "costs without the other processes on this shared host). Then the same start again (second start, "
             "warm). The install compiles "
             "the nodes' numba kernels into the built copy (star_tracker/install_compile.py, two processes) and "
             "builds the pattern database into the user's cache; numba keys its cache on source content, CPU and "
             "version, so the installed copy loads it. The machine is a shared 2-core VM: figures vary between "
             "runs.", "",
             "| install | install [s] | cache files | start | centroider ready [s] | identifier ready [s] | "
             "first identified frame [s] | CPU by then: camera, centroider, identifier [s] | frames seen |",
             "|---|---:|---:|---|---:|---:|---:|---:|---:|"]
    for result in results:
        for key, label in (("first_start", "first"), ("second_start", "second")):
            start = result[key]
            value = seconds(start["first_identified_s"])
            if start["first_identified_s"] is not None and key == "first_start":
                value = f"**{value}**"
            lines.append(f"| {labels[result['case']] if key == 'first_start' else ''} | "
                         f"{seconds(result['install_s']) if key == 'first_start' else ''} | "
                         f"{result['cache_index_files_installed'] if key == 'first_start' else ''} | {label} | "
                         f"{seconds(start['ready_s']['centroider'])} | {seconds(start['ready_s']['identifier'])} | "
                         f"{value} | {cpu_text(start.get('cpu_s_at_first_identified', {}))} | {start['frames']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", type=Path, default=None, help="markdown file to write the section into")
    parser.add_argument("--only", default=",".join(CASES), help=f"comma-separated cases of {CASES}")
    parser.add_argument("--repo", type=Path, default=REPO, help="repository to clone (its HEAD)")
    parser.add_argument("--timeout", type=float, default=300.0, help="longest wait for a first identified frame [s]")
    parser.add_argument("--keep", type=Path, default=None, help="keep each case's clone, install and logs here")
    args = parser.parse_args(argv)
    cases = [c for c in args.only.split(",") if c]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        parser.error(f"unknown cases {unknown}; known: {CASES}")
    started = time.perf_counter()
    results = []
    for k, case in enumerate(cases):
        results.append(measure(case, args.repo.resolve(), FIRST_DOMAIN_ID + k % 4, args.timeout, args.keep))
        print(json.dumps(results[-1]), flush=True)
    command = "python -m bench.bench_cold_start" + (f" --only {args.only}" if args.only != ",".join(CASES) else "") + \
        (f" --output {args.output}" if args.output else "")
    text = report(results, time.perf_counter() - started, command)
    print(text)
    if args.output:
        write_section(args.output, text)
        (args.output.parent / "bench_cold_start.json").write_text(json.dumps(
            {"meta": {"elapsed_s": time.perf_counter() - started, "quick": cases != list(CASES), "cpu": cpu_model(),
                      "cores": os.cpu_count(), "command": command,
                      "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")},
             "results": results}, indent=2))


if __name__ == "__main__":
    main()
