# SPDX-License-Identifier: Apache-2.0
"""
Salvaging an MCAP file that was never finished (no footer, possibly cut inside a record).

Schemas, channels and messages of every complete record, chunks included, copied to a
BagWriter.
"""
from __future__ import annotations

import struct
from pathlib import Path

from .format import BagError
from .writer import BagWriter

MCAP_MAGIC = b"\x89MCAP0\r\n"


def _records(buffer: bytes, offset: int, end: int):
    """(opcode, body) of each complete MCAP record in buffer[offset:end]; stops at a cut one."""
    while offset + 9 <= end:
        op, length = buffer[offset], struct.unpack_from("<Q", buffer, offset + 1)[0]
        body = offset + 9
        if body + length > end:
            return  # cut inside this record
        yield op, buffer[body:body + length]
        offset = body + length


def _string(buffer: bytes, offset: int) -> tuple[str, int]:
    """Return an MCAP string (uint32 length + UTF-8) at offset, and the offset after it."""
    (n,) = struct.unpack_from("<I", buffer, offset)
    return buffer[offset + 4:offset + 4 + n].decode(), offset + 4 + n


def salvage_mcap_records(file: Path, writer: BagWriter) -> None:
    """
    Copy schemas, channels and messages of every complete record of `file` to `writer`.

    Stops at the first incomplete record: the point where the recorder was killed.
    """
    from rosbags.rosbag2.metadata import parse_qos

    data = file.read_bytes()
    if not data.startswith(MCAP_MAGIC):
        raise BagError(f"{file}: not an MCAP file (bad magic); it cannot be reindexed")
    schemas: dict[int, tuple[str, str, str]] = {}
    topics: dict[int, str] = {}

    def handle(op: int, body: bytes) -> bool:
        if op == 0x03:  # schema
            (sid,) = struct.unpack_from("<H", body, 0)
            name, o = _string(body, 2)
            encoding, o = _string(body, o)
            (n,) = struct.unpack_from("<I", body, o)
            schemas[sid] = (name, encoding, body[o + 4:o + 4 + n].decode())
        elif op == 0x04:  # channel
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, o = _string(body, 4)
            _encoding, o = _string(body, o)
            (n,) = struct.unpack_from("<I", body, o)
            meta, o, end = {}, o + 4, o + 4 + n
            while o < end:
                key, o = _string(body, o)
                value, o = _string(body, o)
                meta[key] = value
            if sid not in schemas:
                raise BagError(f"{file}: channel {topic} refers to a missing schema")
            if cid not in topics and not writer.has_topic(topic):
                writer.add_topic(topic, schemas[sid][0], parse_qos(meta.get("offered_qos_profiles", "")))
            topics[cid] = topic
        elif op == 0x05:  # message
            cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
            if cid in topics:
                writer.write(topics[cid], log_time, body[22:])
        elif op == 0x02:  # footer: the file was complete after all
            return False
        return True

    for op, body in _records(data, len(MCAP_MAGIC), len(data)):
        if op == 0x06:  # chunk: start, end, uncompressed size, crc, compression, records
            o = 28
            compression, o = _string(body, o)
            (size,) = struct.unpack_from("<Q", body, o)
            payload = body[o + 8:o + 8 + size]
            if compression == "zstd":
                from backports import zstd

                payload = zstd.decompress(payload)
            elif compression == "lz4":
                import lz4.frame

                payload = lz4.frame.decompress(payload)
            elif compression:
                raise BagError(f"{file}: unsupported MCAP chunk compression {compression!r}")
            for inner_op, inner in _records(payload, 0, len(payload)):
                handle(inner_op, inner)
        elif not handle(op, body):
            break
