# SPDX-License-Identifier: Apache-2.0
"""
Opening a rosbag2 bag for reading.

metadata.yaml and storage checked against each other, topic listing (BagInfo), raw messages
in timestamp order; every failure becomes a BagError that says what to do (often
`star-tracker reindex`).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

from .format import BagError, absolute_topic


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: type, message count, the QoS its publishers offered (rosbags Qos)."""

    name: str
    type: str
    count: int
    offered_qos: tuple = ()
    type_hash: str = ""
    serialization_format: str = "cdr"


@dataclass(frozen=True)
class BagInfo:
    """What metadata.yaml and the storage say about a bag."""

    path: Path
    storage: str
    files: tuple[str, ...]
    start_ns: int
    end_ns: int  # timestamp of the last message
    message_count: int
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    custom_data: dict[str, str] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return max(0, self.end_ns - self.start_ns) * 1e-9

    def describe(self) -> str:
        """Return a `ros2 bag info`-like summary."""
        size = sum(f.stat().st_size for f in (self.path / name for name in self.files) if f.exists()) \
            if self.path.is_dir() else self.path.stat().st_size
        lines = [f"bag:       {self.path}",
                 f"storage:   {self.storage} ({', '.join(self.files)}), {size / 2**20:.1f} MiB",
                 f"duration:  {self.duration_s:.3f} s",
                 f"start:     {self.start_ns * 1e-9:.6f} s",
                 f"messages:  {self.message_count}",
                 "topics:"]
        width = max((len(t) for t in self.topics), default=0)
        for topic in sorted(self.topics):
            info = self.topics[topic]
            qos = ", ".join(_qos_text(q) for q in info.offered_qos) or "QoS not recorded"
            lines.append(f"  {topic:<{width}}  {info.type}  {info.count} msgs  [{qos}]")
        return "\n".join(lines)


def _qos_text(qos) -> str:
    return f"{qos.reliability.name.lower()}, {qos.durability.name.lower()}"


def _storage_files(path: Path) -> str:
    if path.is_dir():
        return ", ".join(sorted(p.name for p in path.iterdir() if p.suffix in (".db3", ".mcap"))) or "(none)"
    return path.name


def explain_read_error(path: Path, exc: BaseException) -> str:
    """Return a rosbags/sqlite error turned into a sentence a user can act on."""
    text = str(exc)
    reindex = f"if a recording was interrupted, `star-tracker reindex {path}` recovers what was written"
    if "magic" in text.lower() or "footer" in text.lower() or "Truncated record" in text or "summary" in text:
        return f"{path}: MCAP file {_storage_files(path)} is truncated or was never finished ({text}); {reindex}"
    if any(key in text
           for key in ("malformed", "not a database", "missing tables", "I/O error", "Cannot open database")):
        return f"{path}: sqlite3 storage file {_storage_files(path)} is corrupt or truncated ({text}); {reindex}"
    if "metadata" in text.lower() or "YAML" in text:
        return f"{path}: invalid metadata.yaml ({text}); `star-tracker reindex {path}` rewrites it from the storage"
    if "database files are missing" in text:
        return f"{path}: {text}"
    return f"{path}: cannot read bag ({type(exc).__name__}: {text})"


class BagReader:
    """
    A rosbag2 bag (directory, or a bare .db3/.mcap file) opened for reading.

    Use as a context manager. `info` lists topics; `messages()` yields
    (topic, bag timestamp [ns], serialized CDR bytes) in timestamp order.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._reader = None
        self.info: BagInfo | None = None

    def open(self) -> "BagReader":
        from rosbags.rosbag2 import Reader

        path = self.path
        if not path.exists():
            raise BagError(f"no bag at {path}")
        if path.is_dir() and not (path / "metadata.yaml").exists():
            stored = sorted(p.name for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
            if stored:
                raise BagError(f"{path} has no metadata.yaml: its recording did not finish (killed or crashed?); "
                               f"`star-tracker reindex {path}` recovers what was written to {', '.join(stored)}")
            raise BagError(f"{path} is not a rosbag2 bag: no metadata.yaml and no .db3 or .mcap file")
        if path.is_file() and path.suffix not in (".db3", ".mcap"):
            raise BagError(f"{path} is not a rosbag2 bag directory nor a .db3/.mcap file")
        try:
            reader = Reader(path)
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds; all become BagError
            raise BagError(explain_read_error(path, exc)) from None
        self._reader = reader
        try:
            self.info = self._collect_info()
        except BagError:
            self.close()
            raise
        return self

    def _collect_info(self) -> BagInfo:
        reader = self._reader
        storage = {".db3": "sqlite3", ".mcap": "mcap"}.get(self.path.suffix, "")
        files: tuple[str, ...] = (self.path.name,)
        custom: dict[str, str] = {}
        if self.path.is_dir():
            meta = load_metadata(self.path)
            storage = meta.get("storage_identifier", "")
            files = tuple(Path(p).name for p in meta.get("relative_file_paths", []))
            custom = dict(meta.get("custom_data") or {})
            self._check_counts(meta)
        topics: dict[str, TopicInfo] = {}
        for conn in reader.connections:
            previous = topics.get(conn.topic)
            if previous is not None and previous.type != conn.msgtype:
                raise BagError(f"{self.path}: topic {conn.topic} has two types, {previous.type} and {conn.msgtype}")
            count = conn.msgcount + (previous.count if previous else 0)
            topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count, tuple(conn.ext.offered_qos_profiles),
                                           conn.digest or "", conn.ext.serialization_format)
        count = reader.message_count
        start = reader.start_time if count else 0
        end = reader.end_time - 1 if count else 0
        return BagInfo(self.path, storage, files, start, end, count, topics, custom)

    def _check_counts(self, meta: dict) -> None:
        """
        metadata.yaml's message counts against what the storage files hold.

        A file cut short after the bag was closed shows up here, not halfway through a
        replay.
        """
        stored: Counter[str] = Counter()
        for storage in getattr(self._reader.storage, "storages", []):
            for conn in storage.connections:
                stored[conn.topic] += conn.msgcount
        if not stored:
            return
        for entry in meta.get("topics_with_message_count", []):
            name = entry["topic_metadata"]["name"]
            if stored[name] != entry["message_count"]:
                raise BagError(f"{self.path}: metadata.yaml lists {entry['message_count']} messages on {name} but "
                               f"the storage holds {stored[name]}: the storage file was truncated or replaced; "
                               f"`star-tracker reindex {self.path}` rewrites metadata.yaml from what is there")

    def select(self, topics: Iterable[str] | None = None) -> list[str]:
        """Absolute topic names to read: all, or `topics`, each of which must be in the bag."""
        assert self.info is not None, "open() the bag first"
        if topics is None:
            return sorted(self.info.topics)
        wanted = [absolute_topic(t) for t in topics]
        missing = [t for t in wanted if t not in self.info.topics]
        if missing:
            raise BagError(f"{self.path}: no topic {', '.join(missing)} in the bag; "
                           f"its topics are {', '.join(sorted(self.info.topics)) or '(none)'}")
        return list(dict.fromkeys(wanted))

    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """
        (topic, timestamp [ns], serialized message) in timestamp order.

        Storage errors met while reading (a damaged file) become BagError.
        """
        selected = set(self.select(topics))
        connections = [c for c in self._reader.connections if c.topic in selected]
        if not connections:
            return
        iterator = self._reader.messages(connections, start=start_ns, stop=stop_ns)
        while True:
            try:
                conn, timestamp, data = next(iterator)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001
                raise BagError(explain_read_error(self.path, exc)) from None
            yield conn.topic, timestamp, data

    def close(self) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            finally:
                self._reader = None

    def __enter__(self) -> "BagReader":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()


def load_metadata(path: Path) -> dict:
    """
    metadata.yaml parsed as YAML 1.2.

    Like rosbags and rosbag2 (PyYAML's 1.1 would turn a custom_data value such as 'yes' into
    True).
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        data = YAML(typ="safe").load((path / "metadata.yaml").read_text())
        return data["rosbag2_bagfile_information"]
    except (OSError, YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"{path}: invalid metadata.yaml ({type(exc).__name__}: {exc}); "
                       f"`star-tracker reindex {path}` rewrites it from the storage") from None
