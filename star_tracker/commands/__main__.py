# SPDX-License-Identifier: Apache-2.0
"""`python -m star_tracker.commands <cmd> ...`: the subcommands of this package on their own."""
from __future__ import annotations

import argparse
import sys

from . import add_commands


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="star-tracker", description="star_tracker tools: render, solve, database, "
                                                                      "monitor, bench.")
    add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
