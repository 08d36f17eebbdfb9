# SPDX-License-Identifier: Apache-2.0
"""
Figures for docs/SIMULATOR.md, rendered by the simulator itself.

    python -m bench.simulator_figures [--output-dir docs/images]

smeared_frame.png: a frame at ~2 deg/s cross-boresight plus a 20 deg/s roll (streaks are arcs
about the rotation pole, marked +), every detector effect on and one debris streak; full
frame (2x2 binned) and a 400 x 400 px crop at full resolution.

photon_transfer.png: photon-transfer curve from pairs of flat fields (no stars) over a sweep
of background levels, against the model var = mean/g + (sigma_read/g)^2 + 1/12 [ADU^2];
prints the fitted slope (1/gain) and intercept.
"""
from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from star_tracker.models.attitude import radec_roll_to_matrix  # noqa: E402
from star_tracker.models.camera import CameraModel  # noqa: E402
from star_tracker.models.catalog import load_hipparcos  # noqa: E402
from star_tracker.sim.motion import ConstantRateMotion  # noqa: E402
from star_tracker.sim.render import (KIND_DEBRIS, KIND_STAR, FalseObjectModel, StarFieldRenderer,  # noqa: E402
                                     frame_seed)
from star_tracker.sim.sensor import SensorModel  # noqa: E402
from star_tracker.visualize import stretch  # noqa: E402

EPOCH_JYEAR = 2026.0
ALL_NOISE = dict(dsnu_fraction=0.1, prnu_fraction=0.01, hot_pixel_fraction=2e-5,
                 cosmic_ray_rate_per_cm2_s=5.0, vignetting_at_corner=0.1)
MAX_PNG_BYTES = 600_000


def save_png(fig, path: Path, dpi: int) -> int:
    """Save, lowering the resolution until the PNG is below MAX_PNG_BYTES; returns its size."""
    while True:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=dpi)
        if buffer.tell() <= MAX_PNG_BYTES or dpi <= 50:
            break
        dpi = int(dpi * 0.85)
    path.write_bytes(buffer.getvalue())
    plt.close(fig)
    return len(buffer.getvalue())


# ------------------------------------------------------------------ smeared frame
def smeared_frame(out: Path, seed: int = 3) -> None:
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    sensor = SensorModel(**ALL_NOISE)
    debris = FalseObjectModel(debris_per_frame=1, debris_magnitude_range=(3.0, 3.5), debris_speed_px_s=(600.0, 800.0))
    catalog = load_hipparcos().at_epoch(EPOCH_JYEAR)
    renderer = StarFieldRenderer(camera, sensor, catalog, 7.5, debris, fixed_pattern_seed=0)
    rate_deg_s = np.array([1.2, -1.6, 20.0])  # |cross-boresight| 2.0 deg/s, roll 20 deg/s
    rotation = radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0)
    motion = ConstantRateMotion(rotation, np.radians(rate_deg_s), t0=0.0)
    frame = renderer.render(motion, 0.0, frame_seed(seed, 0))
    truth = frame.truth
    # Rotation pole: the image point whose ray is parallel to omega (stars circle about it).
    pole_u, pole_v, _ = camera.project(rate_deg_s[None, :])
    pole_u, pole_v = float(pole_u[0]), float(pole_v[0])

    display = stretch(frame.image)
    binned = display.reshape(512, 2, 512, 2).astype(np.float32).mean(axis=(1, 3))
    # Crop: the 400 x 400 window (on a 32 px grid) with the most star track length in it.
    stars = truth.kind == KIND_STAR
    best, crop = -1.0, (0, 0)
    for r0 in range(0, 1024 - 400 + 1, 32):
        for c0 in range(0, 1024 - 400 + 1, 32):
            inside = stars & (truth.x >= c0 + 10) & (truth.x < c0 + 390) & (truth.y >= r0 + 10) & (truth.y < r0 + 390)
            score = float(np.sum(truth.extent_px[inside]))
            if score > best:
                best, crop = score, (r0, c0)
    r0, c0 = crop

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11.0, 6.1), gridspec_kw={"width_ratios": [1, 1]})
    ax0.imshow(binned, cmap="gray", vmin=0, vmax=255, extent=(-0.5, 1023.5, 1023.5, -0.5), interpolation="nearest")
    ax0.plot([pole_u], [pole_v], "+", color="tab:orange", ms=14, mew=2)
    ax0.annotate("rotation pole", (pole_u, pole_v), (pole_u + 10, pole_v + 110), color="tab:orange",
                 arrowprops=dict(arrowstyle="->", color="tab:orange"))
    ax0.add_patch(plt.Rectangle((c0 - 0.5, r0 - 0.5), 400, 400, fill=False, ec="tab:cyan", lw=1.2))
    for x, y, ext in zip(truth.x[truth.kind == KIND_DEBRIS], truth.y[truth.kind == KIND_DEBRIS],
                         truth.extent_px[truth.kind == KIND_DEBRIS]):
        ax0.annotate(f"debris ({ext:.0f} px)", (x, y), (x + 60 if x < 700 else x - 330, y + 90 if y < 800 else y - 90),
                     color="tab:red", arrowprops=dict(arrowstyle="->", color="tab:red"))
    ax0.set_title("full frame (1024² px, shown 2×2 binned)")
    ax0.set_xlabel("column [px]")
    ax0.set_ylabel("row [px]")
    ax1.imshow(display[r0:r0 + 400, c0:c0 + 400], cmap="gray", vmin=0, vmax=255,
               extent=(c0 - 0.5, c0 + 399.5, r0 + 399.5, r0 - 0.5), interpolation="nearest")
    ax1.set_title(f"crop: columns {c0}–{c0 + 399}, rows {r0}–{r0 + 399} (full resolution)")
    ax1.set_xlabel("column [px]")
    n_stars = int(np.count_nonzero(stars))
    fig.suptitle(f"Smeared frame: body rate ({rate_deg_s[0]:g}, {rate_deg_s[1]:g}, {rate_deg_s[2]:g}) °/s "
                 f"(2.0 °/s cross-boresight + 20 °/s roll), exposure {sensor.exposure_s * 1e3:g} ms, "
                 f"{frame.substeps} sub-steps\n{n_stars} stars to Hp 7.5, all detector effects on, one debris "
                 "streak; asinh stretch", fontsize=10)
    fig.tight_layout()
    size = save_png(fig, out, dpi=110)
    smear = truth.extent_px[stars]
    print(f"{out}: {size / 1e3:.0f} kB; {n_stars} stars, smear {smear.min():.1f}-{smear.max():.1f} px "
          f"(median {np.median(smear):.1f}), pole at ({pole_u:.0f}, {pole_v:.0f}) px, crop at column {c0}, row {r0}")


# ------------------------------------------------------------------ photon transfer
def photon_transfer(out: Path, seed: int = 7) -> dict[str, float]:
    gain, read_noise, full_well, bias = 2.0, 8.0, 60000.0, 100.0
    exposure = 0.1
    camera = CameraModel.from_fov(1024, 1024, np.radians(15.0))
    catalog = load_hipparcos().at_epoch(EPOCH_JYEAR)
    motion = ConstantRateMotion(radec_roll_to_matrix(np.radians(80.0), np.radians(20.0), 0.0), np.zeros(3))
    dark_e = SensorModel().dark_e_per_px_s * exposure
    # Expected electrons per pixel per exposure: 12 log-spaced levels (~10 ADU to 2.5x full
    # well) plus 4 levels around the full-well knee.
    log_levels = np.geomspace(20.0, 2.5 * full_well, 12)
    knee_levels = full_well * np.array([0.98, 0.995, 1.0, 1.005])
    rows = []
    for kind, levels in (("log", log_levels), ("knee", knee_levels)):
        for level in levels:
            sensor = SensorModel(background_e_per_px_s=(level - dark_e) / exposure, gain_e_per_adu=gain,
                                 read_noise_e=read_noise, full_well_e=full_well, bias_adu=bias, exposure_s=exposure,
                                 prnu_fraction=0.0, dsnu_fraction=0.0)
            renderer = StarFieldRenderer(camera, sensor, catalog, magnitude_limit=-5.0)
            a = renderer.render(motion, 0.0, frame_seed(seed, 2 * len(rows))).image.astype(np.float64)
            b = renderer.render(motion, 0.0, frame_seed(seed, 2 * len(rows) + 1)).image.astype(np.float64)
            mean = 0.5 * (a.mean() + b.mean()) - bias
            variance = float(np.var(a - b) / 2.0)
            rows.append((kind, level, mean, variance))
    kinds = np.array([r[0] for r in rows])
    level = np.array([r[1] for r in rows])
    mean = np.array([r[2] for r in rows])
    var = np.array([r[3] for r in rows])
    knee_adu = full_well / gain

    def model(m):
        return m / gain + (read_noise / gain) ** 2 + 1.0 / 12.0

    # Weighted least squares var = s mean + c below 90 % of full well (sigma_var ~ var).
    fit = (level < 0.9 * full_well) & (var > 0)
    w = 1.0 / var[fit]
    design = np.column_stack([mean[fit], np.ones(fit.sum())]) * w[:, None]
    (slope, intercept), *_ = np.linalg.lstsq(design, var[fit] * w, rcond=None)
    fitted_gain = 1.0 / slope
    fitted_read = fitted_gain * np.sqrt(max(intercept - 1.0 / 12.0, 0.0))
    residual = var[fit] / model(mean[fit]) - 1.0

    print(f"{'kind':5s} {'e-/px':>9s} {'mean ADU':>10s} {'var ADU^2':>11s} {'model':>11s} {'ratio':>7s}")
    for k, lv, m, v in rows:
        print(f"{k:5s} {lv:9.1f} {m:10.2f} {v:11.3f} {model(m):11.3f} {v / model(m):7.4f}")
    print(f"PTC fit below 90 % full well: slope {slope:.5f} (1/gain, ADU/e-) -> gain {fitted_gain:.4f} e-/ADU "
          f"(true {gain}); intercept {intercept:.3f} ADU^2 (model {(read_noise / gain) ** 2 + 1 / 12:.3f}) -> "
          f"read noise {fitted_read:.3f} e- (true {read_noise}); max |var/model - 1| = {np.max(np.abs(residual)):.4f}")

    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    grid = np.geomspace(5.0, knee_adu, 200)
    ax.plot(grid, model(grid), "-", color="0.5", lw=1.2,
            label=fr"model: mean/$g$ + $(\sigma_r/g)^2$ + 1/12  ($g$={gain:g} e⁻/ADU, $\sigma_r$={read_noise:g} e⁻)")
    ax.axvline(knee_adu, color="tab:red", ls="--", lw=1)
    ax.text(knee_adu * 0.93, 3.0, f"full well\n{full_well:.0f} e⁻ = {knee_adu:.0f} ADU",
            color="tab:red", ha="right", va="center", fontsize=9)
    floor = 0.3
    ok = var > floor
    for k, marker, label in (("log", "o", "flat-field pairs (log-spaced levels)"), ("knee", "s", "levels at the knee")):
        sel = (kinds == k) & ok
        ax.plot(mean[sel], var[sel], marker, ms=6, mfc="none" if k == "knee" else "tab:blue", color="tab:blue",
                label=label)
    sat = ~ok
    if sat.any():
        ax.plot(mean[sat], np.full(sat.sum(), floor), "v", color="tab:red", ms=7,
                label="saturated: variance 0 (drawn at the axis floor)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(floor * 0.8, None)
    # Inset: the knee on linear axes (read noise is clipped with the charge, so saturated
    # pixels all read full_well/g + bias and the variance collapses).
    inset = ax.inset_axes([0.36, 0.09, 0.30, 0.34])
    near = mean > 0.97 * knee_adu
    inset.plot(mean[near & (kinds == "log")], var[near & (kinds == "log")], "o", color="tab:blue", ms=4)
    inset.plot(mean[near & (kinds == "knee")], var[near & (kinds == "knee")], "s", mfc="none", color="tab:blue", ms=4)
    lin = np.linspace(0.975 * knee_adu, knee_adu, 20)
    inset.plot(lin, model(lin), "-", color="0.5", lw=1)
    inset.axvline(knee_adu, color="tab:red", ls="--", lw=1)
    inset.set_xlim(0.975 * knee_adu, 1.003 * knee_adu)
    inset.set_ylim(-800, 1.15 * model(knee_adu))
    inset.set_title("knee (linear axes)", fontsize=8)
    inset.tick_params(labelsize=7)
    ax.set_xlabel("mean signal above bias [ADU]")
    ax.set_ylabel("variance of (frame₁ − frame₂)/√2 [ADU²]")
    ax.set_title(f"Photon-transfer curve of the simulated detector\nfit below 90 % full well: slope "
                 f"{slope:.4f} (gain {fitted_gain:.3f} e⁻/ADU), intercept {intercept:.2f} ADU² "
                 f"(read noise {fitted_read:.2f} e⁻)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    size = save_png(fig, out, dpi=110)
    print(f"{out}: {size / 1e3:.0f} kB")
    return {"slope": float(slope), "intercept": float(intercept), "gain": float(fitted_gain),
            "read_noise": float(fitted_read)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Render the simulator figures of docs/SIMULATOR.md.")
    parser.add_argument("--output-dir", type=Path, default=Path("docs/images"))
    args = parser.parse_args(argv)
    args.output_dir.mkdir(parents=True, exist_ok=True)
    smeared_frame(args.output_dir / "smeared_frame.png")
    photon_transfer(args.output_dir / "photon_transfer.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
