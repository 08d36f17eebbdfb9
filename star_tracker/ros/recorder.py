# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker record`: subscribe to topics as serialized bytes and write a rosbag2 bag.

A topic is subscribed once a publisher for it is discovered: its type and the QoS its
publishers offer are then known (both go into the bag). The subscription is reliable when
every publisher is (best effort otherwise: a reliable reader does not match a best-effort
writer), keep last `queue_depth`. Messages go through a queue to a writer thread, so disk
I/O never delays the DDS readers; the writer flushes every `flush_period_s` (sqlite3
commit / closed MCAP chunk), so a killed recorder loses at most that much and
`star-tracker reindex` recovers the rest. SIGINT/SIGTERM finish the bag (metadata.yaml).

Loss accounting per topic: received (callbacks), written (to the bag) and lost = gaps in the
publisher's sequence numbers (publication_sequence_number of the message info), checked
while a topic has a single publisher.
"""
from __future__ import annotations

import json
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..bags import BagError, BagInfo, BagWriter, absolute_topic, message_definition
from .bag_ros import RECORD_QUEUE_DEPTH, message_class, offered_qos, qos_text, subscription_qos
from .middleware import configure_middleware

_STOP = object()
_INTERNAL_TOPICS = ("/rosout", "/parameter_events")


@dataclass
class TopicStats:
    type: str = ""
    received: int = 0
    lost: int = 0  # sequence-number gaps while a single publisher
    last_sequence: int | None = None
    single_publisher: bool = True


class BagWriterThread(threading.Thread):
    """
    Owns the BagWriter (sqlite connections belong to one thread).

    Takes topics and messages from a queue; flushes periodically; closes the bag on stop().
    """

    def __init__(self, path: Path, storage: str, flush_period_s: float):
        super().__init__(name="bag_writer", daemon=True)
        self.path, self.storage, self.flush_period_s = path, storage, flush_period_s
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.opened = threading.Event()
        self.error: BaseException | None = None
        self.written: Counter[str] = Counter()
        self.write_errors: Counter[str] = Counter()
        self.failed_topics: dict[str, str] = {}
        self.custom_data: dict[str, str] = {}
        self.info: BagInfo | None = None
        self.max_backlog = 0

    def add_topic(self, name: str, msgtype: str, offered, type_hash: str | None) -> None:
        self.queue.put(("topic", name, msgtype, offered, type_hash))

    def put(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        self.queue.put(("message", topic, timestamp_ns, data))

    def stop(self, custom_data: dict[str, str]) -> None:
        self.custom_data = custom_data
        self.queue.put(_STOP)

    def run(self) -> None:
        try:
            writer = BagWriter(self.path, self.storage)
        except BagError as exc:
            self.error = exc
            self.opened.set()
            return
        self.opened.set()
        last_flush = time.monotonic()
        try:
            while True:
                try:
                    item = self.queue.get(timeout=self.flush_period_s)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    break
                if item is not None:
                    self.max_backlog = max(self.max_backlog, self.queue.qsize())
                    self._handle(writer, item)
                if time.monotonic() - last_flush >= self.flush_period_s:
                    writer.flush()
                    last_flush = time.monotonic()
            self.info = writer.close(self.custom_data)
        except Exception as exc:  # noqa: BLE001 - disk full, ...: reported by the recorder
            self.error = exc
            writer.abort()

    def _handle(self, writer: BagWriter, item: tuple) -> None:
        if item[0] == "topic":
            _, name, msgtype, offered, type_hash = item
            try:
                writer.add_topic(name, msgtype, offered, type_hash)
            except BagError as exc:
                self.failed_topics[name] = str(exc)
            return
        _, topic, timestamp_ns, data = item
        if topic in self.failed_topics:
            self.write_errors[topic] += 1
            return
        writer.write(topic, timestamp_ns, data)
        self.written[topic] += 1


class BagRecorder(Node):
    """
    Subscribe (raw) to `topics` as their publishers appear; hand every message to a BagWriterThread.

    `topics` None: every topic but /rosout and /parameter_events.
    """

    def __init__(self, path: Path, storage: str = "sqlite3", topics: list[str] | None = None,
                 queue_depth: int = RECORD_QUEUE_DEPTH, flush_period_s: float = 1.0, use_sim_time: bool = False,
                 log=print):
        super().__init__("star_tracker_recorder",
                         parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, use_sim_time)])
        self.wanted = None if topics is None else [absolute_topic(t) for t in topics]
        self.queue_depth, self.use_sim_time, self.log = queue_depth, use_sim_time, log
        self.stats: dict[str, TopicStats] = {}
        self.skipped: dict[str, str] = {}
        self._topic_subscriptions: dict[str, object] = {}
        self.writer = BagWriterThread(Path(path), storage, flush_period_s)
        self.writer.start()
        self.writer.opened.wait()
        if self.writer.error is not None:
            raise self.writer.error
        self.started = time.monotonic()
        # Graph polling on the steady clock: with use_sim_time, ROS-time timers would wait for /clock.
        self._discovery = self.create_timer(0.05, self.discover, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.discover()

    def _candidates(self, graph: dict[str, list[str]]) -> list[str]:
        if self.wanted is not None:
            return self.wanted
        return [t for t in graph if t not in _INTERNAL_TOPICS]

    def discover(self) -> None:
        graph = dict(self.get_topic_names_and_types())
        for topic in self._candidates(graph):
            if topic in self._topic_subscriptions:
                if self.stats[topic].single_publisher and self.count_publishers(topic) > 1:
                    self.stats[topic].single_publisher = False  # sequence numbers interleave: no gap check
                continue
            if topic in self.skipped or topic not in graph:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far
            types = graph[topic]
            if len(types) != 1:
                self._skip(topic, f"published with several types {types}")
                continue
            try:
                _, known_hash = message_definition(types[0])
                msg_class = message_class(types[0])
            except BagError as exc:
                self._skip(topic, str(exc))
                continue
            offers = [p.qos_profile for p in publishers]
            qos = subscription_qos(offers, self.queue_depth)
            type_hash = str(publishers[0].topic_type_hash)
            if type_hash.startswith("RIHS01_") and type_hash != known_hash:
                self.log(f"WARNING: {topic}: the publisher's {types[0]} (hash {type_hash}) differs from the "
                         f"ROS 2 Jazzy definition written to the bag ({known_hash})")
            self.writer.add_topic(topic, types[0], [offered_qos(q) for q in offers],
                                  type_hash if type_hash.startswith("RIHS01_") else None)
            self.stats[topic] = TopicStats(type=types[0], single_publisher=len(publishers) == 1)
            self._topic_subscriptions[topic] = self.create_subscription(
                msg_class, topic, self._callback(topic), qos, raw=True)
            self.log(f"recording {topic} ({types[0]}; {qos_text(qos)})")

    def _skip(self, topic: str, reason: str) -> None:
        self.skipped[topic] = reason
        self.log(f"not recording {topic}: {reason}")

    def _callback(self, topic: str):
        stats = self.stats[topic]
        writer = self.writer

        def on_message(data: bytes, info: dict) -> None:
            stats.received += 1
            sequence = info.get("publication_sequence_number") if info else None
            if sequence:
                last = stats.last_sequence
                if last is not None and sequence > last + 1 and stats.single_publisher:
                    stats.lost += sequence - last - 1
                stats.last_sequence = sequence
            received = info.get("received_timestamp") if info else None
            # Bag time = receive time, as rosbag2: the DDS reception stamp (wall clock), or the
            # node's clock under use_sim_time.
            stamp = self.get_clock().now().nanoseconds if self.use_sim_time or not received else received
            writer.put(topic, stamp, data)

        return on_message

    def finish(self) -> tuple[int, str]:
        """Stop subscribing, let the writer drain and close the bag; (exit code, report)."""
        for subscription in self._topic_subscriptions.values():
            self.destroy_subscription(subscription)
        self._topic_subscriptions.clear()
        summary = {t: {"received": s.received, "lost": s.lost if s.single_publisher else None}
                   for t, s in self.stats.items()}
        self.writer.stop({"star_tracker.recorder": json.dumps(summary, sort_keys=True)})
        self.writer.join()
        return self.report()

    def report(self) -> tuple[int, str]:
        writer = self.writer
        lines, problems = [], []
        if writer.info is not None:
            info = writer.info
            size = sum((info.path / f).stat().st_size for f in info.files) / 2**20
            lines.append(f"bag {info.path} ({info.storage}): {info.message_count} messages, {size:.1f} MiB, "
                         f"{info.duration_s:.2f} s")
        if writer.error is not None:
            problems.append(f"the bag could not be finished: {type(writer.error).__name__}: {writer.error}; "
                            f"`star-tracker reindex {writer.path}` recovers what was flushed")
        width = max([len(t) for t in self.stats] + [5])
        lines.append(f"{'topic':<{width}}  {'received':>8}  {'written':>8}  {'lost':>5}")
        for topic, stats in sorted(self.stats.items()):
            written = writer.written[topic]
            lost = str(stats.lost) if stats.single_publisher else "?"
            lines.append(f"{topic:<{width}}  {stats.received:8d}  {written:8d}  {lost:>5}")
            if written != stats.received:
                reason = writer.failed_topics.get(topic, "write error")
                problems.append(f"{topic}: received {stats.received} but wrote {written} ({reason})")
            if stats.lost:
                problems.append(f"{topic}: {stats.lost} message(s) lost before reaching the recorder "
                                f"(gaps in the publisher's sequence numbers); a deeper --queue-depth may help")
        wanted = self.wanted or []
        for topic in wanted:
            if topic not in self.stats and topic not in self.skipped:
                lines.append(f"{topic:<{width}}  never published")
        for topic, reason in sorted(self.skipped.items()):
            lines.append(f"{topic:<{width}}  not recorded: {reason}")
        lines += [f"WARNING: {p}" for p in problems]
        return (1 if problems else 0), "\n".join(lines)


def record(output: str | Path, topics: list[str] | None = None, storage: str = "sqlite3",
           duration_s: float | None = None, queue_depth: int = RECORD_QUEUE_DEPTH, flush_period_s: float = 1.0,
           use_sim_time: bool = False) -> int:
    """
    Record until SIGINT/SIGTERM (or `duration_s`); print the per-topic report.

    Returns the exit code: 0 recorded without loss, 1 messages lost or not written, 2 could
    not start.
    """
    configure_middleware()
    path = Path(output)
    if path.exists():
        print(f"star-tracker record: error: {path} exists already; choose a new --output", flush=True)
        return 2
    wanted = "every topic" if topics is None else " ".join(absolute_topic(t) for t in topics)
    print(f"recording {wanted} to {path} ({storage}); Ctrl-C to stop", flush=True)
    rclpy.init(args=[])
    recorder = None
    try:
        try:
            recorder = BagRecorder(path, storage, topics, queue_depth, flush_period_s, use_sim_time,
                                   log=lambda text: print(text, flush=True))
        except BagError as exc:
            print(f"star-tracker record: error: {exc}", flush=True)
            return 2
        executor = SingleThreadedExecutor(context=recorder.context)
        executor.add_node(recorder)
        deadline = None if not duration_s else time.monotonic() + duration_s
        failed = False
        try:
            while recorder.context.ok() and recorder.writer.is_alive():
                if deadline is not None and time.monotonic() >= deadline:
                    break
                executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception as exc:  # noqa: BLE001 - finish the bag anyway, then report
            print(f"star-tracker record: error while recording: {type(exc).__name__}: {exc}", flush=True)
            failed = True
        executor.remove_node(recorder)
        executor.shutdown()
        code, report = recorder.finish()
        print(report, flush=True)
        return max(code, 1) if failed else code
    finally:
        if recorder is not None:
            recorder.destroy_node()
        rclpy.try_shutdown()
