# SPDX-License-Identifier: Apache-2.0
"""
The fault plan of the stress campaign through the nodes (stress_nodes.py), and the frames it renders.

No ROS: a run is planned from its seed alone (missions of random motions and sensor storms, with
per-frame faults drawn into them), so the plan, and every frame's content, are the same on any
host. A mission is 20-50 frames at FRAME_PERIOD_S of one motion (rest, an eigen-axis slew with
an acceleration <= 2 deg/s^2, a torque-free tumble <= 5 deg/s, either with jitter) under one
sensor condition (nominal; a hot-pixel storm or a cosmic-ray rate up to 100x the simulated
camera's; bright false objects, planets and debris); missions are MISSION_GAP_S apart on the
time line, longer than the tracker's coast, so each starts lost-in-space.

Per-frame faults (FRAME_FAULTS): a frame dropped, a burst of 3-15 dropped, a frame sent twice,
stamps jumping back by 2.5-6 s (a bag replayed with --loop: beyond stamp.reset_after_s, a
time reset; the frames after it show the motion at those earlier times again), back by less
(out of order), forward (a gap the tracker cannot coast over) or into the future beyond
stamp.max_future_s, a malformed image (an
unsupported encoding, a step shorter than a row, an empty image), random bit flips in the
pixels, an occulted (blank) frame, and a bad CameraInfo in place of the good one.

Times: `t_s` is a frame's time on the run's time line [s] (its truth and its rendering); its
stamp is the run's base plus t_s, except a `stamp_future` frame, stamped ahead of the clock
when it is sent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

FRAME_PERIOD_S = 0.1  # 10 Hz, the simulated camera's rate_hz
MISSION_GAP_S = 3.0  # between missions: > tracking.max_coast_s (2 s)
MISSION_FRAMES = (20, 50)
FRAME_FAULT_PROBABILITY = 0.15  # chance that a frame of a mission starts a per-frame fault
NOMINAL_HOT_PIXEL_FRACTION = 2e-5  # the simulated camera's (camera_simulator_parameters.SIMULATED_SENSOR)
NOMINAL_COSMIC_RATE = 5.0  # [1/cm^2/s], likewise
STORM_FACTORS = (10.0, 100.0)  # hot pixels and cosmic rays: this many times nominal
MAX_ACCEL_DEG_S2 = 2.0
MAX_SLEW_RATE_DEG_S = 3.0
MAX_TUMBLE_RATE_DEG_S = 5.0
RESET_AFTER_S = 2.0  # the nodes' shipped stamp.reset_after_s
MAX_FUTURE_S = 1.0  # the nodes' shipped stamp.max_future_s

STEADY_RATE_CHANGE_RAD_S = math.radians(0.01)  # a rate change within the exposure beyond this: accelerating
MOTIONS = ("rest", "slew", "tumble", "rest_jitter", "slew_jitter")
ENVIRONMENTS = ("nominal", "hot_pixel_storm", "cosmic_ray_storm", "false_objects")
FRAME_FAULTS = ("drop", "drop_burst", "duplicate", "stamp_back_loop", "stamp_back_small", "stamp_forward",
                "stamp_future", "malformed_encoding", "malformed_step", "malformed_empty", "bit_flips", "blank",
                "bad_camera_info")
MALFORMED = ("malformed_encoding", "malformed_step", "malformed_empty")
STAMP_EVENTS = ("drop_burst", "stamp_back_loop", "stamp_back_small", "stamp_forward", "stamp_future")
BAD_CAMERA_INFOS = ("nan_k", "zero_k", "negative_focal", "wild_distortion")
FAULT_KINDS = FRAME_FAULTS + ENVIRONMENTS[1:]


@dataclass
class PlannedFrame:
    """
    One frame of the plan: an image message sent (or, `sent` False, dropped before the nodes).

    index: the order of the plan; mission: its mission; t_s: time on the run's time line [s];
    copy: 0, or 1 for the second copy of a duplicated frame (same stamp, same image); fault: the
    per-frame fault on it ('' none); event: a stamp event or dropped burst that ended just
    before this frame (its recovery starts here); bad_info: the bad CameraInfo sent with it
    ('' none); bit_flips: pixels with a flipped bit; future_s: a stamp_future frame's lead
    over the clock [s]; seed: its render seed.
    """

    index: int
    mission: int
    t_s: float
    seed: int
    sent: bool = True
    copy: int = 0
    fault: str = ""
    event: str = ""
    bad_info: str = ""
    bit_flips: int = 0
    future_s: float = 0.0


@dataclass
class Mission:
    """One motion under one sensor condition, from t0_s on the run's time line [s]."""

    index: int
    motion_kind: str
    environment: str
    level: float  # storm factor (x nominal), or the number of false objects
    t0_s: float
    initial_rotation: np.ndarray
    params: dict = field(default_factory=dict)  # the motion's drawn parameters
    frames: list[PlannedFrame] = field(default_factory=list)

    def motion(self):
        """Return the mission's MotionProfile (times on the run's time line)."""
        from ..sim.motion import ConstantRateMotion, JitterMotion, SlewMotion, TumbleMotion

        p = self.params
        if self.motion_kind.startswith("rest"):
            base = ConstantRateMotion(self.initial_rotation, np.zeros(3), t0=self.t0_s)
        elif self.motion_kind.startswith("slew"):
            base = SlewMotion(self.initial_rotation, np.asarray(p["axis"]), math.radians(p["angle_deg"]),
                              math.radians(p["max_rate_deg_s"]), math.radians(p["accel_deg_s2"]), t0=self.t0_s,
                              t_start=p["start_s"])
        else:
            base = TumbleMotion(self.initial_rotation, np.radians(p["rate_deg_s"]), np.asarray(p["inertia"]),
                                t0=self.t0_s)
        if self.motion_kind.endswith("jitter"):
            return JitterMotion(base, np.radians(np.asarray(p["jitter_arcsec"]) / 3600.0), np.asarray(p["jitter_hz"]),
                                np.asarray(p["jitter_phase"]))
        return base


@dataclass
class StressPlan:
    """Every mission and frame of a run, in the order they are sent."""

    seed: int
    missions: list[Mission]

    @property
    def frames(self) -> list[PlannedFrame]:
        return [f for m in self.missions for f in m.frames]

    def fault_counts(self) -> dict[str, int]:
        """Frames per fault kind (a dropped burst counts its frames; a sensor condition every frame of its missions)."""
        counts = {kind: 0 for kind in FAULT_KINDS}
        for mission in self.missions:
            for frame in mission.frames:
                if frame.fault:
                    counts[frame.fault] += 1
                if frame.bad_info:
                    counts["bad_camera_info"] += 1
                if mission.environment != "nominal" and frame.sent:
                    counts[mission.environment] += 1
        return counts


def _draw_motion(kind: str, rng: np.random.Generator) -> dict:
    params: dict = {}
    if kind.startswith("slew"):
        axis = rng.standard_normal(3)
        params.update(axis=(axis / np.linalg.norm(axis)).tolist(), angle_deg=float(rng.uniform(-15.0, 15.0)),
                      max_rate_deg_s=float(rng.uniform(0.5, MAX_SLEW_RATE_DEG_S)),
                      accel_deg_s2=float(rng.uniform(0.2, MAX_ACCEL_DEG_S2)), start_s=float(rng.uniform(0.0, 1.5)))
    elif kind == "tumble":
        direction = rng.standard_normal(3)
        rate = direction / np.linalg.norm(direction) * rng.uniform(0.5, MAX_TUMBLE_RATE_DEG_S)
        inertia = rng.uniform(1.0, 2.0, 3)  # any three in [1, 2] obey the triangle inequality
        params.update(rate_deg_s=rate.tolist(), inertia=inertia.tolist())
    if kind.endswith("jitter"):
        terms = int(rng.integers(1, 4))
        params.update(jitter_arcsec=rng.uniform(1.0, 20.0, (terms, 3)).tolist(),
                      jitter_hz=rng.uniform(1.0, 20.0, terms).tolist(),
                      jitter_phase=rng.uniform(0.0, 2 * math.pi, (terms, 3)).tolist())
    return params


def _draw_environment(rng: np.random.Generator) -> tuple[str, float]:
    environment = ENVIRONMENTS[0] if rng.random() < 0.5 else str(rng.choice(ENVIRONMENTS[1:]))
    if environment in ("hot_pixel_storm", "cosmic_ray_storm"):
        return environment, float(rng.choice(STORM_FACTORS))
    if environment == "false_objects":
        return environment, float(rng.integers(1, 6))
    return environment, 0.0


def plan_stress(frames: int, seed: int, required: tuple[str, ...] = (),
                mission_frames: tuple[int, int] = MISSION_FRAMES) -> StressPlan:
    """
    Return the plan of a run of at least `frames` image messages sent.

    Each fault in `required` (FAULT_KINDS) occurs at least once: for a short run that must
    show every kind (the test), drawn in place of random faults early in the run (the run
    grows until each is placed). mission_frames: (fewest, most) frames of a mission's schedule.
    """
    from ..sim.scenes import random_rotation

    rng = np.random.default_rng([int(seed), 0x57E55])
    missions: list[Mission] = []
    pending = list(required)  # faults still to place
    sent = 0
    t = 0.0
    used_stamps: set[int] = set()
    index = 0
    while sent < frames or pending:
        kind = str(rng.choice(MOTIONS))
        environment, level = _draw_environment(rng)
        storms = [k for k in pending if k in ENVIRONMENTS]
        placed_storm = bool(storms)  # this mission runs mission_frames[0] frames at least
        if storms:
            environment = storms[0]
            pending.remove(environment)
            level = float(STORM_FACTORS[-1]) if environment != "false_objects" else 3.0
        mission = Mission(len(missions), kind, environment, level, t, random_rotation(rng), _draw_motion(kind, rng))
        length = int(rng.integers(mission_frames[0], mission_frames[1] + 1))
        k = 0  # frames of the mission's own schedule
        newest_t = t  # the mission's newest time so far
        event = ""
        since_start = 0
        while k < length and (sent < frames or pending or (placed_storm and k < mission_frames[0])):
            frame_t = t + k * FRAME_PERIOD_S
            fault = ""
            per_frame = [f for f in pending if f in FRAME_FAULTS]
            if since_start >= 3 and k < length - 5:  # a mission first acquires, and ends clean
                if per_frame and rng.random() < 0.6:
                    fault = per_frame[0]
                elif rng.random() < FRAME_FAULT_PROBABILITY:
                    fault = str(rng.choice(FRAME_FAULTS))
            if fault in pending:
                pending.remove(fault)
            if fault == "drop":
                mission.frames.append(PlannedFrame(index, mission.index, frame_t, _seed(seed, index), sent=False,
                                                   fault="drop"))
                index, k = index + 1, k + 1
                continue
            if fault == "drop_burst":
                for j in range(int(rng.integers(3, 16))):
                    mission.frames.append(PlannedFrame(index, mission.index, t + (k + j) * FRAME_PERIOD_S,
                                                       _seed(seed, index), sent=False, fault="drop_burst"))
                    index += 1
                k += j + 1
                event = "drop_burst"
                continue
            if fault in ("stamp_back_loop", "stamp_back_small", "stamp_forward"):
                if fault == "stamp_back_loop":  # a bag looped: further back than reset_after_s, off the frame grid
                    shift = -rng.uniform(RESET_AFTER_S + 0.5, 6.0)
                elif fault == "stamp_back_small":
                    shift = -rng.uniform(0.3, RESET_AFTER_S - 0.3)
                else:
                    shift = rng.uniform(2.5, 8.0)
                t += shift  # the rest of the mission follows the jumped stamps
                frame_t += shift
                event = fault
            planned = PlannedFrame(index, mission.index, frame_t, _seed(seed, index), event=event)
            event = ""
            if fault in ("stamp_back_loop", "stamp_back_small", "stamp_forward"):
                planned.fault = fault
            elif fault == "stamp_future":
                planned.fault, planned.future_s = fault, float(rng.uniform(MAX_FUTURE_S + 1.0, 60.0))
                event = "stamp_future"  # recovery counts from the next frame
            elif fault == "bit_flips":
                planned.fault, planned.bit_flips = fault, int(10 ** rng.uniform(0.0, 3.0))
            elif fault == "bad_camera_info":
                planned.bad_info = str(rng.choice(BAD_CAMERA_INFOS))
            elif fault in MALFORMED + ("blank", "duplicate"):
                planned.fault = fault
            key = int(round(planned.t_s * 1e9))
            while key in used_stamps:  # a loop or a jump back landing on a stamp already sent: 1 us later
                key += 1000
            planned.t_s = key * 1e-9
            used_stamps.add(key)
            mission.frames.append(planned)
            index, sent, k, since_start = index + 1, sent + 1, k + 1, since_start + 1
            newest_t = max(newest_t, planned.t_s)
            if fault == "duplicate":
                mission.frames.append(replace(planned, index=index, copy=1, fault="duplicate", event=""))
                index, sent = index + 1, sent + 1
        missions.append(mission)
        t = max(newest_t, t + k * FRAME_PERIOD_S) + MISSION_GAP_S
    return StressPlan(int(seed), missions)


def _seed(seed: int, index: int) -> int:
    from ..sim.render import frame_seed

    return frame_seed(seed, index)


# ------------------------------------------------------------------------------ rendering
class FrameSource:
    """
    The renderers of a plan's sensor conditions (built on first use) and the faults applied to the images.

    The default camera (1024 x 1024, 15 deg), the simulated camera's sensor
    (camera_simulator_parameters.SIMULATED_SENSOR) and Hipparcos at epoch_jyear [Julian year]
    (the through-nodes run: its stamps' date, as the camera simulator's sky.epoch_jyear 0),
    rendered to Hp 7.5 (the camera simulator's sky.magnitude_limit).
    """

    def __init__(self, magnitude_limit: float = 7.5, epoch_jyear: float = 2026.0):
        from ..models.camera import CameraModel
        from ..models.catalog import load_hipparcos
        from ..ros.camera_simulator_parameters import SIMULATED_SENSOR

        self.camera = CameraModel.from_fov(1024, 1024, math.radians(15.0))
        self.sensor = SIMULATED_SENSOR
        self.catalog = load_hipparcos().at_epoch(epoch_jyear)
        self.magnitude_limit = magnitude_limit
        self._renderers: dict[tuple, object] = {}
        self._motions: dict[int, object] = {}

    def renderer(self, environment: str, level: float):
        from ..sim.render import FalseObjectModel, StarFieldRenderer

        key = (environment, level)
        if key not in self._renderers:
            sensor, objects = self.sensor, FalseObjectModel()
            if environment == "hot_pixel_storm":
                sensor = replace(sensor, hot_pixel_fraction=NOMINAL_HOT_PIXEL_FRACTION * level)
            elif environment == "cosmic_ray_storm":
                sensor = replace(sensor, cosmic_ray_rate_per_cm2_s=NOMINAL_COSMIC_RATE * level)
            elif environment == "false_objects":
                planets = int(level) // 2 + 1
                objects = FalseObjectModel(planets_per_frame=planets, debris_per_frame=int(level) - planets + 1)
            self._renderers[key] = StarFieldRenderer(self.camera, sensor, self.catalog, self.magnitude_limit,
                                                     objects)
        return self._renderers[key]

    def motion(self, mission: Mission):
        """Return the MotionProfile of a mission, kept for one mission at a time (a tumble caches its path)."""
        if mission.index not in self._motions:
            self._motions = {mission.index: mission.motion()}
        return self._motions[mission.index]

    def render(self, mission: Mission, frame: PlannedFrame):
        """Return the RenderedFrame of a planned frame (a blank one: its median level and read noise, no objects)."""
        rendered = self.renderer(mission.environment, mission.level).render(self.motion(mission), frame.t_s,
                                                                            frame.seed)
        if frame.fault == "blank":
            rendered = blank(rendered, self.sensor, frame.seed)
        elif frame.bit_flips:
            rendered = replace(rendered, image=flip_bits(rendered.image, frame.bit_flips, frame.seed))
        return rendered

    def reference(self, mission: Mission, frame: PlannedFrame, truth) -> tuple[np.ndarray, str, float]:
        """
        Return the attitude a frame is judged against, its motion phase and the jitter within its exposure [arcsec].

        The mid-exposure attitude (the truth's), but under jitter the exposure's mean one: jitter
        faster than a frame is unobservable in it (as the core stress campaign judges it). Phase:
        jitter, tumble, accelerating (the rate changes within the exposure), constant_rate or rest.
        """
        motion = self.motion(mission)
        t, exposure = frame.t_s, self.sensor.exposure_s
        if mission.motion_kind.endswith("jitter"):
            from ..models.attitude import matrix_to_rotation_vector

            mean = exposure_average_rotation(motion, t, exposure)
            offset = float(np.linalg.norm(matrix_to_rotation_vector(truth.rotation.T @ mean)))
            return mean, "jitter", math.degrees(offset) * 3600.0
        if mission.motion_kind == "tumble":
            return truth.rotation, "tumble", 0.0
        change = motion.angular_velocity_at(t + 0.5 * exposure) - motion.angular_velocity_at(t - 0.5 * exposure)
        if np.linalg.norm(change) > STEADY_RATE_CHANGE_RAD_S:
            return truth.rotation, "accelerating", 0.0
        rate = np.linalg.norm(motion.angular_velocity_at(t))
        return truth.rotation, "constant_rate" if rate > 1e-9 else "rest", 0.0


def exposure_average_rotation(motion, t: float, exposure_s: float, samples: int = 33) -> np.ndarray:
    """Return the attitude (sensor -> ICRS) averaged over the exposure centred on t [s] (mean rotation vector)."""
    from ..models.attitude import matrix_to_rotation_vector, rotation_vector_to_matrix

    times = t + ((np.arange(samples) + 0.5) / samples - 0.5) * exposure_s
    rotations = motion.rotations_at(times)
    middle = motion.rotations_at(np.array([t]))[0]
    mean = np.mean([matrix_to_rotation_vector(middle.T @ r) for r in rotations], axis=0)
    return middle @ rotation_vector_to_matrix(mean)


def blank(frame, sensor, seed: int):
    """Return the frame occulted: its median level plus read noise, nothing in view (as the camera simulator's)."""
    rng = np.random.default_rng([seed, 0x5EED])
    level = float(np.median(frame.image))
    noise = sensor.read_noise_e / sensor.gain_e_per_adu
    image = np.clip(np.round(rng.normal(level, noise, frame.image.shape)), 0, np.iinfo(frame.image.dtype).max)
    none = np.zeros(0, bool)
    truth = frame.truth
    empty = replace(truth, kind=truth.kind[none], hip=truth.hip[none], x=truth.x[none], y=truth.y[none],
                    electrons=truth.electrons[none], extent_px=truth.extent_px[none])
    return replace(frame, image=image.astype(frame.image.dtype), truth=empty)


def flip_bits(image: np.ndarray, count: int, seed: int) -> np.ndarray:
    """Return a copy of a uint16 image with one random bit flipped in each of `count` random pixels."""
    rng = np.random.default_rng([seed, 0xB17])
    out = image.copy()
    flat = out.reshape(-1)
    pixels = rng.choice(flat.size, size=min(count, flat.size), replace=False)
    bits = rng.integers(0, 8 * image.dtype.itemsize, pixels.size).astype(image.dtype)
    flat[pixels] ^= (np.ones(1, image.dtype) << bits)
    return out


class StampRule:
    """
    What a node says of each stamp in turn: the nodes' own rule (track/stamp_order.py), shipped thresholds.

    classify(stamp, now): `now` is the node's clock at the time (the sending time: a run's
    stamps from the future are seconds ahead, far beyond any transport delay).
    """

    def __init__(self, max_future_s: float = MAX_FUTURE_S, reset_after_s: float = RESET_AFTER_S):
        from ..track.stamp_order import StampOrder

        self._now = 0
        self._order = StampOrder(lambda: self._now, max_future_s, reset_after_s)

    def classify(self, stamp: int, now: int) -> str:
        self._now = now
        return self._order.classify(stamp)
