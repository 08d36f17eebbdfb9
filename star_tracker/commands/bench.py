"""`star-tracker bench`: the benchmark scripts of `make bench` (bench/*.py in the source tree),
one after the other, with a progress line each."""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from .common import CommandError, add_parser, guarded


@dataclass(frozen=True)
class Bench:
    """name: what --only selects; module: python -m target; full/quick: its options
    ({out} = the Markdown file, {images} = the figure directory); peers: takes --no-peers."""

    name: str
    module: str
    full: tuple[str, ...]
    quick: tuple[str, ...]
    what: str
    peers: bool = False


# The Makefile's `bench` target, in its order.
BENCHES = (
    Bench("render", "bench.bench_render", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "frame render time vs stars, smear, image size"),
    Bench("simulator_figures", "bench.simulator_figures", ("--output-dir", "{images}"), ("--output-dir", "{images}"),
          "simulator figures (smeared frame, photon transfer)"),
    Bench("centroid", "bench.bench_centroid", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "centroid accuracy vs the Cramer-Rao bound, peers"),
    Bench("identify", "bench.bench_identify", ("--output", "{out}"),
          ("--scenes", "20", "--hard-scenes", "5", "--tune-scenes", "0", "--output", "{out}"),
          "identification on the seed papers' setups, peers", peers=True),
    Bench("databases", "bench.bench_databases", ("--output", "{out}"), ("--output", "{out}"),
          "pattern database build/load time and size"),
    Bench("attitude", "bench.bench_attitude", ("--output", "{out}"), ("--frames", "20", "--output", "{out}"),
          "attitude accuracy and covariance consistency"),
    Bench("tracking", "bench.bench_tracking", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "tracking, re-acquisition, delay compensation, peers", peers=True),
    Bench("replay", "bench.bench_replay", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "rosbag2 replay throughput through the nodes"),
)
NAME = "bench"


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "run the benchmarks (make bench) with progress; write docs/BENCHMARKS.md and figures",
        "Run the benchmark scripts of `make bench` one after the other in the source tree: "
        + "; ".join(f"{b.name} ({b.what})" for b in BENCHES)
        + ". Each replaces its own section of the Markdown file (--output) and writes its figures under "
        "images/ beside it. A progress line per benchmark shows its elapsed time; each one's full output "
        "goes to a log file (--log-dir). --quick runs each with its smoke-run options and, unless --output "
        "is given, writes to a temporary directory instead of docs/. Peers (tetra3rs, cedar-solve) are "
        "optional: `pip install -r requirements-bench.txt` (see the Makefile). Exit code 0 if every "
        "benchmark succeeded, 1 otherwise.",
        "star-tracker bench                         # everything, into docs/BENCHMARKS.md (hours)\n"
        "star-tracker bench --only identify --quick\n"
        "star-tracker bench --only render,centroid --output /tmp/B.md --dry-run")
    parser.add_argument("--only", action="append", default=None, metavar="NAME[,NAME]",
                        help=f"run only these benchmarks (repeatable; of {', '.join(b.name for b in BENCHES)}; "
                             "default: all)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: each benchmark's quick options (--quick, or few scenes/frames)")
    parser.add_argument("--output", metavar="MD",
                        help="Markdown file whose sections are written (default: docs/BENCHMARKS.md of the source "
                             "tree; with --quick a temporary directory's BENCHMARKS.md)")
    parser.add_argument("--no-peers", action="store_true",
                        help="skip the peer solvers (tetra3rs, cedar-solve) in identify and tracking")
    parser.add_argument("--log-dir", metavar="DIR",
                        help="where each benchmark's output goes as NAME.log (default: a new temporary directory)")
    parser.add_argument("--repo", metavar="DIR",
                        help="source tree holding bench/ (default: the one this star_tracker was imported from)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="also stream each benchmark's output to the terminal")
    parser.add_argument("--dry-run", action="store_true", help="print the commands and run nothing")
    parser.set_defaults(func=run)


def selected(only: list[str] | None) -> list[Bench]:
    if not only:
        return list(BENCHES)
    names = [n.strip() for item in only for n in item.split(",") if n.strip()]
    known = {b.name: b for b in BENCHES}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise CommandError(f"unknown benchmark(s) {', '.join(unknown)}; choose from {', '.join(known)}")
    return [b for b in BENCHES if b.name in names]


def find_repo(repo: str | None) -> Path:
    root = Path(repo) if repo else Path(__file__).resolve().parents[2]
    if not (root / "bench" / "__init__.py").is_file():
        raise CommandError(f"{root} has no bench/ package: run from the source tree or give --repo")
    return root.resolve()


def command_for(bench: Bench, quick: bool, out: Path, no_peers: bool) -> list[str]:
    options = [a.format(out=out, images=out.parent / "images") for a in (bench.quick if quick else bench.full)]
    if no_peers and bench.peers:
        options.append("--no-peers")
    return [sys.executable, "-m", bench.module, *options]


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    benches = selected(args.only)
    repo = find_repo(args.repo)
    if args.output:
        out = Path(args.output).resolve()
    elif args.quick:  # smoke numbers never overwrite docs/
        parent = Path(tempfile.gettempdir()) / "star_tracker_bench_quick_DIR" if args.dry_run else Path(
            tempfile.mkdtemp(prefix="star_tracker_bench_quick_"))
        out = parent / "BENCHMARKS.md"
    else:
        out = repo / "docs" / "BENCHMARKS.md"
    if not out.parent.is_dir() and not args.dry_run:
        raise FileNotFoundError(2, "No such directory", str(out.parent))
    commands = [(b, command_for(b, args.quick, out, args.no_peers)) for b in benches]
    if args.dry_run:
        print(f"cd {shlex.quote(str(repo))}")
        for _, cmd in commands:
            print(" ".join(shlex.quote(c) for c in ["python", *cmd[1:]]))
        return 0
    log_dir = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="star_tracker_bench_logs_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(repo) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    print(f"{len(commands)} benchmark(s){' (quick)' if args.quick else ''} in {repo}; writing {out}; logs in {log_dir}",
          flush=True)
    failed = []
    total_started = time.perf_counter()
    for index, (bench, cmd) in enumerate(commands, 1):
        label = f"[{index}/{len(commands)}] {bench.name:<17}"
        log_path = log_dir / f"{bench.name}.log"
        code, elapsed = run_one(cmd, repo, env, log_path, label, args.verbose)
        if code == 0:
            print(f"{label} done in {_duration(elapsed)}", flush=True)
        else:
            failed.append(bench.name)
            print(f"{label} FAILED (exit code {code}) after {_duration(elapsed)}; last lines of {log_path}:", flush=True)
            for line in log_path.read_text(errors="replace").splitlines()[-15:]:
                print(f"    {line}")
    print(f"{len(commands) - len(failed)}/{len(commands)} benchmark(s) succeeded in "
          f"{_duration(time.perf_counter() - total_started)}; {out}" + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


def run_one(cmd: list[str], cwd: Path, env: dict, log_path: Path, label: str, verbose: bool) -> tuple[int, float]:
    """Run one benchmark, its output to log_path (and the terminal with verbose); on a
    terminal the label line shows the elapsed time, redrawn every second."""
    started = time.perf_counter()
    tty = sys.stdout.isatty() and not verbose
    with open(log_path, "w") as log:
        log.write("$ " + " ".join(shlex.quote(c) for c in cmd) + "\n")
        log.flush()
        process = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, text=True, bufsize=1)
        done = threading.Event()

        def ticker() -> None:
            while not done.wait(1.0):
                sys.stdout.write(f"\r\x1b[K{label} running {_duration(time.perf_counter() - started)}")
                sys.stdout.flush()

        thread = threading.Thread(target=ticker, daemon=True) if tty else None
        if thread is not None:
            thread.start()
        elif not verbose:
            print(f"{label} running ...", flush=True)
        try:
            for line in process.stdout:
                log.write(line)
                if verbose:
                    sys.stdout.write(f"    {line}")
            code = process.wait()
        except KeyboardInterrupt:
            process.terminate()
            process.wait()
            raise
        finally:
            done.set()
            if thread is not None:
                thread.join()
                sys.stdout.write("\r\x1b[K")
    return code, time.perf_counter() - started


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
