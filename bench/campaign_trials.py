# SPDX-License-Identifier: Apache-2.0
"""
A benchmark's trials through the campaign engine (star_tracker/campaign): local cores or a Dask cluster.

A benchmark whose trials are independent defines them as a `CampaignKind` (its module, bench/)
and runs them with `run_trials`: on a `LocalCluster` of `--workers` processes (default: every
core), or on the scheduler at `--scheduler tcp://HOST:8786` (or $DASK_SCHEDULER_ADDRESS) whose
workers have star_tracker installed (the engine ships bench/ to them). The records come back in
task order, so the figures do not depend on how many workers ran them or where. With
`--campaign-output DIR` each benchmark's records stay in DIR/<kind> (Parquet) and an
interrupted run resumes there; without it they live in a temporary directory.

Timing columns a kind records (e.g. ms per solve) are measured on the worker that ran the
trial: on a cluster, on its machine, which the section's machine line then does not describe
(`engine_line` says where the trials ran).
"""
from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa

from star_tracker.campaign import CampaignKind, CampaignSpec, run_campaign
from star_tracker.campaign.engine import SCHEDULER_ENV


def add_engine_arguments(parser: argparse.ArgumentParser, timed: bool = False) -> None:
    """
    Add --workers, --scheduler and --campaign-output (module docstring).

    timed: the benchmark's figures include times per call compared with peers, so by default
    one local worker runs the trials, one call at a time on an otherwise idle core, as a latency
    is measured (a second worker shares the host's caches and memory bandwidth with it);
    --workers N or --scheduler when only the counts matter.
    """
    group = parser.add_argument_group("campaign engine")
    default_text = "1, the times measured on one quiet core" if timed else "every core"
    group.add_argument("--workers", type=int, default=1 if timed else None,
                       help=f"local worker processes (default: {default_text})")
    group.add_argument("--scheduler", metavar="ADDR", default=None,
                       help=f"run the trials on this Dask scheduler (tcp://HOST:8786; default ${SCHEDULER_ENV}, "
                            "else a local cluster)")
    group.add_argument("--campaign-output", type=Path, metavar="DIR", default=None,
                       help="keep the trials' records in DIR/<kind> (Parquet; resumes an interrupted run); default: "
                            "a temporary directory")


def engine_arguments_text(args: argparse.Namespace) -> str:
    """Return the engine options as typed, for a section's command line ("" when defaults)."""
    parts = []
    if getattr(args, "workers", None):
        parts.append(f" --workers {args.workers}")
    if getattr(args, "scheduler", None):
        parts.append(f" --scheduler {args.scheduler}")
    if getattr(args, "campaign_output", None):
        parts.append(f" --campaign-output {args.campaign_output}")
    return "".join(parts)


def run_trials(kind: CampaignKind, trials: int, options: dict, args: argparse.Namespace | None = None,
               seed: int = 2026, batch: int | None = None, log=None, progress=None) -> tuple[pa.Table, dict]:
    """
    Run `trials` trials of `kind` through the engine; return their records (task order) and what the engine did.

    args: the parsed engine arguments (add_engine_arguments; None = a local cluster on every
    core, records in a temporary directory). log(text): progress, about every tenth of the trials;
    progress(done, total): after every batch (trials done, resumed ones included, of the campaign's).
    A trial that raised is a record with its error: the caller counts and reports them.
    """
    kind = importable(kind)
    spec = CampaignSpec(kind.name, trials, seed, batch or kind.default_batch, options)
    workers = getattr(args, "workers", None)
    scheduler = getattr(args, "scheduler", None)
    keep = getattr(args, "campaign_output", None)
    step = [max(trials // 10, 1), 0]

    def on_batch(done: int, total: int, _batch: int) -> None:
        if progress is not None:
            progress(done, total)
        if log is not None and (done - step[1] >= step[0] or done == total):
            step[1] = done
            log(f"  {kind.name}: {done}/{total} trials")

    with tempfile.TemporaryDirectory(prefix=f"bench-{kind.name}-") as scratch:
        output = Path(keep) / kind.name if keep else Path(scratch)
        run = run_campaign(kind, spec, output, workers=workers, scheduler=scheduler, on_batch=on_batch)
        from star_tracker.campaign.results import ResultStore

        table = ResultStore(output, spec, kind.schema()).read()
    table = table.sort_by("task")
    return table, run.to_dict()


def importable(kind: CampaignKind) -> CampaignKind:
    """
    Return the kind as its module's real name knows it.

    A benchmark run as `python -m bench.NAME` defines its kind in `__main__`, which a worker
    process cannot import: the same class is taken from bench.NAME instead.
    """
    cls = type(kind)
    if cls.__module__ != "__main__":
        return kind
    spec = getattr(sys.modules["__main__"], "__spec__", None)
    if spec is None:
        raise ValueError(f"campaign kind {cls.__name__} is defined in a script: run it as `python -m bench.<name>`")
    return getattr(importlib.import_module(spec.name), cls.__name__)()


def records(table: pa.Table) -> list[dict]:
    """
    Return the table's rows as dicts; list columns become numpy arrays.

    Numbers, or nested lists of one shape, become a numeric array; lists holding nulls inside
    nested ones (a frame without a 3-vector) an object array of their items.
    """
    rows = table.to_pylist()
    lists = [f.name for f in table.schema if pa.types.is_list(f.type)]
    for row in rows:
        for name in lists:
            if row[name] is not None:
                try:
                    row[name] = np.asarray(row[name])
                except ValueError:  # ragged: [[x, y, z], None, ...]
                    items = np.empty(len(row[name]), object)
                    items[:] = row[name]
                    row[name] = items
    return rows


def errors(table: pa.Table) -> list[str]:
    """Return the errors of the trials that raised (task: error)."""
    task, error = table.column("task").to_pylist(), table.column("error").to_pylist()
    return [f"task {t}: {e}" for t, e in zip(task, error) if e]


def engine_line(run: dict) -> str:
    """One line for a section: where the trials ran, on how many workers, how busy."""
    share = run.get("utilization")
    return (f"trials on the campaign engine: {run.get('trials_run', 0)} on {run.get('threads', '?')} worker(s) at "
            f"{run.get('scheduler', '?')}" + (f", {100 * share:.0f} % busy" if share is not None else ""))


def log_stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
