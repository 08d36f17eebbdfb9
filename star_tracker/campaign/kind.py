# SPDX-License-Identifier: Apache-2.0
"""
What a campaign runs: a `CampaignKind` makes one trial's result record from its task number and seed.

A kind (one per preset, presets/) declares its options (a dataclass of `parameter(...)`
fields, validated at construction), the columns of its records (a pyarrow schema), how a
worker process prepares once what every trial shares (`prepare`: the catalog, the database,
the identifier), one trial (`trial`: seeded by the engine, no other randomness), and what a
finished table says (`summarize`, `report`). The contract is checked when a subclass is
defined, as `identify/base.py` does for `StarIdentifier`.
"""
from __future__ import annotations

import abc
import dataclasses
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

# Columns every record carries (the engine fills them): the task's number, the campaign's seed
# (task and seed replay the trial exactly), the error of a trial that raised ("" otherwise).
ENGINE_FIELDS = (pa.field("task", pa.int64()), pa.field("seed", pa.int64()), pa.field("error", pa.string()))


class CampaignKind(abc.ABC):
    """One kind of trial (module docstring)."""

    name: ClassVar[str]
    description: ClassVar[str]
    options_type: ClassVar[type]
    columns: ClassVar[tuple[pa.Field, ...]]
    default_trials: ClassVar[int]
    default_batch: ClassVar[int]  # trials per Dask task: ~1 s of work, so a ~1 ms trial keeps the workers busy

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if getattr(cls, "__abstractmethods__", None):
            return
        missing = [a for a in ("name", "description", "options_type", "columns", "default_trials", "default_batch")
                   if not hasattr(cls, a)]
        if missing:
            raise TypeError(f"campaign kind {cls.__name__} lacks {missing}")
        if not dataclasses.is_dataclass(cls.options_type):
            raise TypeError(f"campaign kind {cls.name}: options_type must be a dataclass")
        clash = {f.name for f in cls.columns} & {f.name for f in ENGINE_FIELDS}
        if clash:
            raise TypeError(f"campaign kind {cls.name}: columns {sorted(clash)} are the engine's")

    @classmethod
    def schema(cls) -> pa.Schema:
        """Return the records' schema: the engine's columns, then the kind's."""
        return pa.schema([*ENGINE_FIELDS, *cls.columns])

    @classmethod
    def options(cls, values: dict[str, Any] | None) -> Any:
        """Return the options dataclass from a mapping; unknown or invalid options raise ValueError."""
        values = dict(values or {})
        known = {f.name for f in dataclasses.fields(cls.options_type)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{cls.name}: unknown option(s) {unknown}; known: {sorted(known)}")
        bad = []
        for f in dataclasses.fields(cls.options_type):
            if f.name in values:
                values[f.name], problem = _typed(f.name, values[f.name], f.default)
                bad += [problem] if problem else []
        if bad:
            raise ValueError(f"{cls.name}: " + "; ".join(bad))
        return cls.options_type(**values)

    @abc.abstractmethod
    def prepare(self, options: Any) -> Any:
        """Return what every trial of a worker process shares (built once per process and options)."""

    @abc.abstractmethod
    def trial(self, shared: Any, options: Any, task: int, rng: np.random.Generator) -> dict[str, Any]:
        """Return trial `task`'s record (the kind's columns), drawing every random number from rng."""

    @abc.abstractmethod
    def summarize(self, table: pa.Table, options: Any) -> dict[str, Any]:
        """Return summary.json's figures for the campaign's records."""

    def report(self, table: pa.Table, summary: dict[str, Any], options: Any, output: Path) -> list[Path]:
        """Write the kind's tables and figures into `output`; return the files written (none by default)."""
        return []


def _typed(name: str, value: Any, default: Any) -> tuple[Any, str]:
    """Return value as the default's type (an int where a float is expected becomes one) and a problem or ""."""
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif isinstance(default, str):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = f"{value:g}"  # YAML read a one-number list ("2") as a number
        ok = isinstance(value, str)
    else:
        ok = True
    wanted = {"bool": "true or false", "int": "a whole number", "float": "a number", "str": "a string"}
    return value, "" if ok else f"{name}={value!r} must be {wanted.get(type(default).__name__, type(default).__name__)}"
