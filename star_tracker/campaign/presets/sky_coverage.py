# SPDX-License-Identifier: Apache-2.0
"""
`sky-coverage`: lost-in-space success and time with the boresight on every HEALPix pixel of the sky.

Trial t points the boresight at the centre of pixel t // rolls (HEALPix, nested order,
`nside`: 12 nside^2 pixels of equal area, astropy-healpix) with roll 2 pi (t % rolls + u) /
rolls (u uniform in [0, 1) from the trial's generator), makes the scene there as false-id does
(sim/scenes.py: noise, false stars), identifies it lost-in-space and scores it as false-id
does (scoring.py). The report names the
pixels where a trial failed (unsolved or wrong) and draws the sky map of the share solved.
"""
from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from ...parameter_spec import parameter
from ..kind import CampaignKind
from .lost_in_space import SceneOptions, SceneShared, prepare_scenes
from .scoring import SCORE_COLUMNS, UNSOLVED, score

MAP_FILE = "sky_coverage.png"
FAILING_FILE = "failing_pixels.csv"


@dataclass(frozen=True)
class SkyCoverageOptions(SceneOptions):
    """The sky grid (and lost_in_space.SceneOptions) of a sky-coverage campaign (each a `parameter`)."""

    nside: int = parameter(16, "HEALPix resolution: 12 nside^2 boresights (16: 3072, ~3.7 deg apart)", "", 1, 1024)
    rolls: int = parameter(4, "rolls per boresight, spread over the turn", "", 1, 360)

    def __post_init__(self) -> None:
        bad = self.problems()
        if self.nside & (self.nside - 1):
            bad.append(f"nside={self.nside} must be a power of 2")
        if bad:
            raise ValueError("sky-coverage options: " + "; ".join(bad))

    @property
    def trials(self) -> int:
        """The trials that cover the grid once: every pixel, every roll."""
        return 12 * self.nside ** 2 * self.rolls


def pixel_centres(nside: int, pixels) -> tuple[np.ndarray, np.ndarray]:
    """Return the (ra, dec) [rad] of HEALPix pixel centres (nested order)."""
    from astropy_healpix import HEALPix

    lon, lat = HEALPix(nside=nside, order="nested").healpix_to_lonlat(np.asarray(pixels, np.int64))
    return np.asarray(lon.to_value("rad"), float), np.asarray(lat.to_value("rad"), float)


class SkyCoverage(CampaignKind):
    """Lost-in-space over the whole sky on a HEALPix grid (module docstring)."""

    name = "sky-coverage"
    description = "lost-in-space success and time with the boresight on every HEALPix pixel, as a sky map"
    options_type = SkyCoverageOptions
    default_trials = 0  # the options' grid: 12 nside^2 rolls
    default_batch = 200
    columns = (pa.field("pixel", pa.int64()), pa.field("ra_rad", pa.float64()), pa.field("dec_rad", pa.float64()),
               pa.field("roll_rad", pa.float64()), pa.field("solved", pa.bool_()), *SCORE_COLUMNS,
               pa.field("matched", pa.int32()),
               pa.field("spots", pa.int32()), pa.field("identify_s", pa.float64()))

    def prepare(self, options: SkyCoverageOptions) -> SceneShared:
        return prepare_scenes(options)

    def trial(self, shared: SceneShared, options: SkyCoverageOptions, task: int, rng: np.random.Generator) -> dict:
        from ...models.attitude import radec_roll_to_matrix
        from ...sim.scenes import make_scene

        pixel = task // options.rolls
        ra, dec = (float(v[0]) for v in pixel_centres(options.nside, [pixel]))
        roll = 2.0 * math.pi * (task % options.rolls + rng.uniform()) / options.rolls
        truth = radec_roll_to_matrix(ra, dec, roll)
        scene = make_scene(shared.setup, shared.catalog, rng, rotation=truth, vectors=shared.vectors)
        started = time.perf_counter()
        result = shared.identifier.identify(scene.spots, shared.setup.camera)
        elapsed = time.perf_counter() - started
        record = {"pixel": pixel, "ra_rad": ra, "dec_rad": dec, "roll_rad": roll, "solved": result.solved,
                  **UNSOLVED, "matched": int(result.hip.size) if result.solved else 0,
                  "spots": len(scene.spots), "identify_s": elapsed}
        if result.solved:
            record.update(score(result, scene.hip, truth, options.wrong_arcsec))
        return record

    def summarize(self, table: pa.Table, options: SkyCoverageOptions) -> dict:
        per_pixel = _per_pixel(table)
        ok = np.asarray(table.column("error").to_pylist(), object) == ""
        solved = np.asarray(table.column("solved").fill_null(False), bool) & ok
        wrong = np.asarray(table.column("wrong").fill_null(False), bool) & ok
        good = solved & ~wrong
        times = np.asarray(table.column("identify_s").fill_null(np.nan), float)[ok]
        failing = [p for p in per_pixel if p["good"] < p["trials"]]
        return {
            "nside": options.nside, "rolls": options.rolls, "pixels": 12 * options.nside ** 2,
            "pixels_tried": len(per_pixel), "trials": int(ok.sum()), "solved": int(solved.sum()),
            "wrong": int(wrong.sum()), "failed_tasks": int((~ok).sum()),
            **{name: int(np.asarray(table.column(name).fill_null(False), bool)[ok].sum())
               for name in ("wrong_attitude", "wrong_deep_star", "false_identification")},
            "success": float(good.sum() / ok.sum()) if ok.any() else None,
            "pixels_all_solved": sum(p["good"] == p["trials"] for p in per_pixel),
            "pixels_failing": len(failing),
            "failing": [{"pixel": p["pixel"], "ra_deg": round(math.degrees(p["ra"]), 3),
                         "dec_deg": round(math.degrees(p["dec"]), 3), "solved": p["good"], "trials": p["trials"],
                         "spots_min": p["spots_min"]} for p in sorted(failing, key=lambda p: p["good"] / p["trials"])],
            "identify_ms_median": float(np.median(times) * 1e3) if times.size else None,
            "identify_ms_p99": float(np.quantile(times, 0.99) * 1e3) if times.size else None,
            "identify_ms_max": float(np.max(times) * 1e3) if times.size else None,
        }

    def report(self, table: pa.Table, summary: dict, options: SkyCoverageOptions, output: Path) -> list[Path]:
        per_pixel = _per_pixel(table)
        failing_path = output / FAILING_FILE
        with failing_path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["pixel", "ra_deg", "dec_deg", "solved", "trials", "spots_min"])
            for row in summary["failing"]:
                writer.writerow([row["pixel"], row["ra_deg"], row["dec_deg"], row["solved"], row["trials"],
                                 row["spots_min"]])
        return [failing_path, sky_map(per_pixel, options.nside, summary, output / MAP_FILE)]


def _per_pixel(table: pa.Table) -> list[dict]:
    """Return per pixel tried: its centre, trials, trials solved right and the fewest spots of a scene."""
    ok = np.asarray(table.column("error").to_pylist(), object) == ""
    pixel = np.asarray(table.column("pixel").fill_null(-1), np.int64)
    good = (np.asarray(table.column("solved").fill_null(False), bool)
            & ~np.asarray(table.column("wrong").fill_null(False), bool))
    spots = np.asarray(table.column("spots").fill_null(0), np.int64)
    ra = np.asarray(table.column("ra_rad").fill_null(np.nan), float)
    dec = np.asarray(table.column("dec_rad").fill_null(np.nan), float)
    out = []
    for p in np.unique(pixel[ok]):
        mine = ok & (pixel == p)
        first = int(np.flatnonzero(mine)[0])
        out.append({"pixel": int(p), "ra": float(ra[first]), "dec": float(dec[first]), "trials": int(mine.sum()),
                    "good": int(good[mine].sum()), "spots_min": int(spots[mine].min())})
    return out


def sky_map(per_pixel: list[dict], nside: int, summary: dict, path: Path) -> Path:
    """Draw the share of trials solved right per HEALPix pixel on a Mollweide sky (ICRS, RA growing left)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ra = np.array([p["ra"] for p in per_pixel])
    dec = np.array([p["dec"] for p in per_pixel])
    share = np.array([p["good"] / p["trials"] for p in per_pixel])
    lon = -np.angle(np.exp(1j * ra))  # RA to [-pi, pi], increasing to the left (sky as seen from inside)
    fig = plt.figure(figsize=(10, 5.6))
    ax = fig.add_subplot(111, projection="mollweide")
    size = max(2.0, 100000.0 / (12 * nside ** 2))  # squares that about tile the sky at 10 x 5.6 in
    points = ax.scatter(lon, dec, c=share, s=size, cmap="viridis", vmin=0.0, vmax=1.0, marker="s", linewidths=0)
    bad = share < 1.0
    if bad.any():
        ax.scatter(lon[bad], dec[bad], s=size * 4, facecolors="none", edgecolors="red", linewidths=0.8,
                   label=f"{int(bad.sum())} pixels with a trial unsolved or wrong")
        ax.legend(loc="lower right", fontsize=8)
    ticks = (-150, -120, -90, -60, -30, 0, 30, 60, 90, 120, 150)
    ax.set_xticks(np.radians(ticks))
    ax.set_xticklabels([f"{(-d) % 360}°" for d in ticks], fontsize=7)  # the RA at each longitude
    ax.grid(True, alpha=0.3)
    fig.colorbar(points, ax=ax, orientation="horizontal", fraction=0.05, pad=0.06, label="share of trials solved right")
    ax.set_title(f"Lost-in-space over the sky: {summary['trials']} trials on {summary['pixels_tried']} HEALPix pixels "
                 f"(nside {nside}), {100 * (summary['success'] or 0):.3f} % solved right, {summary['wrong']} wrong",
                 fontsize=10)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
