# SPDX-License-Identifier: Apache-2.0
"""
A node's own process.

argv and environment checks, rclpy start-up, spin, and a shutdown that never hangs (watchdog), with
exit codes 0 (normal stop), 1 (hung clean-up), 2 (could not start).
"""
from __future__ import annotations

import faulthandler
import logging
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Callable, NoReturn

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..process_memory import keep_freed_memory
from .managed_node import ManagedNode
from .middleware import configure_middleware
from .parameters import report_unknown_parameters
from .shared_memory import remove_own_segments


def check_params_files(args: list[str]) -> None:
    """Every `--params-file PATH` must name a readable regular file (rcl's own error is a C parser trace)."""
    for i, arg in enumerate(args):
        if arg == "--params-file" or arg.startswith("--params-file="):
            value = arg.partition("=")[2] if "=" in arg else (args[i + 1] if i + 1 < len(args) else "")
            path = Path(value)
            if not value:
                raise ValueError("--params-file needs a path")
            if not path.exists():
                raise ValueError(f"--params-file {value}: no such file")
            if not path.is_file():
                raise ValueError(f"--params-file {value}: not a regular file")
            if not os.access(path, os.R_OK):
                raise ValueError(f"--params-file {value}: not readable")


def check_cache_directory(environ=os.environ) -> None:
    """
    Check STAR_TRACKER_CACHE (catalog and pattern-database caches), when set.

    It must be a directory this process can read and write, or a path it can create.
    """
    value = environ.get("STAR_TRACKER_CACHE")
    if not value:
        return
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise ValueError(f"STAR_TRACKER_CACHE={value} is not a directory")
    if path.is_dir() and not os.access(path, os.R_OK | os.W_OK | os.X_OK):
        raise ValueError(f"STAR_TRACKER_CACHE={value} is not readable and writable by this process")


SHUTDOWN_WATCHDOG_S = 10.0  # [s] from the end of the spin to the end of the process
STOP_POLL_S = 0.5  # [s] longest wait of the spin between checks of a requested stop


def run_node(factory: Callable[[], Node], argv: list[str] | None = None) -> int:
    """
    Init rclpy, build the node, spin until SIGINT/SIGTERM (or a shutdown transition), clean up.

    A stop signal ends the spin (within STOP_POLL_S) but leaves the context up until the node is
    destroyed: its clean-up still talks DDS (the camera's truth flush, a frame in progress
    published). Returns the process exit code: 0 on a normal shutdown, 2 when the node could not start
    (bad arguments or parameters: one `fatal:` line on stderr, no traceback). A clean-up
    that hangs ends the process after SHUTDOWN_WATCHDOG_S with code 1 and every thread's
    stack on stderr; SIGUSR1 prints those stacks at any time. Once stopping, further
    SIGINT/SIGTERM are ignored (the watchdog bounds the clean-up). For a node's own process
    only (main()): the signal handlers are not restored.
    """
    args = sys.argv if argv is None else argv
    keep_freed_memory()  # a node's own process: freed frame buffers are reused (process_memory.py)
    configure_middleware()
    node = None
    code = 0
    initialized = spinning = False

    stop_requested = threading.Event()

    def on_stop_signal(signum, frame):
        # The only handler in a node's own process: rclpy's (SignalHandlerOptions.NO below)
        # would shut the context down at once, before destroy_node, and the camera's truth
        # flush was skipped. The spin polls this flag (also where rclpy's wake-up of the
        # executor was lost: a replayed node in CI once went on waiting after SIGINT). A
        # KeyboardInterrupt would land in whatever Python code the main thread runs, and
        # inside a __del__ it is only printed ("Exception ignored ... Traceback").
        if not spinning:
            raise KeyboardInterrupt  # still starting up: stop now
        stop_requested.set()

    main_thread = threading.current_thread() is threading.main_thread()
    stop_signals = (signal.SIGINT, signal.SIGTERM)
    if main_thread:
        for sig in stop_signals:
            signal.signal(sig, on_stop_signal)
    if main_thread and hasattr(signal, "SIGUSR1"):
        # `kill -USR1 <pid>` prints every thread's stack to stderr, even while the main
        # thread is blocked in C (a node that does not stop, a stuck DDS call).
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        check_params_files(args)
        check_cache_directory()
        # Off the main thread this process's handlers are not ours to set: rclpy's stay.
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO if main_thread else None)
        initialized = True
        node = factory()
        report_unknown_parameters(node)
        if not isinstance(node, ManagedNode):
            node.get_logger().info("ready")
        elif node.autostart:
            node.autostart_now()  # a failed configure/activate is a failed start (code 2)
            node.get_logger().info("ready (active)")  # for people: readiness is ~/get_state
        else:
            node.get_logger().info(f"unconfigured (autostart false): waiting for "
                                   f"`ros2 lifecycle set {node.get_fully_qualified_name()} configure`")
        spinning = True
        spin_until_stopped(node, stop_requested)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # startup errors: bad parameters, unreadable catalog, ...
        if initialized and not rclpy.ok():
            # SIGINT/SIGTERM shut the context down under a running call (e.g. the executor
            # building its wait set: RCLError "the given context is not valid"): a normal stop.
            pass
        else:
            print(f"[star_tracker] fatal: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
            code = 2
    finally:
        if main_thread:
            # Stopping now: a second SIGINT (Ctrl-C reaches the whole process group, and `ros2
            # launch` forwards one more) must not kill the clean-up half way (exit code -2).
            for sig in stop_signals:
                signal.signal(sig, signal.SIG_IGN)
            # A stop must never hang: past SHUTDOWN_WATCHDOG_S (here or in the interpreter's
            # exit), every thread's stack goes to stderr and the process exits with code 1.
            # A node with longer legitimate work in flight declares it (shutdown_extra_s [s]).
            faulthandler.dump_traceback_later(SHUTDOWN_WATCHDOG_S + getattr(node, "shutdown_extra_s", 0.0), exit=True)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def exit_node_process(code: int) -> NoReturn:
    """
    End a node's own process with `code`, once run_node has cleaned up (a node module's main).

    Logging and the standard streams are flushed, then os._exit: the interpreter's and the C
    library's exit are skipped. In CI a centroider outlived its SIGINT by 15 s after
    rclpy's shutdown (exit -10: the harness's SIGUSR1 stack dump met no handler, faulthandler
    was already finalized, so was the watchdog): past Python, in the middleware's static
    destructors, where no watchdog reaches (a known class of DDS exit hangs). The participant's
    shared-memory segments, which those destructors would have removed, are removed here
    (shared_memory.remove_own_segments).
    """
    remove_own_segments()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or broken pipe: nothing more to say
            pass
    os._exit(code)


def spin_until_stopped(node: Node, stop_requested: threading.Event) -> None:
    """
    Spin the global executor (rclpy.spin), waiting at most STOP_POLL_S at a time.

    So a stop signal ends the spin even if its wake-up of the executor is lost. A managed
    node's shutdown transition ends it too (after the transition's answer went out).
    """
    executor = rclpy.get_global_executor()
    executor.add_node(node)
    finished = getattr(node, "finished", threading.Event())
    try:
        while executor.context.ok() and not stop_requested.is_set() and not finished.is_set():
            executor.spin_once(timeout_sec=STOP_POLL_S)
    finally:
        executor.remove_node(node)
