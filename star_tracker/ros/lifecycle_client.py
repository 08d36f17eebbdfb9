# SPDX-License-Identifier: Apache-2.0
"""
Ask managed nodes in other processes for their lifecycle state and drive their transitions.

Through the lifecycle_msgs services ~/get_state and ~/change_state, from a private rclpy
context on their ROS domain: what `ros2 lifecycle get/set` does.
"""
from __future__ import annotations

import itertools
import os
import subprocess
import sys
import time
from typing import Callable

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from .middleware import configure_middleware

# The environment a process reads at rclpy.init: these must match the nodes' (discovery, profile).
_DDS_VARIABLES = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "FASTRTPS_DEFAULT_PROFILES_FILE",
                  "FASTDDS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION")

TRANSITIONS = {"configure": Transition.TRANSITION_CONFIGURE, "cleanup": Transition.TRANSITION_CLEANUP,
               "activate": Transition.TRANSITION_ACTIVATE, "deactivate": Transition.TRANSITION_DEACTIVATE}
GOAL_STATES = {"configure": "inactive", "cleanup": "unconfigured", "activate": "active", "deactivate": "inactive",
               "shutdown": "finalized"}
PRIMARY_STATES = ("unconfigured", "inactive", "active", "finalized")  # a managed node's resting states
ANSWER_WAIT_S = 20.0  # a transition unanswered this long is judged by the node's state (change_state)


class LifecycleClient:
    """
    Lifecycle service calls to nodes on the domain of `env`.

    `env`: ROS_DOMAIN_ID and discovery settings as the node processes get them. Close it (or use `with`) when done.
    """

    _instances = itertools.count()

    def __init__(self, env: dict[str, str], name: str | None = None):
        # The nodes' own profile (run_node does the same) unless `env` names one: the first
        # participant of a process fixes Fast DDS's profiles for every later one in it (a test
        # process without it lost most 2 MiB frames of a burst over fragmented UDP).
        env = dict(env)
        configure_middleware(env)
        saved = {key: os.environ.get(key) for key in _DDS_VARIABLES}
        try:
            for key in _DDS_VARIABLES:  # rmw reads them from this process's environment at init
                if env.get(key):
                    os.environ[key] = env[key]
                else:
                    os.environ.pop(key, None)
            self.context = Context()
            rclpy.init(args=[], context=self.context, domain_id=int(env.get("ROS_DOMAIN_ID", "0")))
        finally:
            for key, value in saved.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
        # A name of its own: several clients in one process (or host) stay distinct.
        name = name or f"star_tracker_lifecycle_client_{os.getpid()}_{next(self._instances)}"
        self.node = rclpy.create_node(name, context=self.context, start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[tuple[str, type], object] = {}

    def _call(self, node_name: str, srv_type, suffix: str, request, timeout_s: float, discovery_s: float = 0.1):
        """
        One service call.

        Wait up to discovery_s for the service, send once, wait up to timeout_s for the
        answer; None if the service is not there or did not answer.
        """
        key = (node_name, srv_type)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_type, f"/{node_name.lstrip('/')}/{suffix}")
        client = self._clients[key]
        found_by = time.monotonic() + discovery_s
        while not client.service_is_ready():
            if time.monotonic() > found_by:
                return None
            self.executor.spin_once(timeout_sec=0.05)  # discovery
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        if not future.done():
            client.remove_pending_request(future)
            return None
        return future.result()

    def get_state(self, node_name: str, timeout_s: float = 5.0) -> str | None:
        """
        Return the node's state label (unconfigured, inactive, active, finalized, ...).

        Or None if its service is not found or does not answer within timeout_s (each).
        """
        response = self._call(node_name, GetState, "get_state", GetState.Request(), timeout_s, discovery_s=timeout_s)
        return None if response is None else response.current_state.label

    def change_state(self, node_name: str, transition: str, timeout_s: float = 120.0) -> bool:
        """
        Request a transition by label (configure, activate, deactivate, cleanup, shutdown) and wait for its answer.

        True if it succeeded, False if refused or failed. Raises TimeoutError if the service is
        absent or did not answer within timeout_s.

        An answer can be lost: Fast DDS sends it after a bounded wait for this client's response
        reader (ros2/rmw_fastrtps#390), which a loaded host can outlast. A request unanswered for
        ANSWER_WAIT_S is judged by the state the node then reports: the transition's goal state
        (when the node was elsewhere before) means it succeeded; another primary state, that it
        never ran (it is requested again); no answer or a transition state, that it is still
        running (waited for). From the goal state itself a transition is refused: requested
        again until answered.
        """
        request = ChangeState.Request()
        request.transition.label = transition
        if transition in TRANSITIONS:
            request.transition.id = TRANSITIONS[transition]
        deadline = time.monotonic() + timeout_s
        goal = GOAL_STATES.get(transition)
        if goal is not None and self.get_state(node_name, timeout_s=min(ANSWER_WAIT_S, timeout_s)) == goal:
            goal = None  # refused: only its answer tells
        discovery_s = timeout_s
        while True:
            wait_s = min(ANSWER_WAIT_S, max(deadline - time.monotonic(), 0.1))
            response = self._call(node_name, ChangeState, "change_state", request, wait_s, discovery_s=discovery_s)
            if response is not None:
                return bool(response.success)
            discovery_s = 0.1  # found once: only the answer is missing now
            while time.monotonic() < deadline:
                state = self.get_state(node_name, timeout_s=min(5.0, max(deadline - time.monotonic(), 0.1)))
                if goal is not None and state == goal:
                    return True
                if state in PRIMARY_STATES:
                    break  # not run: requested again
                time.sleep(0.2)
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{node_name}: no answer to {transition!r} within {timeout_s} s")

    def wait_for_state(self, node_names, state: str = "active", timeout_s: float = 120.0,
                       check: Callable[[str], None] | None = None) -> None:
        """
        Block until every node answers ~/get_state with `state`.

        `check(name)` runs between attempts (to raise if the node's process died).
        TimeoutError names the nodes still elsewhere and their last answer.
        """
        deadline = time.monotonic() + timeout_s
        last: dict[str, str | None] = {name: None for name in node_names}
        while True:
            for name in [n for n, s in last.items() if s != state]:
                if check is not None:
                    check(name)
                last[name] = self.get_state(name, timeout_s=2.0)
            if all(s == state for s in last.values()):
                return
            if time.monotonic() > deadline:
                pending = {n: s for n, s in last.items() if s != state}
                raise TimeoutError(f"not {state} after {timeout_s} s: {pending}")
            time.sleep(0.1)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> "LifecycleClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_for_state(env: dict[str, str], node_names, state: str = "active", timeout_s: float = 120.0,
                   check: Callable[[str], None] | None = None) -> None:
    """
    Block until every node answers ~/get_state with `state`, from this process or a child.

    Where this process has no default rclpy context yet (a test of the CLI or the install,
    the demo's own code), the polling client runs in a child process: a private context as
    the first DDS participant of a process was followed, in the same process, by best-effort
    2 MiB bursts that never arrived (test_overload_nodes after test_colcon_install). Where the
    default context is up already, in-process as before. `check(name)` as in
    LifecycleClient.wait_for_state; TimeoutError with the child's reason.
    """
    names = list(node_names)
    if rclpy.ok():
        with LifecycleClient(env) as client:
            client.wait_for_state(names, state, timeout_s, check=check)
        return
    child = subprocess.Popen([sys.executable, "-m", __name__, state, str(timeout_s), *names], env=dict(env),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while child.poll() is None:
            if check is not None:
                for name in names:
                    check(name)
            time.sleep(0.2)
    finally:
        if child.poll() is None:
            child.kill()
        reason = child.communicate()[1].strip()
    if child.returncode != 0:
        raise TimeoutError(reason.splitlines()[-1] if reason else f"not {state} after {timeout_s} s: {names}")


def main(argv: list[str] | None = None) -> int:
    """Wait in this process: `python -m star_tracker.ros.lifecycle_client STATE TIMEOUT_S NODE...` (exit 1: timeout)."""
    state, timeout_s, *names = sys.argv[1:] if argv is None else argv
    with LifecycleClient(dict(os.environ)) as client:
        try:
            client.wait_for_state(names, state, float(timeout_s))
        except TimeoutError as exc:
            print(exc, file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
