# SPDX-License-Identifier: Apache-2.0
"""
Synthetic centroid-list scenes with known truth, for identification tests and benchmarks.

A scene is what a centroider would report for a random attitude: the projected positions of
the catalog stars in the field of view plus Gaussian noise, fluxes from the stars' Hp
magnitudes plus magnitude noise, optionally false stars (uniform over the field, magnitudes
drawn like the real ones') and a cut to the brightest spots. It carries the true rotation
and the HIP id behind every spot (0 for a false star), so results are scored exactly.

The setups of the seed papers are in SETUPS. No image is rendered: these scenes test the
identification stage alone, as the papers do.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models.attitude import radec_roll_to_matrix
from ..models.camera import CameraModel
from ..models.catalog import StarCatalog
from ..centroid import Spots

ARCSEC_RAD = float(np.radians(1.0 / 3600.0))
FLUX_AT_MAG0 = 1.0e6  # flux of an Hp = 0 star in the scenes [arbitrary units]


@dataclass(frozen=True)
class SceneSetup:
    """
    One test setup.

    camera: the pixel grid and optics; fov_radius_rad: circular field stop around the
    boresight (None: the whole rectangular image) [rad]; magnitude_limit: faintest star that
    makes a spot [Hp]; noise_rad: 1-sigma position noise per axis of each spot [rad];
    magnitude_sigma: 1-sigma error of each spot's magnitude [mag]; real_stars: keep only this
    many real stars, chosen at random (None: all; scenes with fewer are redrawn);
    false_stars: added false spots; brightest: keep only the N brightest spots (None: all);
    min_separation_px: stars closer than this merge into the brighter one's spot [px].
    """

    name: str
    camera: CameraModel
    fov_radius_rad: float | None
    magnitude_limit: float
    noise_rad: float
    magnitude_sigma: float = 0.0
    real_stars: int | None = None
    false_stars: int = 0
    brightest: int | None = None
    min_separation_px: float = 3.0
    description: str = ""

    @property
    def noise_px(self) -> float:
        return self.noise_rad / self.camera.pixel_scale_rad


@dataclass(frozen=True)
class Scene:
    """
    spots: the centroid list, brightest first.

    Rotation: true sensor->ICRS matrix; hip: (N,) HIP id behind each spot, 0 for false
    stars; setup: how it was made.
    """

    spots: Spots
    rotation: np.ndarray
    hip: np.ndarray
    setup: SceneSetup = field(repr=False)

    @property
    def real_count(self) -> int:
        return int(np.count_nonzero(self.hip))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed attitude (sensor->ICRS rotation matrix)."""
    return radec_roll_to_matrix(rng.uniform(0, 2 * np.pi), np.arcsin(rng.uniform(-1, 1)), rng.uniform(-np.pi, np.pi))


def _inside_field(setup: SceneSetup, u: np.ndarray, v: np.ndarray, rays: np.ndarray | None = None,
                  beyond_px: float = 0.0) -> np.ndarray:
    """Return True where (u, v) [px] lies in the field (2 px inside the image; the circle) or beyond_px outside it."""
    camera = setup.camera
    inside = camera.in_image(u, v, margin=2.0 - beyond_px)
    if setup.fov_radius_rad is not None:
        if rays is None:
            rays = camera.pixel_to_ray(u, v)
        inside &= rays[..., 2] >= np.cos(setup.fov_radius_rad + beyond_px * camera.pixel_scale_rad)
    return inside


def _random_field_points(setup: SceneSetup, count: int, rng: np.random.Generator,
                         avoid: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """
    Return pixel positions uniform over the field (by rejection).

    Each at least min_separation_px from every position in `avoid` (u, v) [px].
    """
    xs, ys = [], []
    camera, have = setup.camera, 0
    while have < count:
        u = rng.uniform(2.0, camera.width - 3.0, size=4 * count + 8)
        v = rng.uniform(2.0, camera.height - 3.0, size=4 * count + 8)
        keep = _inside_field(setup, u, v)
        if avoid[0].size:
            d = np.hypot(u[:, None] - avoid[0][None], v[:, None] - avoid[1][None])
            keep &= np.all(d >= setup.min_separation_px, axis=1)
        xs.append(u[keep])
        ys.append(v[keep])
        have += int(keep.sum())
    return np.concatenate(xs)[:count], np.concatenate(ys)[:count]


def make_scene(setup: SceneSetup, catalog: StarCatalog, rng: np.random.Generator,
               rotation: np.ndarray | None = None, max_redraws: int = 1000,
               vectors: np.ndarray | None = None) -> Scene:
    """
    One scene for a random (or the given) attitude.

    `catalog` is at the scene epoch. When `real_stars` is set and the field holds fewer
    stars, a new attitude is drawn. vectors: the unit vectors of a catalog already cut to
    the setup's magnitude limit (a caller making many scenes computes them once).
    """
    if vectors is None:
        stars = catalog.brighter_than(setup.magnitude_limit)
        vectors = stars.unit_vectors()
    elif len(vectors) != len(catalog) or catalog.hp.max(initial=-np.inf) > setup.magnitude_limit:
        raise ValueError("vectors must be those of a catalog cut to the setup's magnitude limit")
    else:
        stars = catalog
    camera = setup.camera
    for _ in range(max_redraws):
        truth = random_rotation(rng) if rotation is None else rotation
        body = vectors @ truth  # ICRS -> sensor, as row vectors
        near = np.flatnonzero(body[:, 2] > np.cos(setup.camera.half_diagonal_fov_rad + 0.01))
        u, v, front = camera.project(body[near])
        rays = body[near] / np.linalg.norm(body[near], axis=1, keepdims=True)
        # Stars closer than min_separation_px blend: the brighter one's spot survives, also when
        # the brighter lies just outside the field (a faint star 0.4 px from a bright one at the
        # edge is that star's light, not a spot of its own), so the blends come before the cut.
        around = front & _inside_field(setup, u, v, rays, beyond_px=setup.min_separation_px)
        idx, u, v, rays = near[around], u[around], v[around], rays[around]
        order = np.argsort(stars.hp[idx], kind="stable")
        idx, u, v, rays = idx[order], u[order], v[order], rays[order]
        if idx.size > 1:
            close = np.hypot(u[:, None] - u[None], v[:, None] - v[None]) < setup.min_separation_px
            keep = ~np.any(np.tril(close, k=-1), axis=1)
            idx, u, v, rays = idx[keep], u[keep], v[keep], rays[keep]
        inside = _inside_field(setup, u, v, rays)
        idx, u, v = idx[inside], u[inside], v[inside]
        if setup.real_stars is not None:
            if idx.size < setup.real_stars:
                if rotation is not None:
                    raise ValueError(f"only {idx.size} stars in the field, {setup.real_stars} required")
                continue
            pick = np.sort(rng.choice(idx.size, setup.real_stars, replace=False))
            idx, u, v = idx[pick], u[pick], v[pick]
        break
    else:
        raise RuntimeError(f"no attitude with {setup.real_stars} stars in {max_redraws} draws")

    magnitude = stars.hp[idx].astype(float)
    hip = stars.hip[idx].astype(np.int64)
    if setup.false_stars:
        # A false object on top of a catalog star would be that star: keep them apart.
        all_u, all_v = camera.project(body[near])[:2]
        fu, fv = _random_field_points(setup, setup.false_stars, rng, avoid=(all_u, all_v))
        # False magnitudes follow the sky's own distribution within the limit.
        pool = stars.hp[stars.hp <= setup.magnitude_limit]
        u, v = np.concatenate([u, fu]), np.concatenate([v, fv])
        magnitude = np.concatenate([magnitude, rng.choice(pool, setup.false_stars)])
        hip = np.concatenate([hip, np.zeros(setup.false_stars, np.int64)])
    noise_px = setup.noise_px
    x = u + rng.normal(scale=noise_px, size=u.size)
    y = v + rng.normal(scale=noise_px, size=v.size)
    measured_mag = magnitude + rng.normal(scale=setup.magnitude_sigma,
                                          size=magnitude.size) if setup.magnitude_sigma else magnitude
    flux = FLUX_AT_MAG0 * 10.0 ** (-0.4 * measured_mag)
    order = np.argsort(-flux, kind="stable")
    if setup.brightest is not None:
        order = order[: setup.brightest]
    spots = Spots.from_xy(x[order], y[order], measured_mag[order], sigma_px=max(noise_px, 1e-6), width=camera.width,
                          height=camera.height, flux_at_magnitude_0=FLUX_AT_MAG0)
    hip = hip[order]
    return Scene(spots, truth, hip, setup)


def _circular_camera(fov_diameter_rad: float, pixels: int = 1024) -> CameraModel:
    """Square camera whose inscribed circle is the circular field of view."""
    return CameraModel.from_fov(pixels, pixels, fov_diameter_rad)


NOMINAL_CAMERA = CameraModel.from_fov(1024, 1024, np.radians(15.0))

SETUPS: dict[str, SceneSetup] = {s.name: s for s in (
    SceneSetup("nominal", NOMINAL_CAMERA, None, 6.5, 0.3 * NOMINAL_CAMERA.pixel_scale_rad, 0.1,
               description="15 deg square FOV, 1024^2, Hp <= 6.5, 0.3 px, 0.1 mag"),
    SceneSetup("cole", _circular_camera(np.radians(8.0)), np.radians(4.0), 6.0, 87e-6, 0.1,
               description="Cole & Crassidis Table 2: 8 deg circular FOV, magnitude 6.0, 87 urad per star, 0.1 mag"),
    SceneSetup("cole_false", _circular_camera(np.radians(8.0)), np.radians(4.0), 6.0, 87e-6, 0.1, false_stars=1,
               description="the same with one false star"),
    # Toloei gives no noise figure; 0.1 px is what our centroider reaches on the nominal camera
    # for stars of SNR >= 20 (docs/BENCHMARKS.md, centroiding).
    SceneSetup("toloei_6_50", NOMINAL_CAMERA, None, 6.5, 0.1 * NOMINAL_CAMERA.pixel_scale_rad, 0.1,
               real_stars=6, false_stars=50,
               description="Toloei: 6 real stars among 56 spots (nominal camera, 0.1 px)"),
    SceneSetup("toloei_4_136", NOMINAL_CAMERA, None, 6.5, 0.1 * NOMINAL_CAMERA.pixel_scale_rad, 0.1,
               real_stars=4, false_stars=136,
               description="Toloei: 4 real stars among 140 spots (nominal camera, 0.1 px)"),
    SceneSetup("fast", _circular_camera(np.radians(11.3)), np.radians(11.3 / 2), 7.0, 10.0 * ARCSEC_RAD, 0.3,
               brightest=8,
               description="van Bezooijen FAST: 11.3 deg circular FOV, 10 arcsec, brightest 8 spots, 0.3 mag"),
)}
