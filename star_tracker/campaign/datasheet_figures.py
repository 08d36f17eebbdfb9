# SPDX-License-Identifier: Apache-2.0
"""The datasheet's figures (datasheet.datasheet_data's figures drawn with matplotlib's Agg backend)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .datasheet import AXES


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: Path) -> Path:
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def error_histograms(data: dict, path: Path) -> Path:
    """Draw the at-rest error per axis as histograms [arcsec], with the 1-sigma and 99.7 % levels."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    histogram = data["accuracy"]["histogram_arcsec"]
    for ax, axis, rms, p997 in zip(axes, AXES, data["accuracy"]["total_rms_arcsec"], data["accuracy"]["p997_arcsec"]):
        values = np.asarray(histogram[axis], float)
        ax.hist(values, bins=60, color="tab:blue", alpha=0.8)
        for level, style, label in ((rms, "--", f"±1σ {rms:.2f}″"), (p997, ":", f"99.7 % {p997:.2f}″")):
            ax.axvline(level, color="k", ls=style, lw=1, label=label)
            ax.axvline(-level, color="k", ls=style, lw=1)
        ax.set_xlabel(f"error about {axis} [arcsec]")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("frames")
    fig.suptitle(f"Attitude error at rest, {data['accuracy']['frames']} rendered frames", fontsize=10)
    return _save(plt, fig, path)


def error_vs_rate(data: dict, path: Path) -> Path:
    """Draw the RMS error per axis against the rate across the boresight."""
    plt = _pyplot()
    rows = data["error_vs_rate"]
    rates = [r["rate_deg_s"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    for i, axis in enumerate(AXES):
        ax.plot(rates, [r["rms_arcsec"][i] for r in rows], "o-", label=f"{axis} (RMS)")
    ax.set_xlabel("rate across the boresight [deg/s]")
    ax.set_ylabel("attitude error [arcsec]")
    ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Error against rate (rendered frames, lost-in-space)", fontsize=10)
    return _save(plt, fig, path)


def tracking_envelope(data: dict, path: Path) -> Path:
    """Draw the share of frames tracked right per (rate, acceleration) case, the envelope marked."""
    plt = _pyplot()
    cases = data["tracking"]["cases"]
    rates = sorted({c["rate_deg_s"] for c in cases})
    accelerations = sorted({c["acceleration_deg_s2"] for c in cases})
    grid = np.full((len(accelerations), len(rates)), np.nan)
    for c in cases:
        grid[accelerations.index(c["acceleration_deg_s2"]), rates.index(c["rate_deg_s"])] = (
            c["right_share"] if c["right_share"] is not None else np.nan)
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    image = ax.imshow(grid, origin="lower", cmap="viridis", vmin=0.0, vmax=1.0, aspect="auto")
    ax.set_xticks(range(len(rates)), [f"{r:g}" for r in rates])
    ax.set_yticks(range(len(accelerations)), [f"{a:g}" for a in accelerations])
    for c in cases:
        i, j = accelerations.index(c["acceleration_deg_s2"]), rates.index(c["rate_deg_s"])
        mark = "✓" if c["right_share"] == 1.0 and c["wrong"] == 0 else f"{c['wrong']} wrong" if c["wrong"] else ""
        ax.text(j, i, mark, ha="center", va="center", color="w", fontsize=8)
    ax.set_xlabel("coast rate [deg/s]")
    ax.set_ylabel("acceleration [deg/s²]")
    fig.colorbar(image, ax=ax, label="share tracked right")
    ax.set_title("Tracking envelope (✓: every frame right)", fontsize=10)
    return _save(plt, fig, path)


def robustness(data: dict, path: Path) -> Path:
    """Draw the share solved right against each sweep's level, one panel per sweep."""
    plt = _pyplot()
    sweeps = data["robustness"]["sweeps"]
    fig, axes = plt.subplots(1, len(sweeps), figsize=(3.0 * len(sweeps), 3.0), squeeze=False)
    for ax, (name, cells) in zip(axes[0], sweeps.items()):
        levels = np.arange(len(cells))
        ax.plot(levels, [100 * (c["availability"] or 0) for c in cells], "o-")
        for x, c in zip(levels, cells):
            if c["wrong"]:
                ax.annotate(f"{c['wrong']} wrong", (x, 100 * (c["availability"] or 0)), fontsize=7, color="red")
        ax.set_xticks(levels, [f"{c['level']:g}" for c in cells], fontsize=7, rotation=30)
        ax.set_ylim(-5, 105)
        ax.set_title(name.replace("_", " "), fontsize=9)
        ax.set_xlabel(data["robustness"]["units"][name], fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("solved right [%]")
    fig.tight_layout()
    return _save(plt, fig, path)
