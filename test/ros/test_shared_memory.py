# SPDX-License-Identifier: Apache-2.0
"""
Fast DDS shared-memory files of ended processes (star_tracker/ros/shared_memory.py).

A directory laid out as Fast DDS leaves /dev/shm (segments and ports, each with a lock file),
one owner "alive" (its lock file held, as the owning process holds it), and the real thing: a
node process's files while it runs, after a normal stop (gone with it) and after it was killed
(left, then removed by the clean-up).
"""
from __future__ import annotations

import fcntl
import os
import time

import pytest

from star_tracker.ros.shared_memory import MIN_AGE_S, remove_own_segments, remove_stale_shared_memory


def _files(directory, names, age_s):
    for name in names:
        path = directory / name
        path.write_bytes(b"x")
        stamp = time.time() - age_s
        os.utime(path, (stamp, stamp))


def test_only_the_files_of_gone_owners_are_removed(tmp_path):
    dead = ["fastrtps_0123456789abcdef", "fastrtps_0123456789abcdef_el"]
    alive = ["fastrtps_fedcba9876543210", "fastrtps_fedcba9876543210_el"]
    young = ["fastrtps_00000000000000aa", "fastrtps_00000000000000aa_el"]
    dead_port = ["fastrtps_port7411", "fastrtps_port7411_el", "sem.fastrtps_port7411_mutex"]
    other = ["lttng-ust-wait-8", "fastrtps_not_a_segment_el"]
    _files(tmp_path, dead + alive + dead_port + other, 3600.0)
    _files(tmp_path, young, 0.2 * MIN_AGE_S)
    with open(tmp_path / alive[1], "ab") as holder:
        fcntl.flock(holder, fcntl.LOCK_SH)  # as a live participant holds its lock file
        removed = remove_stale_shared_memory(tmp_path, environ={})
        left = sorted(p.name for p in tmp_path.iterdir())
    assert removed == 5
    assert left == sorted(alive + young + other)
    assert remove_stale_shared_memory(tmp_path, environ={}) == 2  # its owner gone now: released
    assert remove_stale_shared_memory(tmp_path, environ={}, now=time.time() + 2 * MIN_AGE_S) == 2  # young no more
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(other)


def test_other_middleware_or_no_directory_is_left_alone(tmp_path):
    _files(tmp_path, ["fastrtps_0123456789abcdef", "fastrtps_0123456789abcdef_el"], 3600.0)
    assert remove_stale_shared_memory(tmp_path, environ={"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}) == 0
    assert remove_stale_shared_memory(tmp_path / "absent", environ={}) == 0
    assert len(list(tmp_path.iterdir())) == 2


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd") or not os.path.isdir("/dev/shm"), reason="no /proc or /dev/shm")
def test_own_segments_are_removed_and_shared_ports_kept(tmp_path):
    shm, fds = tmp_path / "shm", tmp_path / "fd"
    shm.mkdir()
    fds.mkdir()
    own = ["fastrtps_0123456789abcdef", "fastrtps_0123456789abcdef_el"]
    port = ["fastrtps_port7411", "fastrtps_port7411_el"]
    other = ["fastrtps_fedcba9876543210", "fastrtps_fedcba9876543210_el"]  # another process's
    _files(shm, own + port + other, 0.0)
    for index, name in enumerate([own[1], port[1], "lttng-ust-wait-8"]):  # the lock files this process holds
        os.symlink(shm / name, fds / str(index))
    assert remove_own_segments(fds, shm) == 2
    assert sorted(p.name for p in shm.iterdir()) == sorted(port + other)


def _start_node():
    """Start a centroider node process; return it once ready, with its own Fast DDS files (segments, ports, locks)."""
    import subprocess
    import sys

    env = dict(os.environ, ROS_DOMAIN_ID="211", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("RMW_IMPLEMENTATION", None)
    node = subprocess.Popen([sys.executable, "-c", "from star_tracker.ros.centroider_node import main; main()"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in node.stdout:
        if "ready" in line:
            break
    # Its own files are the lock files it holds open (other tests' processes may add theirs).
    locks = set()
    for fd in os.listdir(f"/proc/{node.pid}/fd"):
        try:
            target = os.readlink(f"/proc/{node.pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("/dev/shm/fastrtps_") and target.endswith("_el"):
            locks.add(os.path.basename(target))
    assert locks, "the node holds no Fast DDS lock file"
    return node, locks | {name[:-3] for name in locks}


def test_a_stopped_node_process_removes_its_segments():
    # Ended by os._exit, with its participant still alive (rclpy's LifecycleNode keeps it): its
    # segments are removed on the way out (node_process.exit_node_process); the port files stay,
    # shared with other participants.
    import signal

    node, own = _start_node()
    segments = {name for name in own if "_port" not in name}
    try:
        assert segments and own <= set(os.listdir("/dev/shm"))
    finally:
        node.send_signal(signal.SIGINT)
        code = node.wait(timeout=60)
    assert code == 0
    assert not segments & set(os.listdir("/dev/shm")), "a node stopped normally left its segments"


def test_a_killed_node_process_files_are_kept_while_it_runs_and_removed_after():
    # A killed process runs no clean-up at all: its files stay until a later process's start-up.
    import signal

    node, own = _start_node()
    try:
        remove_stale_shared_memory(now=time.time() + 2 * MIN_AGE_S)
        assert own <= set(os.listdir("/dev/shm"))  # locked by the live process: kept
    finally:
        node.send_signal(signal.SIGKILL)
        node.wait(timeout=60)
    assert own & set(os.listdir("/dev/shm")), "a killed node left nothing: this clean-up is not needed"
    remove_stale_shared_memory(now=time.time() + 2 * MIN_AGE_S)
    assert not own & set(os.listdir("/dev/shm"))
