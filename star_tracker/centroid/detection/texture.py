# SPDX-License-Identifier: Apache-2.0
"""
Texture: elongated spots that point every way, not a motion's smear.

A cloud bank lit from below (granasat's IMG_007985) gives hundreds of elongated blobs, some
brighter than the faint stars; ranked by flux they fill the fit budget and max_spots and the
stars never reach the identifier. A smear or a trail shares one direction (the axes' mean
resultant length R = |mean exp(2i angle)| is 0.3-0.9 on the real corpus; the cloud texture
reads 0.06). Bloated stars of poor optics can point every way too (the Stellarium
photograph of Sh2-264), so ranking the texture last is a choice (CentroidConfig.texture_last),
made by `star-tracker solve` when a first solve leaves most spots unexplained.
"""
from __future__ import annotations

import numpy as np

from ..spots import FLAG_RATE_AIDED, FLAG_STREAK

TEXTURE_MIN_STREAKS = 30  # at least this many elongated spots ...
TEXTURE_MAX_ALIGNMENT = 0.15  # ... whose axes' mean resultant length is below this


def point_every_way(angles: np.ndarray) -> bool:
    """Whether at least TEXTURE_MIN_STREAKS elongated spots of axis directions `angles` [rad] point every way."""
    angles = np.asarray(angles, float)
    return angles.size >= TEXTURE_MIN_STREAKS and abs(np.mean(np.exp(2j * angles))) < TEXTURE_MAX_ALIGNMENT


def texture_streaks(flags: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """
    Mask of the free streaks (FLAG_STREAK, not rate aided) when they point every way; none otherwise.

    flags: spot flags (Spots.flags); angles: their streak directions [rad].
    """
    free = ((flags & FLAG_STREAK) != 0) & ((flags & FLAG_RATE_AIDED) == 0)
    return free if point_every_way(angles[free]) else np.zeros(np.shape(flags), bool)


def rank_last(items: np.ndarray, last: np.ndarray) -> np.ndarray:
    """Return `items` with those where `last` (bool, same length) moved behind the others, each part in its order."""
    return np.concatenate([items[~last], items[last]])
