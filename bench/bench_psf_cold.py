# SPDX-License-Identifier: Apache-2.0
"""
Cold frames across PSF widths and fluxes: the share of its stars each frame keeps.

Every frame is centroided alone at the defaults (`extract_spots(image, CentroidConfig())`: no
running prior, the 1 px prior of CentroidConfig.psf_sigma_px), as at first light or in
`star-tracker solve`. Stars of one flux per frame, kept apart (no blends), PSF sigma
0.4-3 px, 1,000-30,000 e-, several seeds per cell; two renderers: `alt` (bench/alt_renderer.py,
written independently of star_tracker.sim: ALT_STARS Gaussian stars >= 5 FWHM (>= 12 px) apart
on 512², its own Poisson and read noise, hot pixels and cosmic rays) and `simulator` (our
StarFieldRenderer, SensorModel(psf_sigma_px=sigma) with hot pixels and cosmic rays, the
8x8 grid of bench/scenes.py on 1024²); and `alt streaks (rate-aided)`, the alt stars smeared
STREAK_PX along a random direction, measured with the rate that smears them.

    python -m bench.bench_psf_cold [--quick] [--seeds N] [--output docs/BENCHMARKS.md]
    python -m bench.bench_psf_cold --delay

`--delay` runs only bench/bench_tracking.py's 36 delay-compensation trials (its own code and
seeds: lost-in-space on frame 0, the frames arriving meanwhile bridged, all centroided unaided,
cold) and prints how many publish a correct attitude for the newest frame, with the PSF widths
its unaided streak frames (1 and 2 deg/s, 0.1 s) were measured at.

A frame's kept share: of its stars with optimal SNR >= 10 (alt_renderer.optimal_snr), not
within 3 sigma + 3 px of a hot pixel or cosmic ray, the share with a spot within 2 sigma + 1
px. Reported per cell (sigma x flux): the minimum over its frames, and the frames whose PSF
was estimated (Spots.psf.source). Goal: no frame keeps fewer than 90 %.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from star_tracker.centroid import CentroidConfig, extract_spots

from . import alt_renderer as alt
from .report import write_section

SIGMAS = (0.4, 0.6, 1.0, 1.5, 2.0, 2.5, 3.0)
FLUXES = (1000.0, 3000.0, 10000.0, 30000.0)
SEEDS = 6
QUICK_SIGMAS, QUICK_FLUXES, QUICK_SEEDS = (0.6, 1.0, 3.0), (1000.0, 30000.0), 2
ALT_SIZE, ALT_STARS = 512, 60
ALT_DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0, hot_pixel_fraction=1e-4,
                            cosmic_rays_per_frame=3.0)
# A dark sky (a space camera's short exposure): shot noise rules, and a wide star's top pixels lie
# within a few noise sigmas of each other, where chance ties look like a clipped (flat) top.
ALT_DARK_DETECTOR = dataclasses.replace(ALT_DETECTOR, sky_e=1.0, read_noise_e=2.0)
SNR_MIN, KEPT_GOAL = 10.0, 0.90
# The rate-aided frames: every star smeared this long, as copies this many (0.25 px apart).
STREAK_PX, STREAK_STEPS, STREAK_EXPOSURE_S = 3.0, 13, 0.1
SEED = 4100


def scored_stars(x, y, snr, defect_x, defect_y, defect_extent, sigma: float) -> np.ndarray:
    """Return which stars are scored: optimal SNR >= SNR_MIN, not within 3 sigma + 3 px of a defect."""
    scored = snr >= SNR_MIN
    if defect_x.size:
        near = np.hypot(x[:, None] - defect_x[None], y[:, None] - defect_y[None]) \
            < 3 * sigma + 3 + 0.5 * defect_extent[None]
        scored &= ~near.any(axis=1)
    return scored


def kept_share(spots, x, y, snr, defect_x, defect_y, defect_extent, sigma: float) -> tuple[int, float]:
    """Return (stars scored, share of them with a spot within 2 sigma + 1 px) (module docstring)."""
    scored = scored_stars(x, y, snr, defect_x, defect_y, defect_extent, sigma)
    if not scored.any():
        return 0, float("nan")
    if len(spots) == 0:
        return int(scored.sum()), 0.0
    d = np.hypot(x[scored, None] - spots.x[None], y[scored, None] - spots.y[None])
    return int(scored.sum()), float((d.min(axis=1) < 2.0 * sigma + 1.0).mean())


def position_chi2(spots, x, y, scored: np.ndarray, sigma: float) -> list[float]:
    """Return each kept scored star's position error under its spot's stated covariance: chi^2, 2 DOF (mean 2)."""
    stars = np.flatnonzero(scored)
    if len(spots) == 0 or stars.size == 0:
        return []
    d = np.hypot(x[stars, None] - spots.x[None], y[stars, None] - spots.y[None])
    nearest = np.argmin(d, axis=1)
    kept = d[np.arange(stars.size), nearest] < 2.0 * sigma + 1.0
    errors = np.column_stack([spots.x[nearest] - x[stars], spots.y[nearest] - y[stars]])[kept]
    return [float(e @ np.linalg.solve(c, e)) for e, c in zip(errors, spots.cov[nearest[kept]])]


def alt_frame(sigma: float, flux: float, seed: int, detector: alt.Detector = ALT_DETECTOR):
    """One alt-renderer frame: (image, x, y, snr, defect x, y, extent)."""
    rng = np.random.default_rng([SEED, seed, int(100 * sigma), int(flux), int(detector.sky_e)])
    psf = alt.GaussianPsf(sigma)
    separation = max(5.0 * sigma / alt.SIGMA_PER_FWHM, 12.0)
    x, y = alt.place_stars(ALT_SIZE, ALT_SIZE, ALT_STARS, separation, 3 * sigma + 8, rng)
    field = alt.StarField.build(psf, x, y)
    frame = alt.render(field, flux, detector, ALT_SIZE, ALT_SIZE, rng)
    t = frame.truth
    return frame.image, t.x, t.y, t.snr, t.defect_x, t.defect_y, t.defect_extent_px


def simulator_frame(sigma: float, flux: float, seed: int):
    """One simulator frame (bench/scenes.py grid): (image, x, y, snr, defect x, y, extent)."""
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import KIND_COSMIC_RAY, KIND_HOT_PIXEL, KIND_STAR, StarFieldRenderer, frame_seed
    from star_tracker.sim.sensor import SensorModel

    from .scenes import CAMERA, POINTING, grid_scene, static_level

    sensor = SensorModel(psf_sigma_px=sigma, hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=5.0)
    rng = np.random.default_rng([SEED + 1, seed, int(100 * sigma), int(flux)])
    renderer = StarFieldRenderer(CAMERA, sensor, grid_scene(sensor, flux, rng), magnitude_limit=30.0,
                                 fixed_pattern_seed=seed)
    frame = renderer.render(ConstantRateMotion(POINTING, np.zeros(3)), 1.0, frame_seed(SEED, seed))
    t = frame.truth
    stars = t.kind == KIND_STAR
    detector = alt.Detector(sky_e=static_level(sensor), read_noise_e=sensor.read_noise_e,
                            gain_e_per_adu=sensor.gain_e_per_adu)
    snr = alt.optimal_snr(alt.StarField.build(alt.GaussianPsf(sigma), t.x[stars], t.y[stars]), flux, detector)
    defects = (t.kind == KIND_COSMIC_RAY) | (t.kind == KIND_HOT_PIXEL)
    return (frame.image, t.x[stars], t.y[stars], snr, t.x[defects], t.y[defects],
            np.maximum(t.extent_px[defects], 1.0))


def alt_streak_frame(sigma: float, flux: float, seed: int):
    """
    One alt-renderer frame of streaks: (image, x, y, snr, defect x, y, extent, smear model).

    ALT_STARS stars each smeared STREAK_PX along one random direction (STREAK_STEPS pixel-integrated
    copies, flux / STREAK_STEPS each), as a body rate across the boresight smears them in a
    STREAK_EXPOSURE_S exposure of an 8 deg camera; the SmearModel of that rate is the frame's aid.
    x, y: the streaks' centres; snr: each streak's optimal SNR (its copies' pixel fractions summed).
    """
    from star_tracker.centroid.streak.smear import SmearModel
    from star_tracker.models.camera import CameraModel

    rng = np.random.default_rng([SEED + 2, seed, int(100 * sigma), int(flux)])
    psf = alt.GaussianPsf(sigma)
    separation = max(5.0 * sigma / alt.SIGMA_PER_FWHM, 12.0) + STREAK_PX
    x, y = alt.place_stars(ALT_SIZE, ALT_SIZE, ALT_STARS, separation, 3 * sigma + 8 + STREAK_PX, rng)
    angle = float(rng.uniform(0.0, np.pi))
    steps = (np.arange(STREAK_STEPS) + 0.5) / STREAK_STEPS - 0.5
    along_x, along_y = STREAK_PX * np.cos(angle) * steps, STREAK_PX * np.sin(angle) * steps
    field = alt.StarField.build(psf, (x[:, None] + along_x).ravel(), (y[:, None] + along_y).ravel())
    frame = alt.render(field, flux / STREAK_STEPS, ALT_DETECTOR, ALT_SIZE, ALT_SIZE, rng)
    snr = np.empty(x.size)
    for k in range(x.size):
        share = sum(alt.star_stamp(psf, x[k] + dx, y[k] + dy, x[k], y[k]).fractions
                    for dx, dy in zip(along_x, along_y)) / STREAK_STEPS
        snr[k] = flux * np.sqrt(np.sum(share ** 2 / (flux * share + ALT_DETECTOR.pixel_variance_e2)))
    camera = CameraModel.from_fov(ALT_SIZE, ALT_SIZE, np.radians(8.0))
    rate = STREAK_PX / (camera.fx * STREAK_EXPOSURE_S)  # about the axis across the smear
    smear = SmearModel(camera, rate * np.array([np.sin(angle), -np.cos(angle), 0.0]), STREAK_EXPOSURE_S)
    t = frame.truth
    return frame.image, x, y, snr, t.defect_x, t.defect_y, t.defect_extent_px, smear


STREAK_RENDERER = "alt streaks (rate-aided)"
RENDERERS = {"alt": alt_frame,
             "alt dark sky": lambda sigma, flux, seed: alt_frame(sigma, flux, seed, ALT_DARK_DETECTOR),
             "simulator": simulator_frame,
             STREAK_RENDERER: alt_streak_frame}


def sweep(sigmas, fluxes, seeds: int, log=print) -> list[dict]:
    """One row per renderer, sigma and flux: the frames' kept shares and PSF estimates."""
    rows = []
    for renderer, make in RENDERERS.items():
        for sigma in sigmas:
            for flux in fluxes:
                shares, estimated, widths, scored, chi2 = [], 0, [], 0, []
                for seed in range(seeds):
                    image, x, y, snr, dx, dy, dext, *aid = make(sigma, flux, seed)
                    spots = extract_spots(image, CentroidConfig(), aid[0] if aid else None)
                    n, share = kept_share(spots, x, y, snr, dx, dy, dext, sigma)
                    scored += n
                    if n:
                        shares.append(share)
                    chi2 += position_chi2(spots, x, y, scored_stars(x, y, snr, dx, dy, dext, sigma), sigma)
                    estimated += spots.psf.estimated
                    widths.append(float(spots.psf.applied_sigma_px))
                row = {"renderer": renderer, "sigma_px": sigma, "flux_e": flux, "frames": seeds,
                       "stars_scored": scored, "min_kept": min(shares) if shares else None,
                       "mean_kept": float(np.mean(shares)) if shares else None, "estimated": estimated,
                       "applied_sigma_px": widths, "chi2_mean": float(np.mean(chi2)) if chi2 else None}
                rows.append(row)
                kept = "-" if row["min_kept"] is None else f"{100 * row['min_kept']:.1f} %"
                log(f"{renderer} sigma {sigma:g} flux {flux:g}: min kept {kept}, "
                    f"estimated {estimated}/{seeds}, applied {np.round(widths, 2).tolist()}")
    return rows


def report(rows: list[dict], sigmas, fluxes, seeds: int, elapsed_s: float, command: str, measured: str = "") -> str:
    def verdict(part: list[dict]) -> str:
        judged = [r for r in part if r["min_kept"] is not None]
        worst = min(judged, key=lambda r: r["min_kept"]) if judged else None
        met = all(r["min_kept"] >= KEPT_GOAL for r in judged)
        return f"{'yes' if met else 'no'}; worst frame " + (
            f"{100 * worst['min_kept']:.1f} % ({worst['renderer']}, σ {worst['sigma_px']:g} px, "
            f"{worst['flux_e']:g} e-)" if worst else "–")

    round_rows = [r for r in rows if r["renderer"] != STREAK_RENDERER]
    streak_rows = [r for r in rows if r["renderer"] == STREAK_RENDERER]
    lines = ["## Cold frames across PSF widths", "",
             f"Command: `{command}` — {measured}{elapsed_s:.0f} s in one process.", "",
             "Every frame centroided alone at the defaults (`extract_spots(image, CentroidConfig())`: no running "
             "prior, the PSF estimate starting from the 1 px prior), as at first light or in `star-tracker solve`. "
             f"Stars of one flux per frame, kept apart (no blends); {seeds} frames per cell. `alt`: "
             f"bench/alt_renderer.py, {ALT_STARS} pixel-integrated Gaussian stars ≥ 5 FWHM (≥ 12 px) apart on "
             f"{ALT_SIZE}², sky 40 e-/px, read noise 5 e-, hot pixels and 3 cosmic rays per frame; `alt dark sky`: "
             "the same at sky 1 e-/px, read noise 2 e- (shot noise rules: a wide star's top pixels lie within a "
             "few noise sigmas of each other, where chance ties look like a clipped flat top). `simulator`: "
             "our StarFieldRenderer, `SensorModel(psf_sigma_px=σ)` with hot pixels and cosmic rays, 64 stars on a "
             "grid on 1024². A frame's kept share: of its stars with optimal SNR ≥ 10 (not beside a defect), "
             "the share with a spot within 2σ + 1 px. `alt streaks (rate-aided)`: the `alt` stars each smeared "
             f"{STREAK_PX:g} px along one random direction per frame, measured with the rate that smears them "
             "(`extract_spots(image, CentroidConfig(), smear)`), the SNR the streak's. Cell: the minimum kept share "
             "over its frames (frames whose PSF was estimated, and χ²: the kept stars' position errors under "
             "their stated covariances, mean; 2 expected). Goal: no frame keeps fewer than 90 %.", "",
             f"Goal met, round stars: {verdict(round_rows)}. Rate-aided streaks: {verdict(streak_rows)}.", ""]
    for renderer in RENDERERS:
        lines += [f"| {renderer}: σ px \\ flux e- | " + " | ".join(f"{f:g}" for f in fluxes) + " |",
                  "|---|" + "---:|" * len(fluxes)]
        for sigma in sigmas:
            cells = []
            for flux in fluxes:
                r = next(r for r in rows if r["renderer"] == renderer and r["sigma_px"] == sigma
                         and r["flux_e"] == flux)
                chi2 = "" if r.get("chi2_mean") is None else f", χ² {r['chi2_mean']:.1f}"
                cells.append("–" if r["min_kept"] is None
                             else f"{100 * r['min_kept']:.0f} % ({r['estimated']}/{r['frames']}{chi2})")
            lines.append(f"| {sigma:g} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def delay_trials(log=print) -> dict:
    """bench_tracking's delay-compensation trials (module docstring): correct ones, and the widths applied."""
    from star_tracker.centroid import extract_spots as extract

    from . import bench_tracking as bt

    widths: list[float] = []

    def recording(image, config=CentroidConfig(), *args, **kwargs):
        spots = extract(image, config, *args, **kwargs)
        widths.append(float(spots.psf.applied_sigma_px))
        return spots

    bt.extract_spots = recording  # the trial's frames, as it measures them
    bench, plan = bt.TrackingBench(use_peer=False, log=log), bt.Plan()
    units = [u for u in bt.plan_units(plan) if u.part == "delay"]
    correct = 0
    for unit in units:
        rec = bt.run_unit(bench, plan, unit)
        ok = bool(rec.get("published") and rec.get("correct"))
        correct += ok
        log(f"{unit.case} trial {unit.run}: {'correct' if ok else 'no correct attitude'} "
            f"(bridged {rec['bridged_ok']} of {rec['newest']})")
    log(f"delay compensation: {correct} of {len(units)} trials publish a correct attitude for the newest frame; "
        f"frames measured at sigma {min(widths):.2f}-{max(widths):.2f} px")
    return {"correct": correct, "trials": len(units), "min_sigma_px": min(widths), "max_sigma_px": max(widths)}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=f"sigmas {QUICK_SIGMAS}, fluxes {QUICK_FLUXES}, "
                        f"{QUICK_SEEDS} seeds")
    parser.add_argument("--seeds", type=int, help=f"frames per cell (default {SEEDS})")
    parser.add_argument("--output", type=Path, help="write the '## Cold frames across PSF widths' section here")
    parser.add_argument("--json", type=Path, help="raw numbers (default: bench_psf_cold.json beside --output)")
    parser.add_argument("--delay", action="store_true", help="only bench_tracking's delay-compensation trials")
    args = parser.parse_args(argv)
    if args.delay:
        return delay_trials()
    sigmas, fluxes, seeds = (QUICK_SIGMAS, QUICK_FLUXES, QUICK_SEEDS) if args.quick else (SIGMAS, FLUXES, SEEDS)
    seeds = args.seeds or seeds
    started = time.perf_counter()
    rows = sweep(sigmas, fluxes, seeds)
    elapsed = time.perf_counter() - started
    command = "python -m bench.bench_psf_cold" + (" --quick" if args.quick else "") \
        + (f" --seeds {args.seeds}" if args.seeds else "") + (f" --output {args.output}" if args.output else "")
    from .bench_attitude import machine_info

    machine = machine_info()
    measured = (f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {machine['cpu']}, {machine['cores']} cores, "
                f"Python {machine['python']}, numpy {machine['numpy']}; ")
    text = report(rows, sigmas, fluxes, seeds, elapsed, command, measured)
    print(text)
    if args.output:
        write_section(args.output, text)
        out = args.json or args.output.parent / "bench_psf_cold.json"
        out.write_text(json.dumps({"rows": rows, "elapsed_s": elapsed, "measured": measured}, indent=1) + "\n")
    judged = [r["min_kept"] for r in rows if r["min_kept"] is not None]
    return {"min_kept": min(judged) if judged else None}


if __name__ == "__main__":
    main(sys.argv[1:])
