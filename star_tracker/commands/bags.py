# SPDX-License-Identifier: Apache-2.0
"""
`star-tracker record | play | info | reindex`: rosbag2 bags (sqlite3, MCAP) without a ROS 2 install.

Through `rosbags` (the package star_tracker/bags/) and the recorder/player nodes in
star_tracker/ros/ (docs/RECORD_REPLAY.md). `add_commands(sub)` registers all four; their
--help keeps the form it had in cli.py (no example epilog).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..bags import BagError
from .common import guarded, non_negative_float, positive_float


@guarded("record", errors=(BagError,))
def cmd_record(args: argparse.Namespace) -> int:
    from ..bags import DEFAULT_RECORD_TOPICS
    from ..ros.recorder import record

    topics = None if args.all else (args.topics or list(DEFAULT_RECORD_TOPICS))
    output = args.output or time.strftime("rosbag2_%Y_%m_%d-%H_%M_%S")
    return record(output, topics, args.storage, args.duration, args.queue_depth, args.flush_period, args.use_sim_time)


def parse_remaps(pairs: list[str]) -> dict[str, str]:
    """["old:=new", ...] -> {old: new}; ValueError naming a malformed pair."""
    remap = {}
    for pair in pairs:
        old, sep, new = pair.partition(":=")
        if not sep or not old or not new:
            raise ValueError(f"--remap {pair!r}: expected OLD:=NEW")
        remap[old] = new
    return remap


def parse_subscriber_counts(items: list[str]) -> tuple[int, dict[str, int]]:
    """["N" | "TOPIC=N", ...] -> (N for every played topic, {TOPIC: N}); ValueError naming a bad item."""
    every, per_topic = 0, {}
    for item in items:
        topic, sep, count = item.rpartition("=")
        if not count.isdigit() or (sep and not topic):
            raise ValueError(f"--wait-for-subscribers {item!r}: expected N or TOPIC=N (N a whole number)")
        if sep:
            per_topic[topic] = int(count)
        else:
            every = int(count)
    return every, per_topic


@guarded("play", errors=(BagError,))
def cmd_play(args: argparse.Namespace) -> int:
    from ..ros.player import DEFAULT_ACK_TOPICS, PlayOptions, play

    every, per_topic = parse_subscriber_counts(args.wait_for_subscribers)
    options = PlayOptions(rate=args.rate, start_offset_s=args.start_offset, loop=args.loop, topics=args.topics,
                          remap=parse_remaps(args.remap), clock_hz=args.clock, lockstep=not args.no_lockstep,
                          ack_topics=tuple(args.ack_topics or DEFAULT_ACK_TOPICS),
                          ack_required=args.ack_topics is not None, ack_timeout_s=args.ack_timeout,
                          wait_for_subscribers=every,
                          subscribers_per_topic=per_topic, wait_timeout_s=args.wait_timeout,
                          delay_s=args.delay, check_images=not args.no_check)
    return play(args.bag, options)


@guarded("info", errors=(BagError,))
def cmd_info(args: argparse.Namespace) -> int:
    from ..bags import BagReader, check_bag

    if args.check:
        info, problems = check_bag(args.bag)
    else:
        with BagReader(args.bag) as bag:
            info, problems = bag.info, []
    print(info.describe())
    if args.check:
        print("check: every message read" + (": no problem found" if not problems else ""))
    for problem in problems:
        print(f"PROBLEM: {problem}")
    return 1 if problems else 0


@guarded("reindex", errors=(BagError,))
def cmd_reindex(args: argparse.Namespace) -> int:
    from ..bags import reindex

    info = reindex(args.bag)
    print(f"rebuilt {Path(args.bag) / 'metadata.yaml'}")
    print(info.describe())
    return 0


def add_commands(sub) -> None:
    """Register record, play, info and reindex on an argparse sub-parser action."""
    add_record_parser(sub)
    add_play_parser(sub)
    add_info_parser(sub)
    add_reindex_parser(sub)


def add_record_parser(sub) -> None:
    record = sub.add_parser(
        "record", help="record topics to a rosbag2 bag (sqlite3 or mcap)",
        description="Subscribe to topics as serialized messages and write a standard rosbag2 bag (metadata "
                    "version 9, message definitions, type hashes and the publishers' QoS), readable by "
                    "`ros2 bag info/play`. A topic is subscribed when its publisher appears (reliable if every "
                    "publisher is, else best effort). Stops on Ctrl-C/SIGTERM (or --duration) and finishes the "
                    "bag; prints per topic the messages received, written and lost (gaps in the publisher's "
                    "sequence numbers). Exit code 0: nothing lost; 1: messages lost or not written; 2: could not "
                    "start. A killed recorder leaves a bag that `star-tracker reindex` recovers. See "
                    "docs/RECORD_REPLAY.md.")
    record.add_argument("topics", nargs="*", metavar="TOPIC",
                        help="topics to record (default: image_raw, camera_info, the truth/ topics and every "
                             "centroider and identifier output)")
    record.add_argument("-a", "--all", action="store_true", help="record every topic (except /rosout and "
                        "/parameter_events)")
    record.add_argument("-o", "--output", help="bag directory to create (default rosbag2_YYYY_MM_DD-HH_MM_SS)")
    record.add_argument("-s", "--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                        help="storage format (default sqlite3, as ros2 bag record)")
    record.add_argument("--duration", type=positive_float, help="stop after this many seconds (default: until Ctrl-C)")
    record.add_argument("--queue-depth", type=int, default=50,
                        help="subscription queue per topic (keep last N; default 50 = 5 s at 10 Hz): size it to "
                             "rate x the longest stall to ride through")
    record.add_argument("--flush-period", type=positive_float, default=1.0,
                        help="seconds between commits to disk; a killed recorder loses at most this much "
                             "(default 1.0)")
    record.add_argument("--use-sim-time", action="store_true",
                        help="stamp messages with the /clock time instead of the reception time")
    record.set_defaults(func=cmd_record)


def add_play_parser(sub) -> None:
    play = sub.add_parser(
        "play", help="publish a bag's messages (original timing, a rate factor, or lockstep batch)",
        description="Publish the serialized messages of a rosbag2 bag with their original timing (bag "
                    "receive times), scaled by --rate. --rate 0 plays as fast as the pipeline answers: after "
                    "each image the player waits until every --ack-topics topic that has a publisher carried a "
                    "message with that image's stamp (or --ack-timeout), so no frame is dropped downstream. The "
                    "bag is validated first (topics, installed types, image encodings): a problem is an error "
                    "naming it (exit code 2). See docs/RECORD_REPLAY.md.")
    play.add_argument("bag", help="bag directory (or a .db3/.mcap file)")
    play.add_argument("-r", "--rate", type=non_negative_float, default=1.0,
                      help="playback speed factor (default 1; 0 = as fast as possible, lockstep)")
    play.add_argument("--start-offset", type=non_negative_float, default=0.0, metavar="S",
                      help="skip the first S seconds of the bag")
    play.add_argument("-l", "--loop", action="store_true", help="play again from the start until Ctrl-C")
    play.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (default: all)")
    play.add_argument("--remap", nargs="+", default=[], metavar="OLD:=NEW",
                      help="publish bag topic OLD under the name NEW")
    play.add_argument("--clock", type=positive_float, nargs="?", const=100.0, metavar="HZ",
                      help="publish /clock with the bag time at HZ (default 100) and before every message, for "
                           "nodes started with use_sim_time:=true")
    play.add_argument("--no-lockstep", action="store_true",
                      help="with --rate 0, publish flat out without waiting for answers (downstream best-effort "
                           "queues then drop frames)")
    play.add_argument("--ack-topics", nargs="+", metavar="TOPIC",
                      help="lockstep: topics whose message with an image's stamp answers it; given explicitly, "
                           "each must have a publisher before playing starts (default: spots and attitude, "
                           "among those that have a publisher)")
    play.add_argument("--ack-timeout", type=positive_float, default=1.0, metavar="S",
                      help="longest wait for an answer in lockstep (default 1.0; unidentified frames wait this long)")
    play.add_argument("--wait-for-subscribers", nargs="+", default=[], metavar="N|TOPIC=N",
                      help="before playing, wait until every played topic has N subscribers, TOPIC=N for one "
                           "topic (e.g. 2 camera_info=4: two pipelines' centroiders and identifiers); default 0, "
                           "lockstep waits for one on the image topics")
    play.add_argument("--wait-timeout", type=positive_float, default=60.0, metavar="S",
                      help="give up waiting for subscribers after S seconds (default 60)")
    play.add_argument("--delay", type=non_negative_float, default=0.0, metavar="S",
                      help="sleep S seconds before the first message (discovery)")
    play.add_argument("--no-check", action="store_true",
                      help="play images the centroider cannot use (wrong encoding or size) instead of refusing "
                           "the bag / skipping them")
    play.set_defaults(func=cmd_play)


def add_info_parser(sub) -> None:
    info = sub.add_parser("info", help="describe a bag (topics, types, counts, QoS); --check reads every message",
                          description="Print a bag's storage, duration, topics with types, message counts and "
                                      "recorded QoS. With --check, read and deserialize every message and check "
                                      "the images' encodings: exit code 1 when a problem is found, 2 when the "
                                      "bag cannot be opened.")
    info.add_argument("bag", help="bag directory (or a .db3/.mcap file)")
    info.add_argument("--check", action="store_true", help="read every message and report bad ones")
    info.set_defaults(func=cmd_info)


def add_reindex_parser(sub) -> None:
    reindex = sub.add_parser("reindex", help="recover a bag whose recording was killed (rebuild metadata.yaml)",
                             description="Rebuild metadata.yaml from a bag directory's storage, like `ros2 bag "
                                         "reindex`: sqlite3 keeps every committed message; an unfinished MCAP "
                                         "file is rewritten from its complete records (the original is kept as "
                                         "NAME.mcap.unfinished).")
    reindex.add_argument("bag", help="bag directory")
    reindex.set_defaults(func=cmd_reindex)
