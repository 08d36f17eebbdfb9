# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker characterize PRESET|CAMPAIGN.yaml`: a Monte-Carlo campaign on Dask (docs/CHARACTERIZE.md).

The preset (campaign/presets: false-id, sky-coverage) or the YAML campaign runs its trials on
a Dask LocalCluster of --workers processes (default: every core) or on the scheduler at
--scheduler / $DASK_SCHEDULER_ADDRESS, streaming the records to OUTPUT/results/*.parquet.
Run again with the same options and output, it resumes; finished, it writes
OUTPUT/summary.json (the preset's figures, the campaign, the engine's throughput and the
software version) beside the preset's tables and figures.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path

from .common import CommandError, Progress, add_parser, guarded, positive_int

NAME = "characterize"
# campaign.presets.KINDS without importing Dask at --help; a test compares the two.
PRESETS = ("false-id", "sky-coverage", "accuracy", "tracking")


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "Monte-Carlo campaigns on Dask: false-id bound, sky coverage, accuracy, tracking",
        "Run a campaign of independent seeded trials on a Dask cluster: a LocalCluster on this machine's cores by "
        "default, or an existing scheduler (--scheduler, or DASK_SCHEDULER_ADDRESS; start one with `dask "
        "scheduler` and `dask worker ADDRESS`). Results stream into OUTPUT/results/*.parquet; the same command "
        "again resumes an interrupted run. Writes OUTPUT/summary.json and the preset's tables and figures. "
        f"Presets: {', '.join(PRESETS)}; or a YAML file with preset, trials, seed, batch and options.",
        "star-tracker characterize false-id --trials 100000 --output /tmp/false_id\n"
        "star-tracker characterize sky-coverage --option nside=8 --output /tmp/sky\n"
        "star-tracker characterize campaign.yaml --scheduler tcp://10.0.0.5:8786")
    parser.add_argument("campaign", metavar="PRESET|CAMPAIGN.yaml", help=f"a preset ({', '.join(PRESETS)}) or a "
                        "campaign file")
    parser.add_argument("--trials", "--frames", dest="trials", type=positive_int,
                        help="trials (frames) to run (default: the preset's or the file's)")
    parser.add_argument("--workers", type=positive_int, help="local worker processes (default: every core)")
    parser.add_argument("--scheduler", metavar="ADDR", help="a Dask scheduler's address (tcp://HOST:8786); "
                        "default $DASK_SCHEDULER_ADDRESS, else a LocalCluster")
    parser.add_argument("--output", metavar="DIR", help="output directory (default characterize_output/PRESET)")
    parser.add_argument("--seed", type=int, help="the campaign's seed (default: 2026 or the file's)")
    parser.add_argument("--batch", type=positive_int, help="trials per Dask task (default: the preset's)")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="a preset option (repeatable; YAML values: --option false_stars=5; default: the "
                        "preset's options)")
    parser.set_defaults(func=run, argv=None)


def campaign_from_args(args: argparse.Namespace):
    """Return (kind, spec) from the preset or file and the options given; bad input raises CommandError."""
    import yaml

    from ..campaign import CampaignSpec, load_campaign_yaml
    from ..campaign.presets import KINDS

    if args.campaign in KINDS:
        data = {"preset": args.campaign}
    elif args.campaign.endswith((".yaml", ".yml")) or Path(args.campaign).exists():
        data = load_campaign_yaml(args.campaign)
    else:
        raise CommandError(f"{args.campaign!r} is neither a preset ({', '.join(KINDS)}) nor a campaign file")
    if data["preset"] not in KINDS:
        raise CommandError(f"preset {data['preset']!r} unknown: choose among {', '.join(KINDS)}")
    kind = KINDS[data["preset"]]()
    options = dict(data.get("options") or {})
    for item in args.option:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise CommandError(f"--option {item!r}: expected NAME=VALUE")
        options[name.strip()] = yaml.safe_load(value)
    parsed = kind.options(options)
    default_trials = getattr(parsed, "trials", None) or kind.default_trials
    spec = CampaignSpec(preset=kind.name, trials=args.trials or data.get("trials") or default_trials,
                        seed=args.seed if args.seed is not None else data.get("seed", 2026),
                        batch=args.batch or data.get("batch") or kind.default_batch, options=options)
    return kind, spec


def cpu_model() -> str:
    """Return the CPU's model name (Linux /proc/cpuinfo), else the architecture."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.machine()


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("star_tracker")
    except Exception:  # noqa: BLE001 - an uninstalled checkout
        return "unknown"


@guarded(NAME)
def run(args: argparse.Namespace) -> int:
    from ..campaign import run_campaign
    from ..campaign.engine import engine_totals
    from ..campaign.results import ResultStore

    kind, spec = campaign_from_args(args)
    if args.argv is None:
        args.argv = [NAME, *sys.argv[sys.argv.index(NAME) + 1:]] if NAME in sys.argv else [NAME, args.campaign]
    output = Path(args.output or Path("characterize_output") / kind.name)
    progress = Progress(spec.trials, f"{kind.name}:")
    print(f"star-tracker characterize: {kind.name}, {spec.trials} trials in batches of {spec.batch}, seed "
          f"{spec.seed}, output {output}", file=sys.stderr)
    started = time.perf_counter()
    campaign = run_campaign(kind, spec, output, workers=args.workers, scheduler=args.scheduler,
                            on_batch=lambda done, total, batch: progress.update(done))
    progress.update(spec.trials)
    options = kind.options(spec.options)
    store = ResultStore(output, spec, kind.schema())
    table = store.read()
    engine = engine_totals(store.runs())
    command = "star-tracker " + " ".join(shlex.quote(a) for a in (args.argv or []))
    summary = {"preset": kind.name, **kind.summarize(table, options), "command": command, "campaign": spec.to_dict(),
               "options": {k: getattr(options, k) for k in options.__dataclass_fields__},
               "engine": engine, "elapsed_s": time.perf_counter() - started,
               "software": {"star_tracker": software_version(), "python": platform.python_version()},
               "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "node": platform.node()},
               "date_utc": engine["last_work_utc"] or time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    files = kind.report(table, summary, options, output)
    (output / "summary.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    now = campaign.to_dict()
    print(f"{kind.name}: {summary.get('trials')} trials; {_headline(summary)}; {campaign.batches_run} batches run now "
          f"({campaign.batches_resumed} resumed) on {now['threads']} worker threads in {campaign.wall_s:.1f} s, "
          + (f"{now['trials_per_s_per_core']:.3g} trials/s/core, {100 * now['utilization']:.0f} % busy"
             if now["utilization"] else "nothing left to run"), file=sys.stderr)
    print(f"wrote {output / 'summary.json'}" + "".join(f", {f}" for f in files), file=sys.stderr)
    return 0


def _headline(summary: dict) -> str:
    if summary["preset"] == "false-id":
        bound = summary["wrong_rate_upper_95"]
        return (f"{summary['correct']} correct, {summary['wrong']} wrong ({summary['false_identification']} false "
                f"identifications, {summary['wrong_deep_star']} with a wrong deep star alone), {summary['unsolved']} "
                f"unsolved; wrong rate <= {bound:.2e}, false identification <= "
                f"{summary['false_identification_upper_95']:.2e} (95 %)" if bound is not None else "no trial")
    if summary["preset"] == "sky-coverage":
        return (f"{100 * (summary['success'] or 0):.3f} % solved right, {summary['wrong']} wrong, "
                f"{summary['pixels_failing']} of {summary['pixels_tried']} pixels with a failure")
    if summary["preset"] == "accuracy":
        axes = summary["axes"]
        return (f"{summary['solved']} solved, {summary['wrong']} wrong; RMS x, y, roll " + ", ".join(
            f"{axes[a]['rms']:.2f}" if axes[a]["rms"] is not None else "-" for a in ("x", "y", "roll")) + '"')
    if summary["preset"] == "tracking":
        envelope = ", ".join(f"{a} deg/s^2: {r if r is not None else '-'}"
                             for a, r in summary["envelope_rate_deg_s_by_acceleration"].items())
        return (f"{summary['frames']} frames, {summary['wrong_frames']} wrong, {summary['overconfident_frames']} "
                f"overconfident; fastest rate [deg/s] tracked right in every frame by acceleration: {envelope}")
    return ""
