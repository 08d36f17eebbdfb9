# SPDX-License-Identifier: Apache-2.0
"""
A campaign's output directory: its definition, one Parquet file per finished batch, the summary.

OUTPUT/campaign.json holds the campaign's definition (CampaignSpec.to_dict); a directory
holding another campaign's is refused, one holding the same one is resumed. Each finished
batch is written to OUTPUT/results/batch-NNNNNNNN.parquet through a temporary name and a
rename, so a file present is a batch complete: an interrupted run resumes with the batches
that have none, and no task is ever written twice. Memory holds one batch at a time.
OUTPUT/runs.jsonl records what the engine did in each run of the command.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from .spec import CampaignSpec

RESULTS = "results"
DEFINITION = "campaign.json"
RUNS = "runs.jsonl"  # one line per run of the command: what the engine did (a resumed campaign has several)


class ResultStore:
    """The output directory of one campaign (module docstring)."""

    def __init__(self, output: Path | str, spec: CampaignSpec, schema: pa.Schema):
        self.output = Path(output)
        self.spec, self.schema = spec, schema
        self.results = self.output / RESULTS

    def check(self) -> None:
        """Raise ValueError when the directory holds another campaign (nothing is created)."""
        definition = self.output / DEFINITION
        if not definition.exists():
            return
        try:
            existing = json.loads(definition.read_text())
        except ValueError as exc:
            raise ValueError(f"{definition}: unreadable ({exc}); use another --output") from None
        if existing != self.spec.to_dict():
            raise ValueError(f"{self.output} holds another campaign ({definition}: {existing}); "
                             "use another --output, or the same options to resume it")

    def open(self) -> set[int]:
        """Create or check the directory; return the batches already finished (resume)."""
        self.check()
        definition = self.output / DEFINITION
        if not definition.exists():
            self.output.mkdir(parents=True, exist_ok=True)
            _write_atomic(definition, json.dumps(self.spec.to_dict(), indent=1).encode())
        self.results.mkdir(exist_ok=True)
        for stale in self.results.glob("*.tmp"):  # a write the last run did not finish
            stale.unlink()
        return {int(p.stem.split("-")[1]) for p in self.results.glob("batch-*.parquet")}

    def write(self, batch: int, table: pa.Table) -> None:
        """Store a finished batch (atomically)."""
        path = self.results / f"batch-{batch:08d}.parquet"
        temporary = path.with_suffix(".tmp")
        pq.write_table(table.cast(self.schema), temporary)
        os.replace(temporary, path)

    def add_run(self, run: dict) -> None:
        """Append one run's engine record (CampaignRun.to_dict) to OUTPUT/runs.jsonl."""
        with (self.output / RUNS).open("a") as f:
            f.write(json.dumps(run) + "\n")

    def runs(self) -> list[dict]:
        """Return every run's engine record, oldest first."""
        path = self.output / RUNS
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []

    def read(self, columns: list[str] | None = None) -> pa.Table:
        """Return every finished batch's records, in task order."""
        files = sorted(self.results.glob("batch-*.parquet"))
        if not files:
            return self.schema.empty_table() if columns is None else self.schema.empty_table().select(columns)
        return pa.concat_tables([pq.read_table(f, columns=columns) for f in files])


def _write_atomic(path: Path, data: bytes) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_bytes(data)
    os.replace(temporary, path)
