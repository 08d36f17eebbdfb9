"""Rosbag2 bags (sqlite3 or MCAP storage) without ROS: open and validate, list topics,
iterate raw (serialized CDR) messages, write, and recover a bag whose recording was killed.

Built on the `rosbags` library, so every bag written here has the standard rosbag2 layout
(a directory with metadata.yaml, version 9, and one .db3 or .mcap file) that `ros2 bag
info/play` read. Every problem raises BagError with a message naming the bag, the file or
topic and what is wrong; nothing here imports rclpy. Times are integer nanoseconds.
"""
from __future__ import annotations

import io
import shutil
import sqlite3
import struct
from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Iterator

# The topics of a star_tracker run (msg_docs/README.md), as absolute names in the root namespace.
CAMERA_TOPICS = ("/image_raw", "/camera_info")
TRUTH_TOPICS = ("/truth/attitude", "/truth/angular_velocity", "/truth/objects")
OUTPUT_TOPICS = ("/spots", "/attitude", "/attitude_with_covariance", "/angular_velocity",
                 "/angular_velocity_with_covariance", "/matched_stars")
DEFAULT_RECORD_TOPICS = CAMERA_TOPICS + TRUTH_TOPICS + OUTPUT_TOPICS

STORAGES = ("sqlite3", "mcap")
BAG_VERSION = 9  # rosbag2 metadata version of ROS 2 Jazzy
IMAGE_TYPE = "sensor_msgs/msg/Image"
# What the centroider accepts (star_tracker.ros.convert.image_to_array), bytes per pixel.
IMAGE_ENCODINGS = {"mono8": 1, "8UC1": 1, "mono16": 2, "16UC1": 2}
_STORAGE_SUFFIX = {"sqlite3": ".db3", "mcap": ".mcap"}
_MCAP_MAGIC = b"\x89MCAP0\r\n"


class BagError(Exception):
    """A bag cannot be opened, read, written or recovered; the message says why."""


@lru_cache(maxsize=1)
def typestore():
    """The ROS 2 Jazzy message definitions shipped with rosbags (no ROS install needed)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def absolute_topic(name: str) -> str:
    """'image_raw' -> '/image_raw' (topics recorded from the root namespace)."""
    name = name.strip()
    if not name or name == "/":
        raise BagError(f"invalid topic name {name!r}")
    return name if name.startswith("/") else "/" + name


def header_stamp_ns(data: bytes | memoryview) -> int:
    """The header stamp [ns] of a serialized message whose first field is a std_msgs/Header
    (every stamped message), read from the CDR bytes without deserializing the rest."""
    if len(data) < 12:
        raise BagError(f"serialized message of {len(data)} bytes is too short for a header")
    order = "<" if bytes(data[1:2]) in (b"\x01", b"\x03") else ">"  # CDR_LE / PL_CDR_LE
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec * 1_000_000_000 + nanosec


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


# ----------------------------------------------------------------------------- reading
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
        """A `ros2 bag info`-like summary."""
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


def _explain_read_error(path: Path, exc: BaseException) -> str:
    """A rosbags/sqlite error turned into a sentence a user can act on."""
    text = str(exc)
    reindex = f"if a recording was interrupted, `star-tracker reindex {path}` recovers what was written"
    if "magic" in text.lower() or "footer" in text.lower() or "Truncated record" in text or "summary" in text:
        return f"{path}: MCAP file {_storage_files(path)} is truncated or was never finished ({text}); {reindex}"
    if any(key in text for key in ("malformed", "not a database", "missing tables", "I/O error", "Cannot open database")):
        return f"{path}: sqlite3 storage file {_storage_files(path)} is corrupt or truncated ({text}); {reindex}"
    if "metadata" in text.lower() or "YAML" in text:
        return f"{path}: invalid metadata.yaml ({text}); `star-tracker reindex {path}` rewrites it from the storage"
    if "database files are missing" in text:
        return f"{path}: {text}"
    return f"{path}: cannot read bag ({type(exc).__name__}: {text})"


class BagReader:
    """A rosbag2 bag (directory, or a bare .db3/.mcap file) opened for reading.

    Use as a context manager. `info` lists topics; `messages()` yields
    (topic, bag timestamp [ns], serialized CDR bytes) in timestamp order."""

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
            raise BagError(_explain_read_error(path, exc)) from None
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
            meta = _load_metadata(self.path)
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
        """metadata.yaml's message counts against what the storage files hold: a file cut
        short after the bag was closed shows up here, not halfway through a replay."""
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
        """(topic, timestamp [ns], serialized message) in timestamp order; storage errors met
        while reading (a damaged file) become BagError."""
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
                raise BagError(_explain_read_error(self.path, exc)) from None
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


def _load_metadata(path: Path) -> dict:
    """metadata.yaml parsed as YAML 1.2, like rosbags and rosbag2 (PyYAML's 1.1 would turn a
    custom_data value such as 'yes' into True)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        data = YAML(typ="safe").load((path / "metadata.yaml").read_text())
        return data["rosbag2_bagfile_information"]
    except (OSError, YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"{path}: invalid metadata.yaml ({type(exc).__name__}: {exc}); "
                       f"`star-tracker reindex {path}` rewrites it from the storage") from None


def check_bag(path: str | Path) -> tuple[BagInfo, list[str]]:
    """Open a bag and read every message: each must deserialize with its type's definition
    and images must suit the centroider. Returns the bag's info and the problems found
    (empty when the bag is sound); a bag that cannot be opened raises BagError."""
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


# ----------------------------------------------------------------------------- writing
def message_definition(msgtype: str) -> tuple[str, str]:
    """(concatenated .msg definition, RIHS01 type hash) of a ROS 2 Jazzy type."""
    store = typestore()
    if msgtype not in store.types:
        raise BagError(f"message type {msgtype} is unknown: no definition in the ROS 2 Jazzy type store, "
                       f"so it cannot be recorded with a definition")
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    return msgdef, store.hash_rihs01(msgtype)


class BagWriter:
    """A new rosbag2 bag (metadata version 9) in directory `path`, which must not exist.

    `flush()` makes what was written so far survive a crash (commit for sqlite3, a closed
    chunk for MCAP); `close()` finishes the bag and writes metadata.yaml. Not thread-safe:
    one thread owns a writer."""

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

    def write(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f"topic {topic} was not added to the bag")
        self._writer.write(conn, int(timestamp_ns), data)
        self.counts[topic] += 1
        self.bytes_written += len(data)

    def flush(self) -> None:
        """Make everything written so far durable against a crash of this process. Uses the
        storage objects of the pinned rosbags 0.11.9, which otherwise keep one open sqlite
        transaction (or one open MCAP chunk) until close()."""
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
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, str(value))
        self._writer.close()
        with BagReader(self.path) as bag:
            return bag.info

    def abort(self) -> None:
        """Stop without finishing (what was flushed stays recoverable with reindex)."""
        try:
            self._writer.abort()
        except Exception:  # noqa: BLE001 - already broken
            pass


# ----------------------------------------------------------------------------- recovery
def reindex(path: str | Path) -> BagInfo:
    """Rebuild metadata.yaml of a bag directory from its storage file(s), like `ros2 bag
    reindex`: after a recorder was killed (no metadata.yaml) or a metadata.yaml was lost.

    sqlite3: opening the database rolls back an unfinished transaction, so everything
    committed (flushed) is kept. MCAP: a file without footer, possibly cut inside a record,
    is rewritten with every complete record up to the cut (the original is kept beside it
    as NAME.unfinished). Returns the recovered bag's info."""
    path = Path(path)
    if not path.is_dir():
        raise BagError(f"{path} is not a bag directory")
    db3 = sorted(path.glob("*.db3"))
    mcap = sorted(path.glob("*.mcap"))
    if db3 and mcap:
        raise BagError(f"{path} holds both .db3 and .mcap files; remove the ones that do not belong to the bag")
    if not db3 and not mcap:
        raise BagError(f"{path} holds no .db3 or .mcap storage file: nothing to reindex")
    if db3:
        for file in db3:
            _recover_sqlite(file)
        _write_metadata(path, "sqlite3", db3)
    else:
        for file in mcap:
            _recover_mcap(file)
        _write_metadata(path, "mcap", mcap)
    with BagReader(path) as bag:
        return bag.info


def _recover_sqlite(file: Path) -> None:
    """Open read-write once: sqlite rolls back a hot journal left by a killed writer."""
    try:
        connection = sqlite3.connect(file)
        try:
            tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            if not {"messages", "topics"} <= tables:
                raise BagError(f"{file}: no rosbag2 tables (messages, topics): the recording died before "
                               f"anything was committed, or this is not a rosbag2 database")
            check = connection.execute("PRAGMA quick_check").fetchone()[0]
            if check != "ok":
                raise BagError(f"{file}: sqlite3 storage file is corrupt ({check}); it cannot be reindexed")
        finally:
            connection.close()
    except sqlite3.DatabaseError as exc:
        raise BagError(f"{file}: sqlite3 storage file is corrupt or truncated ({exc}); it cannot be reindexed") from None


def _recover_mcap(file: Path) -> None:
    """Keep a readable MCAP file; rewrite one that has no footer from its complete records."""
    from rosbags.rosbag2.storage_mcap import McapReader

    reader = McapReader(file)
    try:
        reader.open()
        reader.close()
        return  # finished file: only metadata.yaml needs rebuilding
    except Exception:  # noqa: BLE001 - unfinished or damaged: salvage below
        pass
    scratch = file.parent / f".{file.stem}.reindex"
    if scratch.exists():
        shutil.rmtree(scratch)
    writer = BagWriter(scratch, "mcap")
    try:
        _salvage_mcap_records(file, writer)
        writer._writer.close()  # the scratch metadata.yaml is discarded below
    except BaseException:
        writer.abort()
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    file.rename(file.with_name(file.name + ".unfinished"))
    (scratch / f"{scratch.name}.mcap").rename(file)
    shutil.rmtree(scratch)


def _salvage_mcap_records(file: Path, writer: BagWriter) -> None:
    """Copy schemas, channels and messages of every complete record of `file` to `writer`
    (stops at the first incomplete record: the point where the recorder was killed)."""
    from rosbags.rosbag2.metadata import parse_qos

    data = file.read_bytes()
    if not data.startswith(_MCAP_MAGIC):
        raise BagError(f"{file}: not an MCAP file (bad magic); it cannot be reindexed")
    schemas: dict[int, tuple[str, str, str]] = {}
    topics: dict[int, str] = {}

    def records(buffer: bytes, offset: int, end: int):
        while offset + 9 <= end:
            op, length = buffer[offset], struct.unpack_from("<Q", buffer, offset + 1)[0]
            body = offset + 9
            if body + length > end:
                return  # cut inside this record
            yield op, buffer[body:body + length]
            offset = body + length

    def string(buffer: bytes, offset: int) -> tuple[str, int]:
        (n,) = struct.unpack_from("<I", buffer, offset)
        return buffer[offset + 4:offset + 4 + n].decode(), offset + 4 + n

    def handle(op: int, body: bytes) -> bool:
        if op == 0x03:  # schema
            (sid,) = struct.unpack_from("<H", body, 0)
            name, o = string(body, 2)
            encoding, o = string(body, o)
            (n,) = struct.unpack_from("<I", body, o)
            schemas[sid] = (name, encoding, body[o + 4:o + 4 + n].decode())
        elif op == 0x04:  # channel
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, o = string(body, 4)
            _encoding, o = string(body, o)
            (n,) = struct.unpack_from("<I", body, o)
            meta, o, end = {}, o + 4, o + 4 + n
            while o < end:
                key, o = string(body, o)
                value, o = string(body, o)
                meta[key] = value
            if sid not in schemas:
                raise BagError(f"{file}: channel {topic} refers to a missing schema")
            if cid not in topics and topic not in writer._connections:
                writer.add_topic(topic, schemas[sid][0], parse_qos(meta.get("offered_qos_profiles", "")))
            topics[cid] = topic
        elif op == 0x05:  # message
            cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
            if cid in topics:
                writer.write(topics[cid], log_time, body[22:])
        elif op == 0x02:  # footer: the file was complete after all
            return False
        return True

    for op, body in records(data, len(_MCAP_MAGIC), len(data)):
        if op == 0x06:  # chunk: start, end, uncompressed size, crc, compression, records
            o = 28
            compression, o = string(body, o)
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
            for inner_op, inner in records(payload, 0, len(payload)):
                handle(inner_op, inner)
        elif not handle(op, body):
            break


def _write_metadata(path: Path, storage: str, files: list[Path]) -> None:
    """metadata.yaml (version 9, as rosbags' Writer and rosbag2 write it) from storage files."""
    from rosbags.rosbag2.metadata import dump_qos_v9
    from ruamel.yaml import YAML
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    topics: dict[tuple[str, str], dict] = {}
    file_entries, starts, ends, total = [], [], [], 0
    for file in files:
        reader = (Sqlite3Reader if storage == "sqlite3" else McapReader)(file)
        try:
            reader.open()
        except Exception as exc:  # noqa: BLE001
            raise BagError(_explain_read_error(file, exc)) from None
        try:
            meta = reader.metadata
            count = meta.message_count
            start, end = (meta.start_time, meta.end_time - 1) if count else (0, 0)
            for conn in reader.connections:
                key = (conn.topic, conn.msgtype)
                entry = topics.setdefault(key, {"conn": conn, "count": 0})
                entry["count"] += conn.msgcount
        finally:
            reader.close()
        file_entries.append({"path": file.name, "starting_time": {"nanoseconds_since_epoch": start},
                             "duration": {"nanoseconds": end - start}, "message_count": count})
        if count:
            starts.append(start)
            ends.append(end)
        total += count
    store = typestore()
    start = min(starts) if starts else 0
    end = max(ends) if ends else 0
    info = {
        "version": BAG_VERSION,
        "storage_identifier": storage,
        "relative_file_paths": [f.name for f in files],
        "duration": {"nanoseconds": end - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total,
        "topics_with_message_count": [
            {"topic_metadata": {
                "name": conn.topic, "type": conn.msgtype,
                "serialization_format": conn.ext.serialization_format,
                "offered_qos_profiles": dump_qos_v9(list(conn.ext.offered_qos_profiles)),
                "type_description_hash": conn.digest or (store.hash_rihs01(conn.msgtype)
                                                         if conn.msgtype in store.types else ""),
            }, "message_count": entry["count"]}
            for entry in topics.values() for conn in [entry["conn"]]
        ],
        "compression_format": "",
        "compression_mode": "",
        "files": file_entries,
        "custom_data": {"star_tracker.reindexed": "true"},
        "ros_distro": "rosbags",
    }
    text = io.StringIO()
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    yaml.dump({"rosbag2_bagfile_information": info}, text)
    tmp = path / "metadata.yaml.tmp"
    tmp.write_text(text.getvalue())
    tmp.replace(path / "metadata.yaml")
