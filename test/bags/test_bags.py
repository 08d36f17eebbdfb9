# SPDX-License-Identifier: Apache-2.0
"""
Bag I/O without ROS (star_tracker.bags) and the bag commands on bad bags.

Every problem is an error naming it (exit code != 0, no traceback).
"""
from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from star_tracker import bags

CLI = [sys.executable, "-m", "star_tracker.cli"]
STORE = bags.typestore()
T0 = 1_700_000_000_000_000_000
PERIOD = 100_000_000


def header(k: int):
    Header, Time = STORE.types["std_msgs/msg/Header"], STORE.types["builtin_interfaces/msg/Time"]
    sec, nanosec = divmod(T0 + k * PERIOD, 1_000_000_000)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id="star_tracker_optical")


def image(k: int, encoding: str = "mono16", size: int = 32) -> bytes:
    data = np.full(size * size * 2, k % 251, np.uint8)
    msg = STORE.types["sensor_msgs/msg/Image"](header=header(k), height=size, width=size, encoding=encoding,
                                               is_bigendian=0, step=2 * size, data=data)
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/Image"))


def attitude(k: int) -> bytes:
    Q = STORE.types["geometry_msgs/msg/Quaternion"]
    msg = STORE.types["geometry_msgs/msg/QuaternionStamped"](header=header(k), quaternion=Q(x=0.0, y=0.0, z=0.0, w=1.0))
    return bytes(STORE.serialize_cdr(msg, "geometry_msgs/msg/QuaternionStamped"))


def make_bag(path: Path, storage: str = "sqlite3", frames: int = 20, encoding: str = "mono16",
             size: int = 32) -> Path:
    writer = bags.BagWriter(path, storage)
    writer.add_topic("/image_raw", bags.IMAGE_TYPE)
    writer.add_topic("truth/attitude", "geometry_msgs/msg/QuaternionStamped")
    for k in range(frames):
        writer.write("/image_raw", T0 + k * PERIOD + 1000, image(k, encoding, size))
        writer.write("/truth/attitude", T0 + k * PERIOD + 2000, attitude(k))
    writer.close({"test": "yes"})
    return path


def cli(*args) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID="231", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True, timeout=120, env=env)


def assert_clear_error(result: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    text = result.stdout + result.stderr
    assert result.returncode == code, text
    assert "Traceback" not in text, text
    for needle in needles:
        assert needle in text, text


# ----------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("storage", bags.STORAGES)
def test_a_written_bag_reads_back_exactly_with_standard_metadata(tmp_path, storage):
    path = make_bag(tmp_path / "bag", storage)
    with bags.BagReader(path) as bag:
        info = bag.info
        messages = list(bag.messages())
        images = list(bag.messages(["image_raw"], start_ns=T0 + 5 * PERIOD))
    assert info.storage == storage and info.message_count == 40 and info.custom_data == {"test": "yes"}
    assert {t: (i.type, i.count) for t, i in info.topics.items()} == {
        "/image_raw": (bags.IMAGE_TYPE, 20), "/truth/attitude": ("geometry_msgs/msg/QuaternionStamped", 20)}
    assert info.topics["/image_raw"].type_hash == STORE.hash_rihs01(bags.IMAGE_TYPE)
    assert info.start_ns == T0 + 1000 and info.end_ns == T0 + 19 * PERIOD + 2000
    assert [t for t, _, _ in messages[:4]] == ["/image_raw", "/truth/attitude"] * 2  # time order
    assert [d for _, _, d in messages[::2]] == [image(k) for k in range(20)]  # bytes unchanged
    assert [bags.header_stamp_ns(d) for _, _, d in images] == [T0 + k * PERIOD for k in range(5, 20)]
    # The standard rosbag2 layout: metadata.yaml version 9 next to one storage file.
    from ruamel.yaml import YAML

    meta = YAML(typ="safe").load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == storage and meta["message_count"] == 40
    assert meta["relative_file_paths"] == [f"bag{'.db3' if storage == 'sqlite3' else '.mcap'}"]
    topic = meta["topics_with_message_count"][0]["topic_metadata"]
    assert topic["type_description_hash"].startswith("RIHS01_") and topic["serialization_format"] == "cdr"
    assert bags.check_bag(path)[1] == []


def test_the_writer_refuses_what_it_cannot_write(tmp_path):
    make_bag(tmp_path / "bag")
    with pytest.raises(bags.BagError, match="exists already"):
        bags.BagWriter(tmp_path / "bag")
    with pytest.raises(bags.BagError, match="unknown storage 'rosbag1'"):
        bags.BagWriter(tmp_path / "other", "rosbag1")
    writer = bags.BagWriter(tmp_path / "new")
    with pytest.raises(bags.BagError, match="foo_msgs/msg/Bar is unknown"):
        writer.add_topic("/x", "foo_msgs/msg/Bar")
    with pytest.raises(bags.BagError, match="not added"):
        writer.write("/y", T0, b"")
    writer.close()


def test_image_checks_name_the_problem():
    assert bags.image_problem(image(0)) is None
    assert "encoding 'rgb8' is not supported" in bags.image_problem(image(0, "rgb8"))
    assert "not a valid sensor_msgs/msg/Image" in bags.image_problem(b"\x00\x01\x00\x00garbage")
    msg = STORE.deserialize_cdr(image(0), bags.IMAGE_TYPE)
    msg.step = 10  # shorter than a row
    assert "step 10 < width 32" in bags.image_problem(bytes(STORE.serialize_cdr(msg, bags.IMAGE_TYPE)))


# ----------------------------------------------------------------------------- bad bags
@pytest.mark.slow  # runs the CLI in a subprocess
def test_missing_topics_are_named(tmp_path):
    path = make_bag(tmp_path / "bag")
    with bags.BagReader(path) as bag, pytest.raises(bags.BagError, match="no topic /spots in the bag; its topics are"):
        bag.select(["image_raw", "spots"])
    assert_clear_error(cli("play", path, "--topics", "image_raw", "spots"), 2, "no topic /spots", "/truth/attitude")
    assert_clear_error(cli("play", path, "--remap", "/nothing:=/x"), 2, "--remap /nothing: no such topic")
    assert_clear_error(cli("play", path, "--topics", "image_raw", "--wait-for-subscribers", "1", "truth/attitude=2"),
                       2, "--wait-for-subscribers /truth/attitude: not a played topic", "/image_raw")


@pytest.mark.slow  # runs the CLI in a subprocess
def test_unknown_message_types_are_named(tmp_path):
    from rosbags.rosbag2 import Writer

    path = tmp_path / "bag"
    with Writer(path, version=9) as writer:  # a bag from another tool, with a custom type
        conn = writer.add_connection("/custom", "foo_msgs/msg/Bar", msgdef="int32 value\n", rihs01="RIHS01_" + "0" * 64)
        writer.write(conn, T0, b"\x00\x01\x00\x00\x05\x00\x00\x00")
        conn = writer.add_connection("/truth/attitude", "geometry_msgs/msg/QuaternionStamped", typestore=STORE)
        writer.write(conn, T0 + 1, attitude(0))
    result = cli("info", path)
    assert result.returncode == 0 and "foo_msgs/msg/Bar" in result.stdout
    assert_clear_error(cli("info", path, "--check"), 1, "/custom: type foo_msgs/msg/Bar is unknown")
    assert_clear_error(cli("play", path), 2, "cannot play /custom: message type foo_msgs/msg/Bar is not installed",
                       "--topics")


@pytest.mark.parametrize("storage", bags.STORAGES)
@pytest.mark.slow  # runs the CLI in a subprocess
def test_truncated_storage_files_are_named(tmp_path, storage):
    path = make_bag(tmp_path / "bag", storage, frames=60)
    file = next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
    with open(file, "r+b") as handle:
        handle.truncate(file.stat().st_size // 2)
    kind = "sqlite3 storage file bag.db3 is corrupt" if storage == "sqlite3" else "MCAP file bag.mcap is truncated"
    with pytest.raises(bags.BagError, match=kind):
        bags.BagReader(path).open()
    assert_clear_error(cli("info", path), 2, kind, file.name)
    assert_clear_error(cli("play", path, "--rate", "0"), 2, kind)


@pytest.mark.slow  # runs the CLI in a subprocess
def test_a_truncated_mcap_is_recovered_up_to_the_cut(tmp_path):
    path = make_bag(tmp_path / "bag", "mcap", frames=60, size=256)  # 128 KiB images: ~8 per 1 MiB chunk
    file = path / "bag.mcap"
    with open(file, "r+b") as handle:
        handle.truncate(int(file.stat().st_size * 0.6))
    (path / "metadata.yaml").unlink()
    result = cli("reindex", path)
    assert result.returncode == 0, result.stdout + result.stderr
    info, problems = bags.check_bag(path)
    assert problems == [] and (path / "bag.mcap.unfinished").exists()
    with bags.BagReader(path) as bag:
        stamps = [bags.header_stamp_ns(d) for _, _, d in bag.messages(["/image_raw"])]
    # Every complete chunk survives: a prefix of the frames, more than half of what was kept.
    assert stamps == [T0 + k * PERIOD for k in range(len(stamps))] and 24 <= len(stamps) < 60


@pytest.mark.slow  # runs the CLI in a subprocess
def test_wrong_image_encodings_are_named(tmp_path):
    path = make_bag(tmp_path / "bag", encoding="rgb8")
    assert_clear_error(cli("play", path, "--rate", "0"), 2, "/image_raw: first image",
                       "image encoding 'rgb8' is not supported", "mono16")
    assert_clear_error(cli("info", path, "--check"), 1, "/image_raw: 20 bad message(s)", "'rgb8'")


@pytest.mark.slow  # runs the CLI in a subprocess
def test_what_is_not_a_finished_bag_is_named(tmp_path):
    assert_clear_error(cli("info", tmp_path / "nowhere"), 2, "no bag at")
    (tmp_path / "empty").mkdir()
    assert_clear_error(cli("play", tmp_path / "empty"), 2, "not a rosbag2 bag: no metadata.yaml")
    (tmp_path / "notes.txt").write_text("hello")
    assert_clear_error(cli("info", tmp_path / "notes.txt"), 2, "not a rosbag2 bag directory")
    assert_clear_error(cli("reindex", tmp_path / "empty"), 2, "no .db3 or .mcap storage file")
    path = make_bag(tmp_path / "bag")
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    assert_clear_error(cli("info", path), 2, "invalid metadata.yaml", "reindex")
    assert cli("reindex", path).returncode == 0 and bags.check_bag(path)[1] == []


@pytest.mark.slow  # runs the CLI in a subprocess
def test_a_storage_file_that_disagrees_with_metadata_is_named(tmp_path):
    path = make_bag(tmp_path / "bag")
    with sqlite3.connect(path / "bag.db3") as db:
        db.execute("DELETE FROM messages WHERE id > 30")
    with pytest.raises(bags.BagError, match="metadata.yaml lists 20 messages on /image_raw but the storage holds 15"):
        bags.BagReader(path).open()
    assert_clear_error(cli("play", path), 2, "lists 20 messages on /image_raw")


_KILLED_WRITER = """
import os, sys
sys.path.insert(0, {test_dir!r})
from test_bags import image, T0, PERIOD
from star_tracker import bags
writer = bags.BagWriter({path!r}, {storage!r})
writer.add_topic("/image_raw", bags.IMAGE_TYPE)
for k in range(30):
    writer.write("/image_raw", T0 + k * PERIOD, image(k, size=128))
    if k == 19:
        writer.flush()
os._exit(9)  # killed: no close(), no metadata.yaml
"""


@pytest.mark.parametrize("storage", bags.STORAGES)
@pytest.mark.slow  # runs the CLI in a subprocess
def test_a_killed_writer_leaves_a_bag_that_reindex_recovers(tmp_path, storage):
    path = tmp_path / "bag"
    code = _KILLED_WRITER.format(test_dir=str(Path(__file__).parent), path=str(path), storage=storage)
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == 9
    assert not (path / "metadata.yaml").exists()
    assert_clear_error(cli("play", path), 2, "has no metadata.yaml", f"star-tracker reindex {path}")
    info = bags.reindex(path)
    with bags.BagReader(path) as bag:
        stamps = [bags.header_stamp_ns(d) for _, _, d in bag.messages()]
    # Everything flushed is back (frames 0..19), in order; nothing invented.
    assert len(stamps) >= 20 and stamps == [T0 + k * PERIOD for k in range(len(stamps))]
    assert info.topics["/image_raw"].count == len(stamps) and bags.check_bag(path)[1] == []
    shutil.rmtree(path)


@pytest.mark.slow  # runs the CLI in a subprocess
def test_every_bag_command_documents_its_options():
    expected = {"record": ("--all", "--output", "--storage", "--duration", "--queue-depth", "--flush-period",
                           "--use-sim-time", "mcap"),
                "play": ("--rate", "--start-offset", "--loop", "--topics", "--remap", "--clock", "--no-lockstep",
                         "--ack-topics", "--ack-timeout", "--wait-for-subscribers", "--wait-timeout", "--delay",
                         "--no-check"),
                "info": ("--check",), "reindex": ("metadata.yaml",)}
    top = cli("--help")
    assert top.returncode == 0 and all(command in top.stdout for command in expected)
    for command, options in expected.items():
        result = cli(command, "--help")
        assert result.returncode == 0 and all(option in result.stdout for option in options), result.stdout
    assert "--record" in cli("demo", "--help").stdout
    assert_clear_error(cli("play", "bag", "--remap", "a=b"), 2, "expected OLD:=NEW")
    assert_clear_error(cli("play", "bag", "--wait-for-subscribers", "camera_info=two"), 2, "expected N or TOPIC=N")
    assert_clear_error(cli("play", "bag", "--wait-for-subscribers", "=2"), 2, "expected N or TOPIC=N")
    assert_clear_error(cli("play", "bag", "--rate", "-1"), 2, "must be >= 0")
