# SPDX-License-Identifier: Apache-2.0
"""
The centroider's body-rate inputs for the rate aid.

`angular_velocity` (geometry_msgs/Vector3Stamped) and `imu` (sensor_msgs/Imu, its
angular_velocity), checked, rotated into the sensor frame and kept for the frames that need
them.

A gyro measures in its own frame: `mounting` rotates its vectors into the sensor frame
(v_sensor = R(q) v_gyro, q = (x, y, z, w): the gyro frame's orientation in the sensor frame).
An Imu message must come from the gyro frame when one is configured (`gyro_frame_id`); a
Vector3Stamped in the gyro frame is rotated likewise, in any other frame it is taken as the
sensor frame (the identifier's own estimate, or a driver remapped onto the topic).

Bad messages are counted and ignored, through `reject(counter, text)`:
`rates_rejected` (non-finite or unstamped), `rates_wrong_frame`, `rates_no_data` (an Imu
with angular_velocity_covariance[0] == -1: no angular velocity, REP 145). Per frame, a source
with samples none of which is within `max_age_s` of the frame's stamp counts
`frames_rate_too_old`; one with no sample yet `frames_without_rate`. Messages are only read
here (duck-typed), so this module needs no running ROS.
"""
from __future__ import annotations

import math
import threading
from collections import deque
from typing import Callable

import numpy as np

from ..models.attitude import quaternion_to_matrix
from ..track.aid_acceleration import from_samples, significant
from ..track.rate import ACCELERATION_MAX_AGE_S

IDENTITY_MOUNTING = (0.0, 0.0, 0.0, 1.0)
UNIT_NORM_TOLERANCE = 1e-3  # a quaternion typed with 4 decimals is accepted (and normalised)
SAMPLES_KEPT = 2000  # per input: 2 s of a 1 kHz gyro
TIME_RESET_S = 1.0  # a sample this much older than the newest: time restarted (replay, simulation reset)
# The angular acceleration for the smear model: the slope of the newest rate samples (those
# within ACCELERATION_SPAN_S of the newest: 3 of the identifier's estimates at 10 Hz, a gyro's
# last 0.25 s), when they span at least ACCELERATION_MIN_SPAN_S: two 0.1 s exposures' worth
# (three 10 Hz estimates, less rounding). Within one exposure a 2-10 Hz jitter's swing looks
# like an acceleration: 20" of it seen by 5 gyro samples in 0.08 s gave a slope significant
# against their scatter in up to 80 % of draws, moving every spot by 1-11" (the first frame
# of each jitter mission through the nodes with a gyro: NEES 300-7800); over 0.2 s by at most 2".
ACCELERATION_SPAN_S = 0.25
ACCELERATION_MIN_SPAN_S = 0.19
ACCELERATIONS_KEPT = 50  # the identifier's, one per frame


def stamp_ns(stamp) -> int:
    """builtin_interfaces/Time -> ns."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def mounting_matrix(quaternion) -> np.ndarray:
    """
    Rotation gyro -> sensor frame (3x3) of a mounting quaternion (x, y, z, w).

    ValueError unless 4 finite values of unit norm (within UNIT_NORM_TOLERANCE).
    """
    q = np.asarray(quaternion, float)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"gyro.mounting_quaternion={list(np.ravel(q))} must be 4 finite values (x, y, z, w)")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
        raise ValueError(f"gyro.mounting_quaternion={list(q)} must have unit norm (has {norm:.6f})")
    return quaternion_to_matrix(q / norm)


class RateSamples:
    """
    Recent body-rate samples of one input: (stamp [ns], rate [rad/s] in the sensor frame).

    Thread-safe: the executor adds, the centroider's worker reads.
    """

    def __init__(self, kept: int = SAMPLES_KEPT):
        self._samples: deque[tuple[int, np.ndarray]] = deque(maxlen=kept)
        self._noise: deque[float] = deque(maxlen=kept)  # each sample's stated noise, 1 sigma [rad/s] (0: not stated)
        # Angular accelerations stamped as rate samples (the identifier's estimate of both).
        self._accelerations: deque[tuple[int, np.ndarray]] = deque(maxlen=ACCELERATIONS_KEPT)
        self._lock = threading.Lock()

    def add(self, stamp: int, omega: np.ndarray, noise_rad_s: float = 0.0) -> None:
        """Add a sample [ns, rad/s in the sensor frame] with its stated white noise, 1 sigma per axis [rad/s]."""
        with self._lock:
            if self._samples and stamp < self._samples[-1][0] - TIME_RESET_S * 1e9:
                self._samples.clear()  # the old timeline's samples must not serve the new one's frames
                self._noise.clear()
                self._accelerations.clear()
            self._samples.append((stamp, omega))
            self._noise.append(float(noise_rad_s))

    def add_acceleration(self, stamp: int, alpha: np.ndarray) -> None:
        """Add the angular acceleration [rad/s^2] estimated with the rate sample of the same stamp."""
        with self._lock:
            if self._accelerations and stamp < self._accelerations[-1][0] - TIME_RESET_S * 1e9:
                self._accelerations.clear()
            self._accelerations.append((stamp, alpha))

    def __len__(self) -> int:
        with self._lock:
            return len(self._samples)

    def for_frame(self, frame_stamp: int, exposure_s: float, max_age_s: float) -> tuple[np.ndarray | None, str]:
        """
        Return the rate for a frame stamped `frame_stamp` (mid-exposure) [ns].

        The mean of the samples inside its exposure when there are any (the smear is the mean
        rate's), else the sample nearest its stamp if within max_age_s. Returns (rate or None,
        "ok" | "none" | "too_old").
        """
        with self._lock:
            if not self._samples:
                return None, "none"
            stamps = np.fromiter((s for s, _ in self._samples), np.int64, len(self._samples))
            rates = np.array([r for _, r in self._samples])
        offsets = np.abs(stamps - frame_stamp)
        inside = offsets <= exposure_s * 0.5e9
        if inside.any():
            return rates[inside].mean(axis=0), "ok"
        nearest = int(np.argmin(offsets))
        if offsets[nearest] > max_age_s * 1e9:
            return None, "too_old"
        return rates[nearest], "ok"

    def around_exposure(self, frame_stamp: int, exposure_s: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """
        Return a gyro's samples around a frame's exposure, (offsets [s] (n,), rates (n, 3), noise), or None.

        Those within an exposure's length of either end (offsets from the frame's stamp), for
        the path within the exposure (centroid/streak/exposure_path.py); noise: the largest
        white noise they state, 1 sigma per axis [rad/s] (an Imu's angular_velocity_covariance;
        0 when none is stated). None for an input that came with accelerations (the
        identifier's estimates: one per frame, no path to draw) or without samples.
        """
        reach = 1.5 * exposure_s * 1e9  # from the stamp: half the exposure and one more
        with self._lock:
            if self._accelerations or not self._samples:
                return None
            near = [(s, r, n) for (s, r), n in zip(self._samples, self._noise) if abs(s - frame_stamp) <= reach]
        if not near:
            return None
        return (np.array([(s - frame_stamp) * 1e-9 for s, _, _ in near]), np.array([r for _, r, _ in near]),
                max(n for _, _, n in near))

    def motion_for_frame(self, frame_stamp: int, exposure_s: float, max_age_s: float
                         ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        """
        Return (rate [rad/s], angular acceleration [rad/s^2] or None, verdict) for a frame, as for_frame.

        When accelerations came with the samples (the identifier's `angular_acceleration`,
        stamped as its `angular_velocity`), the newest sample's is the frame's and the rate is
        that sample carried to the frame by it (RateEstimate.at: what the tracker's covariance
        assumes the aid was); the newest sample without one (the identifier had none, or it was
        lost): no acceleration. Otherwise (a gyro) the acceleration is the slope of a straight
        line fitted to the samples stamped within
        ACCELERATION_SPAN_S of the newest one up to the frame's end (at least two stamps
        ACCELERATION_MIN_SPAN_S apart; else None): successive gyro samples, or rate estimates
        that came without accelerations (they arrive a frame or two late), when significant
        against the samples' scatter about the line (track/aid_acceleration.py: three samples at
        least; jitter's slope is not an acceleration). None as well when
        the newest of them is more than ACCELERATION_MAX_AGE_S before the frame's stamp (the
        slope of stale samples is not the frame's: a slew may have stopped or started since; the
        tracker assumes the same age for what the centroider had).
        With samples inside the exposure the rate is their mean (as for_frame); otherwise it is
        the line's value at the frame's stamp (the newest estimate carried forward by the
        acceleration, not the nearest sample's stale value).
        """
        omega, verdict = self.for_frame(frame_stamp, exposure_s, max_age_s)
        if omega is None:
            return None, None, verdict
        end = frame_stamp + exposure_s * 0.5e9
        with self._lock:
            usable = [(s, r) for s, r in self._samples if s <= end]
            accelerations = list(self._accelerations)
        if not usable:
            return omega, None, verdict
        # The newest samples (the identifier's arrive a frame or two after their stamps).
        newest, newest_rate = max(usable, key=lambda sample: sample[0])
        if frame_stamp - newest > ACCELERATION_MAX_AGE_S * 1e9:
            return omega, None, verdict
        inside_exposure = any(abs(s - frame_stamp) <= exposure_s * 0.5e9 for s, _ in usable)
        if accelerations:
            alpha = next((a for s, a in reversed(accelerations) if s == newest), None)
            if alpha is None:
                return omega, None, verdict
            carried = newest_rate + alpha * ((frame_stamp - newest) * 1e-9)
            return (omega if inside_exposure else carried), alpha, verdict
        recent = [(s, r) for s, r in usable if s >= newest - ACCELERATION_SPAN_S * 1e9]
        if len(recent) < 2:
            return omega, None, verdict
        t = np.array([(s - frame_stamp) * 1e-9 for s, _ in recent])
        if t.max() - t.min() < ACCELERATION_MIN_SPAN_S:
            return omega, None, verdict
        rates = np.array([r for _, r in recent])
        design = np.column_stack([np.ones_like(t), t])
        (at_frame, alpha), *_ = np.linalg.lstsq(design, rates, rcond=None)
        if not (np.all(np.isfinite(alpha)) and np.all(np.isfinite(at_frame))):
            return omega, None, verdict
        inside = np.abs(t) <= exposure_s * 0.5
        # Only a slope the samples show beyond their scatter about it (jitter makes a spurious one).
        return (omega if inside.any() else at_frame), significant(*from_samples(t, rates)), verdict


class RateInput:
    """Both rate topics' messages -> RateSamples in the sensor frame, with the checks above."""

    def __init__(self, reject: Callable[[str, str], None], mounting_quaternion=IDENTITY_MOUNTING,
                 gyro_frame_id: str = "", gyro_noise_rad_s: float = 0.0):
        """
        Keep the samples of both rate topics.

        reject(counter, text): count and report a refused message or an unaided frame;
        gyro_noise_rad_s: the gyro's white noise per sample, 1 sigma per axis [rad/s], for the
        messages that state none (angular_velocity; an imu whose covariance is all zeros);
        0: not known.
        """
        self.reject = reject
        self.mounting = mounting_matrix(mounting_quaternion)
        self.gyro_frame_id = gyro_frame_id
        self.gyro_noise_rad_s = float(gyro_noise_rad_s)
        self.samples = {"angular_velocity": RateSamples(), "imu": RateSamples()}

    def clear(self) -> None:
        """Forget every sample received (lifecycle cleanup); the mounting and frame stay."""
        self.samples = {topic: RateSamples() for topic in self.samples}

    def on_vector3(self, msg) -> None:
        """geometry_msgs/Vector3Stamped: in the gyro frame (when configured) or the sensor frame."""
        v = msg.vector
        in_gyro_frame = bool(self.gyro_frame_id) and msg.header.frame_id == self.gyro_frame_id
        self._add("angular_velocity", msg.header, np.array([v.x, v.y, v.z], float), rotate=in_gyro_frame,
                  noise_rad_s=self.gyro_noise_rad_s)

    def on_acceleration(self, msg) -> None:
        """geometry_msgs/Vector3Stamped angular_acceleration (the identifier's): kept with its input's rate samples."""
        v = msg.vector
        vector = np.array([v.x, v.y, v.z], float)
        if not np.all(np.isfinite(vector)):
            self.reject("rates_rejected", f"rejected angular_acceleration with non-finite values {vector}")
            return
        stamp = stamp_ns(msg.header.stamp)
        if stamp == 0:
            self.reject("rates_rejected", "rejected angular_acceleration: unstamped (stamp 0)")
            return
        in_gyro_frame = bool(self.gyro_frame_id) and msg.header.frame_id == self.gyro_frame_id
        self.samples["angular_velocity"].add_acceleration(stamp, self.mounting @ vector if in_gyro_frame else vector)

    def on_imu(self, msg) -> None:
        """sensor_msgs/Imu: its angular_velocity, in the gyro frame (REP 145)."""
        frame_id = msg.header.frame_id
        if self.gyro_frame_id and frame_id != self.gyro_frame_id:
            self.reject("rates_wrong_frame", f"ignored imu in frame {frame_id!r}: the gyro frame is "
                        f"{self.gyro_frame_id!r} (parameter gyro.frame_id)")
            return
        if msg.angular_velocity_covariance[0] == -1.0:
            self.reject("rates_no_data", "ignored imu without angular velocity (angular_velocity_covariance[0] == -1)")
            return
        w = msg.angular_velocity
        # Its stated noise: the largest variance on the diagonal (all zeros: not stated, REP 145,
        # then the configured gyro noise).
        variance = max(float(v) for v in (msg.angular_velocity_covariance[0], msg.angular_velocity_covariance[4],
                                          msg.angular_velocity_covariance[8]))
        noise = math.sqrt(variance) if math.isfinite(variance) and variance > 0.0 else self.gyro_noise_rad_s
        self._add("imu", msg.header, np.array([w.x, w.y, w.z], float), rotate=True, noise_rad_s=noise)

    def _add(self, topic: str, header, vector: np.ndarray, rotate: bool, noise_rad_s: float = 0.0) -> None:
        if not np.all(np.isfinite(vector)):
            self.reject("rates_rejected", f"rejected {topic} with non-finite values {vector}")
            return
        stamp = stamp_ns(header.stamp)
        if stamp == 0:
            self.reject("rates_rejected", f"rejected {topic}: unstamped (stamp 0)")
            return
        self.samples[topic].add(stamp, self.mounting @ vector if rotate else vector, noise_rad_s)

    def for_frame(self, topic: str, frame_stamp: int, exposure_s: float, max_age_s: float) -> np.ndarray | None:
        """Return the body rate [rad/s, sensor frame] from `topic` for a frame, or None (counted)."""
        omega, verdict = self.samples[topic].for_frame(frame_stamp, exposure_s, max_age_s)
        if verdict == "too_old":
            self.reject("frames_rate_too_old", f"frame {frame_stamp * 1e-9:.6f}: no {topic} message within "
                        f"max_rate_age_s={max_age_s:g} s of its stamp; measured without the rate aid")
        elif verdict == "none":
            self.reject("frames_without_rate", f"frame {frame_stamp * 1e-9:.6f}: no {topic} message received yet; "
                        "measured without the rate aid")
        return omega

    def motion_for_frame(self, topic: str, frame_stamp: int, exposure_s: float, max_age_s: float
                         ) -> tuple[np.ndarray, np.ndarray | None] | None:
        """
        Return (body rate [rad/s], angular acceleration [rad/s^2] or None) from `topic` for a frame.

        None when there is no rate (counted as for_frame).
        """
        omega, alpha, verdict = self.samples[topic].motion_for_frame(frame_stamp, exposure_s, max_age_s)
        if omega is None:
            self.for_frame(topic, frame_stamp, exposure_s, max_age_s)  # counts why
            return None
        return omega, alpha

    def around_exposure(self, topic: str, frame_stamp: int, exposure_s: float
                        ) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Return `topic`'s gyro samples around a frame's exposure (RateSamples.around_exposure)."""
        return self.samples[topic].around_exposure(frame_stamp, exposure_s)
