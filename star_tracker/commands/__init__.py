# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker` subcommands, one module each.

`register(subparsers)` adds the subcommand's parser (with a complete --help: description,
every option with units and defaults, an example), `run(args) -> int` runs it (exit code;
bad input is a one-line `star-tracker <cmd>: error: ...` on stderr with exit code 2).

`python -m star_tracker.commands <cmd> ...` runs them without the rest of the CLI.

bags.py (record, play, info, reindex) registers its four with `bags.add_commands(sub)` from
cli.py: their --help predates the example epilogs of COMMANDS and keeps its form.
"""
from __future__ import annotations

from . import bench, calibrate, characterize, database, monitor, render, solve

COMMANDS = [render, solve, calibrate, database, monitor, bench, characterize]


def add_commands(subparsers) -> None:
    """Register every subcommand of COMMANDS on an argparse sub-parser action."""
    for module in COMMANDS:
        module.register(subparsers)


__all__ = ["COMMANDS", "add_commands"]
