# SPDX-License-Identifier: Apache-2.0
"""
The lifecycle of the star tracker's nodes (REP 2005-style managed nodes, lifecycle_msgs).

    unconfigured --configure--> inactive --activate--> active
    active --deactivate--> inactive --cleanup--> unconfigured; any of them --shutdown--> finalized

Parameters are declared in the constructor (so `ros2 param` works while unconfigured);
`configure` loads what is slow (catalog, pattern database, compiled kernels) and creates the
topics; `activate` starts publishing (lifecycle publishers) and processing; `deactivate`
stops it, keeping everything configured (input arriving meanwhile is ignored and counted);
`cleanup` releases what `configure` made; `shutdown` releases everything and ends the
process. After `configure` the heap is collected and frozen (settle_heap), so no full garbage
collection scans the long-lived objects while frames arrive. /diagnostics is published in
every state, with `lifecycle_state`.

A transition requested in a state that has no such transition is refused (success false),
logged and counted (`transitions_refused`); the node keeps its state. A transition callback
that raises is logged with the reason and reported as a failure: the node stays where it was.
With the read-only parameter `autostart` (default true) the node configures and activates
itself on start, so `ros2 run` stays one command.
"""
from __future__ import annotations

import functools
import gc
import threading
import traceback
from typing import Callable

from diagnostic_msgs.msg import DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from .diagnostics import Diagnostics


SHUTDOWN_TRANSITIONS = (Transition.TRANSITION_UNCONFIGURED_SHUTDOWN, Transition.TRANSITION_INACTIVE_SHUTDOWN,
                        Transition.TRANSITION_ACTIVE_SHUTDOWN)


def transition_callback(method: Callable) -> Callable:
    """
    Make a lifecycle callback that never raises.

    An exception is logged with its reason (rclpy itself would swallow it), kept in
    `transition_error`, and returned as FAILURE.
    """

    @functools.wraps(method)
    def wrapper(self: "ManagedNode", state: LifecycleState) -> TransitionCallbackReturn:
        try:
            result = method(self, state)
        except Exception as exc:
            self.transition_error = f"{type(exc).__name__}: {exc}"
            # Bad configuration (ValueError, a missing file) is stated in one line; a defect with its place.
            where = "" if isinstance(exc, (ValueError, OSError)) else "\n" + "".join(
                traceback.format_exception(exc)[-3:-1]).rstrip()
            if not self._autostarting:  # autostart: run_node's one `fatal:` line says it
                self.get_logger().error(f"{method.__name__} failed: {self.transition_error}{where}")
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS if result is None else result

    return wrapper


def settle_heap() -> None:
    """
    Collect once, then exempt every object alive now from later collections (gc.freeze).

    The imports, kernels and database leave ~1.5e5 long-lived objects; without this a full
    collection scans them all while frames arrive (a 134 ms pause mid-run measured in the
    centroider of `star-tracker demo`; 0.1 ms after the freeze).
    """
    gc.collect()
    gc.freeze()


class ManagedNode(LifecycleNode):
    """
    A lifecycle node that gates input, refuses a wrong transition cleanly and reports its state.

    Its `active` flag gates input, its ~/change_state refuses a wrong transition cleanly, and it
    reports its state on /diagnostics (`self.diag`: the subclass's constructor makes it with
    start_diagnostics()). Subclasses override configure/activate/deactivate/release, each returning None
    (success) or raising.
    """

    def __init__(self, node_name: str, **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.active = False  # processing input and publishing; read by the subscription callbacks
        self.transition_error: str | None = None  # why the last transition failed
        self.finished = threading.Event()  # set on shutdown: run_node ends the process
        self._autostarting = False
        self._service_change_state.callback = self._on_change_state

    @property
    def lifecycle_state(self) -> str:
        """The current state's label: unconfigured, inactive, active, finalized, or a transition's."""
        return self._state_machine.current_state[1]

    # --- what a node does in each transition (override; return None or raise) ---
    def configure(self) -> None:
        """Load what processing needs and create the topics."""

    def activate(self) -> None:
        """Start processing and publishing (lifecycle publishers are enabled by the base)."""

    def deactivate(self) -> None:
        """Stop processing and publishing; keep what configure made."""

    def release(self) -> None:
        """Release what configure made (safe to call in any state, and twice)."""

    # --- rclpy's lifecycle callbacks ---
    @transition_callback
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except Exception:
            self.release()  # nothing half-made survives a failed configure
            raise
        settle_heap()
        self._report("inactive", "configured; waiting for activate")
        return None

    @transition_callback
    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.activate()
        super().on_activate(state)  # enables the lifecycle publishers
        self.active = True
        self._report("active", "activated")
        return None

    @transition_callback
    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        super().on_deactivate(state)
        self.deactivate()
        self._report("inactive", "deactivated")
        return None

    @transition_callback
    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.release()
        gc.unfreeze()  # what configure made may be collected again
        self._report("unconfigured", "cleaned up; waiting for configure")
        return None

    @transition_callback
    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.release()
        self._report("finalized", "shut down")
        self.finished.set()
        return None

    @transition_callback
    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.release()
        gc.unfreeze()  # as cleanup: a later configure freezes what it makes
        self._report("unconfigured", f"error in a transition from {state.label}; cleaned up")
        return None

    def start_diagnostics(self) -> Diagnostics:
        """Start this node's /diagnostics, published from now on in every state."""
        diag = Diagnostics(self)
        diag.value("lifecycle_state", self.lifecycle_state)
        diag.set(DiagnosticStatus.OK, "unconfigured; waiting for configure")
        return diag

    def _report(self, state: str, message: str) -> None:
        self.diag.value("lifecycle_state", state)
        self.diag.set(DiagnosticStatus.OK, message)
        self.get_logger().info(f"lifecycle: {state} ({message})")

    # --- transitions requested from outside (~/change_state) or by autostart ---
    def _on_change_state(self, request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        """
        ~/change_state: a transition this state offers runs.

        Any other is refused, logged and counted (rclpy would raise out of the executor on an
        unknown transition id).
        """
        wanted = request.transition.label or str(request.transition.id)
        offered = self._state_machine.available_transitions  # (id, label, start id, start, goal id, goal)
        matches = [t[0] for t in offered if (t[1] == request.transition.label if request.transition.label
                                             else t[0] == request.transition.id)]
        if not matches:
            self.diag.count("transitions_refused")
            self.get_logger().warning(
                f"transition {wanted!r} refused in state {self.lifecycle_state} "
                f"(offered: {', '.join(sorted({t[1] for t in offered})) or 'none'})")
            response.success = False
            return response
        response.success = self.transition(matches[0])
        return response

    def transition(self, transition_id: int) -> bool:
        """Run one lifecycle transition by its lifecycle_msgs/Transition id; True if it succeeded."""
        trigger = {Transition.TRANSITION_CONFIGURE: self.trigger_configure,
                   Transition.TRANSITION_CLEANUP: self.trigger_cleanup,
                   Transition.TRANSITION_ACTIVATE: self.trigger_activate,
                   Transition.TRANSITION_DEACTIVATE: self.trigger_deactivate,
                   **{t: self.trigger_shutdown for t in SHUTDOWN_TRANSITIONS}}[transition_id]
        self.transition_error = None
        ok = trigger() == TransitionCallbackReturn.SUCCESS
        if not ok:
            self.diag.count("transitions_failed")
            self.diag.value("lifecycle_state", self.lifecycle_state)
        return ok

    def autostart_now(self) -> None:
        """configure, then activate; raise RuntimeError with the reason if either fails."""
        self._autostarting = True
        try:
            for transition, name in ((Transition.TRANSITION_CONFIGURE, "configure"),
                                     (Transition.TRANSITION_ACTIVATE, "activate")):
                if not self.transition(transition):
                    raise RuntimeError(f"autostart: {name} failed: {self.transition_error or 'see the log'}")
        finally:
            self._autostarting = False
