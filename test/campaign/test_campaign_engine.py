# SPDX-License-Identifier: Apache-2.0
"""
The campaign engine (campaign/engine.py) on real Dask clusters: local, and a scheduler with workers.

Every run is compared with the same trials run in this process without Dask (run_batch, one
batch after another): the records (but the time each identification took) must be equal,
each task exactly once, whatever the workers, a worker killed, or an interrupted run resumed.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from star_tracker.campaign import CampaignKind, CampaignSpec, run_campaign
from star_tracker.campaign.engine import run_batch
from star_tracker.campaign.presets import KINDS
from star_tracker.campaign.results import ResultStore

pytestmark = pytest.mark.slow

KIND = KINDS["false-id"]()
TIMING = ("identify_s",)  # host speed, not a result


def _comparable(table: pa.Table) -> dict:
    return table.drop_columns(list(TIMING)).sort_by("task").to_pydict()


def _reference(spec: CampaignSpec) -> dict:
    """Compute the campaign's records here, batch after batch, without Dask."""
    return _comparable(pa.concat_tables([run_batch(KIND, spec, b).table for b in range(spec.batches)]))


def _stored(output: Path, spec: CampaignSpec) -> pa.Table:
    return ResultStore(output, spec, KIND.schema()).read()


def _once_each(table: pa.Table, spec: CampaignSpec) -> bool:
    tasks = np.sort(np.asarray(table.column("task")))
    return np.array_equal(tasks, np.arange(spec.trials))


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "star_tracker.cli", "characterize", *args]


@dataclass(frozen=True)
class _DrawOptions:
    scale: float = 1.0


class OutsideKind(CampaignKind):
    """A kind defined outside star_tracker, as a benchmark's is (bench/): the engine ships its module to the workers."""

    name = "outside-draw"
    description = "normal draws, a number and a list per trial"
    options_type = _DrawOptions
    columns = (pa.field("total", pa.float64()), pa.field("draws", pa.list_(pa.float64())))
    default_trials = 40
    default_batch = 7

    def prepare(self, options):
        return None

    def trial(self, shared, options, task, rng):
        draws = options.scale * rng.normal(size=1 + task % 4)
        return {"total": float(draws.sum()), "draws": draws.tolist()}

    def summarize(self, table, options):
        return {}


@pytest.fixture(scope="module")
def spec(database):  # the session's database built before any worker would build its own
    return CampaignSpec("false-id", trials=240, seed=11, batch=20)


@pytest.fixture(scope="module")
def reference(spec):
    return _reference(spec)


@pytest.mark.parametrize("workers", [1, 2])
def test_records_do_not_depend_on_the_number_of_workers(spec, reference, tmp_path, workers):
    run = run_campaign(KIND, spec, tmp_path, workers=workers)
    table = _stored(tmp_path, spec)
    assert run.batches_run == spec.batches and run.threads == workers
    assert _once_each(table, spec) and _comparable(table) == reference
    solved = np.asarray(table.column("solved"))
    assert solved.mean() > 0.95 and not np.asarray(table.column("wrong")).any()  # the scenes' truth


@pytest.fixture
def dask_cluster(tmp_path):
    """Start a real `dask scheduler` and two `dask worker` processes on localhost; yield (address, workers)."""
    scheduler_file = tmp_path / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(scheduler_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        import json

        address = json.loads(scheduler_file.read_text())["address"]
        workers = [subprocess.Popen([sys.executable, "-m", "dask", "worker", "--scheduler-file", str(scheduler_file),
                                     "--nthreads", "1", "--no-dashboard", "--no-nanny", "--host", "127.0.0.1"],
                                    env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                    cwd=tmp_path)  # where neither bench/ nor this file is importable
                   for _ in range(2)]
        procs += workers
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:  # a worker that ran an uploaded kind once sat out SIGTERM for 20 s
                p.kill()
                p.wait(timeout=20)


def test_a_campaign_on_a_scheduler_equals_the_local_run(spec, reference, dask_cluster, tmp_path):
    address, _ = dask_cluster
    out = tmp_path / "remote"
    done = subprocess.run(_cli("false-id", "--trials", str(spec.trials), "--seed", str(spec.seed), "--batch",
                               str(spec.batch), "--scheduler", address, "--output", str(out)),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    table = _stored(out, spec)
    assert _once_each(table, spec) and _comparable(table) == reference
    assert (out / "summary.json").exists()


def test_a_kind_from_outside_the_package_runs_on_workers_that_cannot_import_it(dask_cluster, tmp_path):
    """Its module is shipped (engine.ship_kind_code); the list column arrives intact and equal to a local run."""
    address, _ = dask_cluster
    kind, spec = OutsideKind(), CampaignSpec("outside-draw", 40, seed=5, batch=7, options={"scale": 2.0})
    run = run_campaign(kind, spec, tmp_path / "remote", scheduler=address)
    table = ResultStore(tmp_path / "remote", spec, kind.schema()).read().sort_by("task")
    here = pa.concat_tables([run_batch(kind, spec, b).table for b in range(spec.batches)])
    assert run.threads == 2 and table.column("error").to_pylist() == [""] * 40
    assert table.to_pydict() == here.to_pydict()
    assert [len(d) for d in table.column("draws").to_pylist()] == [1 + t % 4 for t in range(40)]


def test_two_campaigns_of_a_shipped_kind_run_one_after_the_other_in_one_process(tmp_path):
    """A LocalCluster's scheduler is this process: nothing is uploaded there to replace the code this process runs."""
    kind = OutsideKind()
    for run in ("first", "second"):
        spec = CampaignSpec("outside-draw", 14, seed=3, batch=7)
        run_campaign(kind, spec, tmp_path / run, workers=1)
        assert ResultStore(tmp_path / run, spec, kind.schema()).read().num_rows == 14
    assert Path(sys.modules[OutsideKind.__module__].__file__).exists()


def test_local_workers_keep_glibcs_own_memory_trimming():
    """Dask's MALLOC_TRIM_THRESHOLD_ would map and fault every frame-sized array anew (engine.connect)."""
    from star_tracker.campaign.engine import MALLOC_TRIM, connect

    client = connect(1, None)
    try:
        environment = client.run(lambda: os.environ.get(MALLOC_TRIM, "unset"))
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    assert list(environment.values()) == ["unset"]


def test_a_worker_killed_mid_run_loses_no_task(dask_cluster, tmp_path):
    address, workers = dask_cluster
    spec = CampaignSpec("false-id", trials=400, seed=12, batch=10)
    out = tmp_path / "killed"
    campaign = subprocess.Popen(_cli("false-id", "--trials", str(spec.trials), "--seed", str(spec.seed), "--batch",
                                     str(spec.batch), "--scheduler", address, "--output", str(out)),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while len(list((out / "results").glob("batch-*.parquet"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    written = len(list((out / "results").glob("batch-*.parquet")))
    workers[0].kill()  # SIGKILL mid-batch: its batches go to the other worker
    _, err = campaign.communicate(timeout=300)
    assert campaign.returncode == 0, err[-2000:]
    assert 3 <= written < spec.batches
    table = _stored(out, spec)
    assert _once_each(table, spec) and _comparable(table) == _reference(spec)


def test_an_interrupted_campaign_resumes_without_redoing_or_losing_a_task(tmp_path):
    spec = CampaignSpec("false-id", trials=400, seed=13, batch=10)
    out = tmp_path / "interrupted"
    argv = _cli("false-id", "--trials", str(spec.trials), "--seed", str(spec.seed), "--batch", str(spec.batch),
                "--workers", "1", "--output", str(out))
    first = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 180
    while len(list((out / "results").glob("batch-*.parquet"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(first.pid, signal.SIGKILL)  # the command, its cluster and its workers, as a crash would
    first.communicate(timeout=60)
    before = sorted(p.name for p in (out / "results").glob("batch-*.parquet"))
    assert 3 <= len(before) < spec.batches and not (out / "summary.json").exists()
    stamps = {name: (out / "results" / name).stat().st_mtime_ns for name in before}
    second = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert second.returncode == 0, second.stderr[-2000:]
    assert f"({len(before)} resumed)" in second.stderr
    assert all((out / "results" / name).stat().st_mtime_ns == stamps[name] for name in before)  # not redone
    table = _stored(out, spec)
    assert _once_each(table, spec) and _comparable(table) == _reference(spec)


def test_an_unreachable_scheduler_and_a_bad_campaign_file_fail_before_any_work(tmp_path, capsys):
    out = tmp_path / "never"
    done = subprocess.run(_cli("false-id", "--trials", "10", "--scheduler", "tcp://127.0.0.1:9", "--output",
                               str(out)), capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "no Dask scheduler answered at tcp://127.0.0.1:9" in done.stderr
    assert not out.exists()
    from star_tracker.cli import main

    bad = tmp_path / "bad.yaml"
    for text, message in (("preset: false-id\ntrials: -3\n", "trials must be a whole number >= 1"),
                          ("preset: false-id\noptions: {false_stars: many}\n", "false_stars"),
                          ("preset: nothing\n", "preset 'nothing' unknown"),
                          ("preset: false-id\ntrails: 10\n", "unknown key(s) ['trails']"),
                          ("preset: [false-id\n", "not valid YAML")):
        bad.write_text(text)
        with pytest.raises(SystemExit) as exited:  # the command line's own entry, in this process
            main(["characterize", str(bad), "--output", str(out)])
        stderr = capsys.readouterr().err
        assert exited.value.code == 2 and message in stderr, (text, stderr[-500:])
        assert not out.exists()
