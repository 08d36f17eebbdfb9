# SPDX-License-Identifier: Apache-2.0
"""
Star-field rendering.

Radiometry, pixel-integrated Gaussian PSF, motion smear over the exposure (global or rolling
shutter), frame-transfer smear, detector effects and noise, with the parameters of
sensor.SensorModel and FalseObjectModel; every frame comes with its truth. Given a per-frame
environment.Environment, the frame also shows what the Sun, the Earth, the Moon and the
planets do to it (environment.EnvironmentModel); without one it is as it always was.

Units: electrons [e-] inside, ADU on output; angles in radians; times in seconds. Equations
are in docs/SIMULATOR.md. A frame is reproducible from (fixed-pattern seed, frame seed).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from scipy.special import erf

from ..parameter_spec import parameter, range_problems
from ..models.camera import CameraModel
from ..models.catalog import StarCatalog
from .apparent_directions import SPEED_OF_LIGHT_M_S, apparent_directions  # noqa: F401 (re-exported)
from .blooming import bloom_columns
from .environment import Environment, EnvironmentModel, EnvironmentTruth
from .environment_scene import EnvironmentScene, environment_scene, hidden_stars
from .moon_disc import DiscView
from .sensor import SensorModel
from .stray_light import half_diagonal_px

KIND_STAR, KIND_PLANET, KIND_DEBRIS, KIND_COSMIC_RAY, KIND_HOT_PIXEL, KIND_MOON = 0, 1, 2, 3, 4, 5
PROBES = 17  # times the image path is probed at over an exposure (for its length and its bend)
MAX_AVERAGE_ERROR_PX = 0.005  # the sub-steps' mean position within this of the exposure's mean


@dataclass(frozen=True)
class FalseObjectModel:
    """
    Non-star objects drawn anew each frame.

    Planets: bright points fixed on the sky (they smear like stars), instrument magnitude
    uniform in planet_magnitude_range. Debris: objects moving across the image at
    debris_speed_px_s [px/s] (uniform in the range, random direction), magnitude uniform in
    debris_magnitude_range.
    """

    planets_per_frame: int = parameter(0, "bright non-catalog points per frame", "", 0, 100)
    planet_magnitude_range: tuple[float, float] = parameter((-1.0, 2.0), "planets' instrument magnitude range "
                                                            "(low, high)", "mag")
    debris_per_frame: int = parameter(0, "moving debris streaks per frame", "", 0, 100)
    debris_magnitude_range: tuple[float, float] = parameter((3.0, 6.0), "debris' instrument magnitude range "
                                                            "(low, high)", "mag")
    debris_speed_px_s: tuple[float, float] = parameter((100.0, 1000.0), "debris' image speed range (low, high)",
                                                       "px/s")

    def __post_init__(self) -> None:
        problems = range_problems(self)
        if problems:
            raise ValueError("; ".join(problems))
        for name in ("planet_magnitude_range", "debris_magnitude_range", "debris_speed_px_s"):
            if len(getattr(self, name)) != 2:
                raise ValueError(f"{name} needs 2 values (low, high), got {list(getattr(self, name))}")
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"{name}=({lo}, {hi}) must be finite with low <= high")
        if self.debris_speed_px_s[0] < 0:
            raise ValueError("debris_speed_px_s must be >= 0")


@dataclass(frozen=True)
class FrameTruth:
    """
    What the simulator used for one frame.

    stamp_s: mid-exposure time [s]; rotation: sensor -> ICRS at mid-exposure; body_rate:
    [rad/s] in the sensor frame at mid-exposure. Per object (stars, then planets, debris,
    cosmic rays, hot pixels, the Moon) that can put light on the chip: kind (KIND_*), hip (0
    for non-stars), x, y: pixel position at its own mid-exposure (the row's, under a rolling
    shutter; may lie just off the chip; the Moon's centre) [px]; electrons: expected signal
    including vignetting [e-] (a hot pixel's dark charge); extent_px: length of its track in
    the image over the exposure [px] (the Moon: its diameter plus its track). environment:
    what the Environment did (None when the frame was rendered without one).
    """

    stamp_s: float
    rotation: np.ndarray
    body_rate: np.ndarray
    kind: np.ndarray
    hip: np.ndarray
    x: np.ndarray
    y: np.ndarray
    electrons: np.ndarray
    extent_px: np.ndarray
    environment: EnvironmentTruth | None = None

    def stars(self) -> np.ndarray:
        return self.kind == KIND_STAR


@dataclass(frozen=True)
class RenderedFrame:
    image: np.ndarray  # uint16 (height, width) [ADU]
    truth: FrameTruth
    substeps: int = field(default=1)


class _Listed(NamedTuple):
    """
    FrameTruth's per-object columns for one group of objects (stars and planets, debris, cosmic rays, hot pixels).

    Kind, hip, x, y [px], electrons [e-] before vignetting, extent_px [px].
    """

    kind: np.ndarray
    hip: np.ndarray
    x: np.ndarray
    y: np.ndarray
    electrons: np.ndarray
    extent_px: np.ndarray

    @classmethod
    def cosmic_rays(cls, x: np.ndarray, y: np.ndarray, electrons: np.ndarray, length_px: np.ndarray) -> "_Listed":
        return cls(np.full(x.size, KIND_COSMIC_RAY), np.zeros(x.size, np.int32), x, y, electrons, length_px)


class _SkyObjects(NamedTuple):
    """
    Objects fixed on the sky in one frame.

    Vectors (N, 3) apparent ICRS unit vectors, electrons (N,) expected per exposure [e-],
    kind (KIND_STAR / KIND_PLANET), hip (0 for planets); occulted_hip: catalog stars near
    the field that the Earth or the Moon hide (none without an environment).
    """

    vectors: np.ndarray
    electrons: np.ndarray
    kind: np.ndarray
    hip: np.ndarray
    occulted_hip: np.ndarray


class _Debris(NamedTuple):
    """
    One frame's debris.

    Tracks u, v (n, steps) [px] over the exposure, step_electrons (n, steps) [e-] per step,
    and their truth listing (at mid-exposure, track length).
    """

    u: np.ndarray
    v: np.ndarray
    step_electrons: np.ndarray
    listed: _Listed


def frame_seed(seed: int, frame_index: int) -> int:
    """32-bit seed of frame `frame_index` from a scenario seed (independent streams)."""
    return int(np.random.SeedSequence([int(seed), int(frame_index)]).generate_state(1)[0])


class StarFieldRenderer:
    """
    Renders frames for a camera, sensor, catalog (stars to a magnitude limit) and false objects.

    The fixed pattern (PRNU, DSNU, hot pixels) is drawn once from `fixed_pattern_seed`.
    observer_velocity_m_s: ICRS velocity of the spacecraft for stellar aberration [m/s] in
    frames rendered without an environment (an Environment brings its own per frame);
    environment_model: what a frame's Environment does (its effects' switches and parameters).
    """

    def __init__(self, camera: CameraModel, sensor: SensorModel, catalog: StarCatalog,
                 magnitude_limit: float = 7.5, false_objects: FalseObjectModel = FalseObjectModel(),
                 fixed_pattern_seed: int = 0, observer_velocity_m_s=(0.0, 0.0, 0.0), max_substep_px: float = 0.5,
                 environment_model: EnvironmentModel = EnvironmentModel()):
        self.camera, self.sensor, self.false_objects = camera, sensor, false_objects
        self.environment_model = environment_model
        self.catalog = catalog.brighter_than(magnitude_limit)
        self.catalog_vectors = self.catalog.unit_vectors()  # geometric (ICRS) directions
        self.star_vectors = apparent_directions(self.catalog_vectors, observer_velocity_m_s)
        self.star_electrons = sensor.star_electrons(self.catalog.hp, self.catalog.b_v)
        self.max_substep_px = max_substep_px
        self._half = int(np.ceil(4.0 * sensor.psf_sigma_px)) + 1
        self._cos_search = np.cos(min(camera.half_diagonal_fov_rad + 0.05, np.pi / 2))
        self._build_fixed_pattern(fixed_pattern_seed)

    # ------------------------------------------------------------------ static maps
    def _build_fixed_pattern(self, seed: int) -> None:
        cam, sensor = self.camera, self.sensor
        # One stream per pattern: switching one effect off leaves the others unchanged.
        prnu_rng, dsnu_rng, hot_rng = (np.random.default_rng([int(seed), 0xF1A7, k]) for k in range(3))
        yy, xx = np.mgrid[0:cam.height, 0:cam.width].astype(np.float32)
        r2 = ((xx - cam.cx) ** 2 + (yy - cam.cy) ** 2) / max((cam.width / 2) ** 2 + (cam.height / 2) ** 2, 1.0)
        self.vignetting = (1.0 - sensor.vignetting_at_corner * r2).astype(np.float32)
        prnu = (1.0 + sensor.prnu_fraction * prnu_rng.standard_normal((cam.height, cam.width))).astype(np.float32)
        self.response = self.vignetting * np.maximum(prnu, 0.0)
        dark = np.full((cam.height, cam.width), sensor.dark_e_per_px_s_at_temperature, np.float32)
        if sensor.dsnu_fraction > 0:
            s = sensor.dsnu_fraction
            dark *= dsnu_rng.lognormal(-0.5 * s * s, s, dark.shape).astype(np.float32)  # mean 1
        hot = hot_rng.random(dark.shape) < sensor.hot_pixel_fraction
        dark[hot] *= sensor.hot_pixel_dark_factor
        self.hot_pixels = np.flatnonzero(hot)
        hot_x, hot_y = np.stack([self.hot_pixels % cam.width, self.hot_pixels // cam.width]).astype(float)
        gx, gy = sensor.stray_light_gradient_e_per_px2_s
        sky = np.maximum(sensor.background_e_per_px_s + gx * (xx - cam.cx) + gy * (yy - cam.cy), 0.0)
        # Expected electrons per exposure of everything but the objects, and its noise sigma.
        self.static_e = ((sky * self.response + dark) * sensor.exposure_s).astype(np.float32)
        n_hot = self.hot_pixels.size  # listed in every frame's truth with their dark charge
        self._hot_pixels_listed = _Listed(np.full(n_hot, KIND_HOT_PIXEL), np.zeros(n_hot, np.int32), hot_x, hot_y,
                                          self.static_e.reshape(-1)[self.hot_pixels].astype(float), np.zeros(n_hot))
        self.static_sigma = np.sqrt(self.static_e + sensor.read_noise_e ** 2).astype(np.float32)
        self._noise = np.empty((cam.height, cam.width), np.float32)
        scale = half_diagonal_px(cam)  # stray-light planes' coordinates: offsets over the half diagonal
        self._x_norm = ((np.arange(cam.width) - cam.cx) / scale).astype(np.float32)
        self._y_norm = ((np.arange(cam.height) - cam.cy) / scale).astype(np.float32)

    # ------------------------------------------------------------------ rendering
    def render(self, motion, stamp_s: float, seed: int, environment: Environment | None = None) -> RenderedFrame:
        """
        Render the exposure centred on stamp_s [s] (the middle row's mid-exposure).

        motion: provides rotations_at(times) -> (K, 3, 3) sensor->ICRS and
        angular_velocity_at(t) -> (3,) [rad/s]; seed: frame seed (see frame_seed). The random
        draws come in a fixed order (planets, debris, detector noise, cosmic rays), so a frame
        is reproducible from its seed. environment: the bodies at mid-exposure (None: no
        environment, the frame as without one, bit for bit).
        """
        rng = np.random.default_rng(seed)
        rot_mid = motion.rotations_at(np.array([stamp_s]))[0]
        body_rate = np.asarray(motion.angular_velocity_at(stamp_s), dtype=float)
        scene = None
        if environment is not None:
            scene = environment_scene(DiscView(self.camera, self.sensor, rot_mid, self.environment_model), environment)

        sky = self._sky_objects(rot_mid, rng, environment, scene)
        vectors, step_electrons = self._with_moon(sky, scene)
        offsets = self._substep_offsets(motion, stamp_s, rot_mid)
        substeps = offsets.size
        u, v, u_mid, v_mid = self._sky_tracks(motion, rot_mid, vectors, stamp_s, offsets,
                                              self.sensor.rolling_shutter_row_time_s)
        extent = (np.nan_to_num(np.hypot(u[:, -1] - u[:, 0], v[:, -1] - v[:, 0]), nan=0.0)
                  * substeps / max(substeps - 1, 1))
        n = sky.electrons.size
        listed = [_Listed(sky.kind, sky.hip, u_mid[:n], v_mid[:n], sky.electrons, extent[:n])]
        debris = self._debris(rng, substeps) if self.false_objects.debris_per_frame else None
        if debris is not None:
            listed.append(debris.listed)

        signal = self._collected_light(u, v, step_electrons / substeps, debris)
        stray = self._stray_map(scene)
        image_e = self._detector(signal, rng, seed, stray)
        listed.append(self._cosmic_rays(image_e, rng))
        listed.append(self._hot_pixels_listed)
        environment_truth = None
        if scene is not None:
            if scene.moon is not None:  # its centre is the last sky track
                listed.append(_Listed(np.array([KIND_MOON]), np.zeros(1, np.int32), u_mid[-1:], v_mid[-1:],
                                      np.array([scene.moon.total_e]), 2.0 * scene.moon.radius_px + extent[-1:]))
            if self.environment_model.blooming:
                bloom_columns(image_e, self.sensor.full_well_e)
            environment_truth = self._environment_truth(scene, sky)
        truth = self._frame_truth(stamp_s, rot_mid, body_rate, listed, environment_truth)
        return RenderedFrame(image=self._digitize(image_e), truth=truth, substeps=substeps)

    @staticmethod
    def _with_moon(sky: _SkyObjects, scene: EnvironmentScene | None) -> tuple[np.ndarray, np.ndarray]:
        """
        Return the directions (N, 3) and electrons per exposure (N,) [e-] of everything fixed on the sky.

        The sky objects, then the Moon's disc samples and its centre (no light of its own: the
        truth's position) when the Moon is in the frame.
        """
        if scene is None or scene.moon is None:
            return sky.vectors, sky.electrons
        moon = scene.moon
        return (np.concatenate([sky.vectors, moon.vectors, moon.centre[None, :]]),
                np.concatenate([sky.electrons, moon.electrons, np.zeros(1)]))

    def _environment_truth(self, scene: EnvironmentScene, sky: _SkyObjects) -> EnvironmentTruth:
        """Return what the environment did: geometry, stray light, blinding, the Moon's size, hidden stars."""
        stray = scene.stray
        return EnvironmentTruth(
            head=scene.head, stray_light_e=stray.levels_e,
            blinded=bool(stray.level_e > 0.0 and stray.level_e - stray.swing_e(self.camera) >= self.sensor.full_well_e),
            moon_radius_px=np.nan if scene.moon is None else scene.moon.radius_px, occulted_hip=sky.occulted_hip)

    def _stray_map(self, scene: EnvironmentScene | None) -> np.ndarray | None:
        """Return the stray-light electrons per pixel (H, W) float32 of this frame [e-], or None when there is none."""
        if scene is None or scene.stray.level_e <= 0.0:
            return None
        plane = scene.stray
        row = np.float32(plane.level_e) + np.float32(plane.gradient_x_e) * self._x_norm
        return row[None, :] + (np.float32(plane.gradient_y_e) * self._y_norm)[:, None]

    def _sky_objects(self, rot_mid: np.ndarray, rng: np.random.Generator, environment: Environment | None = None,
                     scene: EnvironmentScene | None = None) -> _SkyObjects:
        """
        Objects fixed on the sky.

        Catalog stars near the boresight (less those the Earth or the Moon hide), then the
        environment's planets, then this frame's random planets (drawn uniformly over the
        image at mid-exposure).
        """
        cam, sensor, fo = self.camera, self.sensor, self.false_objects
        vectors, hip, occulted_hip = self._catalog_stars(rot_mid, environment, scene)
        electrons = [self.star_electrons[hip]]
        kinds = [np.full(hip.size, KIND_STAR)]
        hips = [self.catalog.hip[hip]]
        vectors = [vectors]
        if scene is not None:
            vectors.append(scene.planet_vectors)
            electrons.append(scene.planet_electrons)
            kinds.append(np.full(scene.planet_electrons.size, KIND_PLANET))
            hips.append(np.zeros(scene.planet_electrons.size, np.int32))
        if fo.planets_per_frame:
            px = rng.uniform(0, cam.width - 1, fo.planets_per_frame)
            py = rng.uniform(0, cam.height - 1, fo.planets_per_frame)
            vectors.append(cam.pixel_to_ray(px, py) @ rot_mid.T)
            electrons.append(sensor.star_electrons(rng.uniform(*fo.planet_magnitude_range, fo.planets_per_frame)))
            kinds.append(np.full(fo.planets_per_frame, KIND_PLANET))
            hips.append(np.zeros(fo.planets_per_frame, np.int32))
        return _SkyObjects(np.concatenate(vectors), np.concatenate(electrons), np.concatenate(kinds),
                           np.concatenate(hips), occulted_hip)

    def _catalog_stars(self, rot_mid: np.ndarray, environment: Environment | None,
                       scene: EnvironmentScene | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        Return the apparent directions (N, 3) and catalog indices (N,) of the stars near the boresight, and hidden HIPs.

        Without an environment: the directions aberrated once with the constructor's velocity.
        With one: the stars the Earth (+ atmosphere) or the Moon hide (tested on geometric
        directions) are left out, the rest aberrated with the Environment's velocity.
        """
        if environment is None:
            near = np.flatnonzero(self.star_vectors @ rot_mid[:, 2] > self._cos_search)
            return self.star_vectors[near], near, np.zeros(0, np.int32)
        near = np.flatnonzero(self.catalog_vectors @ rot_mid[:, 2] > self._cos_search)
        view = DiscView(self.camera, self.sensor, rot_mid, self.environment_model)
        hidden = hidden_stars(scene, self.catalog_vectors[near], environment, view)
        shown = near[~hidden]
        vectors = self.catalog_vectors[shown]
        if self.environment_model.aberration:
            vectors = apparent_directions(vectors, environment.observer_velocity_m_s)
        return vectors, shown, self.catalog.hip[near[hidden]].astype(np.int32)

    def _substep_offsets(self, motion, stamp_s: float, rot_mid: np.ndarray) -> np.ndarray:
        """
        Sub-step times relative to mid-exposure (K,) [s]: no object moves more than max_substep_px between two of them.

        The image path of the corners and centre over the exposure bounds it (roll moves the
        centre not at all). A path that bends (jitter, an angular acceleration) is sampled
        finely enough too that the sub-steps' mean position is the exposure's to
        MAX_AVERAGE_ERROR_PX: the midpoint rule's error is h^2 |p''| / 24 for sub-steps h apart,
        |p''| [px/s^2] from the probed path's second differences. (Sampled only by its extent,
        1-20" of jitter at 5 Hz got 1-3 sub-steps, whose mean missed the exposure's by up to
        0.1 px: a truth the image did not hold.)
        """
        cam, exposure = self.camera, self.sensor.exposure_s
        row_time = self.sensor.rolling_shutter_row_time_s
        span = exposure + abs(row_time) * cam.height
        probe_times = stamp_s + np.linspace(-0.5, 0.5, PROBES) * span
        probe_px = self._probe_paths(motion.rotations_at(probe_times), rot_mid)
        smear_px = float(np.max(np.sum(np.linalg.norm(np.diff(probe_px, axis=1), axis=2), axis=1)))
        substeps = np.ceil(smear_px / self.max_substep_px)
        step = span / (PROBES - 1)
        bend = np.linalg.norm(probe_px[:, 2:] - 2.0 * probe_px[:, 1:-1] + probe_px[:, :-2], axis=2) / step ** 2
        bend_px_s2 = float(np.max(bend)) if np.all(np.isfinite(bend)) else 0.0
        substeps = max(substeps, np.ceil(exposure * np.sqrt(bend_px_s2 / (24.0 * MAX_AVERAGE_ERROR_PX))))
        substeps = int(min(400, max(1, substeps)))
        return ((np.arange(substeps) + 0.5) / substeps - 0.5) * exposure

    def _debris(self, rng: np.random.Generator, substeps: int) -> _Debris:
        """
        Return this frame's debris.

        Straight tracks in the image (their angular motion dominates the attitude's),
        sampled finely enough that a step moves at most max_substep_px.
        """
        cam, sensor, fo = self.camera, self.sensor, self.false_objects
        exposure = sensor.exposure_s
        n = fo.debris_per_frame
        p0 = np.column_stack([rng.uniform(0, cam.width - 1, n), rng.uniform(0, cam.height - 1, n)])
        speed = rng.uniform(*fo.debris_speed_px_s, n)
        heading = rng.uniform(0, 2 * np.pi, n)
        total_e = sensor.star_electrons(rng.uniform(*fo.debris_magnitude_range, n))
        steps = int(min(2000, max(substeps, np.ceil(speed.max() * exposure / self.max_substep_px))))
        t = ((np.arange(steps) + 0.5) / steps - 0.5) * exposure
        return _Debris(u=p0[:, 0:1] + (speed * np.cos(heading))[:, None] * t[None],
                       v=p0[:, 1:2] + (speed * np.sin(heading))[:, None] * t[None],
                       step_electrons=np.repeat((total_e / steps)[:, None], steps, axis=1),
                       listed=_Listed(np.full(n, KIND_DEBRIS), np.zeros(n, np.int32), p0[:, 0], p0[:, 1], total_e,
                                      speed * exposure))

    def _collected_light(self, u: np.ndarray, v: np.ndarray, sky_step_electrons: np.ndarray,
                         debris: _Debris | None) -> np.ndarray:
        """
        Return the expected signal electrons (H, W) [e-] collected over the exposure.

        The sky tracks u, v (N, K) [px] with sky_step_electrons (N,) per sub-step, the debris
        tracks, then vignetting, PRNU and frame-transfer smear.
        """
        cam, sensor = self.camera, self.sensor
        signal = np.zeros((cam.height, cam.width), np.float32)
        per_step = np.broadcast_to(sky_step_electrons[:, None], u.shape)
        visible = cam.in_image(u, v, margin=-self._half)  # False for NaN (behind the camera)
        seen = visible.any(axis=1)
        self._accumulate(signal, np.where(visible, u, np.nan)[seen], v[seen], per_step[seen])
        if debris is not None:
            self._accumulate(signal, debris.u, debris.v, debris.step_electrons)
        signal *= self.response  # vignetting and PRNU act on collected light
        if sensor.frame_transfer_time_s > 0:
            # During transfer every pixel of a column sees each row's light for t_ft / H.
            signal += (signal.sum(axis=0) * (sensor.frame_transfer_time_s / (sensor.exposure_s * cam.height)))[None, :]
        return signal

    def _frame_truth(self, stamp_s: float, rot_mid: np.ndarray, body_rate: np.ndarray,
                     listed: list[_Listed], environment: EnvironmentTruth | None = None) -> FrameTruth:
        """
        Return the FrameTruth of the objects that can put light on the chip (PSF wings and streaks included).

        Their expected electrons scaled by the vignetting where they land.
        """
        cam = self.camera
        u_all = np.concatenate([group.x for group in listed])
        v_all = np.concatenate([group.y for group in listed])
        kind = np.concatenate([group.kind for group in listed])
        hip = np.concatenate([group.hip for group in listed]).astype(np.int32)
        expected = np.concatenate([group.electrons for group in listed])
        extent = np.concatenate([group.extent_px for group in listed])
        on_chip = cam.in_image(u_all, v_all, margin=-(self._half + 0.5 * extent)) & np.isfinite(u_all)
        vign = np.ones(u_all.size)
        ui = np.clip(np.rint(u_all[on_chip]).astype(int), 0, cam.width - 1)
        vi = np.clip(np.rint(v_all[on_chip]).astype(int), 0, cam.height - 1)
        vign[on_chip] = self.vignetting[vi, ui]
        vign[kind >= KIND_COSMIC_RAY] = 1.0  # deposited in the silicon, not collected light
        return FrameTruth(stamp_s=stamp_s, rotation=rot_mid, body_rate=body_rate, kind=kind[on_chip], hip=hip[on_chip],
                          x=u_all[on_chip], y=v_all[on_chip], electrons=(expected * vign)[on_chip],
                          extent_px=extent[on_chip], environment=environment)

    def _probe_paths(self, rotations: np.ndarray, rot_mid: np.ndarray):
        """
        Return image positions (P, K, 2) over `rotations` of the sky directions at the image corners and centre.

        The directions are those at the corners and the centre at mid-exposure.
        """
        cam = self.camera
        px = np.array([0, cam.width - 1, 0, cam.width - 1, cam.cx], dtype=float)
        py = np.array([0, 0, cam.height - 1, cam.height - 1, cam.cy], dtype=float)
        directions = cam.pixel_to_ray(px, py) @ rot_mid.T
        u, v, _ = cam.project(np.einsum("kji,pj->pki", rotations, directions))
        return np.stack([u, v], axis=-1)

    def _sky_tracks(self, motion, rot_mid, vectors, stamp_s, offsets, row_time):
        """
        Pixel tracks (N, K) of sky-fixed objects over the exposure, and their positions at their own mid-exposure.

        Under a rolling shutter each object's exposure is shifted by its row's delay; tracks
        are then interpolated on a common time grid.
        """
        cam = self.camera
        u_mid, v_mid, front = cam.project(vectors @ rot_mid)
        u_mid = np.where(front, u_mid, np.nan)
        v_mid = np.where(front, v_mid, np.nan)
        if row_time == 0.0 or vectors.shape[0] == 0:
            rotations = motion.rotations_at(stamp_s + offsets)
            rays = np.einsum("kji,nj->nki", rotations, vectors)
            u, v, front = cam.project(rays)
            return np.where(front, u, np.nan), np.where(front, v, np.nan), u_mid, v_mid
        # Row delay of each object, from its row at the frame's mid time (iterated once).
        delay = (np.nan_to_num(v_mid, nan=cam.cy) - (cam.height - 1) / 2) * row_time
        half_span = abs(row_time) * cam.height / 2 + offsets.max() + 1e-9
        step = (offsets[1] - offsets[0]) if offsets.size > 1 else half_span
        grid = np.arange(-half_span, half_span + step, step)
        rotations = motion.rotations_at(stamp_s + grid)
        rays = np.einsum("kji,nj->nki", rotations, vectors)
        gu, gv, gfront = cam.project(rays)
        gu, gv = np.where(gfront, gu, np.nan), np.where(gfront, gv, np.nan)

        def sample(times):  # linear interpolation of each object's track at its own times
            f = np.clip((times - grid[0]) / step, 0, grid.size - 1 - 1e-9)
            i = np.floor(f).astype(int)
            w = f - i
            rows = np.arange(vectors.shape[0])[:, None]
            return (gu[rows, i] * (1 - w) + gu[rows, i + 1] * w, gv[rows, i] * (1 - w) + gv[rows, i + 1] * w)

        own_mid_u, own_mid_v = sample(delay[:, None])
        delay = (np.nan_to_num(own_mid_v[:, 0], nan=cam.cy) - (cam.height - 1) / 2) * row_time
        u, v = sample(delay[:, None] + offsets[None, :])
        own_mid_u, own_mid_v = sample(delay[:, None])
        return u, v, own_mid_u[:, 0], own_mid_v[:, 0]

    def _accumulate(self, signal: np.ndarray, u: np.ndarray, v: np.ndarray, electrons: np.ndarray) -> None:
        """
        Add objects' smeared, pixel-integrated Gaussian PSFs to `signal` (H, W) in place.

        u, v, electrons: (N, K) track of each object over K sub-steps [px] (NaN = not visible)
        and the electrons of each sub-step. Each pixel gets the PSF integral over its area
        (separable: erf differences along x and y), so over an object's bounding box the
        smeared image is sum_k e_k py_k (x) px_k = PY^T diag(e) PX. All objects are done as
        one batched matrix product over a common window size, then one scatter-add.
        """
        cam, half = self.camera, self._half
        finite = np.isfinite(u) & np.isfinite(v)
        keep = finite.any(axis=1)
        if not keep.any():
            return
        u, v, finite = u[keep], v[keep], finite[keep]
        electrons = np.where(finite, electrons[keep], 0.0)
        # Invisible sub-steps carry no light; park them on a visible one so erf stays finite.
        u = np.where(finite, u, np.nanmean(np.where(finite, u, np.nan), axis=1, keepdims=True))
        v = np.where(finite, v, np.nanmean(np.where(finite, v, np.nan), axis=1, keepdims=True))
        c0 = np.floor(u.min(axis=1)).astype(np.int64) - half
        r0 = np.floor(v.min(axis=1)).astype(np.int64) - half
        n_cols = int(np.max(np.ceil(u.max(axis=1)).astype(np.int64) + half - c0)) + 1
        n_rows = int(np.max(np.ceil(v.max(axis=1)).astype(np.int64) + half - r0)) + 1
        scale = 1.0 / (np.sqrt(2.0) * self.sensor.psf_sigma_px)
        k = u.shape[1]
        chunk = max(1, int(4_000_000 // max(k * (n_cols + n_rows) + n_rows * n_cols, 1)))
        flat_signal = signal.reshape(-1)
        for start in range(0, u.shape[0], chunk):
            sl = slice(start, start + chunk)
            cols = c0[sl, None] + np.arange(n_cols)[None, :]
            rows = r0[sl, None] + np.arange(n_rows)[None, :]
            # erf at pixel edges, differenced: the PSF integral per pixel (x2 each axis).
            col_edges = np.concatenate([cols, cols[:, -1:] + 1], axis=1) - 0.5
            row_edges = np.concatenate([rows, rows[:, -1:] + 1], axis=1) - 0.5
            px = np.diff(erf((col_edges[:, None, :] - u[sl, :, None]) * scale), axis=2)  # (n, K, C)
            py = np.diff(erf((row_edges[:, None, :] - v[sl, :, None]) * scale), axis=2)  # (n, K, R)
            blocks = 0.25 * np.matmul((py * electrons[sl, :, None]).transpose(0, 2, 1), px)  # (n, R, C)
            valid = ((rows >= 0) & (rows < cam.height))[:, :, None] & ((cols >= 0) & (cols < cam.width))[:, None, :]
            flat = (rows[:, :, None] * cam.width + cols[:, None, :])[valid]
            np.add.at(flat_signal, flat, blocks[valid].astype(np.float32))  # no full-frame pass

    def _detector(self, signal: np.ndarray, rng: np.random.Generator, seed: int,
                  stray: np.ndarray | None = None) -> np.ndarray:
        """
        Electrons read out: expected static level (+ stray light) + signal with shot and read noise.

        Pixels with object signal get exact Poisson draws of (signal + static level). Elsewhere
        shot noise of the static level (sky + dark + stray light, tens of e- or more) and read
        noise are one Gaussian of the exact variance, drawn with OpenCV's fast generator seeded
        per frame.
        """
        sensor = self.sensor
        static_e = self.static_e if stray is None else self.static_e + stray
        if not sensor.noise:
            return static_e + signal
        cv2.setRNGSeed(seed & 0x7FFFFFFF)
        cv2.randn(self._noise, 0.0, 1.0)
        if stray is None:
            electrons = static_e + self.static_sigma * self._noise
        else:  # the sigma of this frame's static level, in place (the full frame, once more)
            electrons = static_e + np.float32(sensor.read_noise_e ** 2)
            np.sqrt(electrons, out=electrons)
            electrons *= self._noise
            electrons += static_e
        lit = np.flatnonzero(signal > 0.05)
        flat = electrons.reshape(-1)
        lam = signal.reshape(-1)[lit] + static_e.reshape(-1)[lit]
        flat[lit] = rng.poisson(lam) + sensor.read_noise_e * self._noise.reshape(-1)[lit]
        return electrons

    def _cosmic_rays(self, electrons: np.ndarray, rng: np.random.Generator) -> _Listed:
        """
        Add cosmic-ray tracks (straight, 1-15 px, exponential energy) in place.

        Returns their listing: centres x, y [px], deposited charge [e-] and track length [px].
        """
        cam, sensor = self.camera, self.sensor
        area_cm2 = cam.width * cam.height * (sensor.pixel_pitch_m * 100.0) ** 2
        count = rng.poisson(sensor.cosmic_ray_rate_per_cm2_s * area_cm2 * sensor.exposure_s)
        if count == 0:
            return _Listed.cosmic_rays(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))
        centre = np.column_stack([rng.uniform(0, cam.width - 1, count), rng.uniform(0, cam.height - 1, count)])
        length = rng.uniform(1.0, 15.0, count)
        heading = rng.uniform(0, np.pi, count)
        energy = rng.exponential(sensor.cosmic_ray_electrons, count)
        for (cx, cy), ell, h, e in zip(centre, length, heading, energy):
            steps = max(2, int(np.ceil(ell * 2)))
            s = np.linspace(-ell / 2, ell / 2, steps)
            cols = np.clip(np.rint(cx + s * np.cos(h)).astype(int), 0, cam.width - 1)
            rows = np.clip(np.rint(cy + s * np.sin(h)).astype(int), 0, cam.height - 1)
            np.add.at(electrons, (rows, cols), e / steps)
        return _Listed.cosmic_rays(centre[:, 0], centre[:, 1], energy, length)

    def _digitize(self, electrons: np.ndarray) -> np.ndarray:
        """
        Full-well clip (blooming, when on, has spilled the excess before), gain, bias, rounding, ADC range -> uint16.

        `electrons` already holds read noise, which comes from the output amplifier and may
        be negative (that is what the bias is for): only the ADC range clips the low end.
        """
        sensor = self.sensor
        np.minimum(electrons, sensor.full_well_e, out=electrons)
        electrons *= 1.0 / sensor.gain_e_per_adu
        electrons += sensor.bias_adu + 0.5  # + 0.5 then truncation = rounding
        np.clip(electrons, 0.0, sensor.max_adu + 0.5, out=electrons)
        return electrons.astype(np.uint16)
