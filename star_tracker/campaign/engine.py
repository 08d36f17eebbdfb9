# SPDX-License-Identifier: Apache-2.0
"""
The campaign engine: a campaign's batches on Dask distributed, their records streamed to Parquet.

`run_campaign(kind, spec, output)` runs every batch not yet in `output` (results.py: resume)
on a Dask cluster: by default a `LocalCluster` of `workers` single-threaded worker processes
on this machine (all its cores), or the scheduler at `scheduler` (`tcp://HOST:8786`, started
with the standard `dask scheduler` / `dask worker` commands; every worker needs this package
installed). A batch is one Dask task of `spec.batch` trials (so ~1 ms trials keep the workers
busy); at most a few batches per worker are in flight, and each finished one is written at
once, so a 3-million-trial campaign holds one batch in memory. A worker that dies loses
nothing: the scheduler runs its batches again elsewhere, and a batch's file is written once.
A trial that raises is a record with its task, seed and error; the campaign goes on.

A kind defined outside this package (a benchmark's, bench/) has its top-level package zipped
and uploaded to the cluster's workers (`ship_kind_code`), so a cluster whose workers have
only star_tracker installed runs it too.

In a worker, `run_batch` builds the kind's shared state once per process (`prepare`), then
each trial with its own generator (spec.rng): the records do not depend on the number of
workers, the batching's order or the machine (tested).
"""
from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
import traceback
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pyarrow as pa

from .kind import CampaignKind
from .results import ResultStore
from .spec import CampaignSpec

SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
CONNECT_TIMEOUT_S = 10.0
IN_FLIGHT_PER_WORKER = 3  # batches queued per worker thread: none idles between two
RETRIES = 3  # a batch whose worker died is run again up to this many times
WORKER_ENVIRONMENT = "distributed.nanny.pre-spawn-environ"  # Dask's environment of a worker process
MALLOC_TRIM = "MALLOC_TRIM_THRESHOLD_"  # left unset in the workers (connect)

_SHARED: dict = {}  # per worker process: (kind name, options) -> the kind's shared state


@dataclass
class BatchResult:
    """A finished batch: its records and the worker's time spent in it [s] (wall and CPU)."""

    batch: int
    table: pa.Table
    busy_s: float
    cpu_s: float
    worker: str = ""


@dataclass
class CampaignRun:
    """What run_campaign did: the batches run now and before, time, throughput and the workers' share busy."""

    trials: int
    batches_run: int
    batches_resumed: int
    wall_s: float
    busy_s: float
    cpu_s: float
    threads: int
    scheduler: str
    trials_run: int = 0
    workers: list[str] = field(default_factory=list)

    @property
    def utilization(self) -> float | None:
        """Share of the worker threads' wall time spent in batches (engine overhead = 1 - this)."""
        return self.busy_s / (self.wall_s * self.threads) if self.wall_s > 0 and self.threads else None

    @property
    def trials_per_s_per_core(self) -> float | None:
        return self.trials_run / self.cpu_s if self.cpu_s > 0 else None

    def to_dict(self) -> dict:
        return {"trials": self.trials, "trials_run": self.trials_run, "batches_run": self.batches_run,
                "batches_resumed": self.batches_resumed, "wall_s": self.wall_s, "busy_s": self.busy_s,
                "cpu_s": self.cpu_s, "threads": self.threads, "scheduler": self.scheduler,
                "workers": len(self.workers), "utilization": self.utilization,
                "trials_per_s": self.trials_run / self.wall_s if self.wall_s > 0 else None,
                "trials_per_s_per_core": self.trials_per_s_per_core}


def run_batch(kind: CampaignKind, spec: CampaignSpec, batch: int) -> BatchResult:
    """Run one batch's trials in this process (module docstring); never raises for a trial."""
    started, cpu_started = time.perf_counter(), time.process_time()
    options = kind.options(spec.options)
    key = (kind.name, repr(options))
    if key not in _SHARED:
        _SHARED.clear()  # one campaign's state at a time
        _SHARED[key] = kind.prepare(options)
    shared = _SHARED[key]
    names = [f.name for f in kind.columns]
    records = []
    for task in spec.batch_tasks(batch):
        record = {"task": task, "seed": spec.seed, "error": ""}
        try:
            record.update(kind.trial(shared, options, task, spec.rng(task)))
        except Exception as exc:  # noqa: BLE001 - a trial's failure is a result, recorded with its seed
            record.update({name: None for name in names})
            record["error"] = f"{type(exc).__name__}: {exc} | " + traceback.format_exc(limit=-2).replace("\n", " ")
        records.append(record)
    table = pa.Table.from_pylist(records, schema=kind.schema())
    return BatchResult(batch, table, time.perf_counter() - started, time.process_time() - cpu_started,
                       f"{os.uname().nodename}:{os.getpid()}")


def connect(workers: int | None, scheduler: str | None):
    """
    Return a Dask client: to `scheduler` (or $DASK_SCHEDULER_ADDRESS), else a new LocalCluster.

    A scheduler that does not answer within CONNECT_TIMEOUT_S raises OSError before any work.
    """
    from distributed import Client, LocalCluster

    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address:
        try:
            return Client(address, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise OSError(f"no Dask scheduler answered at {address} within {CONNECT_TIMEOUT_S:g} s ({exc})") from None
    import dask

    count = workers or os.cpu_count() or 1
    # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536, which also turns off glibc's
    # growing mmap threshold: every frame-sized temporary is then mapped and faulted in anew
    # (render + centroid of a 1024^2 frame measured 33-41 ms of CPU in such a worker, 20-23 ms
    # without it). Memory is not this engine's constraint (one batch in flight per worker).
    with dask.config.set({f"{WORKER_ENVIRONMENT}.{MALLOC_TRIM}": None}):
        cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR)
    return Client(cluster)


def ship_kind_code(client, kind: CampaignKind) -> str | None:
    """
    Upload the top-level package of a kind defined outside star_tracker to every worker; return its name.

    The package's .py files are zipped (client.upload_file puts the zip on the workers' path
    and imports it); None when the kind is star_tracker's own (installed on every worker) or the
    cluster is a LocalCluster (its workers import what this process imports).
    """
    from distributed import LocalCluster

    top = type(kind).__module__.split(".")[0]
    if top == __name__.split(".")[0] or isinstance(getattr(client, "cluster", None), LocalCluster):
        # A LocalCluster's workers run in this process or start from its sys.path (spawned):
        # they import the kind as this process does; an upload would re-import it beside ours.
        return None
    module = sys.modules[top]
    root = Path(module.__file__).parent if module.__file__.endswith("__init__.py") else Path(module.__file__)
    with tempfile.TemporaryDirectory() as scratch:
        archive = Path(scratch) / f"{top}.zip"
        with zipfile.ZipFile(archive, "w") as out:
            files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
            for path in files:
                out.write(path, path.relative_to(root.parent).as_posix())
        if client.run_on_scheduler(_this_process) == _this_process():
            # A LocalCluster's scheduler runs in this process, which imports the package already: the
            # scheduler's copy of an upload would re-import it here from the zip (deleted with the
            # cluster), breaking the next campaign. The workers only.
            from distributed.diagnostics.plugin import UploadFile

            client.register_plugin(UploadFile(str(archive)), name=f"ship-{top}")
        else:
            client.upload_file(str(archive))
    return top


def _this_process() -> tuple[str, int]:
    return os.uname().nodename, os.getpid()


def run_campaign(kind: CampaignKind, spec: CampaignSpec, output: Path | str, workers: int | None = None,
                 scheduler: str | None = None, on_batch: Callable[[int, int, int], None] | None = None,
                 client=None) -> CampaignRun:
    """
    Run the campaign's missing batches and return what ran (module docstring).

    on_batch(trials_done, trials_total, batch): after each batch is stored (progress). A
    client given is used as is (not closed).
    """
    from distributed import as_completed

    kind.options(spec.options)  # bad options fail here, before a cluster starts
    store = ResultStore(output, spec, kind.schema())
    store.check()  # another campaign's directory too
    own = client is None
    client = client or connect(workers, scheduler)  # an unreachable scheduler: before anything is written
    try:
        ship_kind_code(client, kind)
        done = store.open()
        pending = [b for b in range(spec.batches) if b not in done]
        done_trials = sum(len(spec.batch_tasks(b)) for b in done)
        threads = sum(client.nthreads().values())
        address = client.scheduler.address
        started = time.perf_counter()
        busy = cpu = 0.0
        run_trials, seen = 0, set()
        queue = iter(pending)

        def submit(batch: int):
            return client.submit(run_batch, kind, spec, batch, pure=False, retries=RETRIES,
                                 key=f"{kind.name}-{spec.seed}-{batch}")

        futures = as_completed([submit(b) for _, b in zip(range(max(threads, 1) * IN_FLIGHT_PER_WORKER), queue)])
        for future in futures:
            result: BatchResult = future.result()
            store.write(result.batch, result.table)
            busy, cpu = busy + result.busy_s, cpu + result.cpu_s
            run_trials += result.table.num_rows
            done_trials += result.table.num_rows
            seen.add(result.worker)
            future.release()
            nxt = next(queue, None)
            if nxt is not None:
                futures.add(submit(nxt))
            if on_batch is not None:
                on_batch(done_trials, spec.trials, result.batch)
        wall = time.perf_counter() - started
    finally:
        if own:
            cluster = getattr(client, "cluster", None)
            client.close()
            if cluster is not None:
                cluster.close()
    run = CampaignRun(spec.trials, len(pending), len(done), wall, busy, cpu, threads, address, run_trials,
                      sorted(seen))
    store.add_run({**run.to_dict(), "finished_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())})
    return run


def engine_totals(runs: list[dict]) -> dict:
    """Return the engine's figures over every run of a campaign (runs.jsonl): a resumed one's work added up."""
    worked = [r for r in runs if r.get("trials_run")]
    wall = sum(r["wall_s"] for r in worked)
    thread_time = sum(r["wall_s"] * r["threads"] for r in worked)
    cpu = sum(r["cpu_s"] for r in worked)
    trials = sum(r["trials_run"] for r in worked)
    return {"runs": len(runs), "runs_with_work": len(worked), "trials_run": trials, "wall_s": wall,
            "busy_s": sum(r["busy_s"] for r in worked), "cpu_s": cpu,
            "threads": max((r["threads"] for r in worked), default=0),
            "utilization": sum(r["busy_s"] for r in worked) / thread_time if thread_time > 0 else None,
            "trials_per_s": trials / wall if wall > 0 else None,
            "trials_per_s_per_core": trials / cpu if cpu > 0 else None,
            "scheduler": worked[-1]["scheduler"] if worked else None,
            "last_work_utc": worked[-1].get("finished_utc") if worked else None}
