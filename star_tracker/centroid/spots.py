"""The `Spots` record passed from the centroider to the identifier."""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

FLAG_SATURATED = 1 << 0  # a pixel of the spot reached the saturation level
FLAG_EDGE = 1 << 1  # the spot's window touches the image border: position biased inward
FLAG_STREAK = 1 << 2  # measured with the streak model: streak_length / streak_angle are valid
FLAG_BLENDED = 1 << 3  # split from a blend with a neighbour (fitted jointly with it)
FLAG_RATE_AIDED = 1 << 4  # fitted on the smear path predicted from a known body rate


@dataclass(frozen=True)
class Spots:
    """Detected spots as parallel arrays (N entries, brightest first).

    x, y: position at mid-exposure [px], (0, 0) = centre of the top-left pixel; flux:
    background-subtracted signal [ADU]; snr: flux / its 1-sigma [-]; cov: (N, 2, 2) covariance
    of (x, y) [px^2] from the noise model; flags: FLAG_* bit set; area: detection footprint
    [px]; peak: brightest background-subtracted pixel [ADU]; streak_length: length of the
    smear over the exposure [px] (0 for point-like spots); streak_angle: its direction [rad]
    from +x toward +y (start -> end when the body rate is known, else in (-pi/2, pi/2]).
    width, height: image size [px]; background_adu, noise_adu: frame background level and
    1-sigma pixel noise [ADU]; rejected_shape: detections dropped as hot pixels or cosmic rays;
    rate_aid_rejected: a body rate was given but the streaks in the image disagreed with it, so
    the frame was measured without it (extract.AID_* rules).
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    snr: np.ndarray
    cov: np.ndarray
    flags: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    width: int
    height: int
    background_adu: float = 0.0
    noise_adu: float = 0.0
    rejected_shape: int = 0
    streak_length: np.ndarray | None = None
    streak_angle: np.ndarray | None = None
    rate_aid_rejected: bool = False

    def __post_init__(self) -> None:
        n = np.asarray(self.x).size
        for name in ("streak_length", "streak_angle"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.zeros(n))

    def __len__(self) -> int:
        return int(self.x.size)

    @staticmethod
    def empty(width: int, height: int, **frame_values) -> "Spots":
        z = np.zeros(0)
        return Spots(z, z, z, z, np.zeros((0, 2, 2)), np.zeros(0, np.uint32), np.zeros(0, np.int32),
                     z, width, height, **frame_values)

    def take(self, index: np.ndarray) -> "Spots":
        """The spots at `index` (integer or boolean), frame values kept."""
        per_spot = {f.name: getattr(self, f.name)[index] for f in fields(self)
                    if isinstance(getattr(self, f.name), np.ndarray)}
        return replace(self, **per_spot)
