# SPDX-License-Identifier: Apache-2.0
"""
`stress`: randomized missions through render -> centroid -> track, judged frame by frame against the truth.

A trial is one mission: `frames_per_mission` frames at 10 Hz (0.1 s exposures, the default
camera 1024 x 1024 15 deg and sensor, stars to Hp 7.5), each dimension drawn independently
from the trial's seed (draw_mission):

- motion: at rest; an eigen-axis slew (0.1-2 deg/s^2 to 0.5-3 deg/s, 5-60 deg); a free tumble
  (0.5-5 deg/s, a random inertia); jitter (1-20" at 0.5-20 Hz on a 0-0.5 deg/s drift);
- false objects: none; 1-5 planets; 1-10 debris streaks; a bright satellite crossing (one
  magnitude -1..1 object moving 20-300 px/s); the Moon 0-12 deg from the first boresight (its
  disc, phase and stray light: sim/environment.py, Earth behind, Sun 90 deg off);
- detector: nominal; a hot-pixel storm (1e-4-3e-3 of the pixels, 200x the dark current);
  cosmic rays at 5-500 hits/cm^2/s (up to 100x a quiet orbit: a South Atlantic Anomaly pass);
  random bit flips (1-1000 per frame, any of the 16 bits of a pixel);
- PSF: the default 1 px, or a defocus of 0.4-3 px (Gaussian; astigmatism is not simulated);
- stray light: none, or 1e3-1e5 e-/px/s rising by half from the centre toward one edge;
- temperature: 20 C, or a ramp of 10-50 K over the mission (dark current doubling every 6 K);
- frame faults (any of): single dropped frames (5 %) and a burst of 2-8; duplicated
  frames (5 %, delivered twice); a loop (the stamps and the scene jump back 2.5-3.5 s, a bag
  replayed with --loop); a gap (time jumps 1-10 s ahead: a pause); a stamp from the future
  (one frame stamped 2-30 s ahead of the clock);
- rate aid: the tracker's own rate (the identifier's, as the node's `angular_velocity`) carried
  to the frame by its angular acceleration, or a gyro: 100 Hz samples of the true rate plus a
  bias (0.01 deg/s per axis, 1 sigma) and noise (0.005 deg/s per sample), their mean over the
  exposure the rate and the slope of the last 0.25 s of them the acceleration, as the centroider
  takes them (an acceleration only when significant: track/aid_acceleration.py), and under
  jitter the path they draw within the exposure (centroid/streak/exposure_path.py).

Each delivered frame goes where the nodes send it: its stamp judged by the nodes' rule
(track/stamp_order.py on the simulated clock: out of order and from the future refused and
counted, a jump back of more than 2 s restarts the track), centroided with the aid as its
smear model when the aid is at most 0.5 s from the frame (the centroider's max_rate_age_s)
and the running PSF prior (centroid/psf/running_prior.py, as the centroider node), and
tracked (`Tracker.process`: tracking, lost-in-space when it fails). A solved frame is scored
(scoring.py) against the truth at mid-exposure, a jitter frame against the exposure's mean
attitude unless a gyro's path carried it to mid-exposure: wrong when its boresight is more
than `wrong_arcsec` off or its error lies outside 5 sigma of its stated covariance
(NEES > 31.8), or when any matched star is not the star behind its spot. Each frame's
stratum is its motion phase (rest, accelerating: the rate changes within the exposure,
constant rate, tumble, jitter); each mission's draws are its strata too. Recovery: after a
dropped-frame burst, a loop or a gap that interrupted tracking, the frames processed until
the first tracked one (1: tracked at once); deliveries refused by their stamps (duplicates,
out of order, from the future) are no frames the tracker could use, and an interruption cut
short by the next one before a frame was tracked is judged by that next one.

The summary: frames, wrong, wrong star IDs, NEES mean and the share above chi^2_3(0.997),
availability (right / accepted frames), per stratum (a frame fault's stratum: the missions
that had it, with others or not); recoveries; every wrong or overconfident
frame with its task and seed (`failures` in summary.json; `star-tracker characterize stress
--replay T --seed S` replays one mission frame by frame).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
import pyarrow as pa
from scipy.stats import chi2

from ...parameter_spec import parameter, range_problems
from ..bounds import rate_upper_bound
from ..kind import CampaignKind
from .accuracy import truth_hip
from .default_chain import MAGNITUDE_LIMIT, default_chain
from .scoring import NEES_5_SIGMA, score

PERIOD_S = 0.1
EPOCH_S = 1000.0  # the simulated clock's reading at mission time 0 [s] (stamps are never zero)
MAX_RATE_AGE_S = 0.5  # the centroider's max_rate_age_s
MAX_FUTURE_S, RESET_AFTER_S = 1.0, 2.0  # the nodes' stamp.max_future_s, stamp.reset_after_s
NEES_997 = float(chi2.ppf(0.997, 3))  # 13.93: a consistent covariance exceeds it 0.3 % of the time
STEADY_RATE_CHANGE_RAD_S = 1e-9
ARCSEC = math.pi / (180.0 * 3600.0)
DEG = math.pi / 180.0
TEMPERATURE_STEP_K = 5.0
GYRO_RATE_HZ = 100.0  # the gyro's sample rate
GYRO_SPAN_SAMPLES = 25  # its samples the centroider fits the acceleration to (ros/rate_input.ACCELERATION_SPAN_S)
GYRO_NOISE_RAD_S = 0.005 * math.pi / 180.0  # per sample, 1 sigma  # a ramp is rendered in steps of this
MOTIONS = ("rest", "slew", "tumble", "jitter")
PHASES = ("rest", "accelerating", "constant_rate", "tumble", "jitter")
FALSE_OBJECTS = ("none", "planets", "debris", "satellite", "moon")
DETECTOR = ("nominal", "hot_pixel_storm", "cosmic_rays", "bit_flips")
FRAME_FAULTS = ("drops", "duplicates", "loop", "gap", "future_stamp")
MISSION_STRATA = ("motion", "false_objects", "detector", "psf", "stray_light", "temperature", "frame_faults",
                  "rate_aid")
# Frame verdicts: the stamp rule's, or dropped before delivery.
DELIVERED_OK = ("ok", "time_reset")


@dataclass(frozen=True)
class StressOptions:
    """The missions of a stress campaign (each a `parameter`)."""

    frames_per_mission: int = parameter(40, "frames per mission (10 Hz)", "", 5, 10000)
    wrong_arcsec: float = parameter(60.0, "a boresight this far from the truth is wrong", "arcsec", 0.0, 1e6,
                                    low_open=True)

    def __post_init__(self) -> None:
        bad = range_problems(self)
        if bad:
            raise ValueError("stress options: " + "; ".join(bad))


@dataclass
class Mission:
    """One mission's draws (module docstring); `labels` are its strata."""

    motion: object
    motion_kind: str
    false_objects: str
    detector: str
    psf_sigma_px: float
    stray_light_e_px_s: float
    temperature_k: tuple[float, float]
    frame_faults: tuple[str, ...]
    rate_aid: str
    sensor: object
    objects: object
    environment: object | None
    bit_flips: int
    gyro_bias_rad_s: np.ndarray
    schedule: list = field(default_factory=list)  # per delivery: (frame, tau_s, clock_s, stamp_s, duplicate)
    events: list = field(default_factory=list)  # delivery index of the first frame after each interruption

    @property
    def labels(self) -> dict[str, str]:
        return {"motion": self.motion_kind, "false_objects": self.false_objects, "detector": self.detector,
                "psf": "defocus" if self.psf_sigma_px != 1.0 else "nominal",
                "stray_light": "high" if self.stray_light_e_px_s > 0 else "nominal",
                "temperature": "ramp" if self.temperature_k[1] != self.temperature_k[0] else "nominal",
                "frame_faults": "+".join(self.frame_faults) or "none", "rate_aid": self.rate_aid}


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    from ...models.attitude import quaternion_to_matrix

    return quaternion_to_matrix(rng.normal(size=4))


def _draw_motion(rng: np.random.Generator, rotation: np.ndarray) -> tuple[str, object]:
    from ...sim.motion import ConstantRateMotion, JitterMotion, SlewMotion, TumbleMotion

    kind = MOTIONS[int(rng.choice(len(MOTIONS), p=(0.2, 0.4, 0.2, 0.2)))]
    if kind == "rest":
        return kind, ConstantRateMotion(rotation, np.zeros(3))
    if kind == "slew":
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        axis = np.array([math.cos(azimuth), math.sin(azimuth), rng.uniform(-0.3, 0.3)])
        return kind, SlewMotion(rotation, axis, angle_rad=rng.uniform(5.0, 60.0) * DEG,
                                max_rate_rad_s=rng.uniform(0.5, 3.0) * DEG, accel_rad_s2=rng.uniform(0.1, 2.0) * DEG,
                                t_start=rng.uniform(0.0, 1.5))
    if kind == "tumble":
        direction = rng.normal(size=3)
        rate = direction / np.linalg.norm(direction) * rng.uniform(0.5, 5.0) * DEG
        principal = rng.uniform(1.0, 3.0, size=3)
        principal[np.argmax(principal)] = min(principal.max(), principal.sum() - principal.max() - 1e-3)
        return kind, TumbleMotion(rotation, rate, principal)
    drift = rng.normal(size=3)
    drift *= rng.uniform(0.0, 0.5) * DEG / np.linalg.norm(drift)
    terms = int(rng.integers(1, 4))
    return kind, JitterMotion(ConstantRateMotion(rotation, drift), rng.uniform(1.0, 20.0, size=(terms, 3)) * ARCSEC,
                              rng.uniform(0.5, 20.0, size=terms), rng.uniform(0.0, 2.0 * math.pi, size=terms))


def _moon_environment(rng: np.random.Generator, boresight: np.ndarray):
    """Return an Environment with the Moon 0-12 deg from `boresight` (ICRS), the Earth behind, the Sun 90 deg off."""
    from ...sim.environment import Environment

    side = np.cross(boresight, rng.normal(size=3))
    side /= np.linalg.norm(side)
    angle = rng.uniform(0.0, 12.0) * DEG
    moon_direction = math.cos(angle) * boresight + math.sin(angle) * side
    sun_direction = np.cross(boresight, side)
    spacecraft = 7.0e6 * boresight  # the Earth directly behind the head
    return Environment(spacecraft_position_m=spacecraft, spacecraft_velocity_m_s=np.zeros(3),
                       sun_position_m=1.496e11 * sun_direction, moon_position_m=spacecraft + 3.844e8 * moon_direction,
                       observer_velocity_m_s=np.zeros(3))


def _schedule(rng: np.random.Generator, frames: int, faults: tuple[str, ...]) -> tuple[list, list]:
    """
    Return the deliveries (frame, tau_s, clock_s, stamp_s, duplicate) and the interruption events.

    tau: the scene's time (the truth); clock: the receiving node's clock; stamp: the header's.
    """
    dropped = np.zeros(frames, bool)
    if "drops" in faults:
        dropped |= rng.random(frames) < 0.05
        start, length = int(rng.integers(1, max(2, frames - 9))), int(rng.integers(2, 9))
        dropped[start:start + length] = True
    duplicated = ("duplicates" in faults) & (rng.random(frames) < 0.05)
    loop_at = int(rng.integers(frames // 3, 2 * frames // 3 + 1)) if "loop" in faults else -1
    loop_back_s = rng.uniform(2.5, 3.5)
    gap_at = int(rng.integers(frames // 4, 3 * frames // 4 + 1)) if "gap" in faults else -1
    gap_s = rng.uniform(1.0, 10.0)
    future_at = int(rng.integers(1, frames)) if "future_stamp" in faults else -1
    future_s = rng.uniform(2.0, 30.0)
    deliveries, events = [], []
    tau_offset = clock_offset = 0.0
    interrupted, run_of_drops = False, 0
    for k in range(frames):
        if k == loop_at:
            tau_offset -= loop_back_s  # the replay starts over: scene and stamps go back, the clock does not
            interrupted = True
        if k == gap_at:
            tau_offset += gap_s
            clock_offset += gap_s
            interrupted = True
        if dropped[k]:
            run_of_drops += 1
            continue
        interrupted |= run_of_drops >= 2  # a burst, not a single lost frame
        run_of_drops = 0
        tau = 0.05 + PERIOD_S * k + tau_offset
        clock = EPOCH_S + 0.05 + PERIOD_S * k + clock_offset + 0.05  # the frame arrives after its exposure
        stamp = EPOCH_S + tau + (future_s if k == future_at else 0.0)
        if interrupted:
            events.append(len(deliveries))
            interrupted = False
        deliveries.append((k, tau, clock, stamp, False))
        if duplicated[k]:
            deliveries.append((k, tau, clock + 0.01, stamp, True))
    return deliveries, events


def draw_mission(rng: np.random.Generator, frames: int, base_sensor) -> Mission:
    """Return one mission's draws (module docstring), every number from rng."""
    from ...sim.render import FalseObjectModel

    rotation = _random_rotation(rng)
    motion_kind, motion = _draw_motion(rng, rotation)
    objects_kind = FALSE_OBJECTS[int(rng.choice(len(FALSE_OBJECTS), p=(0.4, 0.15, 0.15, 0.15, 0.15)))]
    objects, environment = FalseObjectModel(), None
    if objects_kind == "planets":
        objects = FalseObjectModel(planets_per_frame=int(rng.integers(1, 6)))
    elif objects_kind == "debris":
        objects = FalseObjectModel(debris_per_frame=int(rng.integers(1, 11)))
    elif objects_kind == "satellite":
        objects = FalseObjectModel(debris_per_frame=1, debris_magnitude_range=(-1.0, 1.0),
                                   debris_speed_px_s=(20.0, 300.0))
    elif objects_kind == "moon":
        environment = _moon_environment(rng, rotation[:, 2])
    detector = DETECTOR[int(rng.choice(len(DETECTOR), p=(0.4, 0.2, 0.2, 0.2)))]
    sensor, bit_flips = base_sensor, 0
    if detector == "hot_pixel_storm":
        sensor = replace(sensor, hot_pixel_fraction=float(10 ** rng.uniform(-4.0, math.log10(3e-3))))
    elif detector == "cosmic_rays":
        sensor = replace(sensor, cosmic_ray_rate_per_cm2_s=float(10 ** rng.uniform(math.log10(5.0), math.log10(500.0))))
    elif detector == "bit_flips":
        bit_flips = int(round(10 ** rng.uniform(0.0, 3.0)))
    psf = float(rng.uniform(0.4, 3.0)) if rng.random() < 0.5 else 1.0
    sensor = replace(sensor, psf_sigma_px=psf)
    stray = float(10 ** rng.uniform(3.0, 5.0)) if rng.random() < 0.2 else 0.0
    if stray:
        from ...sim.stray_light import half_diagonal_px
        from ...models.camera import CameraModel

        half = half_diagonal_px(CameraModel.from_fov(1024, 1024, 15.0 * DEG))
        direction = rng.uniform(0.0, 2.0 * math.pi)
        rise = 0.5 * stray / half
        sensor = replace(sensor, background_e_per_px_s=base_sensor.background_e_per_px_s + stray,
                         stray_light_gradient_e_per_px2_s=(rise * math.cos(direction), rise * math.sin(direction)))
    start_k = base_sensor.temperature_k
    temperature = (start_k, start_k + float(rng.uniform(10.0, 50.0))) if rng.random() < 0.2 else (start_k, start_k)
    faults = tuple(f for f in FRAME_FAULTS if rng.random() < 0.15)
    rate_aid = "gyro" if rng.random() < 0.5 else "identifier"
    bias = rng.normal(0.0, 0.01 * DEG, size=3)
    mission = Mission(motion, motion_kind, objects_kind, detector, psf, stray, temperature, faults, rate_aid, sensor,
                      objects, environment, bit_flips, bias)
    mission.schedule, mission.events = _schedule(rng, frames, faults)
    return mission


def flip_bits(image: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Return a copy of a uint16 image with `count` random bits flipped (any pixel, any of its 16 bits)."""
    flipped = image.copy()
    flat = flipped.reshape(-1)
    where = rng.integers(0, flat.size, size=count)
    bits = rng.integers(0, 16, size=count).astype(np.uint16)
    np.bitwise_xor.at(flat, where, np.left_shift(np.uint16(1), bits))
    return flipped


def exposure_average_rotation(motion, tau: float, exposure_s: float, samples: int = 33) -> np.ndarray:
    """
    Return the attitude (sensor -> ICRS) averaged over the exposure centred on tau [s].

    The mean of the rotation vectors of R(tau)^T R(t) over `samples` evenly spaced times: what
    the stars of a frame record when the body moves faster than a frame can resolve.
    """
    from ...models.attitude import matrix_to_rotation_vector, rotation_vector_to_matrix

    times = tau + ((np.arange(samples) + 0.5) / samples - 0.5) * exposure_s
    rotations = motion.rotations_at(times)
    middle = motion.rotations_at(np.array([tau]))[0]
    mean = np.mean([matrix_to_rotation_vector(middle.T @ r) for r in rotations], axis=0)
    return middle @ rotation_vector_to_matrix(mean)


def motion_phase(mission: Mission, tau: float, exposure_s: float) -> str:
    """Return a frame's motion stratum from the truth (module docstring)."""
    if mission.motion_kind in ("tumble", "jitter"):
        return mission.motion_kind
    motion = mission.motion
    change = motion.angular_velocity_at(tau + 0.5 * exposure_s) - motion.angular_velocity_at(tau - 0.5 * exposure_s)
    if np.linalg.norm(change) > STEADY_RATE_CHANGE_RAD_S:
        return "accelerating"
    return "constant_rate" if np.linalg.norm(motion.angular_velocity_at(tau)) > 1e-9 else "rest"


@dataclass
class _Shared:
    camera: object
    sensor: object
    catalog: object
    identifier: object
    exposure_s: float


FRAME_COLUMNS = (("frame", pa.int32()), ("tau_s", pa.float64()), ("stamp_s", pa.float64()),
                 ("duplicate", pa.bool_()), ("verdict", pa.string()), ("phase", pa.string()),
                 ("aided", pa.bool_()), ("mode", pa.string()), ("solved", pa.bool_()), ("wrong", pa.bool_()),
                 ("wrong_star", pa.bool_()), ("cross_arcsec", pa.float64()), ("nees", pa.float64()),
                 ("matched", pa.int32()), ("spots", pa.int32()), ("jitter_arcsec", pa.float64()))


class Stress(CampaignKind):
    """Randomized missions judged frame by frame (module docstring)."""

    name = "stress"
    description = "randomized missions (motion, false objects, detector, PSF, stray light, temperature, frame and " \
                  "stamp faults, rate aid) judged frame by frame: wrong attitudes, wrong stars, NEES per stratum"
    options_type = StressOptions
    default_trials = 2500  # 100,000 frames at 40 per mission
    default_batch = 1
    columns = (*(pa.field(name, pa.string()) for name in MISSION_STRATA),
               pa.field("psf_sigma_px", pa.float64()), pa.field("bit_flips", pa.int32()),
               *(pa.field(name, pa.list_(kind)) for name, kind in FRAME_COLUMNS),
               pa.field("recoveries", pa.list_(pa.int32())), pa.field("frame_s", pa.float64()))

    @staticmethod
    def trials_for_frames(frames: int, options: StressOptions) -> int:
        """Return the missions that make at least `frames` frames."""
        return -(-int(frames) // options.frames_per_mission)

    def prepare(self, options: StressOptions) -> _Shared:
        from ...track.tracking import Tracker

        chain = default_chain()
        Tracker(chain.identifier).warm_up(chain.camera)
        return _Shared(chain.camera, chain.sensor, chain.catalog, chain.identifier, chain.sensor.exposure_s)

    def trial(self, shared: _Shared, options: StressOptions, task: int, rng: np.random.Generator) -> dict:
        record, _ = run_mission(shared, options, rng)
        return record

    def summarize(self, table: pa.Table, options: StressOptions) -> dict:
        return summarize_stress(table)

    def replay(self, shared: _Shared, options: StressOptions, rng: np.random.Generator) -> str:
        return replay_text(shared, options, rng)


def run_mission(shared: _Shared, options: StressOptions, rng: np.random.Generator,
                mission: Mission | None = None) -> tuple[dict, list[dict]]:
    """
    Return one mission's record and its frames (dicts of FRAME_COLUMNS) (module docstring).

    mission: these draws instead of the rng's (a test's scenario); the rng still seeds the frames.
    """
    from ...centroid import CentroidConfig, extract_spots
    from ...centroid.psf.running_prior import RunningPsf
    from ...centroid.streak.smear import SmearModel
    from ...models.attitude import matrix_to_rotation_vector
    from ...sim.environment import EnvironmentModel
    from ...sim.render import StarFieldRenderer
    from ...track.aid_acceleration import from_samples, significant
    from ...track.stamp_order import STAMP_RESET, StampOrder
    from ...track.tracking import MODE_TRACKING, Tracker

    mission = mission or draw_mission(rng, options.frames_per_mission, shared.sensor)
    renderers: dict[float, object] = {}

    def renderer_at(fraction: float):
        low, high = mission.temperature_k
        step = round((low + fraction * (high - low)) / TEMPERATURE_STEP_K) * TEMPERATURE_STEP_K if high != low \
            else low
        if step not in renderers:
            renderers[step] = StarFieldRenderer(shared.camera, replace(mission.sensor, temperature_k=float(step)),
                                                shared.catalog, magnitude_limit=MAGNITUDE_LIMIT,
                                                false_objects=mission.objects)
        return renderers[step]

    clock = [0]
    stamps = StampOrder(lambda: clock[0], MAX_FUTURE_S, RESET_AFTER_S)
    tracker = Tracker(shared.identifier)
    psf = RunningPsf()
    # The renderers (default EnvironmentModel) bloom whenever they render an environment (the
    # Moon's missions); the centroider is told so, as a user of a blooming sensor sets sensor_blooms.
    config = CentroidConfig(sensor_blooms=mission.environment is not None and EnvironmentModel().blooming)
    frames: list[dict] = []
    rendered: dict[int, tuple] = {}
    started = time.perf_counter()
    for frame, tau, clock_s, stamp_s, duplicate in mission.schedule:
        clock[0] = int(round(clock_s * 1e9))
        stamp_ns = int(round(stamp_s * 1e9))
        row = {"frame": frame, "tau_s": tau, "stamp_s": stamp_s, "duplicate": duplicate, "verdict": "",
               "phase": motion_phase(mission, tau, shared.exposure_s), "aided": False, "mode": "", "solved": False,
               "wrong": False, "wrong_star": False, "cross_arcsec": None, "nees": None, "matched": 0, "spots": 0,
               "jitter_arcsec": 0.0}
        frames.append(row)
        if duplicate and frame in rendered:
            image, truth = rendered[frame]
        else:
            seed = int(rng.integers(2 ** 31))
            rendered_frame = renderer_at(frame / max(options.frames_per_mission - 1, 1)).render(
                mission.motion, tau, seed, mission.environment)
            image, truth = rendered_frame.image, rendered_frame.truth
            if mission.bit_flips:
                image = flip_bits(image, mission.bit_flips, rng)
            rendered = {frame: (image, truth)}
        verdict = stamps.classify(stamp_ns)
        row["verdict"] = verdict
        if verdict not in DELIVERED_OK:
            continue  # refused and counted, as the identifier node does
        if verdict == STAMP_RESET:
            tracker.reset()
        if mission.rate_aid == "gyro":
            # The centroider's aid from a gyro (ros/rate_input.py): the mean of the samples inside
            # the exposure, the acceleration the slope of a line through the last
            # ACCELERATION_SPAN_S of samples up to the exposure's end.
            offsets = 0.5 * shared.exposure_s - (np.arange(GYRO_SPAN_SAMPLES) + 0.5) / GYRO_RATE_HZ
            samples = np.array([mission.motion.angular_velocity_at(tau + dt) for dt in offsets]) \
                + mission.gyro_bias_rad_s + rng.normal(0.0, GYRO_NOISE_RAD_S, size=(offsets.size, 3))
            inside = np.abs(offsets) <= 0.5 * shared.exposure_s
            smear = SmearModel(shared.camera, samples[inside].mean(axis=0), shared.exposure_s,
                               significant(*from_samples(offsets, samples)))
            smear = smear.with_exposure_path(offsets, samples, GYRO_NOISE_RAD_S)
        else:
            # The identifier's estimate carried to the frame by its acceleration, as the centroider does.
            smear = tracker.centroider_aid(stamp_ns, shared.camera, shared.exposure_s, MAX_RATE_AGE_S)
        row["aided"] = smear is not None
        spots = extract_spots(image, config, smear, psf_prior=psf.prior, prior_rings=psf.rings)
        psf.update(spots.psf)
        result = tracker.process(stamp_ns, spots, shared.camera)
        row["mode"], row["spots"] = result.mode, len(spots)
        ident = result.identification
        if ident.solved:
            # Jitter faster than a frame is unobservable in it: the head measures, and is judged
            # against, the exposure's mean attitude (the mid-exposure one elsewhere), unless a
            # gyro's path carried it to mid-exposure (Tracker._accept_on_path).
            reference = exposure_average_rotation(mission.motion, tau, shared.exposure_s) \
                if mission.motion_kind == "jitter" and not result.on_exposure_path else truth.rotation
            scored = score(ident, truth_hip(truth, spots, ident), reference, options.wrong_arcsec)
            row["jitter_arcsec"] = float(np.linalg.norm(matrix_to_rotation_vector(truth.rotation.T @ reference))) \
                / ARCSEC
            far = scored["cross_arcsec"] > options.wrong_arcsec
            wrong = scored["wrong_star"] or far or scored["nees"] > NEES_5_SIGMA
            row.update(solved=True, wrong=bool(wrong),
                       wrong_star=bool(scored["wrong_star"]), cross_arcsec=scored["cross_arcsec"],
                       nees=scored["nees"], matched=int(ident.hip.size))
    recoveries = _recoveries(frames, mission.events, MODE_TRACKING)
    record = {**mission.labels, "psf_sigma_px": mission.psf_sigma_px, "bit_flips": mission.bit_flips,
              **{name: [row[name] for row in frames] for name, _ in FRAME_COLUMNS},
              "recoveries": recoveries, "frame_s": (time.perf_counter() - started) / max(len(frames), 1)}
    return record, frames


def _recoveries(frames: list[dict], events: list[int], tracking: str) -> list[int]:
    """
    Return, per interruption that cut a track, the frames processed until the first tracked one (-1: none).

    An interruption cuts a track when the last delivered frame before it was tracked or solved.
    Processed: accepted by its stamp (DELIVERED_OK); a refused delivery (a duplicate, out of
    order, from the future) is not counted. An interruption followed by another before a
    frame was tracked is left to that one (a loop and a gap back to back: the gap's frames
    are the first the tracker could have tracked).
    """
    out = []
    events = sorted(set(events))
    for index, event in enumerate(events):
        if event == 0 or event >= len(frames) or not frames[event - 1]["solved"]:
            continue
        following = events[index + 1] if index + 1 < len(events) else len(frames)
        count, processed = -1, 0
        for k in range(event, following):
            if frames[k]["verdict"] not in DELIVERED_OK:
                continue
            processed += 1
            if frames[k]["mode"] == tracking:
                count = processed
                break
        if count < 0 and following < len(frames):
            continue  # cut short by the next interruption: that one is judged
        out.append(count)
    return out


def _stratum_figures(nees: np.ndarray, solved: np.ndarray, wrong: np.ndarray, wrong_star: np.ndarray,
                     accepted: np.ndarray) -> dict:
    n = int(accepted.sum())
    solved_n = int((accepted & solved).sum())
    right = int((accepted & solved & ~wrong).sum())
    values = nees[accepted & solved]
    return {"frames": n, "solved": solved_n, "right": right, "wrong": int((accepted & wrong).sum()),
            "wrong_upper_95": rate_upper_bound(int((accepted & wrong).sum()), solved_n) if solved_n else None,
            "wrong_star_frames": int((accepted & wrong_star).sum()),
            "availability": right / n if n else None,
            "nees_mean": float(values.mean()) if values.size else None,
            "nees_above_997_share": float(np.mean(values > NEES_997)) if values.size else None,
            "nees_above_5_sigma": int(np.sum(values > NEES_5_SIGMA))}


def summarize_stress(table: pa.Table) -> dict:
    """Return summary.json's figures of a stress campaign (module docstring)."""
    ok = np.asarray(table.column("error").to_pylist(), object) == ""
    rows = table.filter(pa.array(ok))
    counts = np.asarray([len(v) for v in rows.column("frame").to_pylist()], int)

    def flat(name, fill):
        return np.asarray([fill if v is None else v for lst in rows.column(name).to_pylist() for v in lst])

    verdict = flat("verdict", "").astype(object)
    accepted = np.isin(verdict, DELIVERED_OK)
    solved, wrong, wrong_star = (flat(n, False).astype(bool) for n in ("solved", "wrong", "wrong_star"))
    nees = flat("nees", np.nan).astype(float)
    phase = flat("phase", "").astype(object)
    strata: dict[str, dict] = {"phase": {p: _stratum_figures(nees, solved, wrong, wrong_star, accepted & (phase == p))
                                         for p in PHASES if np.any(phase == p)}}
    for name in MISSION_STRATA:
        per_frame = np.repeat(np.asarray(rows.column(name).to_pylist(), object), counts)
        if name == "frame_faults":  # a mission may have several: each fault's missions, and those without
            has = {fault: np.array([fault in str(v).split("+") for v in per_frame], bool) for fault in FRAME_FAULTS}
            has["none"] = per_frame == "none"
            strata[name] = {fault: _stratum_figures(nees, solved, wrong, wrong_star, accepted & mask)
                            for fault, mask in has.items() if mask.any()}
            continue
        values = sorted(set(per_frame.tolist()))
        strata[name] = {v: _stratum_figures(nees, solved, wrong, wrong_star, accepted & (per_frame == v))
                        for v in values}
    recoveries = np.asarray([r for lst in rows.column("recoveries").to_pylist() for r in lst], int)
    tasks = np.repeat(np.asarray(rows.column("task").to_pylist(), int), counts)
    seeds = np.repeat(np.asarray(rows.column("seed").to_pylist(), int), counts)
    frame_index = flat("frame", -1).astype(int)
    cross = flat("cross_arcsec", np.nan).astype(float)
    bad = np.flatnonzero(accepted & (wrong | (solved & (nees > NEES_997))))
    failures = [{"task": int(tasks[i]), "seed": int(seeds[i]), "frame": int(frame_index[i]),
                 "wrong": bool(wrong[i]), "wrong_star": bool(wrong_star[i]),
                 "cross_arcsec": float(cross[i]), "nees": float(nees[i]), "phase": str(phase[i])} for i in bad]
    verdicts = {v: int(np.sum(verdict == v)) for v in sorted(set(verdict.tolist()))}
    return {"missions": int(ok.sum()), "failed_tasks": int((~ok).sum()),
            "errors": sorted(set(np.asarray(table.column("error").to_pylist(), object)[~ok].tolist())),
            "deliveries": int(verdict.size), "verdicts": verdicts,
            **_stratum_figures(nees, solved, wrong, wrong_star, accepted),
            "nees_997": NEES_997, "nees_5_sigma": NEES_5_SIGMA,
            "recoveries": {"events": int(recoveries.size),
                           "max_frames": int(recoveries.max()) if recoveries.size else None,
                           "not_recovered": int(np.sum(recoveries < 0)),
                           "within_2_frames": int(np.sum((recoveries >= 1) & (recoveries <= 2)))},
            "strata": strata, "failures": failures[:1000], "failures_total": int(bad.size)}


def replay_text(shared: _Shared, options: StressOptions, rng: np.random.Generator) -> str:
    """Return one mission replayed frame by frame as text (`star-tracker characterize stress --replay TASK`)."""
    record, frames = run_mission(shared, options, rng)
    lines = [", ".join(f"{name} {record[name]}" for name in MISSION_STRATA) + f", psf {record['psf_sigma_px']:.2f} px"
             + (f", {record['bit_flips']} bit flips" if record["bit_flips"] else "")]
    for row in frames:
        nees = "" if row["nees"] is None else f"{row['nees']:.2f}"
        cross = "" if row["cross_arcsec"] is None else f"{row['cross_arcsec']:.2f}"
        lines.append(f"{row['frame']:4d} tau {row['tau_s']:7.2f} s {row['verdict']:12s} {row['phase']:13s} "
                     f"{row['mode']:13s} spots {row['spots']:4d} matched {row['matched']:3d} cross {cross:>8s}\" "
                     f"NEES {nees:>8s}{'  WRONG' if row['wrong'] else ''}{'  WRONG STAR' if row['wrong_star'] else ''}")
    lines.append(f"recoveries (frames to tracking after each interruption): {record['recoveries']}")
    return "\n".join(lines)
