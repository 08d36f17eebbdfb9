# SPDX-License-Identifier: Apache-2.0
"""
Centroiding across PSFs: the centroider at its defaults, the PSF width unknown to it.

The centroider at its defaults (`CentroidConfig()`, PSF width unknown to it) on stars of PSF sigma 0.4-3 px, from our
simulator and from a second, independently written renderer (bench/alt_renderer.py: Gaussian, Moffat, defocused annulus,
elliptical Gaussian; its own noise, hot pixels and cosmic rays).

    python -m bench.bench_psf_range [--quick] [--output docs/BENCHMARKS.md]
        [--workers N] [--scheduler tcp://HOST:8786] [--campaign-output DIR]

Each case (one PSF on one renderer, every flux: an alt case's fields are rendered at each flux
in turn from one generator, so its fluxes cannot be split) and each star-free frame is a trial
of the `bench-psf-range` campaign kind (`PsfRangeTrials`), run by the campaign engine
(bench/campaign_trials.py): on `--workers` local processes (default: every core), or on the
Dask scheduler at `--scheduler` (or $DASK_SCHEDULER_ADDRESS); `--campaign-output DIR` keeps
their records in DIR/bench-psf-range and resumes an interrupted run there. A case is seeded
by its number as the loop did (1700 + case), a star-free frame by its own, so the figures do
not depend on the workers; `ms / frame` is measured on the worker that ran the case.

Goals, judged per row: >= 99 % of the stars with SNR >= 10 detected; RMS position
error <= 1.2x the Cramér–Rao bound (over the matched stars with SNR >= 10, in rows whose median
SNR is >= 10, with at least MIN_MATCHED stars matched); <= 1 false detection per star-free frame
with hot pixels and cosmic rays.

SNR = F sqrt(sum_i p_i^2 / (F p_i + B + r^2 + g^2/12)): the SNR of an optimal PSF-weighted
aperture (p_i the star's pixel fractions for its true PSF; F star electrons, B sky (+ dark)
electrons per pixel, r read noise, g gain). CRB: bench/alt_renderer.cramer_rao from the same
model (for simulator frames: its pixel-integrated Gaussian and noise levels). A star is
matched to the nearest spot within 2 sigma + 1 px (sigma: the PSF's equivalent Gaussian
sigma); stars within 3 sigma + 3 px of a hot pixel or cosmic ray (truth of both renderers) are
not scored.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from star_tracker.campaign import CampaignKind
from star_tracker.centroid import CentroidConfig, extract_spots
from star_tracker.commands.bench import report_progress

from . import alt_renderer as alt
from .campaign_trials import add_engine_arguments, engine_arguments_text, engine_line, errors, records, run_trials
from .machine import cpu_model
from .report import write_section

SIGMAS = (0.4, 0.6, 1.0, 2.0, 3.0)
FLUXES = (300.0, 1000.0, 5000.0, 30000.0)
ALT_SIZE = 512  # alt renderer frames [px] (square)
ALT_STARS = 50  # stars per alt field
ALT_DETECTOR = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=1.0, hot_pixel_fraction=1e-4,
                            cosmic_rays_per_frame=3.0)
ALT_DETECTOR_12BIT = alt.Detector(sky_e=40.0, read_noise_e=5.0, gain_e_per_adu=16.0, adc_bits=12,
                                  hot_pixel_fraction=1e-4, cosmic_rays_per_frame=3.0)
SNR_GOAL, DETECTED_GOAL, RATIO_GOAL, FALSE_GOAL = 10.0, 0.99, 1.2, 1.0
MIN_MATCHED = 10  # fewer matched stars than this: the RMS goal is not met (nothing to measure)
KINDS = {"GaussianPsf": "Gaussian", "MoffatPsf": "Moffat β 3", "AnnulusPsf": "annulus",
         "EllipticalGaussianPsf": "elliptical"}


@dataclass(frozen=True)
class Case:
    """
    One PSF on one renderer.

    Renderer "alt" (psf an alt_renderer PSF, detector) or "simulator" (psf an
    alt_renderer.GaussianPsf giving the simulator's psf_sigma_px).
    """

    renderer: str
    psf: object
    detector: alt.Detector = ALT_DETECTOR
    note: str = ""

    @property
    def sigma_px(self) -> float:
        return float(self.psf.equivalent_sigma_px)

    @property
    def kind(self) -> str:
        """The PSF family (and detector note) without its width: a column of the overview."""
        return KINDS[type(self.psf).__name__] + (f" {self.note}" if self.note else "")

    @property
    def name(self) -> str:
        return f"{self.psf.label()}{' ' + self.note if self.note else ''}"


QUICK_FLUXES = (1000.0, 5000.0)


def cases(quick: bool) -> list[Case]:
    sigmas = (0.6, 1.0, 2.0) if quick else SIGMAS
    out = [Case("simulator", alt.GaussianPsf(s)) for s in sigmas]
    out += [Case("alt", alt.GaussianPsf(s)) for s in sigmas]
    out += [Case("alt", alt.MoffatPsf(s / alt.SIGMA_PER_FWHM, beta=3.0)) for s in sigmas]
    if not quick:
        out += [Case("alt", alt.AnnulusPsf.with_equivalent_sigma(s)) for s in (1.0, 2.0, 3.0)]
        out += [Case("alt", alt.EllipticalGaussianPsf(1.3 * s, s / 1.3, np.radians(30.0))) for s in (0.6, 1.0, 2.0)]
        out.append(Case("alt", alt.GaussianPsf(1.0), ALT_DETECTOR_12BIT, "(12-bit ADC, 16 e-/ADU)"))
    return out


class Scored:
    """Per-star and per-frame tallies of one row (one case, one flux)."""

    def __init__(self):
        self.snr, self.hit, self.err2, self.crb = [], [], [], []
        self.extra, self.ms = [], []

    def add(self, spots, x, y, snr, crb_trace, defect_x, defect_y, defect_extent, sigma, elapsed_s):
        """Score one frame: stars (x, y, snr, trace of their CRB [px^2]) against `spots`."""
        radius = 2.0 * sigma + 1.0
        if defect_x.size:
            near = np.hypot(x[:, None] - defect_x[None],
                            y[:, None] - defect_y[None]) < 3 * sigma + 3 + 0.5 * defect_extent[None]
            scored = ~near.any(axis=1)
        else:
            scored = np.ones(x.size, bool)
        assigned = np.zeros(len(spots), bool)
        if len(spots):
            d = np.hypot(x[:, None] - spots.x[None], y[:, None] - spots.y[None])
            nearest = d.argmin(axis=1)
            hit = d[np.arange(x.size), nearest] < radius
            assigned[nearest[hit]] = True
            err2 = (spots.x[nearest] - x) ** 2 + (spots.y[nearest] - y) ** 2
        else:
            hit, err2 = np.zeros(x.size, bool), np.full(x.size, np.nan)
        self.snr.extend(snr[scored])
        self.hit.extend(hit[scored])
        self.err2.extend(err2[scored])
        self.crb.extend(crb_trace[scored])
        self.extra.append(int((~assigned).sum()))
        self.ms.append(1e3 * elapsed_s)

    def arrays(self) -> dict[str, np.ndarray]:
        """Return the tallies as arrays: per star snr, hit (0/1), err2 [px^2], crb [px^2]; per frame extra, ms."""
        return {"snr": np.asarray(self.snr, float), "hit": np.asarray(self.hit, np.int64),
                "err2": np.asarray(self.err2, float), "crb": np.asarray(self.crb, float),
                "extra": np.asarray(self.extra, np.int64), "ms": np.asarray(self.ms, float)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> "Scored":
        """Return the tallies of `arrays` (Scored.arrays), in their order."""
        scored = cls()
        for name in ("snr", "hit", "err2", "crb", "extra", "ms"):
            setattr(scored, name, list(arrays[name]))
        return scored

    def row(self) -> dict:
        snr, hit = np.asarray(self.snr), np.asarray(self.hit, bool)
        err2, crb = np.asarray(self.err2), np.asarray(self.crb)
        bright = snr >= SNR_GOAL
        measured = hit & bright if bright.any() else hit
        median_snr = float(np.median(snr)) if snr.size else float("nan")
        rms = float(np.sqrt(np.mean(err2[measured]))) if measured.any() else float("nan")
        crb_rms = float(np.sqrt(np.mean(crb[measured]))) if measured.any() else float("nan")
        detected = float(hit[bright].mean()) if bright.any() else float("nan")
        detect_ok = None if not bright.any() else detected >= DETECTED_GOAL
        ratio = rms / crb_rms if measured.any() else float("nan")
        ratio_ok = None if not median_snr >= SNR_GOAL else bool(measured.sum() >= MIN_MATCHED and ratio <= RATIO_GOAL)
        return {"stars": int(snr.size), "matched": int(measured.sum()), "stars_snr_ge_10": int(bright.sum()),
                "median_snr": median_snr,
                "detected_snr_ge_10": detected, "detected_all": float(hit.mean()) if hit.size else float("nan"),
                "rms_px": rms, "crb_px": crb_rms, "ratio": ratio, "extra_spots_per_frame": float(np.mean(self.extra)),
                "median_ms": float(np.median(self.ms)), "frames": len(self.ms),
                "detection_met": detect_ok, "ratio_met": ratio_ok}


def alt_star_field(psf, rng: np.random.Generator) -> "alt.StarField":
    """ALT_STARS stars of an alt_renderer `psf` at random positions >= 5 FWHM (at least 12 px) apart on ALT_SIZE²."""
    sigma = float(psf.equivalent_sigma_px)
    separation = max(5.0 * sigma / alt.SIGMA_PER_FWHM, 12.0)
    x, y = alt.place_stars(ALT_SIZE, ALT_SIZE, ALT_STARS, separation, 3 * sigma + 8, rng)
    return alt.StarField.build(psf, x, y)


def case_rows(case: Case, scores: dict[float, Scored]) -> list[dict]:
    """Rows (one per flux, in the order of `scores`) of a case from its tallies."""
    return [{"renderer": case.renderer, "kind": case.kind, "psf": case.name, "sigma_px": round(case.sigma_px, 3),
             "flux_e": flux, **scored.row()} for flux, scored in scores.items()]


def score_alt(case: Case, fluxes, fields: int, seed: int) -> dict[float, Scored]:
    """
    Tallies (per flux) of an alt-renderer case.

    `fields` star fields of ALT_STARS stars, each rendered once at every flux (independent
    noise, drawn in turn from the field's generator).
    """
    sigma = case.sigma_px
    scores = {flux: Scored() for flux in fluxes}
    for k in range(fields):
        rng = np.random.default_rng([seed, k])
        star_field = alt_star_field(case.psf, rng)
        for flux in fluxes:
            frame = alt.render(star_field, flux, case.detector, ALT_SIZE, ALT_SIZE, rng)
            t0 = time.perf_counter()
            spots = extract_spots(frame.image, CentroidConfig())
            elapsed = time.perf_counter() - t0
            crb = alt.cramer_rao(star_field, flux, case.detector)
            t = frame.truth
            scores[flux].add(spots, t.x, t.y, t.snr, crb[:, 0, 0] + crb[:, 1, 1], t.defect_x, t.defect_y,
                             t.defect_extent_px, sigma, elapsed)
    return scores


def measure_alt(case: Case, fluxes, fields: int, seed: int) -> list[dict]:
    """Rows (one per flux) of an alt-renderer case (score_alt)."""
    return case_rows(case, score_alt(case, fluxes, fields, seed))


def simulator_sensor(sigma: float, **defects):
    from star_tracker.sim.sensor import SensorModel

    return SensorModel(psf_sigma_px=sigma, hot_pixel_fraction=2e-5, cosmic_ray_rate_per_cm2_s=5.0, **defects)


def measure_simulator(case: Case, fluxes, frames: int, seed: int) -> list[dict]:
    """Rows (one per flux) of a simulator case (score_simulator)."""
    return case_rows(case, score_simulator(case, fluxes, frames, seed))


def score_simulator(case: Case, fluxes, frames: int, seed: int) -> dict[float, Scored]:
    """
    Tallies (per flux) of a simulator case.

    Grids of 64 stars (bench/scenes.py grid_scene, random sub-pixel phase) rendered by
    StarFieldRenderer with SensorModel(psf_sigma_px=sigma) and hot pixels and cosmic rays on.
    SNR and CRB from alt_renderer's Gaussian at the simulator's noise levels (sky + dark, read
    noise, gain).
    """
    from star_tracker.sim.motion import ConstantRateMotion
    from star_tracker.sim.render import KIND_COSMIC_RAY, KIND_HOT_PIXEL, KIND_STAR, StarFieldRenderer, frame_seed

    from .scenes import CAMERA, POINTING, grid_scene, static_level

    sigma = case.sigma_px
    sensor = simulator_sensor(sigma)
    detector = alt.Detector(sky_e=static_level(sensor), read_noise_e=sensor.read_noise_e,
                            gain_e_per_adu=sensor.gain_e_per_adu)
    scores = {flux: Scored() for flux in fluxes}
    for flux in fluxes:
        for k in range(frames):
            rng = np.random.default_rng([seed, k, int(flux)])
            renderer = StarFieldRenderer(CAMERA, sensor, grid_scene(sensor, flux, rng), magnitude_limit=30.0)
            frame = renderer.render(ConstantRateMotion(POINTING, np.zeros(3)), 1.0,
                                    frame_seed(seed, k * 100 + int(flux) % 97))
            t0 = time.perf_counter()
            spots = extract_spots(frame.image, CentroidConfig())
            elapsed = time.perf_counter() - t0
            t = frame.truth
            stars = t.kind == KIND_STAR
            star_field = alt.StarField.build(case.psf, t.x[stars], t.y[stars])
            snr = alt.optimal_snr(star_field, flux, detector)
            crb = alt.cramer_rao(star_field, flux, detector)
            defects = (t.kind == KIND_COSMIC_RAY) | (t.kind == KIND_HOT_PIXEL)
            scores[flux].add(spots, t.x[stars], t.y[stars], snr, crb[:, 0, 0] + crb[:, 1, 1], t.x[defects],
                             t.y[defects], np.maximum(t.extent_px[defects], 1.0), sigma, elapsed)
    return scores


def star_free_spots(renderer: str, k: int) -> int:
    """
    Spots at the defaults on star-free frame `k` of `renderer` ("simulator" or "alt").

    Hot pixels and cosmic rays on (simulator: also DSNU and PRNU), each frame its own fixed
    pattern and noise.
    """
    if renderer == "simulator":
        from star_tracker.models.catalog import StarCatalog
        from star_tracker.sim.motion import ConstantRateMotion
        from star_tracker.sim.render import StarFieldRenderer, frame_seed

        from .scenes import CAMERA, POINTING

        empty = StarCatalog(*(np.zeros(0) for _ in range(7)))
        sensor = simulator_sensor(1.0, dsnu_fraction=0.1, prnu_fraction=0.01)
        frame = StarFieldRenderer(CAMERA, sensor, empty, fixed_pattern_seed=k).render(
            ConstantRateMotion(POINTING, np.zeros(3)), 1.0, frame_seed(177, k))
        return len(extract_spots(frame.image, CentroidConfig()))
    nobody = alt.StarField.build(alt.GaussianPsf(1.0), np.zeros(0), np.zeros(0))
    detector = alt.Detector(sky_e=40.0, read_noise_e=5.0, hot_pixel_fraction=1e-4, hot_pixel_seed=k,
                            cosmic_rays_per_frame=5.0)
    frame = alt.render(nobody, 0.0, detector, 1024, 1024, np.random.default_rng([277, k]))
    return len(extract_spots(frame.image, CentroidConfig()))


def false_detections(counts: dict[str, list[int]]) -> dict:
    """Spots per star-free frame per renderer (star_free_spots of its frames) against the goal."""
    return {name: {"mean": float(np.mean(c)) if c else float("nan"), "max": int(np.max(c)) if c else -1,
                   "frames": len(c), "met": bool(np.mean(c) <= FALSE_GOAL) if c else False}
            for name, c in counts.items()}


@dataclass(frozen=True)
class PsfRangeOptions:
    """The sizes of bench_psf_range's trials (the defaults: the full run)."""

    quick: bool = False  # the quick run's cases (cases(True)) and fluxes (QUICK_FLUXES)
    frames: int = 4  # alt frames per row; the simulator's: one fewer (at least 1)
    false_frames: int = 10  # star-free frames per renderer

    def __post_init__(self) -> None:
        bad = [f"{name} must be >= 1" for name in ("frames", "false_frames") if getattr(self, name) < 1]
        if bad:
            raise ValueError("bench-psf-range options: " + "; ".join(bad))

    @property
    def fluxes(self) -> tuple[float, ...]:
        return QUICK_FLUXES if self.quick else FLUXES

    @property
    def trials(self) -> int:
        return len(cases(self.quick)) + 2 * self.false_frames

    def unit(self, task: int) -> tuple[str, str | None, int]:
        """Return trial `task`'s part ("case" or "false"), renderer of a star-free frame, and index in its part."""
        count = len(cases(self.quick))
        if task < count:
            return "case", None, task
        task -= count
        if task < 2 * self.false_frames:
            return "false", ("simulator", "alt")[task // self.false_frames], task % self.false_frames
        raise ValueError(f"bench-psf-range: no trial {count + task}, the last is {self.trials - 1}")


TALLIES = {"star_flux_e": "flux", "star_snr": "snr", "star_hit": "hit", "star_err2_px2": "err2",
           "star_crb_px2": "crb", "frame_flux_e": "flux", "frame_extra_spots": "extra", "frame_ms": "ms"}


class PsfRangeTrials(CampaignKind):
    """
    bench_psf_range's trials: tasks 0.. are the cases, then the simulator's and the alt renderer's star-free frames.

    A case's record holds its tallies (Scored.arrays) for every flux, flattened in flux order
    with each star's and frame's flux beside it; main() makes the rows from them. Case c is
    seeded 1700 + c and a star-free frame by its number, as the benchmark's loop always did:
    the engine's rng is not used.
    """

    name = "bench-psf-range"
    description = "bench_psf_range: the centroider at its defaults on PSFs of sigma 0.4-3 px, two renderers"
    options_type = PsfRangeOptions
    default_trials = 0  # the options' sizes: PsfRangeOptions.trials
    default_batch = 1  # a case is ~1-10 s (its fluxes x frames)
    columns = (pa.field("part", pa.string()), pa.field("renderer", pa.string()), pa.field("index", pa.int64()),
               *(pa.field(column, pa.list_(pa.int64() if tally in ("hit", "extra") else pa.float64()))
                 for column, tally in TALLIES.items()),
               pa.field("spots", pa.int64()))

    def prepare(self, options: PsfRangeOptions) -> list[Case]:
        # Compile the centroider's kernels here, so that no case's ms / frame includes it.
        extract_spots(alt.render(alt.StarField.build(alt.GaussianPsf(1.0), [64.5], [64.5]), 5000.0, ALT_DETECTOR,
                                 128, 128, np.random.default_rng(0)).image, CentroidConfig())
        return cases(options.quick)

    def trial(self, shared: list[Case], options: PsfRangeOptions, task: int, rng: np.random.Generator) -> dict:
        part, renderer, index = options.unit(task)
        if part == "false":
            return {"part": part, "renderer": renderer, "index": index, "spots": star_free_spots(renderer, index)}
        case = shared[index]
        seed = 1700 + index
        if case.renderer == "simulator":
            scores = score_simulator(case, options.fluxes, max(options.frames - 1, 1), seed)
        else:
            scores = score_alt(case, options.fluxes, options.frames, seed)
        return {"part": part, "renderer": case.renderer, "index": index, **scores_columns(scores)}

    def summarize(self, table: pa.Table, options: PsfRangeOptions) -> dict:
        return {}  # main() makes the figures


def scores_columns(scores: dict[float, Scored]) -> dict[str, list]:
    """Return a case's tallies (per flux) as the TALLIES columns: flattened in flux order, each flux beside."""
    tallies = {flux: scored.arrays() for flux, scored in scores.items()}
    columns = {}
    for column, tally in TALLIES.items():
        per = "snr" if column.startswith("star_") else "ms"  # an array as long as the stars' or the frames'
        if tally == "flux":
            columns[column] = np.concatenate([np.full(a[per].size, flux) for flux, a in tallies.items()]).tolist()
        else:
            columns[column] = np.concatenate([a[tally] for a in tallies.values()]).tolist()
    return columns


def record_scores(record: dict, fluxes) -> dict[float, Scored]:
    """Return a case's tallies per flux from its record (scores_columns, read back by campaign_trials.records)."""
    scores = {}
    for flux in fluxes:
        star, frame = record["star_flux_e"] == flux, record["frame_flux_e"] == flux
        arrays = {tally: record[column][star if column.startswith("star_") else frame]
                  for column, tally in TALLIES.items() if tally != "flux"}
        scores[flux] = Scored.from_arrays(arrays)
    return scores


def progress_bar(steps: int):
    """Return a run_trials progress callback that moves the `star-tracker bench` bar (trials done of `steps`)."""
    return lambda done, _total: report_progress(done, steps, "trials on the campaign engine")


def verdict(flag) -> str:
    return "–" if flag is None else ("yes" if flag else "**no**")


def table(rows: list[dict]) -> list[str]:
    lines = ["| renderer | PSF | σ px | flux e- | median SNR | stars (SNR ≥ 10) | detected (SNR ≥ 10) | RMS px | "
             "√CRB px | RMS / CRB | extra spots / frame | ms / frame | ≥ 99 % | ≤ 1.2× |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for r in rows:
        detected = "–" if np.isnan(r["detected_snr_ge_10"]) else f"{100 * r['detected_snr_ge_10']:.1f} %"
        lines.append(
            f"| {r['renderer']} | {r['psf']} | {r['sigma_px']:.2f} | {r['flux_e']:.0f} | {r['median_snr']:.1f} | "
            f"{r['stars']} ({r['stars_snr_ge_10']}) | {detected} | {r['rms_px']:.4f} | {r['crb_px']:.4f} | "
            f"{r['ratio']:.2f} | {r['extra_spots_per_frame']:.1f} | {r['median_ms']:.1f} | "
            f"{verdict(r['detection_met'])} | {verdict(r['ratio_met'])} |")
    return lines


def overview(rows: list[dict]) -> list[str]:
    """Rows meeting both goals (of those judged) per renderer, PSF family and sigma."""
    sigmas = sorted({r["sigma_px"] for r in rows})
    lines = ["| renderer | PSF | " + " | ".join(f"σ {s:g}" for s in sigmas) + " |", "|---|---|" + "---:|" * len(sigmas)]
    for renderer, kind in dict.fromkeys((r["renderer"], r["kind"]) for r in rows):
        cells = []
        for sigma in sigmas:
            judged = [r for r in rows if (r["renderer"], r["kind"], r["sigma_px"]) == (renderer, kind, sigma)
                      and r["detection_met"] is not None]
            met = sum(bool(r["detection_met"]) and r["ratio_met"] is not False for r in judged)
            cells.append(f"{met}/{len(judged)}" if judged else "")
        lines.append(f"| {renderer} | {kind} | " + " | ".join(cells) + " |")
    return lines


def summary(rows: list[dict], false: dict) -> list[str]:
    lines = ["| goal | renderer | rows met / judged | worst |", "|---|---|---|---|"]
    for renderer in ("simulator", "alt"):
        mine = [r for r in rows if r["renderer"] == renderer]
        judged = [r for r in mine if r["detection_met"] is not None]
        worst = min(judged, key=lambda r: r["detected_snr_ge_10"]) if judged else None
        lines.append(f"| ≥ 99 % of SNR ≥ 10 stars detected | {renderer} | "
                     f"{sum(r['detection_met'] for r in judged)}/{len(judged)} | "
                     + (f"{100 * worst['detected_snr_ge_10']:.1f} % ({worst['psf']}, {worst['flux_e']:.0f} e-) |"
                        if worst else "– |"))
        judged = [r for r in mine if r["ratio_met"] is not None]
        worst = max(judged, key=lambda r: np.nan_to_num(r["ratio"], nan=np.inf)) if judged else None
        lines.append(f"| RMS ≤ 1.2× CRB (median SNR ≥ 10) | {renderer} | "
                     f"{sum(r['ratio_met'] for r in judged)}/{len(judged)} | "
                     + (f"{worst['ratio']:.2f}× ({worst['psf']}, {worst['flux_e']:.0f} e-) |".replace("nan×",
                                                                                                      "no star matched")
                        if worst else "– |"))
        f = false[renderer]
        lines.append(f"| ≤ 1 false detection per star-free frame | {renderer} | {verdict(f['met'])} | "
                     f"{f['mean']:.2f} on average, max {f['max']} ({f['frames']} frames) |")
    return lines


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="3 sigmas, 3 PSF kinds, 2 fluxes, 1 frame each (smoke run)")
    parser.add_argument("--output", type=Path,
                        help="write the '## Centroiding across PSFs' section of this Markdown file")
    parser.add_argument("--json", type=Path, help="raw numbers (default: bench_psf_range.json beside --output)")
    add_engine_arguments(parser)
    args = parser.parse_args(argv)
    options = PsfRangeOptions(quick=args.quick, frames=1 if args.quick else 4, false_frames=2 if args.quick else 10)
    frames = options.frames
    started = time.perf_counter()
    todo = cases(args.quick)
    report_progress(0, options.trials, "cases and star-free frames on the campaign engine")
    stored, run = run_trials(PsfRangeTrials(), options.trials, dataclasses.asdict(options), args,
                             progress=progress_bar(options.trials))
    failed, trials = errors(stored), records(stored)
    for error in failed:
        print(f"bench-psf-range trial raised: {error}", file=sys.stderr)
    rows = []
    for r in trials:
        if r["part"] == "case" and not r["error"]:
            rows += case_rows(todo[r["index"]], record_scores(r, options.fluxes))
    false = false_detections({renderer: [r["spots"] for r in trials if r["part"] == "false"
                                         and r["renderer"] == renderer and not r["error"]]
                              for renderer in ("simulator", "alt")})
    report_progress(options.trials, options.trials, "done")
    elapsed = time.perf_counter() - started
    date = f"{dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC"
    command = ("python -m bench.bench_psf_range" + (" --quick" if args.quick else "") + engine_arguments_text(args)
               + " --output docs/BENCHMARKS.md")
    raised = [r["task"] for r in trials if r["error"]]
    where = (f"Cases and star-free frames: {engine_line(run)}"
             + (f"; {len(failed)} of {options.trials} trials raised (tasks {raised}, the errors in the JSON's "
                "meta.trial_errors), their rows missing below" if failed else "; none raised") + ".")
    cpu = cpu_model()
    text = "\n".join([
        "## Centroiding across PSFs",
        "",
        f"Command: `{command}` (part of `make bench`). Measured {date} in {elapsed:.0f} s. Machine: `nproc` = "
        f"{os.cpu_count()}, {cpu}; Python {platform.python_version()}, numpy {np.__version__}.",
        "",
        where,
        "",
        "The centroider at its defaults (`CentroidConfig()`: the PSF width is not told to it) on isolated stars of "
        "one flux per row, PSF equivalent Gaussian σ 0.4-3 px, from two renderers: `simulator` (our "
        "`StarFieldRenderer`, `SensorModel(psf_sigma_px=σ)`, 8x8 grids of stars at random sub-pixel phase on "
        "1024², sky + dark 42 e-/px, read noise 8 e-, 20 hot pixels, cosmic rays 5 /cm²/s; "
        f"{max(frames - 1, 1)} frames per row) and `alt` (bench/alt_renderer.py, written independently of "
        f"star_tracker.sim: {ALT_STARS} stars at random positions ≥ 5 FWHM apart on {ALT_SIZE}², sky 40 e-/px, "
        "read noise 5 e-, Poisson noise of its own, 26 fixed hot pixels of 500-20 000 e-, 3 cosmic-ray tracks "
        f"per frame 2-12 px long and 1-2 px wide; {frames} frames per row). PSFs of `alt`: pixel-integrated "
        "Gaussian (erf), Moffat β 3 of the Gaussian's FWHM, defocused annulus (ring r_in = r_out/2 blurred by "
        "0.3 σ, same second moment as the Gaussian), elliptical Gaussian (σ 1.3 σ / σ/1.3 at 30°), and one "
        "12-bit ADC at 16 e-/ADU.",
        "",
        "SNR = F √(Σ p_i² / (F p_i + B + r² + g²/12)), the SNR of an optimal PSF-weighted aperture (p_i the "
        "star's pixel fractions for its true PSF). The CRB is the Fisher bound of (x, y) for the star's own "
        "pixel-integrated PSF under the same noise (flux and sky known), per star; `RMS / CRB` compares the "
        "RMS 2-D error with √(mean CRB_xx + CRB_yy) over the matched stars with SNR ≥ 10 (all matched stars "
        "when none has it). A star is matched to the nearest spot within 2σ + 1 px; stars within 3σ + 3 px of "
        "a hot pixel or cosmic ray are not scored. `extra spots` are spots matched to no star (false "
        "detections, split stars). `ms / frame`: `extract_spots` time, informational (1024² simulator, 512² "
        "alt frames). Goals: ≥ 99 % of the SNR ≥ 10 stars detected; RMS ≤ 1.2× CRB in rows of "
        f"median SNR ≥ 10 (with at least {MIN_MATCHED} stars matched); ≤ 1 false detection per star-free frame "
        "(simulator: 1024² with hot pixels, cosmic rays, DSNU, PRNU; alt: 1024² with 105 hot pixels and 5 cosmic rays "
        "per frame). `–`: not judged (no star with SNR ≥ 10).",
        "",
        *summary(rows, false),
        "",
        "Overview: rows meeting both goals / rows judged (fluxes with SNR ≥ 10 stars), per PSF and equivalent σ:",
        "",
        *overview(rows),
        "",
        *table(rows),
        "",
    ])
    print(text)
    results = {"meta": {"command": command, "date": date, "elapsed_s": elapsed, "quick": args.quick,
                        "engine": engine_line(run), "engine_run": run, "trial_errors": failed,
                        "machine": {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
                                    "numpy": np.__version__}},
               "goals": {"snr": SNR_GOAL, "detected": DETECTED_GOAL, "ratio": RATIO_GOAL,
                         "false_per_frame": FALSE_GOAL},
               "rows": rows, "false_detections": false}
    json_path = args.json or (args.output.parent / "bench_psf_range.json" if args.output else None)
    if json_path:
        json_path.write_text(json.dumps(results, indent=1, default=float) + "\n")
    if args.output:
        write_section(args.output, text)
    return results


if __name__ == "__main__":
    main()
