# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker characterize PRESET|CAMPAIGN.yaml`: a Monte-Carlo campaign on Dask (docs/CHARACTERIZE.md).

The preset (campaign/presets: false-id, sky-coverage, accuracy, tracking, robustness, stress) or the
YAML campaign runs its trials on a Dask LocalCluster of --workers processes (default: every
core) or on the scheduler at --scheduler / $DASK_SCHEDULER_ADDRESS, streaming the records to OUTPUT/results/*.parquet.
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
PRESETS = ("false-id", "sky-coverage", "accuracy", "tracking", "robustness", "stress")
DATASHEET = "datasheet"  # not a preset: every campaign of the datasheet, then its report
# The datasheet's campaigns whose summaries --docs keeps as docs/characterize_<name>.json (DATASHEET.md's
# and BENCHMARKS.md's sources); the false-id figure there comes from its own 3,000,000-trial campaign.
DOCS_SUMMARIES = ("accuracy", "sky_coverage", "tracking", "robustness")


def register(subparsers) -> None:
    parser = add_parser(
        subparsers, NAME, "Monte-Carlo campaigns on Dask: false-id bound, sky coverage, accuracy, tracking",
        "Run a campaign of independent seeded trials on a Dask cluster: a LocalCluster on this machine's cores by "
        "default, or an existing scheduler (--scheduler, or DASK_SCHEDULER_ADDRESS; start one with `dask "
        "scheduler` and `dask worker ADDRESS`). Results stream into OUTPUT/results/*.parquet; the same command "
        "again resumes an interrupted run. Writes OUTPUT/summary.json and the preset's tables and figures. "
        f"Presets: {', '.join(PRESETS)}; or a YAML file with preset, trials, seed, batch and options; or "
        f"`{DATASHEET}`: the datasheet's campaigns (~20 min on two cores) and its report OUTPUT/DATASHEET.md.",
        "star-tracker characterize false-id --trials 100000 --output /tmp/false_id\n"
        "star-tracker characterize sky-coverage --option nside=8 --output /tmp/sky\n"
        "star-tracker characterize campaign.yaml --scheduler tcp://10.0.0.5:8786")
    parser.add_argument("campaign", metavar="PRESET|CAMPAIGN.yaml|datasheet", help=f"a preset ({', '.join(PRESETS)}), "
                        f"a campaign file, or {DATASHEET}")
    parser.add_argument("--trials", "--frames", dest="trials", type=positive_int,
                        help="trials (frames) to run (default: the preset's or the file's)")
    parser.add_argument("--workers", type=positive_int, help="local worker processes (default: every core)")
    parser.add_argument("--scheduler", metavar="ADDR", help="a Dask scheduler's address (tcp://HOST:8786); "
                        "default $DASK_SCHEDULER_ADDRESS, else a LocalCluster")
    parser.add_argument("--output", metavar="DIR", help="output directory (default characterize_output/PRESET)")
    parser.add_argument("--seed", type=int, help="the campaign's seed (default: 2026 or the file's)")
    parser.add_argument("--batch", type=positive_int, help="trials per Dask task (default: the preset's)")
    parser.add_argument("--docs", metavar="DIR", help=f"{DATASHEET}: also copy datasheet.json, the campaigns' "
                        "summaries (characterize_<campaign>.json) and the figures "
                        "into DIR (and DIR/images), where `python -m bench.datasheet` puts them in DATASHEET.md; "
                        "stress: write its section of DIR/RELIABILITY.md and keep DIR/characterize_stress.json")
    parser.add_argument("--quick", action="store_true", help=f"{DATASHEET} only: a few trials per campaign (a "
                        "minute; to try the command, the figures meaningless)")
    parser.add_argument("--replay", type=int, metavar="TASK", help="run trial TASK of the campaign (its --seed and "
                        "options) in this process and print it frame by frame, for presets that can (stress)")
    parser.add_argument("--through-nodes", action="store_true", help="stress only: the campaign's DDS part: --frames "
                        "image messages (default 2000) with faults through the centroider and identifier processes "
                        "(campaign/stress_nodes.py), into OUTPUT/summary_nodes.json")
    parser.add_argument("--gyro", action="store_true", help="with --through-nodes: the centroider aided by a biased, "
                        "noisy gyro on imu instead of the identifier's rate")
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
    # A kind whose trial is a sequence of frames (stress: a mission) takes --frames as frames.
    asked = kind.trials_for_frames(args.trials, parsed) if args.trials and hasattr(kind, "trials_for_frames") \
        else args.trials
    spec = CampaignSpec(preset=kind.name, trials=asked or data.get("trials") or default_trials,
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
    if args.argv is None:
        args.argv = [NAME, *sys.argv[sys.argv.index(NAME) + 1:]] if NAME in sys.argv else [NAME, args.campaign]
    if args.campaign == DATASHEET:
        return run_datasheet(args)
    if args.quick or (args.docs and args.campaign != "stress"):
        raise CommandError(f"--quick is for {DATASHEET} only, --docs for {DATASHEET} and stress")
    if args.through_nodes or args.gyro:
        return run_through_nodes(args)
    kind, spec = campaign_from_args(args)
    if args.replay is not None:
        return replay(kind, spec, args.replay)
    output = Path(args.output or Path("characterize_output") / kind.name)
    command = "star-tracker " + " ".join(shlex.quote(a) for a in (args.argv or []))
    summary, _, files = run_one(kind, spec, output, args.workers, args.scheduler, command)
    if args.docs:
        files += stress_docs(summary, Path(args.docs))
    print(f"wrote {output / 'summary.json'}" + "".join(f", {f}" for f in files), file=sys.stderr)
    return 0


def stress_docs(summary: dict, docs: Path) -> list[Path]:
    """Write the stress section of DOCS/RELIABILITY.md; keep the summary as DOCS/characterize_stress.json."""
    from ..campaign.presets.stress_report import reliability_section, write_section

    reliability = docs / "RELIABILITY.md"
    if not reliability.exists():
        raise CommandError(f"--docs {docs}: no RELIABILITY.md there")
    write_section(reliability, reliability_section(summary))
    kept = docs / "characterize_stress.json"
    kept.write_text(json.dumps(summary, indent=1, default=float) + "\n")
    return [reliability, kept]


def run_through_nodes(args: argparse.Namespace) -> int:
    """`characterize stress --through-nodes`: the stress plan through the real nodes (campaign/stress_nodes.py)."""
    if args.campaign != "stress" or not args.through_nodes:
        raise CommandError("--through-nodes (and --gyro with it) is for the stress preset only")
    from ..campaign.stress_nodes import run_stress_through_nodes, stamp_summary

    frames = args.trials or 2000
    seed = 1 if args.seed is None else args.seed
    output = Path(args.output or Path("characterize_output") / "stress_nodes")
    progress = Progress(frames, "stress through the nodes:")
    summary = run_stress_through_nodes(frames, seed, output, lambda done, total: progress.update(done), gyro=args.gyro)
    progress.update(frames)
    stamp_summary(summary, "star-tracker " + " ".join(shlex.quote(a) for a in (args.argv or [])), output)
    nodes = summary.get("nodes", {})
    print(f"stress through the nodes: {frames} frames; every frame accounted for: "
          f"{summary['accounting']['unaccounted'] == 0}; nodes alive: {nodes.get('all_alive')}; "
          f"passed: {summary.get('passed')}; wrote {output / 'summary_nodes.json'}", file=sys.stderr)
    return 0 if nodes.get("all_alive") else 1


def replay(kind, spec, task: int) -> int:
    """Print trial `task` of the campaign, run here (its seed and options), as the kind tells it."""
    if not hasattr(kind, "replay"):
        raise CommandError(f"preset {kind.name} cannot replay a trial; --replay is for stress")
    if task < 0:
        raise CommandError(f"--replay {task}: a task number is >= 0")
    options = kind.options(spec.options)
    print(kind.replay(kind.prepare(options), options, spec.rng(task)))
    return 0


def run_one(kind, spec, output: Path, workers: int | None, scheduler: str | None, command: str,
            campaign_name: str | None = None, client=None):
    """
    Run (or resume) one campaign into output; write its summary.json and report; return (summary, table, files).

    campaign_name: the datasheet campaign it is (summary's `datasheet_campaign`), None for a lone one;
    client: a Dask client to run on (engine.connect; kept open), None for a cluster of its own.
    """
    from ..campaign import run_campaign
    from ..campaign.engine import engine_totals
    from ..campaign.results import ResultStore

    progress = Progress(spec.trials, f"{kind.name}:")
    print(f"star-tracker characterize: {kind.name}, {spec.trials} trials in batches of {spec.batch}, seed "
          f"{spec.seed}, output {output}", file=sys.stderr)
    started = time.perf_counter()
    campaign = run_campaign(kind, spec, output, workers=workers, scheduler=scheduler,
                            on_batch=lambda done, total, batch: progress.update(done), client=client)
    progress.update(spec.trials)
    options = kind.options(spec.options)
    store = ResultStore(output, spec, kind.schema())
    table = store.read()
    engine = engine_totals(store.runs())
    summary = {"preset": kind.name, **kind.summarize(table, options), "command": command,
               **({"datasheet_campaign": campaign_name} if campaign_name else {}), "campaign": spec.to_dict(),
               "options": {k: getattr(options, k) for k in options.__dataclass_fields__},
               "engine": engine, "elapsed_s": time.perf_counter() - started,
               "software": {"star_tracker": software_version(), "python": platform.python_version()},
               "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "node": platform.node()},
               "date_utc": engine["last_work_utc"] or time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    files = kind.report(table, summary, options, output)
    (output / "summary.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    now = campaign.to_dict()
    print(f"{kind.name}: {summary.get('trials', spec.trials)} trials; {_headline(summary)}; "
          f"{campaign.batches_run} batches run now "
          f"({campaign.batches_resumed} resumed) on {now['threads']} worker threads in {campaign.wall_s:.1f} s, "
          + (f"{now['trials_per_s_per_core']:.3g} trials/s/core, {100 * now['utilization']:.0f} % busy"
             if now["utilization"] else "nothing left to run"), file=sys.stderr)
    return summary, table, files


def run_datasheet(args: argparse.Namespace) -> int:
    """Run the datasheet's campaigns into OUTPUT/<name>/ and write OUTPUT/DATASHEET.md, datasheet.json, images/."""
    import shutil

    from ..campaign import CampaignSpec
    from ..campaign import datasheet_figures as figures
    from ..campaign.engine import connect
    from ..campaign.datasheet import FALSE_ID_TRIALS, datasheet_campaigns, datasheet_data, render_report
    from ..campaign.presets import KINDS

    if args.option:
        raise CommandError("the datasheet's campaigns take no --option (their sizes are fixed; --trials sets the "
                           "false-id trials)")
    output = Path(args.output or Path("characterize_output") / DATASHEET)
    command = "star-tracker " + " ".join(shlex.quote(a) for a in (args.argv or []))
    seed = args.seed if args.seed is not None else 2026
    started = time.perf_counter()
    summaries, tables = {}, {}
    planned = []
    for item in datasheet_campaigns(args.trials or FALSE_ID_TRIALS, quick=args.quick):
        kind = KINDS[item.preset]()
        options = kind.options(item.options)  # every campaign's options checked before a cluster starts
        trials = item.trials or getattr(options, "trials", None) or kind.default_trials
        planned.append((item, kind, CampaignSpec(preset=kind.name, trials=trials, seed=seed,
                                                 batch=args.batch or kind.default_batch, options=item.options)))
    client = connect(args.workers, args.scheduler)  # one cluster for all: its workers start once
    try:
        for item, kind, spec in planned:
            summaries[item.name], tables[item.name], _ = run_one(kind, spec, output / item.name, args.workers,
                                                                 args.scheduler, command, campaign_name=item.name,
                                                                 client=client)
    finally:
        cluster = getattr(client, "cluster", None)
        client.close()
        if cluster is not None:
            cluster.close()
    # The campaigns' own work (added up over resumed runs), not this call's: a finished datasheet
    # run again only rewrites the report.
    meta = {"command": command, "date_utc": max(s["date_utc"] for s in summaries.values()),
            "software": software_version(), "machine": f"{cpu_model()}, {os.cpu_count()} cores",
            "wall_s": sum(s["engine"]["wall_s"] for s in summaries.values())}
    data = datasheet_data(summaries, tables, meta)
    images = output / "images"
    images.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(output / "sky_coverage" / "sky_coverage.png", images / "datasheet_sky_coverage.png")
    figures.error_histograms(data, images / "datasheet_error_histograms.png")
    figures.error_vs_rate(data, images / "datasheet_error_vs_rate.png")
    figures.tracking_envelope(data, images / "datasheet_tracking_envelope.png")
    figures.robustness(data, images / "datasheet_robustness.png")
    (output / "datasheet.json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    (output / "DATASHEET.md").write_text("# star_tracker datasheet\n\n" + render_report(data))
    if args.docs:
        docs = Path(args.docs)
        (docs / "images").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(output / "datasheet.json", docs / "datasheet.json")
        for png in sorted(images.glob("datasheet_*.png")):
            shutil.copyfile(png, docs / "images" / png.name)
        for name in DOCS_SUMMARIES:
            shutil.copyfile(output / name / "summary.json", docs / f"characterize_{name}.json")
    print(f"wrote {output / 'DATASHEET.md'}, {output / 'datasheet.json'} and {images}; the campaigns' work "
          f"{meta['wall_s'] / 60:.1f} min, this call {(time.perf_counter() - started) / 60:.1f} min", file=sys.stderr)
    return 0


def _headline(summary: dict) -> str:
    if summary["preset"] == "false-id":
        bound = summary["wrong_rate_upper_95"]
        return (f"{summary['correct']} correct, {summary['wrong']} wrong ({summary['false_identification']} false "
                f"identifications, {summary['wrong_deep_star']} with a wrong deep star alone, "
                f"{summary['outside_5_sigma']} outside 5 sigma (a consistent covariance: "
                f"{summary['outside_5_sigma_expected']:.1f})), {summary['unsolved']} "
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
    if summary["preset"] == "robustness":
        worst = ", ".join(f"{name} {cells[-1]['level']:g}: {100 * (cells[-1]['availability'] or 0):.0f} %"
                          for name, cells in summary["sweeps"].items())
        return f"{summary['solved']} solved, {summary['wrong']} wrong; solved right at the strongest level: {worst}"
    if summary["preset"] == "stress":
        nees = summary["nees_mean"]
        worst = max(((name, value, cell["nees_mean"]) for name, cells in summary["strata"].items()
                     for value, cell in cells.items() if cell["nees_mean"] is not None), key=lambda c: c[2],
                    default=None)
        return (f"{summary['missions']} missions, {summary['frames']} frames accepted, {summary['wrong']} wrong, "
                f"{summary['wrong_star_frames']} with a wrong star; NEES mean "
                + (f"{nees:.2f}" if nees is not None else "-")
                + (f" (worst stratum {worst[0]} {worst[1]}: {worst[2]:.2f})" if worst else ""))
    return ""
