# SPDX-License-Identifier: Apache-2.0
"""
Pictures for people.

A frame with its identified stars circled and labelled (OpenCV), and matplotlib figures
(imported lazily): a solved frame with residual arrows, a sky chart of the field, and
attitude error and body rate against time for a run.
"""
from __future__ import annotations

import cv2
import numpy as np


def stretch(image: np.ndarray) -> np.ndarray:
    """
    Display stretch of a raw frame to 8-bit.

    Background at ~10 % grey, asinh compression so faint stars and bright stars are both
    visible.
    """
    data = image.astype(np.float32)
    background = float(np.median(data))
    noise = float(1.4826 * np.median(np.abs(data - background))) or 1.0
    scaled = np.arcsinh(np.maximum(data - background, -2 * noise) / (3.0 * noise))
    top = float(np.percentile(scaled, 99.99)) or 1.0
    return np.clip(25.0 + 230.0 * scaled / top, 0, 255).astype(np.uint8)


def annotate_frame(image: np.ndarray, pixel_x: np.ndarray, pixel_y: np.ndarray, hip: np.ndarray,
                   title: str = "", spots_xy: np.ndarray | None = None) -> np.ndarray:
    """
    Draw a BGR picture: detected spots as small grey squares, identified stars as labelled green circles.

    Identified stars are labelled with their HIP number; a title band above the frame.
    """
    canvas = cv2.cvtColor(stretch(image), cv2.COLOR_GRAY2BGR)
    if spots_xy is not None:
        for x, y in np.asarray(spots_xy).reshape(-1, 2):
            cv2.rectangle(canvas, (int(x) - 5, int(y) - 5), (int(x) + 5, int(y) + 5), (140, 140, 140), 1)
    width = canvas.shape[1]
    for x, y, h in zip(pixel_x, pixel_y, hip):
        centre = (int(round(x)), int(round(y)))
        label = f"HIP {int(h)}"
        (text_w, _), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        # Label right of the circle, or left of it near the right edge.
        text_x = centre[0] + 14 if centre[0] + 14 + text_w < width else centre[0] - 14 - text_w
        cv2.circle(canvas, centre, 12, (60, 220, 60), 1, cv2.LINE_AA)
        cv2.putText(canvas, label, (text_x, max(centre[1] - 8, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (60, 220, 60), 1, cv2.LINE_AA)
    if title:
        canvas = cv2.copyMakeBorder(canvas, 34, 0, 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0))
        cv2.putText(canvas, title, (10, 23), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


# ---------------------------------------------------------------- matplotlib figures
# matplotlib (Agg, no display) is imported inside each function: the nodes never need it.

def pyplot():
    """Return matplotlib.pyplot on the Agg backend (no display); ValueError naming the package when it is absent."""
    try:
        import matplotlib
    except ImportError:
        raise ValueError("pictures need matplotlib (pip install matplotlib)") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> str:
    plt = pyplot()
    fig.savefig(str(path), dpi=fig.dpi)
    plt.close(fig)
    return str(path)


def solution_figure(image: np.ndarray, matched: list[dict], unmatched_xy: np.ndarray, title: str = "",
                    residual_scale: float | None = None, max_labels: int = 40):
    """
    Figure of an identified frame.

    The stretched image; identified stars circled and labelled with their HIP number; each
    star's residual (catalog position predicted by the solved attitude minus the measured spot)
    drawn as an arrow magnified `residual_scale` times (default: the median residual drawn as
    ~15 px); unmatched spots as small grey squares. matched: dicts with x, y, predicted_x,
    predicted_y [px], hip, magnitude (solve's records).
    """
    plt = pyplot()
    height, width = image.shape
    size_in = 9.0
    fig = plt.figure(figsize=(size_in, size_in * height / width + 0.5), dpi=max(100, int(min(width, 1400) / size_in)))
    ax = fig.add_axes([0.0, 0.0, 1.0, height / width * size_in / (size_in * height / width + 0.5)])
    ax.imshow(stretch(image), cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_axis_off()
    unmatched_xy = np.asarray(unmatched_xy, dtype=float).reshape(-1, 2)
    if unmatched_xy.size:
        ax.scatter(unmatched_xy[:, 0], unmatched_xy[:, 1], s=40, marker="s", facecolors="none",
                   edgecolors="#9a9a9a", linewidths=0.6, label=f"unmatched spots ({len(unmatched_xy)})")
    if matched:
        x = np.array([m["x"] for m in matched])
        y = np.array([m["y"] for m in matched])
        dx = np.array([m["predicted_x"] for m in matched]) - x
        dy = np.array([m["predicted_y"] for m in matched]) - y
        length = np.hypot(dx, dy)
        if residual_scale is None:
            typical = float(np.median(length)) if length.size else 0.0
            residual_scale = 15.0 / typical if typical > 0 else 1.0
        ax.scatter(x, y, s=180, facecolors="none", edgecolors="#3cdc3c", linewidths=0.9,
                   label=f"identified ({len(matched)})")
        ax.quiver(x, y, dx * residual_scale, dy * residual_scale, angles="xy", scale_units="xy", scale=1,
                  color="#ffb000", width=0.0025, label=f"residual x{residual_scale:.0f}")
        brightest = sorted(range(len(matched)), key=lambda k: matched[k].get("magnitude", 99))[:max_labels]
        for k in brightest:
            right = x[k] < width - 90
            ax.text(x[k] + (10 if right else -10), y[k] - 8, f"HIP {matched[k]['hip']}", color="#3cdc3c",
                    fontsize=7, ha="left" if right else "right", va="bottom")
    ax.legend(loc="lower left", fontsize=8, framealpha=0.6)
    if title:
        fig.text(0.01, 1.0 - 0.25 / (size_in * height / width + 0.5), title, fontsize=9, va="center")
    return fig


def save_solution_plot(path, image: np.ndarray, record: dict, spots, residual_scale: float | None = None) -> str:
    """
    `star-tracker solve --plot`.

    solution_figure of a solve record (solve.solution_record) with the spots of the frame,
    written as PNG.
    """
    matched = record.get("matched", [])
    used = {(round(m["x"], 3), round(m["y"], 3)) for m in matched}
    unmatched = np.array([(x, y) for x,
                          y in zip(spots.x, spots.y) if (round(float(x), 3), round(float(y), 3)) not in used])
    if record.get("solved"):
        s = record["sigma_arcsec"]
        title = (f"RA {record['ra_deg']:.4f}°  Dec {record['dec_deg']:+.4f}°  roll {record['roll_deg']:+.3f}°   "
                 f"1σ {s['cross_boresight']:.1f}\" / {s['roll']:.1f}\" roll   {len(matched)} stars, "
                 f"FOV {record['camera']['fov_x_deg']:.3f}°")
    else:
        title = f"not solved: {record.get('reason', '')}"
    return _save(solution_figure(image, matched, unmatched, title, residual_scale), path)


def sky_chart(catalog, rotation: np.ndarray, camera, identified_hip=(), magnitude_limit: float = 7.0,
              title: str = ""):
    """
    Draw a chart of the sky around a field of view.

    In the camera's own gnomonic projection about its boresight (so the image rectangle is
    drawn as it is seen): an RA/Dec grid, catalog stars (`catalog`: StarCatalog) to
    `magnitude_limit` as dots sized by magnitude, the identified ones (`identified_hip`)
    circled, and the image outline. rotation: sensor -> ICRS. Axes in degrees from the
    boresight (x right, y up = -image y).
    """
    plt = pyplot()
    rotation = np.asarray(rotation, dtype=float)
    half = np.degrees(camera.half_diagonal_fov_rad) * 1.25
    reach = np.tan(np.radians(min(half, 60.0)))
    stars = catalog.brighter_than(magnitude_limit)
    body = stars.unit_vectors() @ rotation  # R^T v as rows
    front = body[:, 2] > np.cos(np.radians(min(half * 1.5, 80.0)))
    gx = body[front, 0] / body[front, 2]
    gy = body[front, 1] / body[front, 2]
    inside = (np.abs(gx) <= reach) & (np.abs(gy) <= reach)
    magnitude = stars.hp[front][inside]
    hip = stars.hip[front][inside]
    gx, gy = np.degrees(np.arctan(gx[inside])), np.degrees(np.arctan(gy[inside]))

    fig, ax = plt.subplots(figsize=(7.5, 7.5), dpi=110)
    ax.set_facecolor("#0b1026")
    # RA/Dec grid: lines of constant Dec and RA through the chart, 1-2-5 spacing.
    step = next(s for s in (0.5, 1, 2, 5, 10, 15, 30) if s >= half / 4)
    boresight = rotation[:, 2]
    dec0 = np.degrees(np.arcsin(np.clip(boresight[2], -1, 1)))
    ra0 = np.degrees(np.arctan2(boresight[1], boresight[0])) % 360.0
    ra_step = step if abs(dec0) < 60 else step * 3
    samples = np.linspace(-1.0, 1.0, 400)
    for dec in np.arange(np.floor((dec0 - 2 * half) / step) * step, dec0 + 2 * half + step, step):
        if abs(dec) > 89.9:
            continue
        ras = ra0 + samples * 180.0
        _grid_line(ax, rotation, ras, np.full_like(ras, dec), reach, f"{dec:+.0f}°" if step >= 1 else f"{dec:+.1f}°")
    for ra in np.arange(np.floor((ra0 - 180) / ra_step) * ra_step, ra0 + 180, ra_step):
        decs = np.clip(dec0 + samples * 2 * half, -89.9, 89.9)
        _grid_line(ax, rotation, np.full_like(decs, ra), decs, reach,
                   f"{ra % 360:.0f}°" if ra_step >= 1 else f"{ra % 360:.1f}°")
    sizes = 2.0 + 60.0 * 10 ** (-0.4 * (magnitude - magnitude.min())) if magnitude.size else 1.0
    ax.scatter(gx, -gy, s=sizes, c="white", linewidths=0, zorder=3)
    marked = np.isin(hip, np.asarray(list(identified_hip), dtype=hip.dtype))
    ax.scatter(gx[marked], -gy[marked], s=120, facecolors="none", edgecolors="#3cdc3c", linewidths=1.0, zorder=4,
               label=f"identified ({int(marked.sum())})")
    for x, y, h, m in zip(gx[marked], -gy[marked], hip[marked], magnitude[marked]):
        if m < magnitude_limit - 1.5:
            ax.text(x + half * 0.015, y + half * 0.015, f"HIP {h}", color="#3cdc3c", fontsize=6, zorder=5)
    # The image outline, pixel edges mapped through the camera model.
    w, h = camera.width, camera.height
    edge = np.concatenate([np.stack([np.linspace(-0.5, w - 0.5, 50), np.full(50, -0.5)], 1),
                           np.stack([np.full(50, w - 0.5), np.linspace(-0.5, h - 0.5, 50)], 1),
                           np.stack([np.linspace(w - 0.5, -0.5, 50), np.full(50, h - 0.5)], 1),
                           np.stack([np.full(50, -0.5), np.linspace(h - 0.5, -0.5, 50)], 1)])
    rays = camera.pixel_to_ray(edge[:, 0], edge[:, 1])
    ax.plot(np.degrees(np.arctan(rays[:, 0] / rays[:, 2])), -np.degrees(np.arctan(rays[:, 1] / rays[:, 2])),
            color="#ffb000", lw=1.2, label="image", zorder=4)
    ax.set_xlim(-half, half)
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.set_xlabel("image x from the boresight [deg]")
    ax.set_ylabel("image up (-y) from the boresight [deg]")
    ax.set_title(title or f"sky around RA {ra0:.2f}°, Dec {dec0:+.2f}° (stars to Hp {magnitude_limit:g})", fontsize=10)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def _grid_line(ax, rotation, ra_deg, dec_deg, reach, label) -> None:
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    v = np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=1) @ rotation
    ok = v[:, 2] > 0.05
    x = np.where(ok, v[:, 0] / np.where(ok, v[:, 2], 1), np.nan)
    y = np.where(ok, v[:, 1] / np.where(ok, v[:, 2], 1), np.nan)
    ok &= (np.abs(x) < 3 * reach) & (np.abs(y) < 3 * reach)
    x, y = np.where(ok, np.degrees(np.arctan(x)), np.nan), np.where(ok, -np.degrees(np.arctan(y)), np.nan)
    ax.plot(x, y, color="#4a5a8a", lw=0.6, zorder=1)
    limit = np.degrees(np.arctan(reach))
    visible = np.flatnonzero(ok & (np.abs(x) < limit * 0.95) & (np.abs(y) < limit * 0.95))
    if visible.size:
        k = visible[visible.size // 2]
        ax.text(x[k], y[k], label, color="#7f8fc0", fontsize=7, zorder=2)


def run_figure(time_s: np.ndarray, cross_boresight_arcsec: np.ndarray, roll_arcsec: np.ndarray,
               rate_deg_s: np.ndarray | None = None, true_rate_deg_s: np.ndarray | None = None,
               sigma_cross_arcsec: np.ndarray | None = None, sigma_roll_arcsec: np.ndarray | None = None,
               title: str = ""):
    """
    Plot the attitude error and body rate against time for a run.

    From plain arrays (one entry per frame; NaN where the frame was not identified): time_s
    [s]; cross-boresight and roll error against truth [arcsec]; optionally the estimated and
    true body rate (N, 3) [deg/s, sensor frame] and the published 1-sigma [arcsec] (drawn as
    3-sigma bands). Unidentified frames are marked along the bottom of the error panel.
    """
    plt = pyplot()
    t = np.asarray(time_s, dtype=float)
    cross = np.asarray(cross_boresight_arcsec, dtype=float)
    roll = np.asarray(roll_arcsec, dtype=float)
    panels = 2 if rate_deg_s is not None or true_rate_deg_s is not None else 1
    fig, axes = plt.subplots(panels, 1, figsize=(8.0, 3.2 * panels + 0.4), dpi=110, sharex=True, squeeze=False)
    ax = axes[0, 0]
    ax.plot(t, cross, ".-", ms=3, lw=0.8, color="#1f77b4", label="cross-boresight error")
    ax.plot(t, roll, ".-", ms=3, lw=0.8, color="#d62728", label="roll error")
    if sigma_cross_arcsec is not None:
        ax.plot(t, 3 * np.asarray(sigma_cross_arcsec, float), lw=0.8, ls="--", color="#1f77b4",
                label="3σ cross-boresight")
    if sigma_roll_arcsec is not None:
        ax.plot(t, 3 * np.asarray(sigma_roll_arcsec, float), lw=0.8, ls="--", color="#d62728", label="3σ roll")
    lost = ~np.isfinite(cross)
    if lost.any():
        ax.plot(t[lost], np.zeros(int(lost.sum())), "x", color="k", ms=5, label=f"not identified ({int(lost.sum())})")
    ax.set_ylabel("attitude error [arcsec]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    if panels == 2:
        ax = axes[1, 0]
        colours = ("#1f77b4", "#2ca02c", "#d62728")
        for axis, colour in enumerate(colours):
            if true_rate_deg_s is not None:
                ax.plot(t, np.asarray(true_rate_deg_s, float)[:, axis], lw=1.6, color=colour, alpha=0.35,
                        label=f"true ω{'xyz'[axis]}")
            if rate_deg_s is not None:
                ax.plot(t, np.asarray(rate_deg_s, float)[:, axis], ".", ms=3, color=colour,
                        label=f"estimated ω{'xyz'[axis]}")
        ax.set_ylabel("body rate [deg/s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    if title:
        axes[0, 0].set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig, path) -> str:
    """Write a figure from this module as PNG and close it."""
    return _save(fig, path)


def run_arrays(frames) -> dict[str, np.ndarray]:
    """
    Return the arrays run_figure takes.

    From per-frame records with the fields of ros.pipeline.FrameRecord (stamp_ns, truth, error(),
    covariance, rate, truth_rate; duck-typed, so this module stays free of ROS): frames with
    truth only, time from the first one [s].
    """
    frames = [f for f in frames if f.truth is not None]
    n = len(frames)
    out = {"time_s": np.zeros(n), "cross_boresight_arcsec": np.full(n, np.nan), "roll_arcsec": np.full(n, np.nan),
           "sigma_cross_arcsec": np.full(n, np.nan), "sigma_roll_arcsec": np.full(n, np.nan),
           "rate_deg_s": np.full((n, 3), np.nan), "true_rate_deg_s": np.full((n, 3), np.nan)}
    if not n:
        return out
    arcsec = np.degrees(1.0) * 3600.0
    t0 = frames[0].stamp_ns
    for k, f in enumerate(frames):
        out["time_s"][k] = (f.stamp_ns - t0) * 1e-9
        error = f.error()
        if error is not None:
            out["cross_boresight_arcsec"][k], out["roll_arcsec"][k] = error[0] * arcsec, error[1] * arcsec
        if f.covariance is not None:
            variance = np.diag(np.asarray(f.covariance, dtype=float))
            out["sigma_cross_arcsec"][k] = np.sqrt(max(variance[0] + variance[1], 0.0)) * arcsec
            out["sigma_roll_arcsec"][k] = np.sqrt(max(variance[2], 0.0)) * arcsec
        if f.rate is not None:
            out["rate_deg_s"][k] = np.degrees(f.rate)
        if f.truth_rate is not None:
            out["true_rate_deg_s"][k] = np.degrees(f.truth_rate)
    return out
