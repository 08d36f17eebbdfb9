# SPDX-License-Identifier: Apache-2.0
"""
The image as the centroider's compiled kernels take it.

Read-only and writeable arrays are distinct numba types, and every dtype is another: the
kernels that read the image are compiled (and warmed) once per dtype in WARM_IMAGE_DTYPES and
are always passed a read-only view.
"""
from __future__ import annotations

import numpy as np

WARM_IMAGE_DTYPES = (np.uint16, np.uint8, np.float32)  # what the nodes and the CLI pass to extract_spots


def read_only(image: np.ndarray) -> np.ndarray:
    """
    `image` as a read-only array (a view when it is writeable, no copy).

    Read-only and writeable arrays are distinct numba types: passing one kind halves the
    variants compiled (each took ~10 s at a cold start).
    """
    if not image.flags.writeable:
        return image
    view = image.view()
    view.flags.writeable = False
    return view
