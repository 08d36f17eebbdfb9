# SPDX-License-Identifier: Apache-2.0
"""
A node process never hangs on shutdown.

run_node's watchdog ends a clean-up that blocks, with every thread's stack on stderr;
SIGUSR1 prints the stacks of a running node. Real rclpy nodes in their own processes (no ROS
mocks).
"""
from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest
pytestmark = pytest.mark.slow  # every test here starts processes (nodes or node executables)

pytest.importorskip("rclpy")

from star_tracker.ros.pipeline import isolated_ros_environment  # noqa: E402

# A node whose destroy_node blocks forever (as a stuck worker or DDS call would), watchdog 2 s.
STUCK_NODE = textwrap.dedent("""
    import sys, threading
    from rclpy.node import Node
    from star_tracker.ros import node_process

    node_process.SHUTDOWN_WATCHDOG_S = 2.0

    class StuckOnDestroy(Node):
        def __init__(self):
            super().__init__("stuck_on_destroy")

        def destroy_node(self):
            threading.Event().wait()  # never set

    sys.exit(node_process.run_node(StuckOnDestroy, sys.argv))
""")


def _start(env) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, "-c", STUCK_NODE], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, start_new_session=True)
    line = process.stdout.readline()  # blocks until the node logged "ready" (or died)
    assert "ready" in line, line + process.stdout.read()
    return process


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_hanging_clean_up_ends_with_the_stacks_after_the_watchdog(sig):
    process = _start(isolated_ros_environment())
    try:
        time.sleep(0.3)
        stopped = time.monotonic()
        process.send_signal(sig)
        output = process.communicate(timeout=30)[0]
        elapsed = time.monotonic() - stopped
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 1, output
    assert 1.5 <= elapsed < 20, elapsed  # the 2 s watchdog, not the test's timeout
    assert "Timeout" in output and "in destroy_node" in output, output  # where it hung


def test_sigusr1_prints_every_thread_stack_and_the_node_runs_on():
    process = _start(isolated_ros_environment())
    try:
        time.sleep(0.3)
        process.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        assert process.poll() is None  # still running
        process.kill()
        output = process.communicate(timeout=30)[0]
    finally:
        if process.poll() is None:
            process.kill()
    assert "Current thread" in output and "in run_node" in output and "in spin" in output, output


# A node whose process has lost rclpy's own signal handling (its wake-up of the executor):
# only run_node's handlers see the signal, as when that wake-up is lost in a race.
DEAF_NODE = textwrap.dedent("""
    import sys
    from rclpy.node import Node
    from rclpy.signals import uninstall_signal_handlers
    from star_tracker.ros import node_process

    class Deaf(Node):
        def __init__(self):
            super().__init__("deaf_to_rclpy_signals")
            uninstall_signal_handlers()

    sys.exit(node_process.run_node(Deaf, sys.argv))
""")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["sigint", "sigterm"])
def test_a_stop_signal_ends_the_spin_even_without_rclpys_wake_up(sig):
    process = subprocess.Popen([sys.executable, "-c", DEAF_NODE], env=isolated_ros_environment(),
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        line = process.stdout.readline()
        assert "ready" in line, line + process.stdout.read()
        time.sleep(0.3)
        process.send_signal(sig)
        code = process.wait(timeout=30)  # the poll ends the spin within STOP_POLL_S of the signal
        output = process.stdout.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert code == 0, output
