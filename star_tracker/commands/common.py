# SPDX-License-Identifier: Apache-2.0
"""
What the `star-tracker` subcommands share.

One-line errors, argument types, progress lines and the pattern-database configuration for a
field of view (camera files: camera_files.py).
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from typing import Callable


# The identifier's default database (config/star_tracker.yaml): 15 deg cameras use exactly it.
DEFAULT_DB_MAGNITUDE = 6.5
DEFAULT_EPOCH_JYEAR = 2026.0
# Guide stars wanted in a field of view when the magnitude limit is chosen automatically.
# Guide stars wanted in view on average: star counts in a field scatter widely over the sky, and
# the sparsest fields (those of the 1st percentile hold ~0.4x the mean: Hipparcos, 4,000 random
# pointings of a 6 x 4.5 deg field) must still hold ~8 for an identification.
STARS_WANTED_IN_VIEW = 20.0
MAX_AUTO_MAGNITUDE = 8.0


class CommandError(ValueError):
    """A problem with the user's input: printed as one line, exit code 2."""


def guarded(command: str, errors: tuple[type[Exception], ...] = ()) -> Callable:
    """
    Return a decorator for a subcommand's run(args).

    Bad input (ValueError, FileNotFoundError, other OSError, and the command's own `errors`,
    e.g. bags.BagError) becomes `star-tracker <command>: error: ...` on stderr and exit code
    2; Ctrl-C exit code 130. Anything else is a bug and keeps its traceback.
    """

    def wrap(run: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
        @functools.wraps(run)
        def guarded_run(args: argparse.Namespace) -> int:
            try:
                return run(args)
            except BrokenPipeError:  # output piped into `head` & co.: not an error of ours
                sys.stderr.close()
                return 141
            except FileNotFoundError as exc:
                name = exc.filename if exc.filename is not None else str(exc)
                error(command, f"no such file: {name}" if exc.filename is not None else str(exc))
                return 2
            except (ValueError, OSError, *errors) as exc:
                error(command, str(exc) or type(exc).__name__)
                return 2
            except KeyboardInterrupt:
                print(file=sys.stderr)
                return 130

        return guarded_run

    return wrap


def error(command: str, message: str) -> None:
    print(f"star-tracker {command}: error: {message}", file=sys.stderr, flush=True)


def _float_argument(accept, requirement: str):
    """Return an argparse type: a finite float for which accept(value) holds, else '<text> must be <requirement>'."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"{text} must be {requirement}")
        return value
    return parse


positive_float = _float_argument(lambda v: v > 0, "> 0")
non_negative_float = _float_argument(lambda v: v >= 0, ">= 0")
finite_float = _float_argument(lambda v: True, "finite")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be >= 1")
    return value


class HelpFormatter(argparse.HelpFormatter):
    """Wraps the description like argparse does, but keeps the epilog's example lines as written."""

    def _fill_text(self, text, width, indent):
        if text.startswith("example"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def add_parser(subparsers, name: str, summary: str, description: str, example: str) -> argparse.ArgumentParser:
    """
    Return a subcommand parser with the summary in `star-tracker --help`.

    A description and an example epilog in `star-tracker NAME --help`.
    """
    return subparsers.add_parser(name, help=summary, description=description,
                                 epilog="example:\n" + "\n".join("  " + line for line in example.strip().splitlines()),
                                 formatter_class=HelpFormatter)


# ---------------------------------------------------------------- progress

def progress_bar(fraction: float, width: int = 28) -> str:
    """`[#####.......]` for a fraction in [0, 1]."""
    filled = int(round(min(max(fraction, 0.0), 1.0) * width))
    return f"[{'#' * filled}{'.' * (width - filled)}]"


class StatusLine:
    """
    One status line on a stream (stderr by default).

    Redrawn in place on a terminal; on anything else (logs, pipes) appended as a new line at
    most every `min_interval_s`, and always when `final`.
    """

    def __init__(self, stream=None, min_interval_s: float = 2.0):
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.min_interval_s = min_interval_s
        self._last_line = -math.inf
        self._shown = False

    def show(self, line: str, final: bool = False) -> None:
        if self.tty:
            self.stream.write("\r\x1b[K" + line + ("\n" if final else ""))
            self._shown = not final
        elif final or time.perf_counter() - self._last_line >= self.min_interval_s:
            self.stream.write(line + "\n")
            self._last_line = time.perf_counter()
        else:
            return
        self.stream.flush()

    def clear(self) -> None:
        """Erase a line being redrawn (terminal only), before other output is printed."""
        if self.tty and self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._shown = False


class Progress:
    """A one-line progress bar on stderr (StatusLine): label, bar, done/total, elapsed time and a note."""

    def __init__(self, total: int, label: str, width: int = 28, stream=None, min_interval_s: float = 2.0):
        self.total, self.label, self.width = max(int(total), 1), label, width
        self.line = StatusLine(stream, min_interval_s)
        self.started = time.perf_counter()
        self.done = 0

    def update(self, done: int | None = None, note: str = "") -> None:
        self.done = self.done + 1 if done is None else int(done)
        self._draw(note, final=self.done >= self.total)

    def _draw(self, note: str, final: bool = False) -> None:
        elapsed = time.perf_counter() - self.started
        self.line.show(f"{self.label} {progress_bar(self.done / self.total, self.width)} {self.done}/{self.total} "
                       f"{elapsed:6.1f} s{'  ' + note if note else ''}", final)


# ---------------------------------------------------------------- databases

def field_diagonal_rad(fov_x_rad: float, width: int, height: int) -> float:
    """Full diagonal field of a pinhole camera of horizontal FOV fov_x_rad [rad]."""
    f = 0.5 * width / math.tan(0.5 * fov_x_rad)
    return 2.0 * math.atan(0.5 * math.hypot(width, height) / f)


def auto_magnitude_limit(fov_x_rad: float, width: int, height: int) -> float:
    """
    Faintest guide star for a field.

    The default 6.5 for fields of ~10 deg and wider, fainter for narrower fields so that
    ~STARS_WANTED_IN_VIEW guide stars are in view on average (star counts grow ~x2.5 per
    magnitude near Hp 7), at most MAX_AUTO_MAGNITUDE.
    """
    f = 0.5 * width / math.tan(0.5 * fov_x_rad)
    solid_angle_deg2 = (width / f) * (height / f) * (180.0 / math.pi) ** 2
    density_at_default = 8000.0 / 41253.0  # Hipparcos stars to Hp 6.5 per square degree
    expected = density_at_default * solid_angle_deg2
    if expected >= STARS_WANTED_IN_VIEW:
        return DEFAULT_DB_MAGNITUDE
    extra = math.log(STARS_WANTED_IN_VIEW / expected) / math.log(2.5)
    return round(min(DEFAULT_DB_MAGNITUDE + extra, MAX_AUTO_MAGNITUDE), 1)


def database_config_for(fov_x_rad: float, width: int, height: int, magnitude_limit: float | None = None,
                        epoch_jyear: float = DEFAULT_EPOCH_JYEAR):
    """
    Return the pattern-database configuration for a pinhole camera (horizontal FOV fov_x_rad [rad], width x height px).

    Pairs as DatabaseConfig.for_camera derives them; guide stars to `magnitude_limit` (None:
    auto_magnitude_limit).
    """
    from ..identify import DatabaseConfig
    from ..models.camera import CameraModel

    limit = auto_magnitude_limit(fov_x_rad, width, height) if magnitude_limit is None else float(magnitude_limit)
    return DatabaseConfig.for_camera(CameraModel.from_fov(width, height, fov_x_rad), limit, epoch_jyear)
