# SPDX-License-Identifier: Apache-2.0
"""
A campaign's definition: which kind of trial, how many, their seed, their batching and options.

From a preset name and the command line, or from a YAML file:

    preset: false-id          # a kind of presets.KINDS
    trials: 100000            # optional: the kind's default
    seed: 2026                # optional: 2026
    batch: 1000               # optional: trials per Dask task, the kind's default
    options:                  # optional: the kind's options (its dataclass), checked
      false_stars: 2

Trial t of a campaign draws every random number from SeedSequence([seed, t]): a trial's
result depends on (seed, t, options) alone, not on the worker, the batching or the order.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_SEED = 2026
KEYS = ("preset", "trials", "seed", "batch", "options")


@dataclass(frozen=True)
class CampaignSpec:
    """
    One campaign (module docstring).

    preset: the kind's name; trials: how many; seed: the campaign's seed; batch: trials per
    Dask task; options: the kind's options (a mapping; checked by the kind).
    """

    preset: str
    trials: int
    seed: int = DEFAULT_SEED
    batch: int = 1000
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        bad = []
        for name in ("trials", "batch"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                bad.append(f"{name} must be a whole number >= 1, got {value!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            bad.append(f"seed must be a whole number >= 0, got {self.seed!r}")
        if not isinstance(self.options, dict):
            bad.append(f"options must be a mapping, got {type(self.options).__name__}")
        if bad:
            raise ValueError("campaign: " + "; ".join(bad))

    @property
    def batches(self) -> int:
        return -(-self.trials // self.batch)

    def batch_tasks(self, batch: int) -> range:
        """Return the task numbers of one batch."""
        return range(batch * self.batch, min((batch + 1) * self.batch, self.trials))

    def rng(self, task: int) -> np.random.Generator:
        """Return task's generator (module docstring)."""
        return np.random.default_rng(np.random.SeedSequence([self.seed, task]))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def load_campaign_yaml(path: Path | str) -> dict[str, Any]:
    """Return a campaign file's mapping (keys checked; values are checked by CampaignSpec and the kind)."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping with keys {list(KEYS)}, got {type(data).__name__}")
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise ValueError(f"{path}: unknown key(s) {unknown}; expected {list(KEYS)}")
    if "preset" not in data:
        raise ValueError(f"{path}: no `preset` (the kind of trial)")
    return data
