# SPDX-License-Identifier: Apache-2.0
"""
The stress campaign's figures as Markdown: docs/RELIABILITY.md's section between its `<!-- stress -->` markers.

`star-tracker characterize stress --frames N --docs docs` writes it (and keeps the summary as
docs/characterize_stress.json); `reliability_section(summary)` is the text.
"""
from __future__ import annotations

from pathlib import Path

from ..markdown_section import write_between_markers

BEGIN, END = "<!-- stress -->", "<!-- /stress -->"
STRATUM_TITLES = {"phase": "motion phase (each frame, from the truth)", "motion": "motion (the mission's)",
                  "false_objects": "false objects", "detector": "detector", "psf": "PSF",
                  "stray_light": "stray light", "temperature": "temperature", "frame_faults": "frame faults",
                  "rate_aid": "rate aid"}


def _number(value, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _row(name: str, cell: dict) -> str:
    share = cell["nees_above_997_share"]
    return (f"| {name} | {cell['frames']:,} | {_number(cell['availability'], 3)} | {cell['wrong']} | "
            f"{cell['wrong_star_frames']} | {_number(cell['nees_mean'])} | "
            f"{'-' if share is None else f'{100 * share:.1f} %'} | {cell['nees_above_5_sigma']} |")


def reliability_section(summary: dict) -> str:
    """Return the section's Markdown from a stress campaign's summary.json."""
    machine = summary.get("machine", {})
    engine = summary.get("engine", {})
    recoveries = summary["recoveries"]
    lines = [
        "### Stress campaign",
        "",
        f"Command: `{summary['command']}` — {summary.get('date_utc', '')}, {machine.get('cpu', '')}, "
        f"{machine.get('cores', '')} cores; {engine.get('wall_s', 0) / 60:.0f} min of campaign work. "
        "The missions and their scoring: [CHARACTERIZE § Presets](CHARACTERIZE.md#presets) (`stress`); each "
        "wrong or overconfident frame is listed in the run's summary.json (`failures`, with its task and seed) and "
        "replays with `star-tracker characterize stress --replay TASK --seed SEED`.",
        "",
        f"- **{summary['frames']:,} frames** judged ({summary['missions']:,} missions, {summary['deliveries']:,} "
        f"deliveries: " + ", ".join(f"{k.replace('_', ' ')} {v:,}" for k, v in summary["verdicts"].items())
        + f"); {summary['failed_tasks']} missions raised.",
        f"- **{summary['wrong']} wrong** (boresight > 60″ or NEES > {summary['nees_5_sigma']:.1f}), "
        f"**{summary['wrong_star_frames']} frames with a wrong star ID**; NEES mean {_number(summary['nees_mean'])}, "
        f"{100 * (summary['nees_above_997_share'] or 0):.2f} % above χ²₃(0.997) = {summary['nees_997']:.1f}; "
        f"availability (right / judged) {_number(summary['availability'], 4)}.",
        f"- Recovery after a loop, a gap or a dropped-frame burst that cut a track: {recoveries['events']} events, "
        f"{recoveries['within_2_frames']} tracked again within 2 frames, the slowest "
        f"{recoveries['max_frames'] if recoveries['max_frames'] is not None else '-'}, "
        f"{recoveries['not_recovered']} not before the mission's end.",
        "",
        "| stratum | frames | availability | wrong | wrong star | NEES mean | NEES > 13.9 | NEES > 31.8 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, cells in summary["strata"].items():
        title = STRATUM_TITLES.get(name, name)
        for value, cell in cells.items():
            lines.append(_row(f"{title}: {value.replace('+', ' + ')}", cell))
    return "\n".join(lines) + "\n"


def write_section(path: Path, text: str) -> None:
    """Put `text` between BEGIN and END in the Markdown file at `path` (appended when the markers are absent)."""
    write_between_markers(path, text, BEGIN, END)
