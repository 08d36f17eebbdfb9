"""`star-tracker` command line. `star-tracker demo` is what `make demo` runs; `record`, `play`,
`info` and `reindex` handle rosbag2 bags (docs/RECORD_REPLAY.md)."""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

SCENARIOS = {
    # camera_simulator parameter overrides; everything else is the default configuration.
    "default": {"attitude.profile": "constant_rate", "attitude.body_rate_deg_s": [0.3, 0.4, 0.05]},
    "rest": {"attitude.profile": "fixed"},
    "fast": {"attitude.profile": "constant_rate", "attitude.body_rate_deg_s": [1.2, 0.9, 0.2]},
    "slew": {"attitude.profile": "slew", "attitude.slew.axis": [0.6, 0.8, 0.0], "attitude.slew.angle_deg": 20.0,
             "attitude.slew.max_rate_deg_s": 2.0, "attitude.slew.accel_deg_s2": 0.5, "attitude.slew.start_s": 3.0},
    "tumble": {"attitude.profile": "tumble", "attitude.tumble.initial_rate_deg_s": [0.4, 0.2, 1.0],
               "attitude.tumble.inertia_kg_m2": [10.0, 12.0, 8.0]},
    "jitter": {"attitude.profile": "jitter", "attitude.body_rate_deg_s": [0.1, 0.0, 0.0],
               "attitude.jitter.amplitudes_rad": [5e-5, 5e-5, 2e-5], "attitude.jitter.frequencies_hz": [3.0]},
}


def default_params_file() -> Path | None:
    """config/star_tracker.yaml from the source tree, or from the colcon install share dir."""
    source = Path(__file__).resolve().parents[1] / "config" / "star_tracker.yaml"
    if source.is_file():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("star_tracker")) / "config" / "star_tracker.yaml"
        return installed if installed.is_file() else None
    except Exception:  # no ament index: the nodes' built-in defaults are the same values
        return None


def cmd_demo(args: argparse.Namespace) -> int:
    from .identify import DatabaseConfig, load_or_build_database
    from .catalog import load_hipparcos

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    print(f"star_tracker demo: scenario '{args.scenario}', {args.duration:g} s at {args.rate:g} Hz"
          + (", centroider rate-aided by the true body rate (--gyro)" if args.gyro else ""), flush=True)
    started = time.perf_counter()
    load_hipparcos()
    load_or_build_database(DatabaseConfig())
    print(f"catalog and pattern database ready ({time.perf_counter() - started:.1f} s)", flush=True)

    from .ros.pipeline import NodeProcesses, TrackerMonitor, isolated_ros_environment, summarize

    env = isolated_ros_environment()
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE") if k in env})
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    frames_wanted = int(round(args.duration * args.rate))
    params = {"camera_simulator": {**SCENARIOS[args.scenario], "rate_hz": float(args.rate),
                                   "max_frames": frames_wanted, "start_delay_s": 2.0, "wait_for_subscribers": True}}
    import rclpy

    rclpy.init(args=[])
    monitor = TrackerMonitor(name="star_tracker_demo_monitor")
    # --gyro: the centroider gets the true body rate, as from a gyro, and uses its rate aid.
    remaps = {"centroider": {"angular_velocity": "truth/angular_velocity"}} if args.gyro else None
    nodes = NodeProcesses(env, out / "logs", params, default_params_file(), remaps=remaps)
    recorder = start_recorder(args.record, env) if args.record else None
    printed: set[int] = set()
    index = 0
    try:
        nodes.start()
        nodes.wait_ready()
        print(f"nodes running (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}, logs in {out / 'logs'})", flush=True)
        print(f"{'frame':>5}  {'stamp [s]':>16}  {'spots':>5}  {'ident':>5}  {'cross-bore':>10}  {'roll':>8}  {'latency':>8}")
        started_frames = time.monotonic()
        end = started_frames + args.duration + 8.0
        while time.monotonic() < end:
            monitor.spin_for(0.2)
            if time.monotonic() > started_frames + args.duration - 2.0:
                monitor.enable_images()  # for the picture: only the last frames are needed
            now = time.monotonic()
            ready = sorted(ns for ns, f in monitor.frames.items() if ns not in printed and f.truth is not None
                           and (f.attitude is not None and f.matched is not None or now - f.first_seen > 1.5))
            for ns in ready:
                f = monitor.frames[ns]
                printed.add(ns)
                index += 1
                error = f.error()
                spots = "-" if f.spot_count is None else str(f.spot_count)
                if error is None:
                    print(f"{index:5d}  {ns * 1e-9:16.3f}  {spots:>5}  {'-':>5}  {'not identified':>19}", flush=True)
                else:
                    arcsec = np.degrees(error) * 3600
                    n_matched = 0 if f.matched is None else f.matched.size
                    print(f"{index:5d}  {ns * 1e-9:16.3f}  {spots:>5}  {n_matched:5d}  {arcsec[0]:9.2f}\"  {arcsec[1]:7.2f}\"  "
                          f"{f.attitude_latency_s * 1e3:6.0f}ms", flush=True)
            if index >= frames_wanted:
                break
    finally:
        codes = nodes.stop()
        if recorder is not None:
            codes["recorder"] = stop_recorder(recorder)
        frames = [monitor.frames[ns] for ns in sorted(monitor.frames)]
        monitor.destroy_node()
        rclpy.try_shutdown()

    summary = summarize(frames)
    summary["scenario"] = args.scenario
    summary["node_exit_codes"] = codes
    picture = write_picture(frames, out / "frame.png")
    history = write_run_figure(frames, out / "run.png")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    with open(out / "frames.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["stamp_ns", "spots", "matched", "cross_boresight_arcsec", "roll_arcsec", "latency_ms"])
        for f in frames:
            if f.truth is None:
                continue
            err = f.error()
            writer.writerow([f.stamp_ns, f.spot_count, None if f.matched is None else f.matched.size,
                             None if err is None else round(np.degrees(err[0]) * 3600, 3),
                             None if err is None else round(np.degrees(err[1]) * 3600, 3),
                             None if f.attitude_latency_s is None else round(f.attitude_latency_s * 1e3, 2)])
    print()
    print(f"summary: {summary['frames']} frames, {summary['identified']} identified "
          f"({100 * summary['identification_rate']:.1f} %), {summary['wrong_over_60_arcsec']} wrong (> 60\")")
    print(f"attitude error vs truth: median {summary['cross_boresight_arcsec_median']:.2f}\" cross-boresight, "
          f"{summary['roll_arcsec_median']:.2f}\" roll; 95th percentile {summary['cross_boresight_arcsec_p95']:.2f}\" / "
          f"{summary['roll_arcsec_p95']:.2f}\"")
    print(f"latency (mid-exposure stamp -> attitude received): median {summary['latency_ms_median']:.0f} ms, "
          f"max {summary['latency_ms_max']:.0f} ms")
    print(f"node exit codes: {codes}")
    print(f"wrote {picture or '(no identified frame with an image: no picture)'}, {history or '(no run plot)'}, "
          f"{out / 'summary.json'}, {out / 'frames.csv'}")
    healthy = all(code == 0 for code in codes.values()) and summary["frames"] > 0 and picture is not None
    return 0 if healthy else 1


def start_recorder(output: str, env: dict[str, str]):
    """`star-tracker record` (default topics) as a separate process on the demo's domain. It
    subscribes as the nodes' publishers appear, well before the camera's first exposure
    (the camera waits for its subscribers, then start_delay_s)."""
    import subprocess

    if Path(output).exists():
        print(f"star-tracker demo: error: --record {output} exists already", file=sys.stderr)
        sys.exit(2)
    cmd = [sys.executable, "-m", "star_tracker.cli", "record", "--output", str(output)]
    print(f"recording the run to {output} (rosbag2, sqlite3)", flush=True)
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_recorder(process) -> int:
    """SIGINT (the bag is finished), then print the recorder's per-topic report."""
    import signal
    import subprocess

    process.send_signal(signal.SIGINT)
    try:
        output, _ = process.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
    print("recorder:\n" + "\n".join("  " + line for line in output.splitlines() if not line.startswith("recording /")),
          flush=True)
    return process.returncode


def write_run_figure(frames, path: Path) -> Path | None:
    """Attitude error and rate against time for the run (visualize.run_figure), or None when
    no frame had truth."""
    from .visualize import run_arrays, run_figure, save_figure

    arrays = run_arrays(frames)
    if arrays["time_s"].size == 0:
        return None
    save_figure(run_figure(**arrays, title="demo run"), path)
    return path


def write_picture(frames, path: Path) -> Path | None:
    """The newest identified frame with its image, identified stars circled + HIP labels."""
    import cv2

    from .visualize import annotate_frame

    for f in reversed(frames):
        if f.image is not None and f.matched is not None and f.matched.size:
            err = f.error()
            title = (f"{f.matched.size} stars identified" +
                     (f", error {np.degrees(err[0]) * 3600:.1f}\" cross-boresight / {np.degrees(err[1]) * 3600:.1f}\" roll"
                      if err is not None else ""))
            canvas = annotate_frame(f.image, f.matched["pixel_x"], f.matched["pixel_y"], f.matched["hip_id"], title)
            cv2.imwrite(str(path), canvas)
            return path
    return None


def cmd_record(args: argparse.Namespace) -> int:
    from .bags import DEFAULT_RECORD_TOPICS
    from .ros.recorder import record

    topics = None if args.all else (args.topics or list(DEFAULT_RECORD_TOPICS))
    output = args.output or time.strftime("rosbag2_%Y_%m_%d-%H_%M_%S")
    return record(output, topics, args.storage, args.duration, args.queue_depth, args.flush_period, args.use_sim_time)


def parse_remaps(pairs: list[str]) -> dict[str, str]:
    remap = {}
    for pair in pairs:
        old, sep, new = pair.partition(":=")
        if not sep or not old or not new:
            raise ValueError(f"--remap {pair!r}: expected OLD:=NEW")
        remap[old] = new
    return remap


def cmd_play(args: argparse.Namespace) -> int:
    from .ros.player import DEFAULT_ACK_TOPICS, PlayOptions, play

    try:
        remap = parse_remaps(args.remap)
    except ValueError as exc:
        print(f"star-tracker play: error: {exc}", file=sys.stderr)
        return 2
    options = PlayOptions(rate=args.rate, start_offset_s=args.start_offset, loop=args.loop, topics=args.topics,
                          remap=remap, clock_hz=args.clock, lockstep=not args.no_lockstep,
                          ack_topics=tuple(args.ack_topics or DEFAULT_ACK_TOPICS),
                          ack_required=args.ack_topics is not None, ack_timeout_s=args.ack_timeout,
                          wait_for_subscribers=args.wait_for_subscribers, wait_timeout_s=args.wait_timeout,
                          delay_s=args.delay, check_images=not args.no_check)
    return play(args.bag, options)


def cmd_info(args: argparse.Namespace) -> int:
    from .bags import BagError, BagReader, check_bag

    try:
        if args.check:
            info, problems = check_bag(args.bag)
        else:
            with BagReader(args.bag) as bag:
                info, problems = bag.info, []
    except BagError as exc:
        print(f"star-tracker info: error: {exc}", file=sys.stderr)
        return 2
    print(info.describe())
    if args.check:
        print("check: every message read" + (": no problem found" if not problems else ""))
    for problem in problems:
        print(f"PROBLEM: {problem}")
    return 1 if problems else 0


def cmd_reindex(args: argparse.Namespace) -> int:
    from .bags import BagError, reindex

    try:
        info = reindex(args.bag)
    except BagError as exc:
        print(f"star-tracker reindex: error: {exc}", file=sys.stderr)
        return 2
    print(f"rebuilt {Path(args.bag) / 'metadata.yaml'}")
    print(info.describe())
    return 0


def positive(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text} must be > 0")
    return value


def non_negative(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text} must be >= 0")
    return value


def add_bag_commands(sub) -> None:
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
    record.add_argument("--duration", type=positive, help="stop after this many seconds (default: until Ctrl-C)")
    record.add_argument("--queue-depth", type=int, default=50,
                        help="subscription queue per topic (keep last N; default 50 = 5 s at 10 Hz): size it to "
                             "rate x the longest stall to ride through")
    record.add_argument("--flush-period", type=positive, default=1.0,
                        help="seconds between commits to disk; a killed recorder loses at most this much "
                             "(default 1.0)")
    record.add_argument("--use-sim-time", action="store_true",
                        help="stamp messages with the /clock time instead of the reception time")
    record.set_defaults(func=cmd_record)

    play = sub.add_parser(
        "play", help="publish a bag's messages (original timing, a rate factor, or lockstep batch)",
        description="Publish the serialized messages of a rosbag2 bag with their original timing (bag "
                    "receive times), scaled by --rate. --rate 0 plays as fast as the pipeline answers: after "
                    "each image the player waits until every --ack-topics topic that has a publisher carried a "
                    "message with that image's stamp (or --ack-timeout), so no frame is dropped downstream. The "
                    "bag is validated first (topics, installed types, image encodings): a problem is an error "
                    "naming it (exit code 2). See docs/RECORD_REPLAY.md.")
    play.add_argument("bag", help="bag directory (or a .db3/.mcap file)")
    play.add_argument("-r", "--rate", type=non_negative, default=1.0,
                      help="playback speed factor (default 1; 0 = as fast as possible, lockstep)")
    play.add_argument("--start-offset", type=non_negative, default=0.0, metavar="S",
                      help="skip the first S seconds of the bag")
    play.add_argument("-l", "--loop", action="store_true", help="play again from the start until Ctrl-C")
    play.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics (default: all)")
    play.add_argument("--remap", nargs="+", default=[], metavar="OLD:=NEW",
                      help="publish bag topic OLD under the name NEW")
    play.add_argument("--clock", type=positive, nargs="?", const=100.0, metavar="HZ",
                      help="publish /clock with the bag time at HZ (default 100) and before every message, for "
                           "nodes started with use_sim_time:=true")
    play.add_argument("--no-lockstep", action="store_true",
                      help="with --rate 0, publish flat out without waiting for answers (downstream best-effort "
                           "queues then drop frames)")
    play.add_argument("--ack-topics", nargs="+", metavar="TOPIC",
                      help="lockstep: topics whose message with an image's stamp answers it; given explicitly, "
                           "each must have a publisher before playing starts (default: spots and attitude, "
                           "among those that have a publisher)")
    play.add_argument("--ack-timeout", type=positive, default=1.0, metavar="S",
                      help="longest wait for an answer in lockstep (default 1.0; unidentified frames wait this long)")
    play.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                      help="before playing, wait until every played topic has N subscribers (default 0; lockstep "
                           "waits for one on the image topics)")
    play.add_argument("--wait-timeout", type=positive, default=60.0, metavar="S",
                      help="give up waiting for subscribers after S seconds (default 60)")
    play.add_argument("--delay", type=non_negative, default=0.0, metavar="S",
                      help="sleep S seconds before the first message (discovery)")
    play.add_argument("--no-check", action="store_true",
                      help="play images the centroider cannot use (wrong encoding or size) instead of refusing "
                           "the bag / skipping them")
    play.set_defaults(func=cmd_play)

    info = sub.add_parser("info", help="describe a bag (topics, types, counts, QoS); --check reads every message",
                          description="Print a bag's storage, duration, topics with types, message counts and "
                                      "recorded QoS. With --check, read and deserialize every message and check "
                                      "the images' encodings: exit code 1 when a problem is found, 2 when the "
                                      "bag cannot be opened.")
    info.add_argument("bag", help="bag directory (or a .db3/.mcap file)")
    info.add_argument("--check", action="store_true", help="read every message and report bad ones")
    info.set_defaults(func=cmd_info)

    reindex = sub.add_parser("reindex", help="recover a bag whose recording was killed (rebuild metadata.yaml)",
                             description="Rebuild metadata.yaml from a bag directory's storage, like `ros2 bag "
                                         "reindex`: sqlite3 keeps every committed message; an unfinished MCAP "
                                         "file is rewritten from its complete records (the original is kept as "
                                         "NAME.mcap.unfinished).")
    reindex.add_argument("bag", help="bag directory")
    reindex.set_defaults(func=cmd_reindex)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="star-tracker", description="Simulated spacecraft star tracker (ROS 2).")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the three nodes on a scenario with live status and a picture",
                          description="Start camera_simulator, centroider and identifier as separate processes "
                                      "on a private DDS domain, print one status line per frame (spots, identified "
                                      "stars, attitude error vs truth, latency), then a summary; write "
                                      "OUTPUT/frame.png, run.png (attitude error and rate vs time), summary.json and frames.csv.")
    demo.add_argument("--scenario", choices=sorted(SCENARIOS), default="default",
                      help="attitude motion: default = 0.5 deg/s cross-boresight + slow roll; rest; fast ~1.5 deg/s; "
                           "slew = 20 deg at up to 2 deg/s from t = 3 s; tumble = torque-free tumble ~1.1 deg/s; "
                           "jitter = 0.1 deg/s + 10\" sinusoidal jitter at 3 Hz")
    demo.add_argument("--duration", type=float, default=30.0, help="seconds of frames to simulate (default 30)")
    demo.add_argument("--rate", type=float, default=10.0, help="frame rate [Hz] (default 10)")
    demo.add_argument("--output", default="demo_output", help="output directory (default demo_output)")
    demo.add_argument("--gyro", action="store_true",
                      help="feed the simulator's true body rate to the centroider's angular_velocity input "
                           "(as a gyro would): streaks are detected with a matched filter and fitted on their "
                           "predicted path")
    demo.add_argument("--record", metavar="DIR",
                      help="also record the run (camera, truth and output topics) to the rosbag2 bag DIR "
                           "with `star-tracker record`; replay it with `star-tracker play DIR`")
    demo.set_defaults(func=cmd_demo)
    add_bag_commands(sub)
    from .commands import add_commands  # render, solve, database, monitor, bench (star_tracker/commands/)

    add_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    if args.command == "demo" and (args.duration <= 0 or args.rate <= 0):
        print("star-tracker: error: --duration and --rate must be > 0", file=sys.stderr)
        sys.exit(2)
    sys.exit(args.func(args))


if __name__ == "__main__":
    main()
