# SPDX-License-Identifier: Apache-2.0
"""Checking a bag's content: every message deserializes with its type's definition, and images suit the centroider."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

from .format import IMAGE_ENCODINGS, IMAGE_TYPE, typestore
from .reader import BagInfo, BagReader


def image_problem(data: bytes | memoryview) -> str | None:
    """Why a serialized sensor_msgs/msg/Image cannot go to the centroider, or None."""
    try:
        msg = typestore().deserialize_cdr(data, IMAGE_TYPE)
    except Exception as exc:  # noqa: BLE001 - any decoding failure is the answer
        return f"not a valid {IMAGE_TYPE} ({type(exc).__name__}: {exc})"
    if msg.encoding not in IMAGE_ENCODINGS:
        return (f"image encoding {msg.encoding!r} is not supported; the centroider accepts "
                f"{', '.join(IMAGE_ENCODINGS)}")
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if width <= 0 or height <= 0:
        return f"empty image {width}x{height}"
    if step < width * IMAGE_ENCODINGS[msg.encoding]:
        return f"step {step} < width {width} x {IMAGE_ENCODINGS[msg.encoding]} bytes per pixel"
    if len(msg.data) != step * height:
        return f"image data holds {len(msg.data)} bytes, step x height is {step * height}"
    return None


def check_bag(path: str | Path) -> tuple[BagInfo, list[str]]:
    """
    Open a bag and read every message.

    Each must deserialize with its type's definition and images must suit the centroider.
    Returns the bag's info and the problems found (empty when the bag is sound); a bag that
    cannot be opened raises BagError.
    """
    problems: list[str] = []
    store = typestore()
    with BagReader(path) as bag:
        info = bag.info
        unknown = {t.name for t in info.topics.values() if t.type not in store.types}
        for topic in sorted(unknown):
            problems.append(f"{topic}: type {info.topics[topic].type} is unknown (not a ROS 2 Jazzy type): "
                            f"its messages were not checked")
        bad: Counter[str] = Counter()
        first_bad: dict[str, str] = {}
        for topic, timestamp, data in bag.messages():
            if topic in unknown:
                continue
            kind = info.topics[topic].type
            if kind == IMAGE_TYPE:
                problem = image_problem(data)
            else:
                try:
                    store.deserialize_cdr(data, kind)
                    problem = None
                except Exception as exc:  # noqa: BLE001
                    problem = f"does not deserialize as {kind} ({type(exc).__name__}: {exc})"
            if problem:
                bad[topic] += 1
                first_bad.setdefault(topic, f"message at {timestamp * 1e-9:.6f} s: {problem}")
        for topic in sorted(bad):
            problems.append(f"{topic}: {bad[topic]} bad message(s); first: {first_bad[topic]}")
    return info, problems
