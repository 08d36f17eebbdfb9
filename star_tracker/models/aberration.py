# SPDX-License-Identifier: Apache-2.0
"""
Apparent directions of starlight for a moving observer: stellar aberration and the Sun's light deflection.

Aberration is exact special relativity (a Lorentz boost of the light's direction), ERFA's eraAb
without its 2e-8 solar-potential term (< 1e-6 arcsec): for a unit direction n to the source
(astrometric, "natural") and the observer's velocity beta = v / c relative to the barycentric frame,

    n' = (n / gamma + (1 + (n . beta) gamma / (1 + gamma)) beta) / (1 + n . beta),

unit-norm by construction; n' leans toward the velocity, by ~20.5 arcsec at 30 km/s. The
velocity is the observer's total barycentric velocity [m/s], ICRS axes: the Earth's
(Ephemeris.earth_velocity) plus the orbital velocity (GCRS, from the orbit's state). unaberrate
is its exact inverse (the boost by -beta).

Light deflection by the Sun's gravity is ERFA's eraLdsun (with ERFA's limiter for directions near
the Sun's centre): 1.75 arcsec at the limb, 4 mas at 90 deg from the Sun. apparent_directions
applies deflection then aberration, as ERFA's eraAtciqz does for a star (astropy's ICRS -> GCRS);
astrometric_directions undoes both. Solar-system bodies get aberration only (their light-time
corrected vectors come from models/ephemeris.py). Directions are
(N, 3) or (3,) unit vectors on ICRS axes; results have the same shape.
"""
from __future__ import annotations

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0
ASTRONOMICAL_UNIT_M = 149_597_870_700.0
SUN_SCHWARZSCHILD_RADIUS_AU = 1.97412574336e-8  # 2 G M_sun / c^2 [au] (ERFA's ERFA_SRS)
# undeflect_by_sun's fixed-point steps: each gains a factor ~ deflection / elongation (< 4e-4 outside
# the Sun's disc, < 0.02 at ERFA's limiter inside it).
_UNDEFLECT_MAX_STEPS = 30
_UNDEFLECT_TOLERANCE_RAD = 1e-15


def _directions(directions, name: str = "directions") -> np.ndarray:
    d = np.asarray(directions, dtype=float)
    if d.ndim not in (1, 2) or d.shape[-1] != 3 or not np.all(np.isfinite(d)):
        raise ValueError(f"{name} must be finite unit vectors of shape (3,) or (N, 3), got shape {d.shape}")
    norm = np.linalg.norm(d, axis=-1)
    if np.any(np.abs(norm - 1.0) > 1e-6):
        raise ValueError(f"{name} must be unit vectors (norms within 1e-6 of 1), got norms up to "
                         f"{float(np.max(np.abs(norm - 1.0))):.3g} away")
    return d / norm[..., None]


def _vector(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite (3,) vector, got {value!r}")
    return v


def aberrate(directions, velocity_m_s) -> np.ndarray:
    """
    Apparent directions seen by an observer moving at velocity_m_s (see the module docstring).

    directions: (N, 3) or (3,) astrometric unit vectors (ICRS axes); velocity_m_s: (3,) the
    observer's barycentric velocity [m/s], |v| < c. Returns unit vectors of the same shape.
    """
    n = _directions(directions)
    beta = _vector(velocity_m_s, "velocity_m_s") / SPEED_OF_LIGHT_M_S
    beta2 = float(beta @ beta)
    if beta2 >= 1.0:
        raise ValueError(f"velocity_m_s must be slower than light, got {np.sqrt(beta2) * SPEED_OF_LIGHT_M_S} m/s")
    inv_gamma = np.sqrt(1.0 - beta2)
    n_beta = n @ beta
    apparent = inv_gamma * n + (1.0 + n_beta / (1.0 + inv_gamma))[..., None] * beta
    return apparent / np.linalg.norm(apparent, axis=-1, keepdims=True)


def unaberrate(directions, velocity_m_s) -> np.ndarray:
    """Exact inverse of aberrate: astrometric unit vectors from apparent ones (the boost by -velocity)."""
    return aberrate(directions, -_vector(velocity_m_s, "velocity_m_s"))


def _deflection_terms(sun_from_observer_m) -> tuple[np.ndarray, float, float]:
    """Return the unit vector Sun -> observer, the ERFA deflection scale and its limiter."""
    s = _vector(sun_from_observer_m, "sun_from_observer_m")
    distance = float(np.linalg.norm(s))
    if distance == 0.0:
        raise ValueError("sun_from_observer_m must be non-zero")
    em = distance / ASTRONOMICAL_UNIT_M
    # eraLdsun's limiter: q . (q + e) is kept >= 1e-6 / max(em^2, 1) so that a direction through
    # the Sun's centre stays finite.
    return -s / distance, SUN_SCHWARZSCHILD_RADIUS_AU / em, 1e-6 / max(em * em, 1.0)


def deflect_by_sun(directions, sun_from_observer_m) -> np.ndarray:
    """
    Directions bent by the Sun's gravity for a source at infinity (ERFA eraLdsun).

    directions: (N, 3) or (3,) unit vectors to the sources; sun_from_observer_m: (3,) vector from
    the observer to the Sun [m] (e.g. Ephemeris.sun_position(t, observer_m)). A source behind the
    Sun's centre is handled by ERFA's limiter, not as an occultation.
    """
    p = _directions(directions)
    e, scale, limit = _deflection_terms(sun_from_observer_m)
    q_dot_qpe = 1.0 + p @ e  # eraLd with q = p (source at infinity): q . (q + e)
    w = scale / np.maximum(q_dot_qpe, limit)
    deflected = p + w[..., None] * np.cross(p, np.cross(e, p))
    return deflected / np.linalg.norm(deflected, axis=-1, keepdims=True)


def undeflect_by_sun(directions, sun_from_observer_m) -> np.ndarray:
    """Inverse of deflect_by_sun by fixed-point iteration (to 1e-15 rad; 3 to 4 steps outside the Sun's disc)."""
    target = _directions(directions)
    p = target
    for _ in range(_UNDEFLECT_MAX_STEPS):
        step = target - deflect_by_sun(p, sun_from_observer_m)
        p = p + step
        p = p / np.linalg.norm(p, axis=-1, keepdims=True)
        if np.max(np.abs(step)) < _UNDEFLECT_TOLERANCE_RAD:
            break
    return p


def apparent_directions(directions, velocity_m_s, sun_from_observer_m=None) -> np.ndarray:
    """
    Apparent directions of stars: deflection by the Sun (if sun_from_observer_m is given), then aberration.

    directions: (N, 3) or (3,) astrometric (catalog, ICRS) unit vectors; velocity_m_s: (3,) the
    observer's barycentric velocity [m/s]; sun_from_observer_m: (3,) vector observer -> Sun [m], or
    None to skip deflection (< 0.01 arcsec farther than 40 deg from the Sun).
    """
    p = directions if sun_from_observer_m is None else deflect_by_sun(directions, sun_from_observer_m)
    return aberrate(p, velocity_m_s)


def astrometric_directions(directions, velocity_m_s, sun_from_observer_m=None) -> np.ndarray:
    """Inverse of apparent_directions: catalog (astrometric) unit vectors of apparent ones."""
    p = unaberrate(directions, velocity_m_s)
    return p if sun_from_observer_m is None else undeflect_by_sun(p, sun_from_observer_m)
