# SPDX-License-Identifier: Apache-2.0
"""
The machine and date a benchmark measured on: what every section and JSON result records.

`machine_info()` is the `meta` block's machine part (CPU model, cores, Python, platform, numpy
and, with `peers`, the peer solvers' versions); `utc_now()` the date stamp every section shows.
"""
from __future__ import annotations

import datetime as dt
import os
import platform
from importlib import metadata

PEER_PACKAGES = ("tetra3rs", "cedar-solve")


def cpu_model() -> str:
    """Return the CPU's model name from /proc/cpuinfo ("?" when unknown)."""
    try:
        with open("/proc/cpuinfo") as info:
            return next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), "?")
    except OSError:
        return "?"


def package_version(name: str) -> str | None:
    """Return an installed distribution's version, or None when it is not installed."""
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def machine_info(peers: bool = False) -> dict:
    """CPU model, cores, Python, platform and numpy; with `peers`, the peer solvers' versions under "versions"."""
    import numpy as np

    info = {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(), "numpy": np.__version__}
    if peers:
        info["versions"] = {name: package_version(name) for name in PEER_PACKAGES}
    return info


def utc_now() -> str:
    """Return the date stamp of a measurement: 'YYYY-MM-DD HH:MM UTC'."""
    return dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def machine_text(meta: dict) -> str:
    """One line naming the machine of a `meta` block: 'CPU, `nproc` = N; Python X, numpy Y'."""
    parts = [f"{meta.get('cpu', '?')}, `nproc` = {meta.get('cores', '?')}", f"Python {meta.get('python', '?')}"]
    if meta.get("numpy"):
        parts[-1] += f", numpy {meta['numpy']}"
    return "; ".join(parts)
