# SPDX-License-Identifier: Apache-2.0
"""
The identifier's `smear_aid/*` inputs: the rate and acceleration each frame's spots were measured with.

The centroider publishes them before the frame's spots, stamped as them
(msg_docs/smear_aid.md); here they are kept by stamp and joined to the spots, so the tracker
knows what each attitude measured (Spots.applied_motion) even when the rate the identifier
sent reached the centroider frames late. `smear_aid/angular_acceleration` comes with every
measured frame (zero: none applied) and completes a frame's entry; `smear_aid/angular_velocity`
only with rate-aided ones, `smear_aid/exposure_path_offset` (PoseWithCovarianceStamped: the
offset to mid-exposure and its covariance) only with frames measured on a gyro's path (one that
arrives after its frame's acceleration is not waited for: that frame is then taken as its
exposure average, the acceleration terms bounding its offset). Messages are only read here
(duck-typed): no running ROS needed.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable

import numpy as np

from ..centroid.applied_motion import AppliedMotion
from .convert import path_offset_from_msg

KEPT = 64  # frames: a few seconds at the usual rates, more than the spots queues hold
# A frame's acceleration message is published just before its spots, on another topic: the
# worker waits this long for one that is late [s] (only once any has arrived).
JOIN_WAIT_S = 0.02


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _vector(msg) -> np.ndarray | None:
    v = np.array([msg.vector.x, msg.vector.y, msg.vector.z], float)
    return v if np.all(np.isfinite(v)) else None


class SmearAidInput:
    """The centroider's smear_aid messages by stamp. Thread-safe: the executor adds, the worker joins."""

    def __init__(self, reject: Callable[[str, str], None]):
        """reject(counter, text): count and report a refused message (`smear_aid_rejected`: non-finite)."""
        self.reject = reject
        self._rates: OrderedDict[int, np.ndarray] = OrderedDict()
        self._path_offsets: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._accelerations: OrderedDict[int, np.ndarray] = OrderedDict()
        self._arrived = threading.Condition()

    @property
    def received(self) -> bool:
        """Whether any frame's aid arrived: the centroider publishes them."""
        with self._arrived:
            return bool(self._accelerations)

    def on_rate(self, msg) -> None:
        self._add(self._rates, msg)

    def on_path_offset(self, msg) -> None:
        offset = path_offset_from_msg(msg)
        if offset is None:
            self.reject("smear_aid_rejected", f"smear_aid/exposure_path_offset with a malformed orientation or "
                        f"covariance (stamp {_stamp_ns(msg.header) * 1e-9:.6f}); ignored")
            return
        self._store(self._path_offsets, _stamp_ns(msg.header), offset)

    def on_acceleration(self, msg) -> None:
        self._add(self._accelerations, msg)

    def _add(self, store: OrderedDict, msg) -> None:
        vector = _vector(msg)
        if vector is None:
            self.reject("smear_aid_rejected", f"smear_aid message with a non-finite vector (stamp "
                        f"{_stamp_ns(msg.header) * 1e-9:.6f}); ignored")
            return
        self._store(store, _stamp_ns(msg.header), vector)

    def _store(self, store: OrderedDict, stamp_ns: int, value) -> None:
        with self._arrived:
            store[stamp_ns] = value
            while len(store) > KEPT:
                store.popitem(last=False)
            self._arrived.notify_all()

    def applied_for(self, stamp_ns: int, wait_s: float = JOIN_WAIT_S) -> AppliedMotion | None:
        """
        Return the motion the frame stamped `stamp_ns` [ns] was measured with, or None when not known.

        Not known: no aid has arrived at all (another centroider, an old bag), or this frame's
        did not arrive within wait_s [s] (lost: best effort).
        """
        with self._arrived:
            if not self._accelerations:
                return None
            if stamp_ns not in self._accelerations:
                self._arrived.wait_for(lambda: stamp_ns in self._accelerations, timeout=wait_s)
            alpha = self._accelerations.get(stamp_ns)
            if alpha is None:
                return None
            omega = self._rates.get(stamp_ns)
            offset = self._path_offsets.get(stamp_ns)
        alpha = alpha if np.any(alpha) else None
        if offset is None or omega is None or alpha is not None:
            return AppliedMotion(omega, alpha)  # no path, or not a frame fitted on one after all (AppliedMotion's rule)
        return AppliedMotion(omega, alpha, *offset)

    def clear(self) -> None:
        with self._arrived:
            self._rates.clear()
            self._path_offsets.clear()
            self._accelerations.clear()
