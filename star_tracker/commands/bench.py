# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker bench` (what `make bench` runs).

The benchmark scripts (bench/*.py in the source tree) of BENCHES, the one list of them, one after
the other, with a progress bar, then the benchmark plots (bench/plots.py) from their JSON
results.

Progress protocol: the command sets PROGRESS_ENV in each benchmark's environment; a benchmark
that knows how far it is calls `report_progress(done, total, note)`, which prints a
`PROGRESS_PREFIX done/total note` line on stderr (throttled; nothing when run on its own).
Benchmarks that do not report show their latest output line, and a bar estimated from their
last run's duration (meta.elapsed_s of their JSON results) or else a moving marker.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from .common import CommandError, StatusLine, add_parser, guarded, progress_bar

PROGRESS_ENV = "STAR_TRACKER_BENCH_PROGRESS"
PROGRESS_PREFIX = "@bench-progress "
_last_report = [0.0]


def report_progress(done: int, total: int, note: str = "", min_interval_s: float = 0.5) -> None:
    """
    For benchmarks: tell a `star-tracker bench` run how far this one is (`done` of `total` units, e.g. scenes solved).

    No-op unless PROGRESS_ENV is set; at most one line every `min_interval_s` (and always the
    last), so it can be called per unit of work.
    """
    if not os.environ.get(PROGRESS_ENV):
        return
    now = time.monotonic()
    if done < total and now - _last_report[0] < min_interval_s:
        return
    _last_report[0] = now
    print(f"{PROGRESS_PREFIX}{int(done)}/{int(total)} {note}".rstrip(), file=sys.stderr, flush=True)


@dataclass(frozen=True)
class Bench:
    """
    name: what --only selects.

    Module: python -m target; full/quick: its options ({out} = the Markdown file, {images} =
    the figure directory); peers: takes --no-peers.
    """

    name: str
    module: str
    full: tuple[str, ...]
    quick: tuple[str, ...]
    what: str
    peers: bool = False


# The benchmarks, in run order: the one list (`make bench` runs `star-tracker bench`).
BENCHES = (
    Bench("render", "bench.bench_render", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "frame render time vs stars, smear, image size"),
    Bench("simulator_figures", "bench.simulator_figures", ("--output-dir", "{images}"), ("--output-dir", "{images}"),
          "simulator figures (smeared frame, photon transfer)"),
    Bench("centroid", "bench.bench_centroid", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "centroid accuracy vs the Cramer-Rao bound, peers"),
    Bench("psf_range", "bench.bench_psf_range", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "centroiding at defaults across PSF widths and shapes, simulator and a second renderer"),
    Bench("beside_tracks", "bench.bench_beside_tracks", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "stars beside a neighbour star or a cosmic-ray track, peers' centroiders", peers=True),
    Bench("identify", "bench.bench_identify", ("--output", "{out}"),
          ("--scenes", "20", "--hard-scenes", "5", "--tune-scenes", "0", "--output", "{out}"),
          "identification on the seed papers' setups, peers", peers=True),
    Bench("databases", "bench.bench_databases", ("--output", "{out}"), ("--output", "{out}"),
          "pattern database build/load time and size"),
    Bench("attitude", "bench.bench_attitude", ("--output", "{out}"), ("--frames", "20", "--output", "{out}"),
          "attitude accuracy and covariance consistency"),
    Bench("rate_aid", "bench.bench_rate_aid", ("--output", "{out}"), ("--frames", "2", "--output", "{out}"),
          "centroider rate-aid check: false alarms, wrong rates caught"),
    Bench("tracking", "bench.bench_tracking", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "tracking, re-acquisition, delay compensation, peers", peers=True),
    Bench("orbit", "bench.bench_orbit", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "two heads over a LEO orbit: availability, blinding against astropy, fusion, aberration, Moon, alignment"),
    Bench("replay", "bench.bench_replay", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "rosbag2 replay throughput through the nodes"),
    Bench("pipeline", "bench.bench_pipeline", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "pipeline throughput and overload through the nodes"),
    Bench("large_sensor", "bench.bench_large_sensor", ("--output", "{out}"), ("--seconds", "8", "--output", "{out}"),
          "2048² frames at 10 Hz through the three nodes: identified, latency"),
    Bench("soak", "bench.bench_soak", ("--minutes", "10", "--output", "{out}"), ("--minutes", "2", "--output", "{out}"),
          "memory growth and latency drift of the nodes over 10 min, 2 with --quick"),
    Bench("realdata", "bench.bench_realdata", ("--output", "{out}"),
          ("--only", "gran_vega_05sec,openstartracker_img0", "--output", "{out}"),
          "real sky images (../shared/realdata) against their references, peers", peers=True),
    Bench("realdata_field", "bench.bench_realdata", ("--field-error", "3", "--output", "{out}"),
          ("--field-error", "3", "--only", "gran_vega_05sec,openstartracker_img0", "--output", "{out}"),
          "the same real images with every solver told a field 3 % off, peers", peers=True),
    Bench("corpus_centroid", "bench.bench_corpus_centroid", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "centroiding time per real image, split by stage, beside cedar-solve's whole solve"),
    Bench("profile", "bench.bench_profile", ("--output", "{out}"), ("--quick", "--output", "{out}"),
          "cProfile by stage: nominal and slewing frames, lost-in-space, a tracking update, three real images"),
    Bench("simulator_vs_real", "bench.simulator_vs_real", ("--output", "{out}", "--images-dir", "{images}"),
          ("--output", "{out}", "--images-dir", "{images}"),
          "the simulator against a real camera: a profile fitted to real frames, the same sky rendered"),
    Bench("psf_sensitivity", "bench.bench_psf_sensitivity", ("--output", "{out}"),
          ("--only", "gran_vega_05sec,unh_DSC_0060", "--output", "{out}"),
          "real sky images solved with the PSF width fixed 5-15 % off its estimate: no cliffs"),
    Bench("cold_start", "bench.bench_cold_start", ("--output", "{out}"), ("--only", "colcon", "--output", "{out}"),
          "process start -> first identified frame on a fresh clone and install (colcon, pip)"),
)
# Not a benchmark: the figures drawn from the benchmarks' JSON results (bench/plots.py),
# run after them; `python -m bench.plots` alone redraws them without rerunning anything.
PLOTS = Bench("plots", "bench.plots", ("--results-dir", "{results}"), ("--results-dir", "{results}"),
              "benchmark figures from the JSON results")
# Not a benchmark either: the datasheet (DATASHEET.md beside the Markdown file) drawn from the
# same results by bench/datasheet.py, last.
DATASHEET = Bench("datasheet", "bench.datasheet", ("--results-dir", "{results}"), ("--results-dir", "{results}"),
                  "the datasheet from the JSON results")
NAME = "bench"


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "run the benchmarks (make bench) with a progress bar; write docs/BENCHMARKS.md and plots",
        "Run the benchmark scripts one after the other in the source tree (`make bench` runs this command): "
        + "; ".join(f"{b.name} ({b.what})" for b in BENCHES)
        + ". Each replaces its own section of the Markdown file (--output) and writes its figures under "
        "images/ beside it; then bench/plots.py draws the benchmark plots (centroid error / Cramer-Rao "
        "bound, identification success vs false stars, solve and centroiding time distributions vs the "
        "peers) into images/ from the JSON results beside the Markdown file, and bench/datasheet.py writes "
        "DATASHEET.md beside it from the same results. A progress bar on stderr shows "
        "which benchmark runs and how far it is (scenes or measurement points done, for those that report "
        "it; else its latest output line); each one's full output goes to a log file (--log-dir). --quick "
        "runs each with its smoke-run options and, unless --output is given, writes to a temporary "
        "directory instead of docs/. Peers (tetra3rs, cedar-solve) are optional: `pip install -r "
        "requirements-bench.txt` (see the Makefile). Exit code 0 if every benchmark, the plots and the datasheet "
        "succeeded, 1 otherwise.",
        "star-tracker bench                         # everything, into docs/BENCHMARKS.md (hours)\n"
        "star-tracker bench --only identify --quick\n"
        "star-tracker bench --only render,centroid --output /tmp/B.md --dry-run\n"
        "python -m bench.plots                      # only redraw the plots from docs/bench_*.json")
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
    parser.add_argument("--no-plots", action="store_true",
                        help="do not draw the benchmark plots afterwards (default: draw them from the JSON results "
                             "present beside --output)")
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


def command_for(bench: Bench, quick: bool, out: Path, no_peers: bool, repo: Path) -> list[str]:
    """
    Return the command running `bench` in the source tree `repo` (its working directory).

    A path inside `repo` is given relative to it (`--output docs/BENCHMARKS.md`): the
    benchmarks write their own command line into the Markdown.
    """
    if out.is_relative_to(repo):
        out = out.relative_to(repo)
    options = [a.format(out=out, images=out.parent / "images", results=out.parent)
               for a in (bench.quick if quick else bench.full)]
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
    commands = [(b, command_for(b, args.quick, out, args.no_peers, repo)) for b in benches]
    if not args.no_plots:
        commands.append((PLOTS, command_for(PLOTS, args.quick, out, args.no_peers, repo)))
    commands.append((DATASHEET, command_for(DATASHEET, args.quick, out, args.no_peers, repo)))
    if args.dry_run:
        print(f"cd {shlex.quote(str(repo))}")
        for _, cmd in commands:
            print(" ".join(shlex.quote(c) for c in ["python", *cmd[1:]]))
        return 0
    log_dir = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="star_tracker_bench_logs_"))
    log_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(repo) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env[PROGRESS_ENV] = "1"
    plots = "" if args.no_plots else ", the plots"
    print(f"{len(benches)} benchmark(s){' (quick)' if args.quick else ''}{plots} and the datasheet "
          f"in {repo}; writing {out}; logs in {log_dir}", flush=True)
    failed = []
    total_started = time.perf_counter()
    for index, (bench, cmd) in enumerate(commands, 1):
        label = f"[{index}/{len(commands)}] {bench.name:<17}"
        log_path = log_dir / f"{bench.name}.log"
        expected_s = None if args.quick else last_duration_s(bench, out.parent)
        code, elapsed = run_one(cmd, repo, env, log_path, label, args.verbose, expected_s)
        if code == 0:
            print(f"{label} done in {_duration(elapsed)}", flush=True)
            if bench is PLOTS:
                for line in log_path.read_text(errors="replace").splitlines():
                    if line.startswith("wrote "):
                        print(f"    {line}")
        else:
            failed.append(bench.name)
            print(f"{label} FAILED (exit code {code}) after {_duration(elapsed)}; last lines of {log_path}:",
                  flush=True)
            for line in log_path.read_text(errors="replace").splitlines()[-15:]:
                print(f"    {line}")
    succeeded = len(commands) - len(failed)
    print(f"{succeeded}/{len(commands)} step(s) succeeded in "
          f"{_duration(time.perf_counter() - total_started)}; {out}"
          + (f"; FAILED: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


class BenchStatus:
    """
    The progress bar of one running benchmark.

    Its fraction when it reports progress (PROGRESS_PREFIX lines), else the elapsed share of
    `expected_s` (its last run's duration), else a moving marker; elapsed time; the latest
    note or output line. Drawn on stderr by a thread (twice a second on a terminal, every 10 s
    in a log).
    """

    WIDTH = 24

    def __init__(self, label: str, stream=None, expected_s: float | None = None):
        self.label = label
        self.expected_s = expected_s  # the last run's duration, for benchmarks that do not report
        self.started = time.perf_counter()
        self.done = self.total = 0
        self.note = ""
        self.line = StatusLine(stream, min_interval_s=10.0)
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def progress(self, text: str) -> None:
        """Parse `done/total note` from a PROGRESS_PREFIX line."""
        count, _, note = text.strip().partition(" ")
        done, _, total = count.partition("/")
        try:
            self.done, self.total = int(done), int(total)
        except ValueError:
            return
        self.note = note or self.note

    def output(self, line: str) -> None:
        """Keep the latest output line: the note of benchmarks that do not report progress."""
        if line.strip() and self.total == 0:
            self.note = line.strip()

    def text(self) -> str:
        elapsed = time.perf_counter() - self.started
        if self.total > 0:
            fraction = self.done / self.total
            bar, count = progress_bar(fraction, self.WIDTH), f"{self.done}/{self.total} {100 * fraction:3.0f} %"
        elif self.expected_s:  # estimated from the last run's duration
            fraction = min(elapsed / self.expected_s, 0.99)
            bar = progress_bar(fraction, self.WIDTH)
            count = f"~{100 * fraction:.0f} % of the last run's {_duration(self.expected_s)}"
        else:  # no progress reported: a marker sweeping along the bar, one step per second
            position = int(elapsed) % (2 * self.WIDTH - 6)
            position = position if position < self.WIDTH - 3 else 2 * self.WIDTH - 6 - position
            bar, count = "[" + "." * position + "###" + "." * (self.WIDTH - 3 - position) + "]", "running"
        note = self.note if len(self.note) <= 60 else self.note[:57] + "..."
        return f"{self.label} {bar} {count}  {_duration(elapsed)}  {note}".rstrip()

    def draw(self) -> None:
        with self.lock:
            self.line.show(self.text())

    def clear(self) -> None:
        with self.lock:
            self.line.clear()

    def echo(self, text: str) -> None:
        """Print a line of the benchmark's output to stdout, above the bar."""
        with self.lock:
            self.line.clear()
            sys.stdout.write(text)
            sys.stdout.flush()

    def _run(self) -> None:
        while not self._stop.wait(0.5):
            self.draw()

    def __enter__(self):
        self.line.show(self.text())
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        with self.lock:  # a terminal gets the "done" line instead; a log keeps the last state
            if self.line.tty:
                self.line.clear()
            else:
                self.line.show(self.text(), final=True)


def last_duration_s(bench: Bench, results_dir: Path) -> float | None:
    """
    Return how long the benchmark's last full run took [s], or None.

    From meta.elapsed_s of its JSON results (bench_NAME.json beside the Markdown file).
    """
    path = results_dir / f"{bench.module.rsplit('.', 1)[-1]}.json"
    try:
        meta = json.loads(path.read_text()).get("meta", {})
        elapsed = float(meta["elapsed_s"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return elapsed if elapsed > 0 and not meta.get("quick") else None


def run_one(cmd: list[str], cwd: Path, env: dict, log_path: Path, label: str, verbose: bool,
            expected_s: float | None = None) -> tuple[int, float]:
    """
    Run one benchmark with its progress bar on stderr.

    Its output goes to log_path (and the terminal with verbose), its progress lines only to
    the bar.
    """
    started = time.perf_counter()
    with open(log_path, "w") as log, BenchStatus(label, expected_s=expected_s) as status:
        log.write("$ " + " ".join(shlex.quote(c) for c in cmd) + "\n")
        log.flush()
        process = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, text=True, bufsize=1)
        try:
            for line in process.stdout:
                if line.startswith(PROGRESS_PREFIX):
                    status.progress(line[len(PROGRESS_PREFIX):])
                    continue
                log.write(line)
                status.output(line)
                if verbose:
                    status.echo(f"    {line}")
            code = process.wait()
        except KeyboardInterrupt:
            process.terminate()
            process.wait()
            raise
    return code, time.perf_counter() - started


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
