# SPDX-License-Identifier: Apache-2.0
"""
Benchmark plots, drawn from the benchmarks' JSON results (no benchmark is rerun).

    python -m bench.plots [--results-dir docs] [--images-dir DIR] [--only NAME[,NAME]]

- centroid_crb.png (bench_centroid.json): RMS centroid error / sqrt(Cramér–Rao bound) against
  SNR, one panel per smear length, one line per centroiding variant.
- centroid_times.png (bench_centroid.json): time per 1024² frame of our centroider and the
  peers' extractors (tetra3rs, cedar-solve) on identical frames, at rest and slewing.
- identify_false_stars.png (bench_identify.json): correct identifications [%] of every
  algorithm and peer against the number of false stars per scene, for the setups that differ
  in it (Cole & Crassidis 0 / 1 false star; nominal camera 0 / 50 / 136).
- identify_times.png (bench_identify.json): solve-time distribution of every algorithm and
  peer per setup (box p25–p75, whiskers p1–p99, median, max) when the results hold the
  percentiles; results from before they were recorded give median, p99 and max only.

`star-tracker bench` runs this after the benchmarks; a missing JSON file skips its plots.
Exit code 0 (also when there was nothing to plot), 1 when a figure failed.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Ours in blues/greens/purples, the peers in orange and red: the same colour per solver everywhere.
SOLVER_COLOURS = {"hybrid": "#1f4e9c", "pyramid": "#4a90d9", "angle_pivot": "#7fb8e6", "spherical_triangle": "#2a9d8f",
                  "composite": "#8ab17d", "match_groups": "#7b5ea7", "tetra3rs": "#e07b00", "cedar-solve": "#c0392b"}
PEER_COLOURS = {"tetra3rs": "#e07b00", "cedar-solve": "#c0392b"}
# Setups of bench_identify that differ (mainly) in false stars, in order: (title, setups).
FALSE_STAR_SERIES = (
    ("8° circular field, Hp ≤ 6.0, 87 µrad (Cole & Crassidis)", ("cole", "cole_false")),
    ("15° camera, Hp ≤ 6.5 (nominal; Toloei)", ("nominal", "toloei_6_50", "toloei_4_136")),
)
TIME_SETUPS = ("nominal", "cole_false", "fast", "toloei_6_50")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _measured(meta: dict) -> str:
    machine = meta.get("machine", {})
    cores = machine.get("cores")
    return (f"measured {meta.get('date', '?')}" + (f", {machine['cpu']}" if machine.get("cpu") else "")
            + (f", {cores} cores" if cores else ""))


def _plain_log_axis(axis, subs=(1.0, 2.0, 5.0)) -> None:
    """Log scale labelled in plain numbers (0.1, 0.2, 0.5, 1, ... by default), no minor labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10, subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _finite(value) -> bool:
    return value is not None and isinstance(value, (int, float)) and math.isfinite(value)


# ---------------------------------------------------------------- centroiding

def plot_centroid_crb(results: dict, path: Path) -> Path:
    """
    RMS error / sqrt(CRB) against SNR.

    One panel per smear length, one line per variant; hollow markers where fewer than half
    the stars were detected.
    """
    plt = _pyplot()
    rows = results["accuracy"]
    goals = results.get("goals", {"ratio_no_smear": 1.2, "ratio_20px_smear": 1.5})
    smears = sorted({r["smear_px"] for r in rows})
    methods = list(dict.fromkeys(r["method"] for r in rows))
    styles = {"cog": ("o", ":", "#888888"), "wcog": ("v", ":", "#444444"), "auto": ("s", "-", "#1f4e9c"),
              "auto + rate": ("D", "--", "#e07b00")}
    columns = len(smears) if len(smears) <= 2 else 2
    panel_rows = math.ceil(len(smears) / columns)
    fig, axes = plt.subplots(panel_rows, columns, figsize=(4.3 * columns + 0.6, 3.2 * panel_rows + 0.7), sharex=True,
                             sharey=True, squeeze=False)
    for ax in axes.flat[len(smears):]:
        ax.set_visible(False)
    for ax, smear in zip(axes.flat, smears):
        for method in methods:
            marker, line, colour = styles.get(method, ("x", "-", None))
            pts = sorted((r for r in rows if r["smear_px"] == smear and r["method"] == method and _finite(r["ratio"])),
                         key=lambda r: r["snr"])
            if not pts:
                continue
            ax.plot([r["snr"] for r in pts], [r["ratio"] for r in pts], line, color=colour, label=method, lw=1.3)
            for r in pts:
                hollow = r["detected"] < 0.5
                ax.plot(r["snr"], r["ratio"], marker, color=colour, ms=4.5, mfc="white" if hollow else colour)
        if smear == 0:  # the goals are set for these two smear lengths (from SNR 20)
            ax.axhline(goals["ratio_no_smear"], color="k", ls="--", lw=0.8, label=f"goal {goals['ratio_no_smear']}×")
        elif smear == 20:
            ax.axhline(goals["ratio_20px_smear"], color="k", ls="--", lw=0.8,
                       label=f"goal {goals['ratio_20px_smear']}×")
        ax.axhline(1.0, color="grey", lw=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"smear {smear:g} px" if smear else "no smear", fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        if smear in (0, 20):
            ax.legend(fontsize=7, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("SNR")
    for ax in axes[:, 0]:
        ax.set_ylabel("RMS error / √CRB")
    fig.suptitle("Centroid position error against the Cramér–Rao bound\n(1 = the bound; hollow markers: "
                 "< 50 % of the stars detected)", fontsize=10)
    fig.text(0.995, 0.005, _measured(results.get("meta", {})), ha="right", va="bottom", fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path)


def plot_centroid_times(results: dict, path: Path) -> Path:
    """
    Per-frame time of each extractor on identical 1024² frames.

    At rest and slewing (box: quartiles, whiskers: 5th-95th percentile, dots beyond).
    """
    plt = _pyplot()
    speed = results["speed"]
    cases = [("at_rest", "at rest"), ("slewing", f"slewing {math.hypot(*speed.get('slew_deg_s', [0, 0])[:2]):.1f}°/s")]
    fig, axes = plt.subplots(1, len(cases), figsize=(10.5, 3.2), sharex=True, squeeze=False)
    for ax, (key, title) in zip(axes[0], cases):
        timing = speed.get(key, {})
        names = [n for n, t in timing.items() if t.get("times_ms")]
        if not names:
            ax.set_visible(False)
            continue
        data = [timing[n]["times_ms"] for n in names]
        box = ax.boxplot(data, orientation="horizontal", whis=(5, 95), widths=0.6, patch_artist=True,
                         flierprops={"ms": 3}, medianprops={"color": "k", "lw": 1.5})
        for patch, name in zip(box["boxes"], names):
            colour = next((c for peer, c in PEER_COLOURS.items() if peer in name), "#1f4e9c")
            patch.set_facecolor(colour)
            patch.set_alpha(0.55)
        ax.set_yticks(range(1, len(names) + 1), [f"{n}\n{timing[n]['median_ms']:.1f} ms, "
                                                 f"{100 * timing[n]['detected']:.0f} % found" for n in names],
                      fontsize=7)
        ax.set_xscale("log")
        _plain_log_axis(ax.xaxis)
        ax.set_xlabel("time per frame [ms]")
        ax.set_title(f"{title}: {len(data[0])} frames", fontsize=10)
        ax.grid(True, axis="x", which="both", alpha=0.25)
        ax.invert_yaxis()
    meta = results.get("meta", {})
    fig.suptitle("Centroiding time per 1024² frame, real sky, every detector effect on", fontsize=10)
    fig.text(0.995, 0.005, _measured(meta) + (f"; reference kernel {meta['reference_kernel_ms']:.2f} ms"
                                              if _finite(meta.get("reference_kernel_ms")) else ""),
             ha="right", va="bottom", fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return _save(fig, path)


# ---------------------------------------------------------------- identification

def _false_stars(name: str, entry: dict) -> tuple[int, int | None]:
    """
    Return (false stars, real stars kept or None = all) of a setup.

    From the results, else from star_tracker.sim.scenes.SETUPS (results written before they
    were recorded).
    """
    if "false_stars" in entry:
        return int(entry["false_stars"]), entry.get("real_stars")
    sys.path.insert(0, str(REPO))
    from star_tracker.sim.scenes import SETUPS

    setup = SETUPS[name]
    return int(setup.false_stars), setup.real_stars


def plot_identify_false_stars(results: dict, path: Path) -> Path:
    """
    Correct % of every solver against the false stars per scene, one panel per series of FALSE_STAR_SERIES.

    A red ring and count where a solver gave incorrect solutions.
    """
    plt = _pyplot()
    setups = results["setups"]
    series = [(title, [n for n in names if n in setups]) for title, names in FALSE_STAR_SERIES]
    series = [(title, names) for title, names in series if len(names) >= 2]
    if not series:
        raise ValueError("no setups that differ in false stars in these results")
    fig, axes = plt.subplots(1, len(series), figsize=(5.4 * len(series), 4.2), squeeze=False,
                             gridspec_kw={"width_ratios": [len(n) for _, n in series]})
    for ax, (title, names) in zip(axes[0], series):
        labels = []
        for name in names:
            false, real = _false_stars(name, setups[name])
            true_mean = setups[name].get("true_stars_mean")
            stars = f"{real} real" if real else (f"all ~{true_mean:.0f} real" if _finite(true_mean) else "all real")
            labels.append(f"{false} false\n{stars}\n({name}, {setups[name]['scenes']})")
        solvers = list(dict.fromkeys(s for n in names for s in setups[n]["solvers"]))
        offsets = {s: (i - (len(solvers) - 1) / 2) * 0.035 for i, s in enumerate(solvers)}  # unstack equal points
        for solver in solvers:
            xs, ys, bad = [], [], []
            for x, name in enumerate(names):
                s = setups[name]["solvers"].get(solver)
                if s is None:
                    continue
                xs.append(x + offsets[solver])
                ys.append(s["correct_pct"])
                bad.append(s["incorrect"])
            peer = setups[names[0]]["solvers"].get(solver, {}).get("kind") == "peer"
            ax.plot(xs, ys, "s--" if peer else "o-", color=SOLVER_COLOURS.get(solver),
                    label=solver + (" (peer)" if peer else ""),
                    lw=1.4, ms=5)
            for x, y, n in zip(xs, ys, bad):
                if n:
                    ax.plot(x, y, "o", ms=11, mfc="none", mec="red", mew=1.2)
                    ax.annotate(f"{n} incorrect", (x, y), textcoords="offset points", xytext=(6, -12), fontsize=7,
                                color="red")
        ax.set_xticks(range(len(names)), labels, fontsize=8)
        ax.set_xlim(-0.4, len(names) - 0.6)
        ax.set_ylim(-3, 103)
        ax.set_ylabel("correct identifications [%]")
        ax.set_title(title, fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0][-1].legend(fontsize=7, loc="upper right", ncol=2)
    meta = results.get("meta", {})
    fig.suptitle("Lost-in-space identification against false stars (red ring: incorrect solutions; "
                 f"time limit {meta.get('max_time_s', 0.5):g} s per call)", fontsize=10)
    fig.text(0.995, 0.005, _measured(meta), ha="right", va="bottom", fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path)


def plot_identify_times(results: dict, path: Path) -> Path:
    """Solve-time distribution per solver, one panel per setup of TIME_SETUPS present."""
    plt = _pyplot()
    setups = results["setups"]
    names = [n for n in TIME_SETUPS if n in setups] or list(setups)[:4]
    columns = min(len(names), 2)
    rows_of_panels = math.ceil(len(names) / columns)
    fig, axes = plt.subplots(rows_of_panels, columns, figsize=(5.2 * columns + 1.0, 3.3 * rows_of_panels + 0.6),
                             sharex=True, sharey=True, squeeze=False)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    solvers = list(dict.fromkeys(s for n in names for s in setups[n]["solvers"]))
    full = True
    for ax, name in zip(axes.flat, names):
        for row, solver in enumerate(solvers):
            s = setups[name]["solvers"].get(solver)
            if s is None or not s.get("time_ms"):
                continue
            colour = SOLVER_COLOURS.get(solver, "k")
            t = s["time_ms"]
            pct = s.get("time_ms_percentiles")
            if pct:
                ax.plot([pct[1], pct[99]], [row, row], "-", color=colour, lw=1.2)
                ax.plot([pct[25], pct[75]], [row, row], "-", color=colour, lw=7, alpha=0.55, solid_capstyle="butt")
            else:
                full = False
                ax.plot([t["median"], t["p99"]], [row, row], "-", color=colour, lw=1.2)
            ax.plot(t["median"], row, "|", color="k", ms=11, mew=1.8)
            ax.plot(t["max"], row, "x", color=colour, ms=5)
            ax.text(0.995, row, f"{s['correct_pct']:.0f} % correct", transform=ax.get_yaxis_transform(),
                    ha="right", va="center", fontsize=6.5, color="grey")
        limit_ms = 1e3 * results.get("meta", {}).get("max_time_s", float("nan"))
        if _finite(limit_ms):
            ax.axvline(limit_ms, color="grey", ls=":", lw=0.8)
        ax.set_xscale("log")
        _plain_log_axis(ax.xaxis, subs=(1.0,))
        entry = setups[name]
        ax.set_title(f"{name} ({entry['scenes']} scenes)", fontsize=10)
        ax.grid(True, axis="x", alpha=0.3)
    low, high = axes[0][0].get_xlim()
    axes[0][0].set_xlim(low, high * 12)  # shared: room for the correct % at the right
    for ax in axes[-1]:
        ax.set_xlabel("solve time per call [ms]")
    axes[0][0].set_yticks(range(len(solvers)), solvers)
    axes[0][0].set_ylim(len(solvers) - 0.5, -0.5)
    for ax in axes[:, 0]:
        ax.tick_params(axis="y", labelsize=8)
    legend = ("box p25–p75, line p1–p99, | median, × max" if full else
              "line median → p99, | median, × max; these results predate the recorded percentiles")
    meta = results.get("meta", {})
    fig.suptitle(f"Lost-in-space solve time, ours and the peers\n({legend}; dotted: the time limit)", fontsize=9.5)
    fig.text(0.995, 0.005, _measured(meta), ha="right", va="bottom", fontsize=6, color="grey")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return _save(fig, path)


# ---------------------------------------------------------------- driver

# name -> (JSON file, function, PNG file)
PLOTS = {
    "centroid_crb": ("bench_centroid.json", plot_centroid_crb, "centroid_crb.png"),
    "centroid_times": ("bench_centroid.json", plot_centroid_times, "centroid_times.png"),
    "identify_false_stars": ("bench_identify.json", plot_identify_false_stars, "identify_false_stars.png"),
    "identify_times": ("bench_identify.json", plot_identify_times, "identify_times.png"),
}


def draw(results_dir: Path, images_dir: Path, only: list[str] | None = None, log=print) -> tuple[list[Path], list[str]]:
    """
    Draw every plot of PLOTS (or `only`) whose JSON is in results_dir.

    Returns (written, failed names); a missing JSON is logged and skipped.
    """
    written, failed, loaded = [], [], {}
    for name in only or PLOTS:
        source, function, png = PLOTS[name]
        path = Path(results_dir) / source
        if source not in loaded:
            loaded[source] = json.loads(path.read_text()) if path.is_file() else None
        if loaded[source] is None:
            log(f"skipped {png}: no {path}")
            continue
        try:
            written.append(function(loaded[source], Path(images_dir) / png))
            log(f"wrote {written[-1]}")
        except Exception as exc:  # noqa: BLE001 - one bad figure must not stop the others; reported
            failed.append(name)
            log(f"FAILED {png}: {type(exc).__name__}: {exc}")
    return written, failed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().split("\n\n")[0])
    parser.add_argument("--results-dir", type=Path, default=REPO / "docs",
                        help="directory holding bench_*.json (default: docs/ of the source tree)")
    parser.add_argument("--images-dir", type=Path, help="where the PNGs go (default: RESULTS_DIR/images)")
    parser.add_argument("--only", help=f"comma-separated plots (default all: {', '.join(PLOTS)})")
    args = parser.parse_args(argv)
    only = [n.strip() for n in args.only.split(",") if n.strip()] if args.only else None
    unknown = [n for n in only or [] if n not in PLOTS]
    if unknown:
        parser.error(f"unknown plot(s) {', '.join(unknown)}; choose from {', '.join(PLOTS)}")
    written, failed = draw(args.results_dir, args.images_dir or args.results_dir / "images", only)
    if not written and not failed:
        print(f"nothing to plot: no benchmark results in {args.results_dir}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
