# SPDX-License-Identifier: Apache-2.0
"""
The datasheet: one page of the figures a design review asks for, drawn from the benchmarks' results.

    python -m bench.datasheet [--results-dir docs] [--output docs/DATASHEET.md]

Reads the default configuration (config/star_tracker.yaml, generated from the parameter specs)
and the benchmarks' JSON results (bench_*.json in --results-dir, written by `make bench`), and
writes DATASHEET.md there: every figure with its conditions and the benchmark, date and machine
that measured it; then the characterization report of `star-tracker characterize datasheet`
(datasheet.json and images/datasheet_*.png in --results-dir, copied there by its --docs; `make
datasheet` runs both). It measures nothing itself, so it is only as current as those results;
`star-tracker bench` runs it last. A benchmark whose results are missing shows as "not measured".
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from star_tracker.campaign.datasheet import phase_text

REPO = Path(__file__).resolve().parents[1]
ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi
NOT_MEASURED = "not measured"


@dataclass(frozen=True)
class Source:
    """A benchmark's results: its docs/BENCHMARKS.md section, command, date and machine."""

    section: str
    command: str
    date: str
    machine: str
    page: str = "BENCHMARKS.md"

    def cite(self) -> str:
        anchor = "".join(c for c in self.section.lower() if c.isalnum() or c in " -").replace(" ", "-")
        return f"[{self.section}]({self.page}#{anchor}), {self.date}, {self.machine}"


@dataclass(frozen=True)
class Row:
    """One figure: what, its value, under which conditions, measured where."""

    quantity: str
    value: str
    conditions: str
    source: Source | None


def load(results: Path, name: str) -> dict | None:
    """Return bench_<name>.json of `results`, or None when that benchmark has not been run there."""
    path = results / f"bench_{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _machine(meta: dict) -> str:
    machine = meta.get("machine")
    if isinstance(machine, dict):
        cpu, cores = machine.get("cpu", "?"), machine.get("cores")
    elif isinstance(machine, str):  # "CPU, N cores, Python ..."
        parts = [p.strip() for p in machine.split(",")]
        cpu, cores = parts[0], next((p.split()[0] for p in parts if p.endswith("cores")), None)
    else:
        cpu, cores = meta.get("cpu", "?"), meta.get("cores")
    cpu = cpu.replace("(R)", "").replace(" Processor", "")
    return f"{cpu}, {cores} cores" if cores else cpu


def source(data: dict, section: str) -> Source:
    """Return the Source of one benchmark's results (`meta`, or the top level for the older node benchmarks)."""
    meta = data.get("meta", data)
    return Source(section, meta.get("command", "?"), meta.get("date") or "date not recorded", _machine(meta))


def _missing(quantity: str, conditions: str) -> Row:
    return Row(quantity, NOT_MEASURED, conditions, None)


def catalog_epoch(epoch_jyear: float) -> str:
    """Return the identifier's database.epoch_jyear as the datasheet states it (0: the clock's date)."""
    return f"epoch {epoch_jyear:g}" if epoch_jyear else "the clock's date (to 0.1 year; proper motion applied)"


def configuration_rows(config: dict) -> list[tuple[str, str]]:
    """(item, value) of the default camera and solver, from the parameter file's defaults."""
    camera = config["/**/camera_simulator"]["ros__parameters"]
    identifier = config["/**/identifier"]["ros__parameters"]
    image, optics, sensor = camera["image"], camera["optics"], camera["sensor"]
    width, height = image["width"], image["height"]
    fov_x = math.radians(optics["fov_x_deg"])
    focal_px = 0.5 * width / math.tan(0.5 * fov_x)
    fov_y = 2.0 * math.degrees(math.atan(0.5 * height / focal_px))
    tracking = identifier["tracking"]
    return [
        ("Detector", f"{width} × {height} px, {sensor['pixel_pitch_m'] * 1e6:g} µm pitch, {sensor['adc_bits']}-bit, "
                     f"full well {sensor['full_well_e']:,.0f} e⁻, read noise {sensor['read_noise_e']:g} e⁻, "
                     f"QE {sensor['quantum_efficiency']:g}"),
        ("Field of view", f"{optics['fov_x_deg']:g}° × {fov_y:.1f}°, {ARCSEC_PER_RAD / focal_px:.1f}″ per pixel at "
                          f"the centre; aperture {optics['aperture_diameter_m'] * 1e3:g} mm, PSF σ "
                          f"{optics['psf_sigma_px']:g} px (the centroider estimates it from each frame)"),
        ("Frame rate, exposure", f"{camera['rate_hz']:g} Hz, {sensor['exposure_s'] * 1e3:g} ms (both parameters); "
                                 "every output stamped at mid-exposure"),
        ("Star catalog", f"Hipparcos at {catalog_epoch(identifier['database']['epoch_jyear'])}: guide stars to Hp "
                         f"{identifier['database']['magnitude_limit']:g}, deep re-match "
                         f"{identifier['deep_match']['magnitude_margin']:g} mag fainter"),
        ("False-positive bound", f"{identifier['false_positive_bound']:g}: a solution is published only below it "
                                 "(docs/IDENTIFICATION.md)"),
        ("Tracking limits", f"{math.degrees(tracking['max_angular_rate_rad_s']):g}°/s, "
                            f"{math.degrees(tracking['max_angular_acceleration_rad_s2']):g}°/s²; lost-in-space "
                            f"beyond them"),
    ]


def attitude_rows(data: dict | None) -> list[Row]:
    if data is None:
        return [_missing("Attitude accuracy", "bench_attitude")]
    src = source(data, "Attitude accuracy and covariance")
    cases = {case["name"]: case for case in data["cases"]}
    rows = []
    for name, label in (("at rest", "at rest"), ("cross 1 deg/s", "1°/s across the boresight"),
                        ("cross 3 deg/s", "3°/s across the boresight"), ("roll 3 deg/s", "3°/s about the boresight")):
        case = cases.get(name)
        if case is None:
            continue
        rows.append(Row(f"Attitude error {label} (RMS)",
                        f"{case['cross_rms_arcsec']:.2f}″ cross-boresight, {case['roll_rms_arcsec']:.2f}″ roll",
                        f"{case['frames']} simulated frames, {case['identified_pct']:.1f} % identified, "
                        f"{case['wrong_id_frames']} with a wrong star, median {case['stars_median']:.0f} stars",
                        src))
    pooled = data.get("pooled_moving")
    rest = cases.get("at rest")
    if rest is not None and pooled is not None:
        rows.append(Row("Published covariance: consistency (NEES, 3 expected)",
                        f"{rest['nees_mean']:.2f} at rest, {pooled['nees_mean']:.2f} under rate",
                        f"{rest['frames']} frames at rest, {pooled['frames']} moving; a consistent covariance "
                        "gives the attitude error's χ² mean 3", src))
    return rows


def identification_rows(data: dict | None) -> list[Row]:
    if data is None:
        return [_missing("Lost-in-space identification", "bench_identify")]
    src = source(data, "Identification")
    setup = data["setups"]["nominal"]
    algorithm = data["meta"].get("reference_algorithm", "hybrid")
    solver = setup["solvers"][algorithm]
    return [Row("Lost-in-space identification",
                f"{solver['correct_pct']:.1f} % correct, {solver['incorrect_pct']:.1f} % wrong; "
                f"{solver['time_ms']['median']:.2f} ms median, {solver['time_ms']['p99']:.2f} ms p99",
                f"{solver['scenes']} random sky scenes, {setup['description']}, algorithm `{algorithm}`", src)]


def tracking_rows(data: dict | None) -> list[Row]:
    if data is None:
        return [_missing("Tracking", "bench_tracking")]
    src = source(data, "Tracking")
    summaries = data["summaries"]
    rows = []
    upto = summaries.get("all runs <= 2 deg/s (constant + slews)")
    if upto is not None:
        rows.append(Row("Tracking up to 2°/s", f"{upto['correct']} of {upto['frames']} frames correct, "
                        f"{upto['incorrect']} wrong; {upto['track_ms_median']:.2f} ms per frame (median)",
                        "constant rates 0-2°/s and slews at 0.5 and 2°/s², simulated frames", src))
    for name in ("3 deg/s", "5 deg/s"):
        run = summaries.get(name)
        if run is not None:
            rows.append(Row(f"Tracking at {name.replace(' deg/s', '°/s')}",
                            f"{run['correct']} of {run['frames']} frames correct, {run['incorrect']} wrong",
                            "constant rate, simulated frames", src))
    delays = data.get("delay_compensation", [])
    if delays:
        from .bench_tracking import fresh_delay_trials

        fresh = fresh_delay_trials(delays)
        rows.append(Row("Delay compensation", f"{fresh} of {len(delays)} trials publish a correct attitude for the "
                        "newest frame", "a lost-in-space solve of 0.25-1 s at 1-2°/s, the frames meanwhile chained "
                        "frame to frame (unaided centroids)", src))
    reacquired = [r["frames_to_correct"] for r in data.get("reacquisition", []) if r.get("frames_to_correct")]
    if reacquired:
        rows.append(Row("Re-acquisition after lost frames", f"{max(reacquired)} frame(s) at most "
                        f"({len(reacquired)} gaps)", "blank frames in a tracked run, then the first good one", src))
    return rows


def centroid_rows(data: dict | None, psf: dict | None) -> list[Row]:
    rows = []
    if data is None:
        rows.append(_missing("Centroid accuracy", "bench_centroid"))
    else:
        src = source(data, "Centroiding")
        from .bench_centroid import worst_ratio  # the goal rows' own measure

        points = worst_ratio(data["accuracy"], "auto", 0, 20)
        smeared = worst_ratio(data["accuracy"], "auto + rate", 20, 20)
        at_rest = data["speed"]["at_rest"]["star_tracker (auto)"]
        if math.isfinite(points):
            rows.append(Row("Centroid error / Cramér-Rao bound", f"≤ {points:.2f}× (point stars)"
                            + (f", ≤ {smeared:.2f}× (20 px streaks, rate-aided)" if math.isfinite(smeared) else ""),
                            "SNR 20-1000, PSF σ 1 px, simulated grids of equal stars", src))
        rows.append(Row("Centroiding time", f"{at_rest['median_ms']:.1f} ms median per frame",
                        f"1024² mono16, ~{at_rest['stars']} stars, every detector effect on", src))
    if psf is None:
        rows.append(_missing("PSF range", "bench_psf_range"))
    else:
        src = source(psf, "Centroiding across PSFs")
        goal_rows = [r for r in psf["rows"] if r.get("stars_snr_ge_10")]
        met = sum(bool(r["detection_met"] and r["ratio_met"]) for r in goal_rows)
        sigmas = sorted({r["sigma_px"] for r in psf["rows"] if r.get("sigma_px")})
        false = psf["false_detections"]
        rows.append(Row("PSF width unknown to the centroider",
                        f"{met} of {len(goal_rows)} rows meet ≥ {100 * psf['goals']['detected']:g} % detected and "
                        f"≤ {psf['goals']['ratio']:g}× the bound; worst detection "
                        f"{100 * min(r['detected_snr_ge_10'] for r in goal_rows):.1f} %",
                        f"PSF σ {sigmas[0]:g}-{sigmas[-1]:g} px (Gaussian, Moffat, annulus, elliptical), SNR ≥ "
                        f"{psf['goals']['snr']:g}, two renderers (ours and an independent one)", src))
        rows.append(Row("False detections", f"{false['simulator']['mean']:.2f} and {false['alt']['mean']:.2f} per "
                        f"frame (max {max(false['simulator']['max'], false['alt']['max'])})",
                        "star-free frames with hot pixels and cosmic rays, both renderers", src))
    return rows


def node_rows(pipeline: dict | None, soak: dict | None, cold: dict | None, large: dict | None = None) -> list[Row]:
    rows = []
    if pipeline is None:
        rows.append(_missing("Output rate and latency", "bench_pipeline"))
    else:
        src = source(pipeline, "Pipeline throughput and overload")
        sweep = pipeline["sweep"]
        clean = [r for r in sweep if r["dropped"] == 0 and r["wrong"] == 0 and r["identified"] == r["frames"]]
        if clean:
            top = max(clean, key=lambda r: r["rate_hz"])
            rows.append(Row("Sustained rate without a drop", f"{top['rate_hz']:g} Hz ({top['frames']} frames, "
                            f"0 dropped, 0 wrong)", f"three nodes in separate processes over DDS, "
                            f"{pipeline['exposure_ms']:g} ms exposure, 2 cores", src))
        for r in sweep:
            if r["rate_hz"] in (10.0, 20.0):
                rows.append(Row(f"Latency at {r['rate_hz']:g} Hz", f"{r['latency_ms']['median']:.0f} ms median, "
                                f"{r['latency_ms']['p95']:.0f} ms p95", "mid-exposure stamp → attitude received "
                                "by a subscriber (half the exposure included)", src))
    if large is None:
        rows.append(_missing("Larger sensor", "bench_large_sensor"))
    else:
        r = large["result"]
        rows.append(Row(f"{large['size']}² frames at {large['rate_hz']:g} Hz", f"{r['identified']} of {r['frames']} "
                        f"identified, {r['wrong']} wrong; latency {r['latency_ms']['median']:.0f} ms median, "
                        f"{r['latency_ms']['p95']:.0f} ms p95", f"three nodes over DDS, {large['size']}² mono16, "
                        f"{large['exposure_ms']:g} ms exposure, 2 cores",
                        source(large, "Larger sensor through the nodes")))
    if soak is None:
        rows.append(_missing("Soak", "bench_soak"))
    else:
        src = source(soak, "Soak")
        summary = soak["summary"]
        growth = max(m["growth_percent"] for m in summary["memory"].values())
        rows.append(Row(f"{soak['minutes']:g}-minute soak at {soak['rate_hz']:g} Hz",
                        f"{summary['identified']} of {summary['frames']} identified, {summary['wrong']} wrong; memory "
                        f"growth ≤ {growth:.2f} % after the first minute; latency drift "
                        f"{summary['latency_slope_ms_per_min']:+.2f} ms/min",
                        "three nodes; drops (counted) only in host stalls", src))
    if cold is None:
        rows.append(_missing("Cold start", "bench_cold_start"))
    else:
        src = source(cold, "Cold start")
        colcon = next((r for r in cold["results"] if r["case"] == "colcon"), None)
        if colcon is not None:
            rows.append(Row("Start to first attitude", f"{colcon['first_start']['first_identified_s']:.1f} s",
                            f"fresh `colcon build` install (kernels compiled at install, "
                            f"{colcon['install_s']:.0f} s), three nodes started together", src))
    return rows


def realdata_rows(data: dict | None) -> list[Row]:
    if data is None:
        return [_missing("Real sky images", "bench_realdata")]
    src = source(data, "Real images")
    summary = data["summary"]
    ours = summary["ours"]
    peers = [name for name in ("tetra3rs", "cedar-solve") if name in summary]
    images = data["images"]
    fields = [row["fov_h_deg"] for row in images]
    versus = "; ".join(f"{name} {summary[name]['solved']} solved, {summary[name]['within_1arcmin']} within 1′"
                       for name in peers)
    return [Row("Real sky images at defaults (only an approximate field of view given)",
                f"{ours['solved']} of {ours['images']} solved, {ours['within_1arcmin']} of {ours['with_reference']} "
                f"within 1′ of the reference; median {ours['median_time_s'] * 1e3:.0f} ms per image",
                f"{len(images)} photographs from {len({row['source'] for row in images})} public "
                f"sources, fields {min(fields):.0f}-{max(fields):.0f}°, not made by our simulator"
                + (f"; peers on the same files: {versus}" if versus else "")
                + "; references: astrometry.net solves, or an independent dense re-fit where the corpus has one "
                "(the images short of 1′ and why: [BENCHMARKS.md](BENCHMARKS.md#images-ours-does-not-solve-within-1))",
                src)]


def orbit_rows(data: dict | None, environment: dict | None) -> list[Row]:
    """Build the rows of the tracker in orbit (bench_orbit: two heads in LEO) and the environment's render cost."""
    rows = []
    if data is None:
        rows.append(_missing("In orbit, two heads", "bench_orbit"))
    else:
        src = source(data, "In orbit: two heads over a LEO orbit")
        fusion, heads, aberration, arcs = data["fusion"], data["heads"], data["aberration"], data["arcs"]
        scenario = ("550 km sun-synchronous orbit, nadir-pointing body, two heads 45° from the zenith and 90° apart, "
                    f"a frame every 3 s over one orbit ({fusion['frames']} per head), the Sun within 23° of one head")
        wrong = sum(heads[h]["wrong"] for h in heads) + fusion["wrong"]
        rows.append(Row("Fused attitude available (two heads)",
                        f"{fusion['available_pct']:.1f} % of frames, {wrong} wrong (> 60″)", scenario, src))
        rms = ", ".join(f"{v:.2f}" for v in fusion["rms_two_heads_arcsec"])
        singles = "; ".join(f"head {h}: {heads[h]['cross_rms_arcsec']:.2f}″ per cross axis, "
                            f"{heads[h]['roll_rms_arcsec']:.2f}″ roll" for h in sorted(heads))
        rows.append(Row("Fused error per body axis (RMS, x, y, z)", f"{rms}″",
                        f"frames with both heads; single heads: {singles}; alignment of the second head estimated "
                        "online (RMS " + ", ".join(f"{v:.2f}" for v in fusion["alignment_rms_arcsec"])
                        + "″ over the last half orbit); with its true mounting given: "
                        + ", ".join(f"{v:.2f}" for v in fusion["rms_two_heads_known_alignment_arcsec"]) + "″", src))
        rows.append(Row("Aberration corrected (LEO + the Earth's velocity)",
                        f"{aberration['moving_corrected']['cross_mean_arcsec']:.2f}″ mean cross-boresight error "
                        f"(uncorrected {aberration['moving_raw']['cross_mean_arcsec']:.1f}″, at rest "
                        f"{aberration['rest_raw']['cross_mean_arcsec']:.2f}″)",
                        f"{aberration['solved_all']} frames solved lost-in-space, the observer's velocity given",
                        src))
        rows.append(Row("The Moon or a bright planet in the field",
                        f"{arcs['solved']} of {arcs['in_field']} frames solved, {arcs['wrong']} wrong",
                        "inertial pointings at the Moon (40-97 % lit), Venus, Mars, Jupiter and Saturn", src))
    if environment is None:
        rows.append(_missing("Environment render cost", "bench_environment"))
    else:
        src = source(environment, "Environment render cost")
        by_case = {row["case"]: row for row in environment["rows"]}
        far, moon = by_case.get("bodies far"), by_case.get("Moon in the field")
        if far is not None:
            rows.append(Row("Render time added by the Sun, Earth and Moon model", f"+{far['added_pct']:.0f} %"
                            + (f" (+{moon['added_pct']:.0f} % with the Moon in the field)" if moon else ""),
                            "bodies far from the field, against no environment; median of "
                            f"{far['frames']} frames", src))
    return rows


def load_campaign(results: Path, preset: str) -> dict | None:
    """Return characterize_<preset>.json of `results` (a campaign's summary.json), or None."""
    path = results / f"characterize_{preset.replace('-', '_')}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _campaign_source(data: dict) -> Source:
    engine = data.get("engine", {})
    machine = data.get("machine", {})
    machine = f"{machine.get('cpu', '?')}, {machine.get('cores', '?')} cores, {engine.get('threads', '?')} workers"
    return Source("Measured", data.get("command", "?"), data.get("date_utc", "date not recorded"), machine,
                  "CHARACTERIZE.md")


def campaign_rows(false_id: dict | None, sky: dict | None, accuracy: dict | None,
                  tracking: dict | None = None) -> list[Row]:
    """Build the rows of the Monte-Carlo campaigns (star-tracker characterize; docs/characterize_*.json)."""
    rows = []
    if false_id is None:
        rows.append(_missing("False identification (lost-in-space)", "star-tracker characterize false-id"))
    else:
        f = false_id
        rows.append(Row(
            "False identification (lost-in-space)",
            f"{f['false_identification']} of {f['trials']:,} trials; rate ≤ {f['false_identification_upper_95']:.3g} "
            f"(95 %); the verification states ≤ {f['stated_bound']:g}",
            f"random attitudes, scenes with {f['options']['false_stars']} false objects "
            f"({f['options']['setup']} setup), algorithm `{f['options']['algorithm']}`; false identification: a wrong "
            f"attitude or guide star. Besides: {f['wrong_deep_star']} trials ({f['wrong_deep_star_rate']:.1e}) "
            "named one false object as a faint star in the deep re-match (the attitude right); "
            f"{f['unsolved']} unsolved; {f['engine']['trials_per_s_per_core']:.0f} trials/s/core",
            _campaign_source(f)))
    if sky is None:
        rows.append(_missing("Lost-in-space over the sky", "star-tracker characterize sky-coverage"))
    else:
        rows.append(Row(
            "Lost-in-space over the sky",
            f"{100 * sky['success']:.2f} % of {sky['trials']:,} solved right ({sky['wrong']} wrong); "
            f"{sky['pixels_failing']} of {sky['pixels_tried']} directions with a failure; "
            f"{sky['identify_ms_median']:.2f} ms median, {sky['identify_ms_p99']:.2f} ms p99",
            f"boresight on every HEALPix pixel (nside {sky['nside']}), {sky['rolls']} rolls each, scenes as above",
            _campaign_source(sky)))
    if accuracy is None:
        rows.append(_missing("Error terms (ECSS-E-ST-60-20C)", "star-tracker characterize accuracy"))
    else:
        axes = accuracy["axes"]
        terms = (("bias", "bias"), ("temporal_noise", "temporal noise"), ("pixel_spatial", "pixel spatial error"),
                 ("fov_spatial", "FOV spatial error"))
        value = "; ".join(f"{label} " + ", ".join(f"{abs(axes[a][key]):.2f}" for a in ("x", "y", "roll")) + "″"
                          for key, label in terms)
        rows.append(Row(
            "Error terms per axis (x, y, roll; 1σ, ECSS-E-ST-60-20C)", value,
            f"{accuracy['trials']} rendered frames at rest: {accuracy['options']['pointings']} pointings × "
            f"{accuracy['options']['offsets']} sub-pixel offsets × {accuracy['options']['repeats']} noise draws; total "
            "RMS " + ", ".join(f"{axes[a]['rms']:.2f}" for a in ("x", "y", "roll")) + "″; 99.7 % of the errors within "
            + ", ".join(f"{axes[a]['p997']:.2f}" for a in ("x", "y", "roll")) + "″; bias: no source in the "
            "simulator (catalog, camera model and epoch are the identifier's), the figure is the terms' residue",
            _campaign_source(accuracy)))
    if tracking is None:
        rows.append(_missing("Tracking envelope", "star-tracker characterize tracking"))
    else:
        envelope = "; ".join(f"{a}°/s²: " + (f"{r:g}°/s" if r is not None else "none")
                             for a, r in tracking["envelope_rate_deg_s_by_acceleration"].items())
        options = tracking["options"]
        rows.append(Row(
            "Tracking envelope (fastest rate reached with every frame tracked right, by acceleration)", envelope,
            f"slews from rest at each acceleration toward each rate of {options['rates_deg_s']}°/s, "
            f"{options['runs']} sequences of {options['frames']} frames at 10 Hz each, rendered, rate-aided by the "
            f"tracker; {tracking['frames']:,} frames, {tracking['wrong_frames']} wrong; "
            f"{tracking['overconfident_frames']:,} with the error outside 5σ of the stated covariance"
            + (phase_text(tracking.get("phases")) or " (angular acceleration, a known limit)"),
            _campaign_source(tracking)))
    return rows


def render(config: dict, results: Path) -> str:
    """Return the datasheet's Markdown."""
    lines = [
        "# star_tracker datasheet",
        "",
        "Generated by `python -m bench.datasheet` from the benchmarks' results (`docs/bench_*.json`) and the "
        "default parameters (`config/star_tracker.yaml`): every figure names the benchmark section, date and "
        "machine that measured it; the exact commands are in [BENCHMARKS.md](BENCHMARKS.md). `make bench` "
        "re-measures everything and writes this page last. Simulated figures use the default camera below; the "
        "real-image row uses photographs our simulator did not make.",
        "",
        "## Default configuration",
        "",
        "| item | value |",
        "|---|---|",
        *[f"| {item} | {value} |" for item, value in configuration_rows(config)],
        "",
        "Interfaces: `sensor_msgs/Image` (+ `CameraInfo`) in; out: the attitude (sensor → ICRS) as "
        "`geometry_msgs/QuaternionStamped` and `PoseWithCovarianceStamped`, the matched stars (`PointCloud2`), the "
        "body rate (`Vector3Stamped`, `TwistWithCovarianceStamped`) and `/diagnostics`; frames, units, QoS and "
        "stamps in [msg_docs/](../msg_docs/README.md).",
        "",
        "## Performance",
        "",
        "| quantity | value | conditions | measured by |",
        "|---|---|---|---|",
    ]
    rows = [*attitude_rows(load(results, "attitude")), *identification_rows(load(results, "identify")),
            *tracking_rows(load(results, "tracking")),
            *centroid_rows(load(results, "centroid"), load(results, "psf_range")),
            *node_rows(load(results, "pipeline"), load(results, "soak"), load(results, "cold_start"),
                       load(results, "large_sensor")),
            *realdata_rows(load(results, "realdata")),
            *orbit_rows(load(results, "orbit"), load(results, "environment")),
            *campaign_rows(load_campaign(results, "false-id"), load_campaign(results, "sky-coverage"),
                           load_campaign(results, "accuracy"), load_campaign(results, "tracking"))]
    for row in rows:
        cite = row.source.cite() if row.source is not None else f"run `{row.conditions}` (`make bench`)"
        conditions = "" if row.source is None else row.conditions
        lines.append(f"| {row.quantity} | {row.value} | {conditions} | {cite} |")
    lines += ["", "Known limits: [USER_GUIDE.md § 6](USER_GUIDE.md#6-known-limits); the goals not met: identification "
              "([BENCHMARKS.md](BENCHMARKS.md#goals-default-algorithm-hybrid)), real images "
              "([within 1′](BENCHMARKS.md#images-ours-does-not-solve-within-1), "
              "[time against cedar-solve](BENCHMARKS.md#time-against-cedar-solve)), in orbit "
              "([fused against a single head](BENCHMARKS.md#in-orbit-two-heads-over-a-leo-orbit))."]
    characterization = results / "datasheet.json"
    if characterization.is_file():
        from star_tracker.campaign.datasheet import render_report

        lines += ["", render_report(json.loads(characterization.read_text()), "images").rstrip()]
    else:
        lines += ["", "## Characterization", "", f"{NOT_MEASURED}: run `make datasheet`."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--results-dir", type=Path, default=REPO / "docs",
                        help="where the benchmarks' bench_*.json are (default: docs/)")
    parser.add_argument("--output", type=Path, help="the Markdown file to write (default: DATASHEET.md in the "
                                                    "results directory)")
    parser.add_argument("--config", type=Path, default=REPO / "config" / "star_tracker.yaml",
                        help="the parameter file of the defaults (default: config/star_tracker.yaml)")
    args = parser.parse_args(argv)
    text = render(yaml.safe_load(args.config.read_text()), args.results_dir)
    output = args.output or args.results_dir / "DATASHEET.md"
    output.write_text(text)
    print(f"wrote {output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
