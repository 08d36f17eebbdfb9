# SPDX-License-Identifier: Apache-2.0
"""
Writing a new rosbag2 bag (metadata version 9, sqlite3 or MCAP storage) that `ros2 bag info/play` read.

Message definitions and type hashes come from the ROS 2 Jazzy type store.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Iterable

from .format import BAG_VERSION, STORAGES, BagError, absolute_topic, typestore
from .reader import BagInfo, BagReader


def message_definition(msgtype: str) -> tuple[str, str]:
    """(concatenated .msg definition, RIHS01 type hash) of a ROS 2 Jazzy type."""
    store = typestore()
    if msgtype not in store.types:
        raise BagError(f"message type {msgtype} is unknown: no definition in the ROS 2 Jazzy type store, "
                       f"so it cannot be recorded with a definition")
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    return msgdef, store.hash_rihs01(msgtype)


class BagWriter:
    """
    A new rosbag2 bag (metadata version 9) in directory `path`, which must not exist.

    `flush()` makes what was written so far survive a crash (commit for sqlite3, a closed
    chunk for MCAP); `close()` finishes the bag and writes metadata.yaml. Not thread-safe:
    one thread owns a writer.
    """

    def __init__(self, path: str | Path, storage: str = "sqlite3"):
        from rosbags.rosbag2 import StoragePlugin, Writer

        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}; choose one of {', '.join(STORAGES)}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists already; choose a new output directory")
        self.storage = storage
        plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=plugin)
        try:
            self._writer.open()
        except Exception as exc:  # noqa: BLE001
            raise BagError(f"cannot create bag {self.path}: {exc}") from None
        self._connections: dict[str, object] = {}
        self.counts: Counter[str] = Counter()
        self.bytes_written = 0

    def add_topic(self, name: str, msgtype: str, offered_qos: Iterable = (), type_hash: str | None = None) -> None:
        """Register a topic before its first message. offered_qos: rosbags Qos of its publishers."""
        name = absolute_topic(name)
        if name in self._connections:
            raise BagError(f"topic {name} is already in the bag")
        msgdef, known_hash = message_definition(msgtype)
        self._connections[name] = self._writer.add_connection(
            name, msgtype, msgdef=msgdef, rihs01=type_hash or known_hash, offered_qos_profiles=list(offered_qos))

    def has_topic(self, name: str) -> bool:
        """Whether topic `name` (absolute) was added."""
        return name in self._connections

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f"topic {topic} was not added to the bag")
        self._writer.write(conn, int(timestamp_ns), data)
        self.counts[topic] += 1
        self.bytes_written += len(data)

    def flush(self) -> None:
        """
        Make everything written so far durable against a crash of this process.

        Uses the storage objects of the pinned rosbags 0.11.9, which otherwise keep one open
        sqlite transaction (or one open MCAP chunk) until close().
        """
        storage = self._writer.storage
        if storage is None:
            return
        if self.storage == "sqlite3":
            storage.conn.commit()
        else:
            if storage.chunk.msgs:
                storage.close_chunk()
            storage.bio.flush()

    def close(self, custom_data: dict[str, str] | None = None) -> BagInfo:
        """Finish the bag (storage and metadata.yaml) and return its info as read back."""
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, str(value))
        self.close_storage()
        with BagReader(self.path) as bag:
            return bag.info

    def close_storage(self) -> None:
        """Finish the storage file and metadata.yaml without reading the bag back."""
        self._writer.close()

    def abort(self) -> None:
        """Stop without finishing (what was flushed stays recoverable with reindex)."""
        try:
            self._writer.abort()
        except Exception:  # noqa: BLE001 - already broken
            pass
