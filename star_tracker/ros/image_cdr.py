# SPDX-License-Identifier: Apache-2.0
"""
A serialized sensor_msgs/Image read in place: the centroider's raw subscription.

rclpy's deserialization copies the 2 MiB pixel array into a new Python object for every
message, whether the centroider then measures the frame or drops it for a newer one
(frame_queue.NewestFrame). Subscribed raw (`create_subscription(..., raw=True)`), the message
arrives as its CDR bytes; `parse_image` reads the few header fields and returns the pixels as
a view into those bytes, so a frame that will be dropped costs almost nothing.

The layout (XCDR1, plain CDR as rmw_fastrtps writes it; alignment counted from the end of
the 4-byte encapsulation header): std_msgs/Header (int32 sec, uint32 nanosec, string
frame_id), uint32 height, uint32 width, string encoding, uint8 is_bigendian, uint32 step,
uint8[] data. A string is a uint32 length counting its NUL, then its bytes; a sequence a
uint32 count, then its elements. ValueError for bytes that do not hold that.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

from builtin_interfaces.msg import Time
from std_msgs.msg import Header

ENCAPSULATION_BYTES = 4
# The encapsulation's second byte: representation identifier, little or big endian (CDR and PL_CDR).
_BYTE_ORDER = {0x00: ">", 0x01: "<", 0x02: ">", 0x03: "<"}


@dataclass(frozen=True)
class RawImage:
    """
    The fields of a serialized Image, the pixel data a read-only view into its bytes.

    Attribute names as sensor_msgs/Image's, so convert.image_to_array reads it as a message.
    """

    header: Header
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: memoryview


class _Reader:
    def __init__(self, raw: memoryview, order: str):
        self.raw, self.order, self.offset = raw, order, ENCAPSULATION_BYTES

    def _align(self, size: int) -> None:
        self.offset += (-(self.offset - ENCAPSULATION_BYTES)) % size

    def unpack(self, code: str, size: int):
        self._align(size)
        if self.offset + size > len(self.raw):
            raise ValueError(f"serialized Image ends at byte {len(self.raw)}, before its fields do")
        value = struct.unpack_from(self.order + code, self.raw, self.offset)[0]
        self.offset += size
        return value

    def take(self, count: int) -> memoryview:
        if count < 0 or self.offset + count > len(self.raw):
            raise ValueError(f"serialized Image holds {len(self.raw) - self.offset} bytes where {count} are declared")
        view = self.raw[self.offset:self.offset + count]
        self.offset += count
        return view

    def string(self) -> str:
        length = self.unpack("I", 4)
        text = bytes(self.take(length))
        if length == 0 or text[-1:] != b"\0":
            raise ValueError("serialized Image has a string without its terminating NUL")
        try:
            return text[:-1].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"serialized Image has a string that is not UTF-8: {exc}") from None


def parse_image(raw) -> RawImage:
    """Return the Image serialized in `raw` (bytes-like, CDR with its encapsulation header), pixels not copied."""
    view = memoryview(raw).cast("B")
    if len(view) < ENCAPSULATION_BYTES:
        raise ValueError(f"serialized Image of {len(view)} bytes is shorter than its encapsulation header")
    order = _BYTE_ORDER.get(view[1])
    if order is None:
        raise ValueError(f"serialized Image has an unknown CDR representation 0x{view[0]:02x}{view[1]:02x}")
    reader = _Reader(view, order)
    sec, nanosec = reader.unpack("i", 4), reader.unpack("I", 4)
    frame_id = reader.string()
    height, width = reader.unpack("I", 4), reader.unpack("I", 4)
    encoding = reader.string()
    is_bigendian = reader.unpack("B", 1)
    step = reader.unpack("I", 4)
    data = reader.take(reader.unpack("I", 4))
    header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)
    return RawImage(header, height, width, encoding, is_bigendian, step, data.toreadonly())
