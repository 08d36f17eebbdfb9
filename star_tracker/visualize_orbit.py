# SPDX-License-Identifier: Apache-2.0
"""
The orbit demo's pictures: availability per head and fused, the fused error per body axis, the sky over the orbit.

Inputs are the orbit monitor's records (commands/orbit_monitor.py): per head and stamp [ns] the
truth and published rotations (sensor -> ICRS), the status word and the spacecraft's position;
per fused stamp the body rotation and its error per body axis [rad].
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .visualize import pyplot, save_figure

STATUS_COLOURS = {"tracking": "#2ca02c", "lost_in_space": "#bcbd22", "blinded_sun": "#ff7f0e",
                  "blinded_earth": "#1f77b4", "blinded_moon": "#7f7f7f", "occulted": "#000000",
                  "rate_too_high": "#d62728"}
ARCSEC = math.radians(1.0 / 3600.0)


def availability_figure(frames: dict, fused: dict, heads: list[str], start_s: float, path: Path) -> Path | None:
    """Draw per head a status strip over orbit time [min] and the fused availability below; None without frames."""
    plt = pyplot()
    if not any(frames[h] for h in heads):
        return None
    fig, ax = plt.subplots(figsize=(11, 1.2 + 0.6 * (len(heads) + 1)))
    for row, head in enumerate(heads):
        for stamp, record in sorted(frames[head].items()):
            status = record.get("status")
            if status is None:
                continue
            ax.broken_barh([((stamp * 1e-9 - start_s) / 60.0, 0.05)], (row - 0.4, 0.8),
                           color=STATUS_COLOURS.get(status, "#9467bd"))
    fused_times = [(stamp * 1e-9 - start_s) / 60.0 for stamp in sorted(fused)]
    ax.plot(fused_times, np.full(len(fused_times), len(heads)), "|", color=STATUS_COLOURS["tracking"], ms=10)
    ax.set_yticks(range(len(heads) + 1), [*heads, "fused"])
    ax.set_xlabel("orbit time [min]")
    ax.set_title("head status per frame, and the fused attitudes")
    for status, colour in STATUS_COLOURS.items():
        ax.plot([], [], "s", color=colour, label=status)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.45), ncol=4, fontsize=8, frameon=False)
    fig.tight_layout()
    save_figure(fig, path)
    return path


def fused_error_figure(fused: dict, start_s: float, path: Path) -> Path | None:
    """Draw the fused attitude's error about each body axis [arcsec] against orbit time [min]; None without truth."""
    rows = [fused[k] for k in sorted(fused) if fused[k].get("truth") is not None]
    if not rows:
        return None
    plt = pyplot()
    t = np.array([(r["stamp_ns"] * 1e-9 - start_s) / 60.0 for r in rows])
    error = np.array([r["axis_error"] for r in rows]) / ARCSEC
    fig, ax = plt.subplots(figsize=(11, 3.5))
    for k, axis in enumerate("xyz"):
        ax.plot(t, error[:, k], ".", ms=2, label=f"body {axis}")
    ax.set_xlabel("orbit time [min]")
    ax.set_ylabel("fused error [arcsec]")
    ax.set_title("fused attitude against the truth, per body axis")
    ax.legend(markerscale=5)
    fig.tight_layout()
    save_figure(fig, path)
    return path


HEAD_COLOURS = ("tab:purple", "tab:green", "tab:brown")


def sky_figure(frames: dict, heads: list[str], start_s: float, end_s: float, path: Path) -> Path | None:
    """
    Draw the heads' boresights over the orbit on the sky (Mollweide, RA/Dec) with the Sun's and the Moon's cones.

    Each head's true boresight per frame, crossed in black where it had no attitude; the Sun's
    (30 deg) and the Moon's (25 deg) exclusion cones at the run's middle (they move < 1 deg per
    orbit). The Earth's cone turns with the spacecraft once per orbit and is not drawn.
    """
    from .models.ephemeris import load_ephemeris
    from .models.sky_geometry import ExclusionModel

    plt = pyplot()
    fig = plt.figure(figsize=(11, 6))
    ax = fig.add_subplot(111, projection="mollweide")
    drawn = False
    for index, head in enumerate(heads):
        rows = [r for _, r in sorted(frames[head].items()) if r.get("truth") is not None]
        if not rows:
            continue
        ra, dec = _radec(np.array([r["truth"][:, 2] for r in rows]))
        ax.plot(ra, dec, ".", ms=1.5, color=HEAD_COLOURS[index % len(HEAD_COLOURS)], label=f"{head} boresight")
        lost = np.array([r.get("attitude") is None for r in rows])
        if np.any(lost):
            ax.plot(ra[lost], dec[lost], "x", ms=3, color="black", label="no attitude" if not drawn else None)
        drawn = True
    if not drawn:
        plt.close(fig)
        return None
    model, ephemeris = ExclusionModel(), load_ephemeris()
    middle = 0.5 * (start_s + end_s)
    sun, moon = ephemeris.sun_position(middle), ephemeris.moon_position(middle)
    _cone(ax, sun / np.linalg.norm(sun), model.sun_exclusion_rad,
          f"Sun ({math.degrees(model.sun_exclusion_rad):.0f} deg)", "#f0a000")
    _cone(ax, moon / np.linalg.norm(moon), model.moon_exclusion_rad,
          f"Moon ({math.degrees(model.moon_exclusion_rad):.0f} deg)", "#7f7f7f")
    ax.grid(True, alpha=0.3)
    ax.set_title(f"true boresights over {(end_s - start_s) / 60:.0f} min of orbit; Sun and Moon exclusion cones")
    ax.legend(loc="lower right", fontsize=8, markerscale=4)
    save_figure(fig, path)
    return path


def _radec(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return Mollweide longitudes (RA wrapped to [-pi, pi), east to the left) and latitudes [rad]."""
    ra = np.arctan2(vectors[:, 1], vectors[:, 0])
    dec = np.arcsin(np.clip(vectors[:, 2], -1.0, 1.0))
    return -ra, dec  # astronomical convention: RA grows to the left


def _cone(ax, axis: np.ndarray, radius_rad: float, label: str, colour: str) -> None:
    """Draw the circle of points radius_rad from axis (a unit vector)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    phase = np.linspace(0.0, 2.0 * np.pi, 361)
    points = (math.cos(radius_rad) * axis[None] + math.sin(radius_rad)
              * (np.cos(phase)[:, None] * u[None] + np.sin(phase)[:, None] * v[None]))
    ra, dec = _radec(points)
    breaks = np.flatnonzero(np.abs(np.diff(ra)) > np.pi) + 1  # no line across the map's edge
    for k, (lo, hi) in enumerate(zip([0, *breaks], [*breaks, ra.size])):
        ax.plot(ra[lo:hi], dec[lo:hi], "-", color=colour, label=label if k == 0 else None)
