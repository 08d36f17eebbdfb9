# SPDX-License-Identifier: Apache-2.0
"""
Fast DDS shared-memory files left behind by processes that ended without the middleware's clean-up.

Fast DDS (rmw_fastrtps_cpp, ROS 2's default) keeps each participant's shared-memory segments and
ports as files in /dev/shm (star_tracker's profile: a 32 MiB segment), and a lock file beside
each that the owning process holds locked while it lives. A process that ends without the
middleware's own exit clean-up -- killed, or a node process ending with os._exit
(node_process.exit_node_process) -- leaves them: 35 MB per node process, 22 GB of RAM on this
machine after a day of tests, until the test workers were killed for memory.

remove_own_segments deletes a node process's own segments (those whose lock files it holds open)
just before its os._exit: the 35 MB no longer outlive a normal stop. Its port files stay: other
participants on the host share them (52 KB each). The participant's own destruction would
remove them all, but rclpy's LifecycleNode keeps the participant alive past destroy_node (its
state machine holds the node), and destroying that state machine hung a node's exit in 1 of 3
parallel test runs (docs/RELIABILITY.md, "a rare abort at exit").

remove_stale_shared_memory deletes the files of segments and ports whose lock file nobody holds
(the test of eProsima's `fastdds shm clean`), leaving alone those changed in the last
MIN_AGE_S (a participant starting now creates its files before it locks them): what killed
processes left. middleware.configure_middleware runs it (node, player and recorder processes, before rclpy starts).
"""
from __future__ import annotations

import fcntl
import os
import re
import time
from pathlib import Path

SHM_DIRECTORY = Path("/dev/shm")
MIN_AGE_S = 60.0  # [s] files younger than this are left alone, locked or not
_SEGMENT_LOCK = re.compile(r"^fastrtps_[0-9a-z]{16}_(el|sl)$")
_PORT_LOCK = re.compile(r"^fastrtps_port\d{1,5}_(el|sl)$")


def remove_stale_shared_memory(directory: Path = SHM_DIRECTORY, environ=os.environ, now: float | None = None) -> int:
    """
    Delete the Fast DDS shared-memory files of processes that are gone; return how many files went.

    Only with Fast DDS as the middleware (RMW_IMPLEMENTATION unset or rmw_fastrtps_cpp) and where
    `directory` exists; never raises (a file another process removes first is skipped).
    """
    if environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp" or not directory.is_dir():
        return 0
    now = time.time() if now is None else now
    removed = 0
    try:
        names = os.listdir(directory)
    except OSError:
        return 0
    for name in names:
        segment, port = _SEGMENT_LOCK.match(name), _PORT_LOCK.match(name)
        if not (segment or port):
            continue
        lock = directory / name
        data = directory / name[:-3]
        files = [lock, data] + ([directory / f"sem.{name[:-3]}_mutex"] if port else [])
        try:
            if now - max(f.stat().st_mtime for f in files if f.exists()) < MIN_AGE_S or _locked(lock):
                continue
        except (OSError, ValueError):  # gone meanwhile
            continue
        removed += _unlink(files)
    return removed


def remove_own_segments(fd_directory: Path = Path("/proc/self/fd"), directory: Path = SHM_DIRECTORY) -> int:
    """
    Delete this process's own Fast DDS segments and their lock files; return how many files went.

    Its own: the segments whose lock file it holds open (`fd_directory`: the process's open files).
    For a process that is about to end without the middleware's clean-up (os._exit): the memory
    is freed when its mappings go with the process; a peer that still maps a segment keeps its
    mapping. Never raises.
    """
    removed = 0
    try:
        descriptors = os.listdir(fd_directory)
    except OSError:
        return 0
    for descriptor in descriptors:
        try:
            target = Path(os.readlink(fd_directory / descriptor))
        except OSError:
            continue
        if target.parent != directory or not _SEGMENT_LOCK.match(target.name):
            continue
        removed += _unlink([directory / target.name[:-3], target])
    return removed


def _unlink(files: list[Path]) -> int:
    """Delete `files`; return how many went (one another process removed first is skipped)."""
    removed = 0
    for f in files:
        try:
            f.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def _locked(path: Path) -> bool:
    """Whether a live process holds `path` locked (an exclusive flock cannot be taken)."""
    try:
        with open(path, "ab") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True
