"""Pictures for people: frames with identified stars circled and labelled (OpenCV only)."""
from __future__ import annotations

import cv2
import numpy as np


def stretch(image: np.ndarray) -> np.ndarray:
    """Display stretch of a raw frame to 8-bit: background at ~10 % grey, asinh compression
    so faint stars and bright stars are both visible."""
    data = image.astype(np.float32)
    background = float(np.median(data))
    noise = float(1.4826 * np.median(np.abs(data - background))) or 1.0
    scaled = np.arcsinh(np.maximum(data - background, -2 * noise) / (3.0 * noise))
    top = float(np.percentile(scaled, 99.99)) or 1.0
    return np.clip(25.0 + 230.0 * scaled / top, 0, 255).astype(np.uint8)


def annotate_frame(image: np.ndarray, pixel_x: np.ndarray, pixel_y: np.ndarray, hip: np.ndarray,
                   title: str = "", spots_xy: np.ndarray | None = None) -> np.ndarray:
    """BGR picture: detected spots as small grey squares, identified stars as green circles
    labelled with their HIP number, and a title band above the frame."""
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
