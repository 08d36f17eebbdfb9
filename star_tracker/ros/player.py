# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker play`: publish a bag's serialized messages, with the original timing or as fast as the pipeline answers.

Timing: message k goes out at t0 + (stamp_k - start) / rate on the monotonic clock, where
stamp is the bag (receive) time; `--clock` publishes /clock with the bag time (nodes started
with `use_sim_time:=true` follow it), at `clock_hz` and before every message.

Batch mode (rate 0) runs in lockstep by default: before publishing the next image the
player waits until every ack topic that has a publisher (default `spots` and `attitude`)
carried a message with the previous image's header stamp, or `ack_timeout_s` passed
(counted per topic and reported). Nothing is dropped in the downstream queues, and the
nodes see the frames in the same order and spacing relative to their own answers as in a
live run that keeps up.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ..bags import IMAGE_TYPE, BagError, BagReader, absolute_topic, header_stamp_ns, image_problem
from .bag_ros import message_class, playback_qos, qos_text
from .middleware import configure_middleware

DEFAULT_ACK_TOPICS = ("spots", "attitude")
ACK_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)  # matches any publisher


@dataclass
class PlayOptions:
    rate: float = 1.0  # playback speed factor; 0 = as fast as possible
    start_offset_s: float = 0.0
    loop: bool = False
    topics: list[str] | None = None  # None: every topic of the bag
    remap: dict[str, str] = field(default_factory=dict)  # bag topic -> published name
    clock_hz: float | None = None  # publish /clock at this rate (and before every message)
    lockstep: bool = True  # rate 0 only
    ack_topics: tuple[str, ...] = DEFAULT_ACK_TOPICS
    ack_required: bool = False  # wait until every ack topic has a publisher before playing
    ack_timeout_s: float = 1.0
    wait_for_subscribers: int = 0  # wait until every played topic has this many subscribers
    subscribers_per_topic: dict[str, int] = field(default_factory=dict)  # bag topic -> count, overrides the above
    wait_timeout_s: float = 60.0
    delay_s: float = 0.0
    check_images: bool = True


@dataclass
class PlayReport:
    published: Counter = field(default_factory=Counter)
    images: int = 0
    skipped_images: Counter = field(default_factory=Counter)
    first_problem: dict = field(default_factory=dict)
    ack_timeouts: Counter = field(default_factory=Counter)
    acked: int = 0
    ack_topics: set = field(default_factory=set)  # topics waited on at least once
    loops: int = 0
    first_image_t: float | None = None  # monotonic time the first image was published
    last_event_t: float | None = None  # ... the last message was published or answered
    interrupted: bool = False

    @property
    def elapsed_s(self) -> float:
        """First image published -> last answer (or last publish) [s]."""
        if self.first_image_t is None or self.last_event_t is None:
            return 0.0
        return self.last_event_t - self.first_image_t

    @property
    def frames_per_s(self) -> float:
        return self.images / self.elapsed_s if self.elapsed_s > 0 else float("nan")


def prepare(bag: BagReader, options: PlayOptions) -> tuple[list[str], dict[str, type], list[str]]:
    """
    Validate a bag for playing before any ROS setup.

    Topics exist, types are installed, the offset is inside the bag, the first image of each
    image topic suits the centroider. Returns (topics, message classes, image topics);
    raises BagError naming the problem.
    """
    info = bag.info
    topics = bag.select(options.topics)
    if not topics:
        raise BagError(f"{bag.path}: the bag has no topics")
    classes = {}
    for topic in topics:
        kind = info.topics[topic]
        if kind.serialization_format != "cdr":
            raise BagError(f"{topic}: serialization format {kind.serialization_format!r} cannot be played (cdr only)")
        try:
            classes[topic] = message_class(kind.type)
        except BagError as exc:
            raise BagError(f"cannot play {topic}: {exc}; leave it out with --topics") from None
    for old in options.remap:
        if old not in info.topics:
            raise BagError(f"--remap {old}: no such topic in the bag (topics: {', '.join(sorted(info.topics))})")
    for topic in options.subscribers_per_topic:
        if topic not in topics:
            raise BagError(f"--wait-for-subscribers {topic}: not a played topic (played: {', '.join(topics)})")
    if options.start_offset_s < 0 or (info.message_count
                                      and options.start_offset_s * 1e9 > info.end_ns - info.start_ns):
        raise BagError(f"--start-offset {options.start_offset_s:g} s is outside the bag's {info.duration_s:.3f} s")
    images = [t for t in topics if info.topics[t].type == IMAGE_TYPE]
    if options.check_images:
        for topic in images:
            first = next(bag.messages([topic]), None)
            if first is None:
                continue
            problem = image_problem(first[2])
            if problem:
                raise BagError(f"{topic}: first image (bag time {first[1] * 1e-9:.6f} s): {problem}; the "
                               f"centroider would reject it (--no-check plays it anyway)")
    return topics, classes, images


class AckTracker:
    """Raw subscriptions to the ack topics (created once a publisher exists) and the header stamps they carried."""

    def __init__(self, node: Node, topics: tuple[str, ...]):
        self.node = node
        self.topics = [absolute_topic(t) for t in topics]
        self.stamps: dict[str, set[int]] = {t: set() for t in self.topics}
        self.subscriptions: dict[str, object] = {}

    def refresh(self) -> None:
        graph = dict(self.node.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self.subscriptions or len(graph.get(topic, [])) != 1:
                continue
            try:
                cls = message_class(graph[topic][0])
            except BagError:
                continue
            stamps = self.stamps[topic]
            self.subscriptions[topic] = self.node.create_subscription(
                cls, topic, lambda data, stamps=stamps: stamps.add(header_stamp_ns(data)), ACK_QOS, raw=True)

    def active(self) -> list[str]:
        return [t for t in self.subscriptions if self.node.count_publishers(t) > 0]

    def matched(self) -> bool:
        """Every ack topic with a publisher in the graph is subscribed and connected."""
        for topic in self.topics:
            publishers = self.node.count_publishers(topic)
            if publishers and (topic not in self.subscriptions
                               or self.subscriptions[topic].get_publisher_count() < publishers):
                return False
        return True

    def forget(self, stamp_ns: int) -> None:
        for stamps in self.stamps.values():
            stamps.discard(stamp_ns)

    def missing(self, stamp_ns: int, topics: list[str]) -> list[str]:
        return [t for t in topics if stamp_ns not in self.stamps[t]]


def _counts(need: dict[str, int], topics: list[str]) -> str:
    """'2 on /image_raw, 4 on /camera_info'."""
    return ", ".join(f"{need[t]} on {t}" for t in topics)


FLUSH_TIMEOUT_S = 5.0  # after the last message: how long reliable subscribers get to acknowledge it


class BagPlayer(Node):
    def __init__(self, bag: BagReader, topics: list[str], classes: dict[str, type], images: list[str],
                 options: PlayOptions, log=print):
        super().__init__("star_tracker_player")
        self.bag, self.topics, self.images, self.options, self.log = bag, topics, set(images), options, log
        self.lockstep = options.rate == 0 and options.lockstep
        self.pubs = {}
        for topic in topics:
            name = absolute_topic(options.remap.get(topic, topic))
            qos = playback_qos(bag.info.topics[topic].offered_qos)
            self.pubs[topic] = self.create_publisher(classes[topic], name, qos)
            log(f"playing {topic}" + (f" as {name}" if name != topic else "") + f" ({qos_text(qos)})")
        self.clock_pub = None
        if options.clock_hz:
            from rosgraph_msgs.msg import Clock

            self._clock_msg = Clock
            # Reliable: matches the nodes' best-effort /clock readers and reliable ones alike.
            self.clock_pub = self.create_publisher(Clock, "/clock",
                                                   QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.acks = AckTracker(self, options.ack_topics if self.lockstep else ())
        self.executor_ = SingleThreadedExecutor(context=self.context)
        self.executor_.add_node(self)
        self.report = PlayReport()
        self._last_clock = 0.0
        self._clock_ns = 0

    # ------------------------------------------------------------------ helpers
    def ok(self) -> bool:
        return self.context.ok()

    def spin(self, timeout_s: float) -> None:
        self.executor_.spin_once(timeout_sec=max(0.0, timeout_s))

    def publish_clock(self, bag_ns: int) -> None:
        """
        Keep /clock from running backwards within a pass.

        A message published late would otherwise follow a periodic tick that got ahead of it.
        """
        from builtin_interfaces.msg import Time

        bag_ns = max(int(bag_ns), self._clock_ns)
        self._clock_ns = bag_ns
        sec, nanosec = divmod(bag_ns, 1_000_000_000)
        self.clock_pub.publish(self._clock_msg(clock=Time(sec=sec, nanosec=nanosec)))
        self._last_clock = time.monotonic()

    def wait_for_graph(self) -> None:
        """Wait for subscribers before the first message: best-effort volatile topics give nothing to a late one."""
        options = self.options
        explicit = bool(options.wait_for_subscribers or options.subscribers_per_topic)
        if explicit:
            need = {t: options.subscribers_per_topic.get(t, options.wait_for_subscribers) for t in self.topics}
        else:
            need = {t: 1 for t in sorted(self.images)} if self.lockstep else {}
        deadline = time.monotonic() + options.wait_timeout_s
        told = False
        while self.ok():
            short = [t for t, n in need.items() if self.pubs[t].get_subscription_count() < n]
            if not short:
                break
            if time.monotonic() > deadline:
                text = f"fewer than {_counts(need, short)} subscriber(s) after {options.wait_timeout_s:g} s"
                if explicit:
                    raise BagError(text)
                self.log(f"WARNING: {text}; playing anyway")
                break
            if not told:
                self.log(f"waiting for {_counts(need, short)} subscriber(s) ...")
                told = True
            self.spin(0.05)
        if self.lockstep:  # connect to the answering nodes before the first image
            self.settle_acks(deadline)
            self.log("lockstep: waiting after each image for "
                     + (", ".join(self.acks.active()) or "nothing (no publisher on "
                        + ", ".join(self.acks.topics) + ")"))
        end = time.monotonic() + options.delay_s
        while self.ok() and time.monotonic() < end:
            self.spin(end - time.monotonic())

    def settle_acks(self, deadline: float) -> None:
        """
        Subscribe to the ack topics and connect before the first image.

        Required ack topics (given explicitly) must all have a publisher; otherwise the graph
        gets a second to show the answering nodes (they are discovered one participant at a
        time).
        """
        required = self.options.ack_required
        quiet_until = time.monotonic() + 1.0
        limit = deadline if required else quiet_until + 3.0
        told = False
        while self.ok():
            self.acks.refresh()
            absent = [t for t in self.acks.topics if self.count_publishers(t) == 0]
            ready = self.acks.matched() and (not required or not absent)
            if ready and (required or time.monotonic() >= quiet_until):
                return
            if time.monotonic() > limit:
                if required:
                    raise BagError(f"no publisher on ack topic(s) {', '.join(absent)} after "
                                   f"{self.options.wait_timeout_s:g} s")
                return
            if required and absent and not told:
                self.log(f"waiting for a publisher on {', '.join(absent)} ...")
                told = True
            self.spin(0.05)

    def wait_answer(self, stamp_ns: int) -> None:
        """Lockstep: until every active ack topic carried `stamp_ns`, or the timeout."""
        self.acks.refresh()
        deadline = time.monotonic() + self.options.ack_timeout_s
        active = self.acks.active()
        self.report.ack_topics.update(active)
        while self.ok():
            missing = self.acks.missing(stamp_ns, active)
            if not missing:
                self.report.acked += 1
                return
            if time.monotonic() > deadline:
                for topic in missing:
                    self.report.ack_timeouts[topic] += 1
                return
            self.spin(0.002)

    def sleep_until(self, target: float, wall0: float, bag0: int) -> None:
        """Real-time mode: wait for a message's time, publishing /clock meanwhile."""
        period = 1.0 / self.options.clock_hz if self.clock_pub else None
        while self.ok():
            now = time.monotonic()
            if period and now - self._last_clock >= period:
                # Never past the next message's time: a late wake-up would run the clock ahead.
                target_ns = bag0 + int((target - wall0) * self.options.rate * 1e9)
                self.publish_clock(min(bag0 + int((now - wall0) * self.options.rate * 1e9), target_ns))
            if now >= target:
                return
            self.spin(min(target - now, period or 0.05))

    # ------------------------------------------------------------------ playing
    def play(self) -> PlayReport:
        options, report = self.options, self.report
        self.wait_for_graph()
        start_ns = self.bag.info.start_ns + int(round(options.start_offset_s * 1e9))
        pending: int | None = None
        while self.ok():
            wall0 = time.monotonic()
            self._clock_ns = 0  # a loop starts the bag's time again
            for topic, bag_ns, data in self.bag.messages(self.topics, start_ns=start_ns):
                if not self.ok():
                    break
                data = bytes(data)
                is_image = topic in self.images
                if is_image and pending is not None:
                    self.wait_answer(pending)
                    pending = None
                    report.last_event_t = time.monotonic()
                if options.rate > 0:
                    self.sleep_until(wall0 + (bag_ns - start_ns) * 1e-9 / options.rate, wall0, start_ns)
                else:
                    self.spin(0.0)
                if is_image and options.check_images:
                    problem = image_problem(data)
                    if problem:
                        report.skipped_images[topic] += 1
                        report.first_problem.setdefault(topic, f"bag time {bag_ns * 1e-9:.6f} s: {problem}")
                        continue
                if self.clock_pub is not None:
                    self.publish_clock(bag_ns)
                if is_image and self.lockstep:
                    pending = header_stamp_ns(data)
                    self.acks.forget(pending)  # a loop replays the same stamps
                self.pubs[topic].publish(data)
                report.published[topic] += 1
                report.last_event_t = time.monotonic()
                if is_image:
                    report.images += 1
                    report.first_image_t = report.first_image_t or report.last_event_t
            if pending is not None and self.ok():
                self.wait_answer(pending)
                pending = None
                report.last_event_t = time.monotonic()
            if not options.loop or not self.ok():
                break
            report.loops += 1
        report.interrupted = not self.ok()
        return report

    def flush(self, timeout_s: float = FLUSH_TIMEOUT_S) -> list[str]:
        """
        Wait until every reliable subscriber has acknowledged all that was published.

        A player that exits at once can take its last messages with it. Returns the topics still
        unacknowledged after timeout_s [s].
        """
        deadline = time.monotonic() + timeout_s
        late = []
        for topic, pub in self.pubs.items():
            left = max(0.0, deadline - time.monotonic())
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                late.append(topic)
        return late

    def destroy_node(self) -> None:
        self.executor_.remove_node(self)
        self.executor_.shutdown()
        super().destroy_node()


def describe(report: PlayReport, lockstep: bool) -> tuple[int, str]:
    """(exit code, text): 1 when images were skipped as unusable."""
    lines = []
    for topic, count in sorted(report.published.items()):
        lines.append(f"published {count:6d}  {topic}")
    if report.images:
        lines.append(f"{report.images} images in {report.elapsed_s:.2f} s: {report.frames_per_s:.2f} frames/s"
                     + (f", {report.loops} loop(s) completed" if report.loops else ""))
    if lockstep and report.images and not report.ack_topics:
        lines.append("lockstep: no node answered on the ack topics: played flat out")
    elif lockstep and report.images:
        lines.append(f"lockstep: {report.acked} of {report.images} images answered on "
                     f"{', '.join(sorted(report.ack_topics))}")
        for topic, count in sorted(report.ack_timeouts.items()):
            lines.append(f"  no answer on {topic} within the timeout for {count} image(s) "
                         f"(not identified, or dropped/slow)")
    code = 0
    for topic, count in sorted(report.skipped_images.items()):
        lines.append(f"WARNING: skipped {count} unusable image(s) on {topic}; first at {report.first_problem[topic]}")
        code = 1
    if report.interrupted:
        lines.append("interrupted")
    return code, "\n".join(lines)


def play(path: str, options: PlayOptions) -> int:
    """Validate, then play; print the report. Exit code 0 played, 1 images skipped, 2 error."""
    configure_middleware()
    try:
        bag = BagReader(path).open()
    except BagError as exc:
        print(f"star-tracker play: error: {exc}", flush=True)
        return 2
    player = None
    try:
        try:
            options.remap = {absolute_topic(k): absolute_topic(v) for k, v in options.remap.items()}
            options.subscribers_per_topic = {absolute_topic(k): n for k, n in options.subscribers_per_topic.items()}
            topics, classes, images = prepare(bag, options)
        except BagError as exc:
            print(f"star-tracker play: error: {exc}", flush=True)
            return 2
        rclpy.init(args=[])
        try:
            player = BagPlayer(bag, topics, classes, images, options, log=lambda text: print(text, flush=True))
            report = player.play()
            late = player.flush()
            if late:
                print(f"star-tracker play: warning: not acknowledged within {FLUSH_TIMEOUT_S:g} s by every reliable "
                      f"subscriber: {', '.join(late)}", flush=True)
        except (KeyboardInterrupt, ExternalShutdownException):
            report = player.report if player is not None else PlayReport()
            report.interrupted = True
        except BagError as exc:
            print(f"star-tracker play: error: {exc}", flush=True)
            return 2
        code, text = describe(report, player is not None and player.lockstep)
        print(text, flush=True)
        return code
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown()
        bag.close()
