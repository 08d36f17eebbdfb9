# SPDX-License-Identifier: Apache-2.0
"""
Crash recovery, like `ros2 bag reindex`.

metadata.yaml rebuilt from the storage files of a bag whose recorder was killed, an
unfinished MCAP file rewritten from its complete records, a sqlite3 hot journal rolled back.
"""
from __future__ import annotations

import io
import shutil
import sqlite3
from pathlib import Path

from .format import BAG_VERSION, BagError, typestore
from .mcap_salvage import salvage_mcap_records
from .reader import BagInfo, BagReader, explain_read_error
from .writer import BagWriter


def reindex(path: str | Path) -> BagInfo:
    """
    Rebuild metadata.yaml of a bag directory from its storage file(s), like `ros2 bag reindex`.

    After a recorder was killed (no metadata.yaml) or a metadata.yaml was lost.

    sqlite3: opening the database rolls back an unfinished transaction, so everything
    committed (flushed) is kept. MCAP: a file without footer, possibly cut inside a record,
    is rewritten with every complete record up to the cut (the original is kept beside it
    as NAME.unfinished). Returns the recovered bag's info.
    """
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
        raise BagError(f"{file}: sqlite3 storage file is corrupt or truncated ({exc}); "
                       "it cannot be reindexed") from None


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
        salvage_mcap_records(file, writer)
        writer.close_storage()  # the scratch metadata.yaml is discarded below
    except BaseException:
        writer.abort()
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    file.rename(file.with_name(file.name + ".unfinished"))
    (scratch / f"{scratch.name}.mcap").rename(file)
    shutil.rmtree(scratch)


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
            raise BagError(explain_read_error(file, exc)) from None
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
