# SPDX-License-Identifier: Apache-2.0
"""
The characterization datasheet: the campaigns a design review asks for, and their report.

`star-tracker characterize datasheet` runs DATASHEET_CAMPAIGNS (each an ordinary campaign in
OUTPUT/<name>/, so an interrupted datasheet resumes) and writes OUTPUT/DATASHEET.md,
OUTPUT/datasheet.json (every figure of the page) and OUTPUT/images/*.png. datasheet_data
gathers the figures from the campaigns' summaries and records; render_report turns them into
the Markdown (bench/datasheet.py puts the same text at the head of docs/DATASHEET.md).

The accuracy table follows ECSS-E-ST-60-20C Rev.2's split of the measurement error: bias,
thermo-elastic error, FOV spatial error, pixel spatial error, temporal noise, aberration; each
per axis (x, y across the boresight; roll about it) at 1 sigma and at 3 sigma, or marked as
not isolated by the simulator with the reason.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

AXES = ("x", "y", "roll")
RATES_DEG_S = (0.5, 1.0, 2.0, 4.0)  # the accuracy campaigns across rates, beside the one at rest
FALSE_ID_TRIALS = 300_000  # ~6 min on two cores: a bound of ~1e-5 with none wrong


@dataclass(frozen=True)
class DatasheetCampaign:
    """One campaign of the datasheet: its directory name, preset, trials (None: the options' grid) and options."""

    name: str
    preset: str
    trials: int | None = None
    options: dict = field(default_factory=dict)


def datasheet_campaigns(false_id_trials: int = FALSE_ID_TRIALS, quick: bool = False) -> tuple[DatasheetCampaign, ...]:
    """
    Return the datasheet's campaigns, sized for ~10 min on two cores (false_id_trials: the false-id run).

    quick: a few trials each (a minute; to try the command and in tests), the figures meaningless.
    """
    if quick:
        return (
            DatasheetCampaign("accuracy", "accuracy", options={"pointings": 2, "offsets": 2, "repeats": 2}),
            *(DatasheetCampaign(f"accuracy_rate_{r:g}", "accuracy", options={
                "pointings": 2, "offsets": 2, "repeats": 2, "rate_deg_s": r}) for r in RATES_DEG_S),
            DatasheetCampaign("sky_coverage", "sky-coverage", options={"nside": 1, "rolls": 1}),
            DatasheetCampaign("tracking", "tracking", options={"runs": 1, "rates_deg_s": "1,2",
                                                               "accelerations_deg_s2": "2", "frames": 10}),
            DatasheetCampaign("robustness", "robustness", options={"frames": 1}),
            DatasheetCampaign("false_id", "false-id", trials=min(false_id_trials, 200)),
        )
    return (
        DatasheetCampaign("accuracy", "accuracy", options={"pointings": 32}),
        *(DatasheetCampaign(f"accuracy_rate_{r:g}", "accuracy", options={"pointings": 8, "rate_deg_s": r})
          for r in RATES_DEG_S),
        DatasheetCampaign("sky_coverage", "sky-coverage", options={"nside": 8, "rolls": 4}),
        DatasheetCampaign("tracking", "tracking", options={"runs": 1}),
        DatasheetCampaign("robustness", "robustness", options={"frames": 32}),
        DatasheetCampaign("false_id", "false-id", trials=false_id_trials),
    )


# ECSS-E-ST-60-20C Rev.2 error terms: (key in the accuracy summary or None, label, why not isolated).
ECSS_TERMS = (
    ("bias", "bias", None),
    (None, "thermo-elastic error", "no thermal model of the head in these campaigns (the in-orbit simulator drifts "
     "a head's mounting: FUSION.md, ORBIT.md)"),
    ("fov_spatial", "FOV spatial error", None),
    ("pixel_spatial", "pixel spatial error", None),
    ("temporal_noise", "temporal noise", None),
    (None, "aberration of light", "the campaigns are at zero velocity; in orbit the identifier corrects it from the "
     "observer's velocity (ORBIT.md: 0.16\" corrected against 15.3\" uncorrected)"),
)


def _axes_errors(table: pa.Table) -> dict[str, np.ndarray]:
    """Return the errors [arcsec] per axis of the frames solved right."""
    ok = np.asarray(table.column("error").to_pylist(), object) == ""
    right = ok & np.asarray(table.column("solved").fill_null(False), bool) \
        & ~np.asarray(table.column("wrong").fill_null(False), bool)
    return {a: np.asarray(table.column(f"error_{a}_arcsec").fill_null(np.nan), float)[right] for a in AXES}


def datasheet_data(summaries: dict[str, dict], tables: dict[str, pa.Table], meta: dict) -> dict:
    """
    Return every figure of the datasheet from the campaigns' summaries and records (keys: DatasheetCampaign.name).

    meta: the command, date, software, machine and wall time of the whole datasheet.
    """
    accuracy = summaries["accuracy"]
    terms = []
    for key, label, reason in ECSS_TERMS:
        row = {"term": label, "reason": reason}
        if key is not None:
            one = [accuracy["axes"][a][key] for a in AXES]
            row.update(sigma_arcsec=[abs(v) if v is not None else None for v in one],
                       three_sigma_arcsec=[3.0 * abs(v) if v is not None else None for v in one])
        terms.append(row)
    rates = [{"rate_deg_s": 0.0, "frames": accuracy["trials"], "solved": accuracy["solved"],
              "wrong": accuracy["wrong"], "false_identification": accuracy["false_identification"],
              "wrong_deep_star": accuracy["wrong_deep_star"], "rms_arcsec": [accuracy["axes"][a]["rms"] for a in AXES],
              "p997_arcsec": [accuracy["axes"][a]["p997"] for a in AXES], "nees_mean": accuracy["nees_mean"]}]
    for r in RATES_DEG_S:
        s = summaries[f"accuracy_rate_{r:g}"]
        rates.append({"rate_deg_s": r, "frames": s["trials"], "solved": s["solved"], "wrong": s["wrong"],
                      "false_identification": s["false_identification"], "wrong_deep_star": s["wrong_deep_star"],
                      "rms_arcsec": [s["axes"][a]["rms"] for a in AXES],
                      "p997_arcsec": [s["axes"][a]["p997"] for a in AXES], "nees_mean": s["nees_mean"]})
    errors = _axes_errors(tables["accuracy"])
    sky, tracking = summaries["sky_coverage"], summaries["tracking"]
    robustness, false_id = summaries["robustness"], summaries["false_id"]
    return {
        "meta": meta,
        "accuracy": {"frames": accuracy["trials"], "solved": accuracy["solved"], "wrong": accuracy["wrong"],
                     "nees_mean": accuracy["nees_mean"], "options": accuracy["options"], "terms": terms,
                     "total_rms_arcsec": [accuracy["axes"][a]["rms"] for a in AXES],
                     "p997_arcsec": [accuracy["axes"][a]["p997"] for a in AXES],
                     "histogram_arcsec": {a: errors[a].tolist() for a in AXES}},
        "error_vs_rate": rates,
        "sky_coverage": {k: sky[k] for k in ("nside", "rolls", "trials", "solved", "wrong", "success",
                                             "pixels_tried", "pixels_failing", "identify_ms_median",
                                             "identify_ms_p99", "wrong_attitude", "wrong_deep_star")},
        "tracking": {"frames": tracking["frames"], "wrong_frames": tracking["wrong_frames"],
                     "overconfident_frames": tracking["overconfident_frames"], "cases": tracking["cases"],
                     "phases": tracking.get("phases"),
                     "envelope_rate_deg_s_by_acceleration": tracking["envelope_rate_deg_s_by_acceleration"]},
        "robustness": {"units": robustness["units"], "sweeps": robustness["sweeps"], "wrong": robustness["wrong"],
                       "trials": robustness["trials"]},
        "false_id": {k: false_id[k] for k in ("trials", "correct", "wrong", "unsolved", "false_identification",
                                              "false_identification_upper_95", "wrong_deep_star", "stated_bound")},
        "campaigns": {name: {"command": s.get("command"), "date_utc": s.get("date_utc"),
                             "wall_s": s.get("engine", {}).get("wall_s")} for name, s in summaries.items()},
    }


def _f(value, digits: int = 2) -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.{digits}f}"


def render_report(data: dict, images: str = "images") -> str:
    """Return the datasheet's Markdown for datasheet_data's figures; images: the figures' directory, relative."""
    meta, acc = data["meta"], data["accuracy"]
    lines = [
        "## Characterization (`star-tracker characterize datasheet`)", "",
        f"Made by `{meta['command']}` on {meta['date_utc']} ({meta['machine']}; star_tracker "
        f"{meta['software']}; {meta['wall_s'] / 60:.0f} min). The default camera: 1024 × 1024 px, 15° field, "
        "the simulator's default sensor (0.1 s exposure, PSF σ 1 px, read noise 8 e⁻), stars to Hp 7.5 rendered, "
        "the default identifier (`hybrid`, Hipparcos at epoch 2026). x and y are across the boresight, roll "
        "about it; 3σ is three times the 1σ term.", "",
        "### Accuracy (ECSS-E-ST-60-20C Rev.2 terms), at rest",
        "",
        f"{acc['frames']} rendered frames: {acc['options']['pointings']} pointings over the sky × "
        f"{acc['options']['offsets']} sub-pixel offsets × {acc['options']['repeats']} noise draws, nested so that "
        "each term is the scatter at its level ([CHARACTERIZE.md](CHARACTERIZE.md)); "
        f"{acc['solved']} solved, {acc['wrong']} wrong, NEES {_f(acc['nees_mean'])} (3 when the stated "
        "covariance is right).", "",
        "| term | x 1σ | y 1σ | roll 1σ | x 3σ | y 3σ | roll 3σ |", "|---|---:|---:|---:|---:|---:|---:|",
    ]
    reasons = []
    for term in acc["terms"]:
        if term["reason"]:
            reasons.append(f"- {term['term']}: {term['reason']}.")
            lines.append(f"| {term['term']} | not isolated ({len(reasons)}) | – | – | – | – | – |")
        else:
            lines.append(f"| {term['term']} | " + " | ".join(f"{_f(v)}″" for v in term["sigma_arcsec"]) + " | "
                         + " | ".join(f"{_f(v)}″" for v in term["three_sigma_arcsec"]) + " |")
    lines += [
        "| total (RMS; 99.7 % of the errors within) | " + " | ".join(f"{_f(v)}″" for v in acc["total_rms_arcsec"])
        + " | " + " | ".join(f"{_f(v)}″" for v in acc["p997_arcsec"]) + " |", "",
        "Not isolated by the simulator:", "", *[f"{i + 1}. {r[2:]}" for i, r in enumerate(reasons)], "",
        "The simulator's catalog, camera model and epoch are the identifier's, so the bias and the FOV spatial "
        "error have no source at the defaults: their figures are the other terms' residue.", "",
        f"![error histograms]({images}/datasheet_error_histograms.png)", "",
        "### Error against rate", "",
        "| rate across the boresight | frames | solved | wrong (false identifications; a wrong faint deep-catalog "
        "star alone) | RMS x, y, roll | 99.7 % within | NEES |",
        "|---:|---:|---:|---|---|---|---:|",
    ]
    for row in data["error_vs_rate"]:
        lines.append(f"| {row['rate_deg_s']:g}°/s | {row['frames']} | {row['solved']} | {row['wrong']} "
                     f"({row['false_identification']}; {row['wrong_deep_star']}) | "
                     + ", ".join(_f(v) for v in row["rms_arcsec"]) + "″ | "
                     + ", ".join(_f(v) for v in row["p997_arcsec"]) + f"″ | {_f(row['nees_mean'])} |")
    sky = data["sky_coverage"]
    lines += [
        "", f"![error against rate]({images}/datasheet_error_vs_rate.png)", "",
        "### Lost-in-space over the sky", "",
        f"{sky['trials']:,} scenes with the boresight on every HEALPix pixel (nside {sky['nside']}, "
        f"{sky['pixels_tried']} directions of equal area) × {sky['rolls']} rolls: "
        f"**{100 * (sky['success'] or 0):.2f} % solved right**, {sky['wrong']} wrong ({sky['wrong_attitude']} wrong "
        f"attitudes, {sky['wrong_deep_star']} with one false object named as a faint star), "
        f"{sky['pixels_failing']} directions with a failure; identification {_f(sky['identify_ms_median'])} ms "
        f"median, {_f(sky['identify_ms_p99'])} ms p99.", "",
        f"![sky coverage]({images}/datasheet_sky_coverage.png)", "",
    ]
    track = data["tracking"]
    envelope = "; ".join(f"{a}°/s²: " + (f"{r:g}°/s" if r is not None else "none")
                         for a, r in track["envelope_rate_deg_s_by_acceleration"].items())
    lines += [
        "### Tracking envelope", "",
        f"Slews from rest at each acceleration toward each coast rate, rendered at 10 Hz, rate-aided by the tracker: "
        f"{track['frames']:,} frames, {track['wrong_frames']} wrong, {track['overconfident_frames']:,} with the error "
        f"outside 5σ of the stated covariance{phase_text(track.get('phases'))}. The fastest rate reached with "
        f"every frame tracked right, in "
        f"its slew and in every slower one: "
        f"**{envelope}**.", "",
        f"![tracking envelope]({images}/datasheet_tracking_envelope.png)", "",
        "### Robustness", "",
        "Lost-in-space on rendered frames while one stress rises, the rest at the defaults "
        "(`campaign/presets/robustness.py`): the share solved right; in brackets the wrong ones: false "
        "identifications / errors beyond 5σ of the stated covariance.", "",
    ]
    robust = data["robustness"]
    for sweep, cells in robust["sweeps"].items():
        lines.append(f"- **{sweep.replace('_', ' ')}** ({robust['units'][sweep]}): " + ", ".join(
            f"{c['level']:g}: {100 * (c['availability'] or 0):.0f} %"
            + (f" ({c['false_identification']} / {c['outside_5_sigma']})" if c["wrong"] else "")
            for c in cells))
    fid = data["false_id"]
    lines += [
        "", f"![robustness]({images}/datasheet_robustness.png)", "",
        "### False identification", "",
        f"{fid['trials']:,} lost-in-space scenes: **{fid['false_identification']} false identifications** (a wrong "
        f"attitude or guide star), a rate ≤ {fid['false_identification_upper_95']:.3g} at 95 % (Clopper-Pearson), "
        f"against the verification's stated {fid['stated_bound']:g}; {fid['wrong_deep_star']} scenes named a false "
        f"object as a faint star (the attitude right); {fid['unsolved']} unsolved.", "",
        "### Availability", "",
        "Not a campaign here: the blinding by the Sun, the Earth and the Moon, and the fused availability of two "
        "heads over an orbit, are measured in orbit ([ORBIT.md](ORBIT.md), bench_orbit).", "",
    ]
    return "\n".join(lines) + "\n"


def phase_text(phases: dict | None) -> str:
    """Return ' (N of them accelerating: NEES mean ...; steady ...)' from a tracking summary's phases ("" without)."""
    if not phases:
        return ""
    parts = [f"{name} {p['overconfident']:,} of {p['frames']:,}, NEES mean {p['nees_mean']:.1f}"
             for name, p in phases.items() if p["frames"]]
    return " (while accelerating within the exposure vs steady: " + "; ".join(parts) + ")"
