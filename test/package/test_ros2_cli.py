# SPDX-License-Identifier: Apache-2.0
"""
The colcon-built package driven with the real `ros2` command line, as a ROS user does it.

The upstream Jazzy `ros2` CLI, launch and launch_ros are vendored in the workplace's
`../shared/ros2cli` (never copied here); `make ros2cli` (a prerequisite of `make test`)
installs them into the project's venv with its install.sh. Where `../shared/ros2cli` is
absent (a clone elsewhere) every test here is skipped with that reason; where it is present
but this interpreter's venv has no `ros2`, they are skipped with the command that installs it.

What a user does, with real processes over DDS on private localhost-only domains (216-220):

* `colcon build` (test/conftest.py `colcon_workspace`, shared with test_colcon_install.py),
  then every command with the environment `source install/setup.bash` gives and the venv on PATH;
* the README's ROS 2 commands ("Using it with a full ROS 2 install"), each run as written
  (`/path/to/my.yaml` becomes a copy of the shipped YAML with a 2 Hz camera);
* on the three `ros2 run` nodes: `ros2 param describe/get/set/dump` on every node,
  `ros2 lifecycle get/set` and `ros2 service call .../reset` (those are tied to issue 18
  part 5 and skip, saying so, while the nodes have no lifecycle services);
* `ros2 launch star_tracker star_tracker.launch.py`, plain and with `namespace:=st1`, with
  `ros2 topic hz` counting the attitudes; Ctrl-C (SIGINT to the process group) ends all.

Judged by counts and states, never by host speed: timeouts are long (a first start compiles
kernels and builds the pattern database, minutes on a loaded 2-core host).
"""
from __future__ import annotations

import copy
import math
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from conftest import sourced_ros_environment

# pytest.ini gives each test 600 s; a first start (cold kernels, database build) under load needs more.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(1200)]

REPO = Path(__file__).resolve().parents[2]
ROS2CLI = REPO.parent / "shared" / "ros2cli"
README = REPO / "README.md"
README_SECTION = "## Using it with a full ROS 2 install"
PACKAGE = "star_tracker"
NODES = ("camera_simulator", "centroider", "identifier")
RCLPY_OWN_PARAMETERS = {"use_sim_time", "start_type_description_service"}  # declared by rclpy itself

DOMAIN_RUN = 216  # the README's three `ros2 run` lines
DOMAIN_REMAP = 217  # the README's remap examples (centroider, identifier)
DOMAIN_GYRO = 218  # the README's gyro example (a second centroider)
DOMAIN_AUTOSTART = 221  # the README's lifecycle walk-through (an identifier started unconfigured)
DOMAIN_LAUNCH = {"": 219, "st1": 220}  # ros2 launch, plain and namespace:=st1

MY_YAML_CAMERA_RATE_HZ = 2.0  # the README's /path/to/my.yaml: the shipped YAML with a slow camera
START_TIMEOUT_S = 400.0  # cold kernels + a first database build under load
CLI_TIMEOUT_S = 120.0  # one `ros2` command (discovery, a service call)
DISCOVERY_ATTEMPTS = 3  # runs of a `ros2` command whose service discovery timed out or whose response was lost
PRIMARY_STATES = ("unconfigured", "inactive", "active", "finalized")  # a managed node's resting states
HUNG_RUN_S = 60.0  # a `ros2` service call still running after this lost its response: run it again
STOP_TIMEOUT_S = 60.0
HZ_WINDOW = 10  # attitudes `ros2 topic hz` must have seen in its window

# A parameter of each node that a real driver changes while running (issue 18 part 2), a valid
# new value and an out-of-range one.
RUNTIME_PARAMETER = {
    "camera_simulator": ("sensor.exposure_s", 0.05, -1.0),
    "centroider": ("detection_sigma", 5.0, -1.0),
    "identifier": ("max_time_s", 0.4, -1.0),
}


# --- the README's ROS 2 commands ---------------------------------------------------------------

def readme_section() -> str:
    text = README.read_text()
    start = text.index(README_SECTION)
    end = text.find("\n## ", start + len(README_SECTION))
    return text[start:end if end >= 0 else len(text)]


def readme_ros2_commands() -> list[str]:
    """
    Return every `ros2 ...` command of the README section, comments stripped, continuations joined.

    From its bash blocks, and its inline code that is a whole command (4+ words, no <placeholder>).
    """
    section = readme_section()
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", section, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            if line.startswith("ros2 "):
                commands.append(line)
    prose = re.sub(r"```.*?```", "", section, flags=re.S)
    commands += [c for c in re.findall(r"`(ros2 [^`]+)`", prose) if len(c.split()) >= 4 and "<" not in c]
    return commands


def kind_of(command: str) -> str:
    """Return which test runs a README command: run, autostart, gyro, remap, launch, describe, ..."""
    words = shlex.split(command)
    if words[:2] == ["ros2", "launch"]:
        return "launch"
    if words[:2] == ["ros2", "run"]:
        if "--params-file" in words:
            return "run"  # the three nodes, one terminal each
        if "autostart:=false" in words:
            return "autostart"  # the lifecycle walk-through
        if any(w.startswith("exposure_time_s:=") for w in words):
            return "gyro"
        if "-r" in words:
            return "remap"
    return {("param", "describe"): "describe", ("lifecycle", "get"): "lifecycle_get",
            ("lifecycle", "set"): "lifecycle_set", ("service", "call"): "service"}.get(tuple(words[1:3]), "unknown")


def readme_commands(kind: str) -> list[str]:
    """Return the README's commands of one kind (see kind_of), in README order."""
    return [c for c in readme_ros2_commands() if kind_of(c) == kind]


def ros_args(command: str, flag: str) -> list[tuple[str, str]]:
    """Return the (name, value) pairs of a command's `-r from:=to` or `-p name:=value` arguments."""
    words = shlex.split(command)
    return [tuple(words[i + 1].split(":=", 1)) for i in range(len(words) - 1) if words[i] == flag]


def test_readme_ros2_commands_are_all_run_here():
    """Every ROS 2 command of the README section is one that a test below runs as written."""
    commands = readme_ros2_commands()
    unknown = [c for c in commands if kind_of(c) == "unknown"]
    assert not unknown, f"README commands no test runs (teach test_ros2_cli.py kind_of): {unknown}"
    assert sorted(c.split()[3] for c in readme_commands("run")) == sorted(NODES), readme_commands("run")
    launches = readme_commands("launch")
    assert len(launches) == 2 and "namespace:=st1" in launches[1] and "/path/to/my.yaml" in launches[1], launches
    assert len(readme_commands("gyro")) <= 1 and len(readme_commands("autostart")) <= 1
    section = readme_section()
    assert "colcon build" in section and "source install/setup.bash" in section  # what the fixtures do


# --- the environment a user's shell has after `colcon build` + `source install/setup.bash` -----

def _default_signals() -> None:
    # pytest started from a script may inherit SIGINT ignored; a terminal's Ctrl-C must work.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@pytest.fixture(scope="module")
def ros2_exe() -> Path:
    """Return the venv's `ros2`, or skip with the reason it is not there."""
    if not (ROS2CLI / "install.sh").is_file():
        pytest.skip(f"{ROS2CLI} is absent (a clone outside the workplace): the tests of the real ros2 CLI need it")
    exe = Path(sys.executable).with_name("ros2")
    if not exe.is_file():
        pytest.skip(f"no ros2 CLI in this venv ({exe}): run `make ros2cli` (make test does) "
                    f"or `bash {ROS2CLI}/install.sh {Path(sys.prefix)}`")
    return exe


@pytest.fixture(scope="module")
def user_env(ros2_exe, colcon_workspace) -> dict[str, str]:
    """Return the environment after `source install/setup.bash`, the venv on PATH (as activated)."""
    env = sourced_ros_environment(ros2_exe, colcon_workspace)
    assert str(colcon_workspace / "install" / PACKAGE) in env.get("AMENT_PREFIX_PATH", ""), \
        "install/setup.bash did not set AMENT_PREFIX_PATH"
    return env


@pytest.fixture(scope="module")
def shipped_yaml(colcon_workspace) -> dict:
    """Return the installed config/star_tracker.yaml (what every README command loads)."""
    path = colcon_workspace / "install" / PACKAGE / "share" / PACKAGE / "config" / "star_tracker.yaml"
    return yaml.safe_load(path.read_text())


def flatten(tree: dict, prefix: str = "") -> dict[str, object]:
    """
    Return a nested ros__parameters dict as {dotted.name: value}.

    Its own copy of star_tracker.parameter_spec.dotted_names: this file tests the installed
    package from the outside and imports nothing of the source tree.
    """
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def yaml_parameters(shipped: dict, node: str) -> dict[str, object]:
    return flatten(shipped[f"/**/{node}"]["ros__parameters"])


def same_value(a, b) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)
    return a == b


class Ros2:
    """A user's shell on one ROS domain: `ros2` commands, long-running ones (Ctrl-C to stop)."""

    def __init__(self, env: dict[str, str], domain: int, log_dir: Path):
        self.env = dict(env, ROS_DOMAIN_ID=str(domain))
        self.domain = domain
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.described: dict[str, dict[str, dict[str, str]]] = {}  # describe(): node -> name -> fields

    def __call__(self, *args: str, timeout: float = CLI_TIMEOUT_S, check: bool = True,
                 rerun_hung: bool | None = None) -> str:
        """
        Run `ros2 *args`; return its stdout (with stderr); fail with both if it fails (or hangs) and `check`.

        A fresh `ros2` process discovers the node's services anew: on a loaded host its 5 s wait
        ran out once (`Wait for service timed out`, while the node's log showed it serving the
        calls before and after). That failure is retried, up to DISCOVERY_ATTEMPTS runs.

        A service response can be lost too: Fast DDS sends it after a bounded wait for the caller's
        response reader (ros2/rmw_fastrtps#390), and the CLI waits for it without a timeout. On a
        loaded host `ros2 lifecycle set` once hung 120 s that way. A run still going after
        HUNG_RUN_S is run again where `rerun_hung` (by default every command but `topic`, which
        waits for data, not a response, and `lifecycle set`, which is not idempotent: see
        lifecycle_set); the last run gets the whole `timeout`.
        """
        if rerun_hung is None:
            rerun_hung = args[0] != "topic" and args[:2] != ("lifecycle", "set")
        for attempt in range(1, DISCOVERY_ATTEMPTS + 1):
            last = attempt == DISCOVERY_ATTEMPTS or not rerun_hung
            try:
                done = subprocess.run(["ros2", *args], env=self.env, cwd=self.log_dir, stdin=subprocess.DEVNULL,
                                      capture_output=True, text=True,
                                      timeout=timeout if last else min(timeout, HUNG_RUN_S))
            except subprocess.TimeoutExpired as exc:
                if not last:
                    continue
                if not check:  # e.g. a service call to a node still starting: the caller retries
                    self.last_returncode = None
                    return f"<still running after {timeout} s>"
                pytest.fail(f"`ros2 {' '.join(args)}` still running after {timeout} s:\n{exc.stdout}\n{exc.stderr}"
                            f"\n{self.tails()}")
            if done.returncode == 0 or "Wait for service timed out" not in done.stdout + done.stderr:
                break
        if check and done.returncode != 0:
            pytest.fail(f"`ros2 {' '.join(args)}` exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
                        f"\n{self.tails()}")
        self.last_returncode = done.returncode
        return done.stdout + done.stderr

    def until(self, args: tuple[str, ...], ok, what: str, deadline: float | None = None) -> str:
        """Repeat `ros2 *args` until ok(output) (or time.monotonic() passes `deadline`); return the output."""
        deadline = deadline or time.monotonic() + START_TIMEOUT_S
        while True:
            self.check_alive()
            out = self(*args, check=False, timeout=min(CLI_TIMEOUT_S, max(1.0, deadline - time.monotonic())))
            if ok(out):
                return out
            if time.monotonic() > deadline:
                pytest.fail(f"{what}: not by the deadline; last `ros2 {' '.join(args)}`:\n{out}\n{self.tails()}")
            time.sleep(1.0)

    def start(self, name: str, command: str) -> subprocess.Popen:
        """Start a shell command line (a README line as written) in its own process group."""
        log_path = self.log_dir / f"{name}.log"
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(["bash", "-c", command], env=self.env, cwd=self.log_dir,
                                    stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, preexec_fn=_default_signals)
        self.procs[name], self.logs[name] = proc, log_path
        return proc

    def check_alive(self) -> None:
        for name, proc in self.procs.items():
            if proc.poll() is not None and not getattr(proc, "stopped", False):
                pytest.fail(f"`{name}` exited with {proc.returncode}:\n{self.tail(name)}")

    def ctrl_c(self, name: str, timeout: float = STOP_TIMEOUT_S) -> int | None:
        """Send SIGINT to the process group (a terminal's Ctrl-C); return the exit code (None: hung)."""
        proc = self.procs[name]
        proc.stopped = True
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def kill_all(self) -> None:
        for proc in self.procs.values():
            proc.stopped = True
            if proc.poll() is None:
                for sig in (signal.SIGINT, signal.SIGKILL):
                    try:
                        os.killpg(proc.pid, sig)
                        proc.wait(timeout=30)
                        break
                    except (ProcessLookupError, subprocess.TimeoutExpired):
                        continue
        # The ros2 daemon a `ros2 node/topic/param ...` started stays running: stop it.
        subprocess.run(["ros2", "daemon", "stop"], env=self.env, cwd=self.log_dir, capture_output=True, timeout=60)

    def tail(self, name: str, chars: int = 5000) -> str:
        text = self.logs[name].read_text(errors="replace") if name in self.logs else ""
        return f"--- {name} ---\n{text[-chars:]}"

    def tails(self) -> str:
        return "\n".join(self.tail(name, 3000) for name in self.procs)

    # --- waiting for what a user would look at ---
    def wait_nodes(self, names: list[str]) -> None:
        """Wait until `ros2 node list` shows the nodes and each answers `ros2 param get`."""
        deadline = time.monotonic() + START_TIMEOUT_S
        self.until(("node", "list"), lambda out: set(names) <= set(out.split()), f"nodes {names} in ros2 node list",
                   deadline)
        for name in names:
            self.until(("param", "get", name, "use_sim_time"), lambda out: "Boolean value is" in out,
                       f"{name} answering ros2 param get", deadline)

    def has_lifecycle(self, node: str) -> bool:
        return f"{node}/get_state" in self("service", "list").split()

    def wait_active(self, names: list[str]) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        for name in names:
            self.until(("lifecycle", "get", name), lambda out: out.strip().startswith("active"), f"{name} active",
                       deadline)

    def one_message(self, topic: str, msg_type: str, timeout: float = START_TIMEOUT_S) -> str:
        """Return one message (`ros2 topic echo --once`) published on `topic` from now on."""
        return self("topic", "echo", "--once", topic, msg_type, timeout=timeout)

    def diagnostics_of(self, node: str) -> dict[str, str]:
        """Return the key/values of the node's next /diagnostics status (star_tracker<node>)."""
        name = f"star_tracker{node}"
        out = self("topic", "echo", "--once", "--filter", f"any(s.name == {name!r} for s in m.status)",
                   "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        message = yaml.safe_load(out.split("\n---")[0])
        (status,) = [s for s in message["status"] if s["name"] == name]
        return {item["key"]: item["value"] for item in status["values"]}

    def hz(self, topic: str, window: int = HZ_WINDOW, timeout: float = START_TIMEOUT_S) -> float:
        """Run `ros2 topic hz` until its window holds `window` messages; return its average rate [Hz]."""
        proc = subprocess.Popen(["ros2", "topic", "hz", topic, "--window", str(window)], env=self.env,
                                cwd=self.log_dir, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True,
                                preexec_fn=_default_signals)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
        reader.start()
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                text = "".join(lines)
                found = re.findall(r"average rate: ([0-9.]+)\n.*window: (\d+)", text)
                full = [float(rate) for rate, seen in found if int(seen) >= window]
                if full:
                    return full[-1]
                self.check_alive()
                time.sleep(0.5)
            pytest.fail(f"ros2 topic hz {topic}: fewer than {window} messages in {timeout} s:\n"
                        f"{''.join(lines)[-3000:]}\n{self.tails()}")
        finally:
            try:
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait(timeout=30)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(proc.pid, signal.SIGKILL)


def describe(ros2: Ros2, node: str, names: list[str]) -> dict[str, dict[str, str]]:
    """
    Return `ros2 param describe` of the names as {name: {field: text}} (Constraints flattened).

    Descriptors never change while a node runs: names described once on this shell are not asked again.
    """
    known = ros2.described.setdefault(node, {})
    if all(name in known for name in names):
        return {name: known[name] for name in names}
    out = ros2("param", "describe", node, *names)
    described = {}
    for block in out.split("Parameter name: ")[1:]:
        lines = block.splitlines()
        fields = {}
        for line in lines[1:]:
            if ":" in line:
                key, _, value = line.strip().partition(":")
                fields[key.strip()] = value.strip()
        described[lines[0].strip()] = fields
    known.update(described)
    return described


def dump(ros2: Ros2, node: str) -> dict[str, object]:
    """Return `ros2 param dump` of the node as {dotted.name: value}."""
    tree = yaml.safe_load(ros2("param", "dump", node))
    return flatten(tree[node]["ros__parameters"])


def mismatches(dumped: dict[str, object], expected: dict[str, object]) -> dict[str, tuple]:
    return {k: (dumped.get(k, "<missing>"), v) for k, v in expected.items()
            if k not in dumped or not same_value(dumped[k], v)}


def stop_all_cleanly(ros2: Ros2) -> None:
    """Ctrl-C each started command; each must exit 0 without a traceback."""
    problems = []
    for name in list(ros2.procs):
        code = ros2.ctrl_c(name)
        text = ros2.logs[name].read_text(errors="replace")
        if code != 0 or "Traceback" in text:
            problems.append(f"`{name}` exit {code} after Ctrl-C:\n{ros2.tail(name)}")
    assert not problems, "\n".join(problems)


# --- `ros2 pkg` ---------------------------------------------------------------------------------

def test_ros2_pkg_finds_the_colcon_built_package(user_env, colcon_workspace, tmp_path):
    ros2 = Ros2(user_env, DOMAIN_RUN, tmp_path)
    prefix = ros2("pkg", "prefix", PACKAGE).strip()
    assert Path(prefix) == colcon_workspace / "install" / PACKAGE
    executables = ros2("pkg", "executables", PACKAGE).split()
    assert set(NODES) <= set(executables[1::2]), executables
    assert shutil.which("ros2", path=user_env["PATH"]) == str(Path(sys.executable).with_name("ros2"))


# --- the README's three `ros2 run` lines: one pipeline, every node's parameters and lifecycle ----

@pytest.fixture(scope="module")
def run_nodes(user_env, tmp_path_factory):
    """Start the README's `ros2 run` lines as written (one terminal each); wait until they are up."""
    ros2 = Ros2(user_env, DOMAIN_RUN, tmp_path_factory.mktemp("ros2_run"))
    try:
        for command in readme_commands("run"):
            ros2.start(command.split()[3], command)
        ros2.wait_nodes([f"/{n}" for n in NODES])
        ros2.lifecycle = ros2.has_lifecycle("/identifier")
        if ros2.lifecycle:
            ros2.wait_active([f"/{n}" for n in NODES])
        yield ros2
    finally:
        ros2.kill_all()


def require_lifecycle(ros2: Ros2) -> None:
    """Fail (never skip: issue 18 made every node managed) when the nodes offer no lifecycle services."""
    if not ros2.lifecycle:
        pytest.fail("the nodes have no lifecycle services (/identifier/get_state): no `ros2 lifecycle` to drive")


def test_ros2_run_nodes_form_the_pipeline(run_nodes):
    """The three README `ros2 run` lines: attitudes on /attitude, every README topic present."""
    out = run_nodes.one_message("/attitude", "geometry_msgs/msg/QuaternionStamped")
    attitude = yaml.safe_load(out.split("\n---")[0])
    assert attitude["header"]["frame_id"] == "icrs"
    q = attitude["quaternion"]
    assert math.isclose(math.hypot(q["x"], q["y"], q["z"], q["w"]), 1.0, abs_tol=1e-6) and q["w"] >= 0.0, q
    topics = set(run_nodes("topic", "list").split())
    for topic in ("/image_raw", "/camera_info", "/spots", "/attitude", "/attitude_with_covariance",
                  "/matched_stars", "/angular_velocity", "/diagnostics"):
        assert topic in topics, f"{topic} not in ros2 topic list: {sorted(topics)}"


def test_readme_param_describe_command(run_nodes):
    for command in readme_commands("describe"):
        name = command.split()[4]
        out = run_nodes(*shlex.split(command)[1:])
        assert f"Parameter name: {name}" in out and "Type: " in out, out
        assert re.search(r"Description: \S", out), out


@pytest.mark.parametrize("node", NODES)
def test_ros2_param_describe_every_parameter(run_nodes, node, shipped_yaml):
    """`ros2 param list/describe`: every parameter is typed and described; ranges and read-only shown."""
    names = run_nodes("param", "list", f"/{node}").split()
    assert set(yaml_parameters(shipped_yaml, node)) <= set(names), "YAML parameters missing from ros2 param list"
    described = describe(run_nodes, f"/{node}", names)
    assert set(described) == set(names)
    ours = {n: d for n, d in described.items() if n not in RCLPY_OWN_PARAMETERS and not n.startswith("qos_overrides.")}
    undescribed = [n for n, d in ours.items() if not d.get("Description")]
    assert not undescribed, f"{node}: parameters without a description: {undescribed}"
    untyped = [n for n, d in ours.items() if d.get("Type") in (None, "", "not set")]
    assert not untyped, f"{node}: parameters without a type: {untyped}"
    assert any(d.get("Read only") == "true" for d in ours.values()), f"{node}: no parameter shown read-only"
    ranged = [n for n, d in ours.items() if "Min value" in d and "Max value" in d]
    assert ranged, f"{node}: no parameter shows its range in ros2 param describe"


@pytest.mark.parametrize("node", NODES)
def test_ros2_param_get_and_dump_equal_the_shipped_yaml(run_nodes, node, shipped_yaml):
    expected = yaml_parameters(shipped_yaml, node)
    assert not mismatches(dump(run_nodes, f"/{node}"), expected), "ros2 param dump differs from the YAML"
    name = next(n for n, v in expected.items() if isinstance(v, float))
    out = run_nodes("param", "get", f"/{node}", name)
    assert out.startswith("Double value is: ") and same_value(float(out.split(":")[1]), expected[name]), out


@pytest.mark.parametrize("node", NODES)
def test_ros2_param_set_of_a_read_only_parameter_is_refused(run_nodes, node, shipped_yaml):
    expected = yaml_parameters(shipped_yaml, node)
    described = describe(run_nodes, f"/{node}", list(expected))
    name = next(n for n, v in expected.items() if described[n].get("Read only") == "true"
                and isinstance(v, (int, float, str)) and not isinstance(v, bool))
    before = run_nodes("param", "get", f"/{node}", name)
    value = before.split(":", 1)[1].strip()
    out = run_nodes("param", "set", f"/{node}", name, value)
    assert "Setting parameter failed" in out and "read-only" in out, out
    assert run_nodes("param", "get", f"/{node}", name) == before


@pytest.mark.parametrize("node", NODES)
def test_ros2_param_set_of_a_runtime_parameter(run_nodes, node):
    """Issue 18 part 2: a runtime parameter is set, an invalid value refused with the reason, unchanged."""
    name, new, invalid = RUNTIME_PARAMETER[node]
    if describe(run_nodes, f"/{node}", [name])[name].get("Read only") == "true":
        pytest.fail(f"{node} {name} is read-only; it must be settable at runtime")
    before = run_nodes("param", "get", f"/{node}", name)
    try:
        out = run_nodes("param", "set", f"/{node}", name, repr(new))
        assert "Set parameter successful" in out, out
        assert same_value(float(run_nodes("param", "get", f"/{node}", name).split(":")[1]), new)
        out = run_nodes("param", "set", f"/{node}", name, repr(invalid))
        assert "Setting parameter failed" in out and len(out.split("failed", 1)[1].strip(" :\n")) > 0, out
        assert same_value(float(run_nodes("param", "get", f"/{node}", name).split(":")[1]), new)
    finally:
        run_nodes("param", "set", f"/{node}", name, before.split(":", 1)[1].strip(), check=False)


def test_ros2_lifecycle_get_every_node(run_nodes):
    require_lifecycle(run_nodes)
    listed = run_nodes("lifecycle", "nodes").split()
    assert {f"/{n}" for n in NODES} <= set(listed), listed
    for node in NODES:
        assert run_nodes("lifecycle", "get", f"/{node}").strip() == "active [3]"
    for command in readme_commands("lifecycle_get"):  # e.g. `ros2 lifecycle get /identifier  # active`
        assert run_nodes(*shlex.split(command)[1:]).strip() == "active [3]", command


LIFECYCLE_GOAL = {"configure": "inactive", "activate": "active", "deactivate": "inactive", "cleanup": "unconfigured"}


def lifecycle_set(ros2: Ros2, node: str, transition: str, state: str) -> None:
    """
    `ros2 lifecycle set node transition`, then the node must be in `state`.

    A run that hangs lost a service response (see Ros2.__call__), or its transition (a database
    load) outlasts HUNG_RUN_S. Once the node rests in a primary state: if that is `state`, only the
    response was lost; if not, the transition never started and is requested again.
    """
    for _ in range(DISCOVERY_ATTEMPTS):
        out = ros2("lifecycle", "set", node, transition, check=False, timeout=HUNG_RUN_S)
        if ros2.last_returncode is not None:
            break
        resting = ros2.until(("lifecycle", "get", node), lambda got: got.split(" [")[0].strip() in PRIMARY_STATES,
                             f"{node} in a primary state after a hung `lifecycle set {transition}`",
                             time.monotonic() + CLI_TIMEOUT_S)
        if resting.strip().startswith(state + " ["):
            return
    assert ros2.last_returncode == 0 and "Transitioning successful" in out, out
    assert in_state(ros2, node, state), f"{node} not {state} after {transition}"


def in_state(ros2: Ros2, node: str, state: str) -> bool:
    return ros2("lifecycle", "get", node).strip().startswith(state + " [")


def bring_active(ros2: Ros2, node: str) -> None:
    """Take a managed node from whatever primary state a failed test left it in back to active."""
    state = ros2("lifecycle", "get", node).strip().split(" [")[0]
    steps = {"unconfigured": [("configure", "inactive"), ("activate", "active")],
             "inactive": [("activate", "active")]}.get(state, [])
    for transition, reached in steps:
        lifecycle_set(ros2, node, transition, reached)


def test_ros2_lifecycle_round_trip_keeps_the_identifier_database(run_nodes):
    """Deactivate, a refused transition, cleanup, configure, activate, deactivate, activate: attitudes again."""
    require_lifecycle(run_nodes)
    node = "/identifier"
    try:
        lifecycle_set(run_nodes, node, "deactivate", "inactive")
        # Refused before any change: a hung run (a lost response) is safe to run again.
        out = run_nodes("lifecycle", "set", node, "deactivate", check=False, rerun_hung=True)
        assert run_nodes.last_returncode != 0 and "Unknown transition requested" in out, out
        assert run_nodes("lifecycle", "get", node).strip() == "inactive [2]"
        lifecycle_set(run_nodes, node, "cleanup", "unconfigured")
        lifecycle_set(run_nodes, node, "configure", "inactive")
        loads = int(run_nodes.diagnostics_of(node)["database_loads"])
        lifecycle_set(run_nodes, node, "activate", "active")
        run_nodes.one_message("/attitude", "geometry_msgs/msg/QuaternionStamped")
        lifecycle_set(run_nodes, node, "deactivate", "inactive")
        lifecycle_set(run_nodes, node, "activate", "active")
        run_nodes.one_message("/attitude", "geometry_msgs/msg/QuaternionStamped")
        values = run_nodes.diagnostics_of(node)
        assert values["lifecycle_state"] == "active" and int(values["database_loads"]) == loads, values
    finally:
        bring_active(run_nodes, node)  # the module's later tests need attitudes, whatever failed here


def test_ros2_service_call_identifier_reset(run_nodes):
    require_lifecycle(run_nodes)
    if "/identifier/reset" not in run_nodes("service", "list").split():
        pytest.fail("no /identifier/reset service")
    command = (readme_commands("service") or ["ros2 service call /identifier/reset std_srvs/srv/Trigger"])[0]
    out = run_nodes(*shlex.split(command)[1:])
    assert "success=True" in out, out
    run_nodes.one_message("/attitude", "geometry_msgs/msg/QuaternionStamped")  # identified again
    assert int(run_nodes.diagnostics_of("/identifier").get("resets", "0")) >= 1


def test_ros2_run_nodes_stop_on_ctrl_c(run_nodes):
    stop_all_cleanly(run_nodes)


# --- the README's remap, gyro and lifecycle examples (started without --params-file) -------------

@pytest.fixture(scope="module")
def readme_examples(user_env, tmp_path_factory):
    """Start the README's remap lines (one domain), gyro line and lifecycle walk-through (one each)."""
    log_dir = tmp_path_factory.mktemp("ros2_examples")
    shells = {kind: Ros2(user_env, domain, log_dir)
              for kind, domain in (("remap", DOMAIN_REMAP), ("gyro", DOMAIN_GYRO), ("autostart", DOMAIN_AUTOSTART))}
    try:
        for kind, ros2 in shells.items():
            for command in readme_commands(kind):
                ros2.start(f"{kind}_{command.split()[3]}", command)
        for kind, ros2 in shells.items():
            ros2.wait_nodes([f"/{c.split()[3]}" for c in readme_commands(kind)])
        yield shells
    finally:
        for ros2 in shells.values():
            ros2.kill_all()


def topics_of(ros2: Ros2, node: str) -> list[str]:
    """Return the topics `ros2 node info` lists under the node's Subscribers and Publishers."""
    out = ros2("node", "info", node)
    section = out.split("Subscribers:", 1)[1].split("Service Servers:", 1)[0]
    return [line.split(":")[0].strip() for line in section.splitlines() if line.strip().startswith("/")]


def test_readme_remaps_and_parameters_take_effect(readme_examples):
    """Each README remap/gyro line: its nodes use the remapped topics and the -p values."""
    checked = 0
    for kind in ("remap", "gyro"):
        ros2 = readme_examples[kind]
        for command in readme_commands(kind):
            node = f"/{command.split()[3]}"
            topics = topics_of(ros2, node)
            for _, to in ros_args(command, "-r"):
                assert to in topics, f"{command}: {to} not among {node}'s topics {topics}"
                checked += 1
            if ros_args(command, "-p"):
                dumped = dump(ros2, node)
                for name, value in ros_args(command, "-p"):
                    assert same_value(dumped.get(name), yaml.safe_load(value)), (command, name, dumped.get(name))
    assert checked >= 3, "the README's remap examples went missing"


def test_readme_lifecycle_walk_through(readme_examples):
    """The README's `-p autostart:=false` identifier driven by its `ros2 lifecycle set` lines, as written."""
    if not readme_commands("autostart"):
        pytest.fail("the README has no lifecycle walk-through")
    ros2 = readme_examples["autostart"]
    (node,) = {f"/{c.split()[3]}" for c in readme_commands("autostart")}
    assert ros2("lifecycle", "get", node).strip() == "unconfigured [1]"
    assert "value is" in ros2("param", "get", node, "autostart")  # parameters visible while unconfigured
    for command in readme_commands("lifecycle_set"):
        words = shlex.split(command)
        assert words[:3] == ["ros2", "lifecycle", "set"] and len(words) == 5, command
        lifecycle_set(ros2, words[3], words[4], LIFECYCLE_GOAL[words[4]])
    values = ros2.diagnostics_of(node)
    assert int(values.get("database_loads", "0")) == 1, values  # activate again did not reload it


def test_nodes_started_without_a_params_file_equal_the_yaml(readme_examples, shipped_yaml):
    """Issue 18 part 1: `ros2 run` without --params-file gives every parameter the YAML's value."""
    ros2 = readme_examples["remap"]
    differ = {}
    for command in readme_commands("remap"):
        node = command.split()[3]
        given = dict(ros_args(command, "-p"))
        expected = {k: v for k, v in yaml_parameters(shipped_yaml, node).items() if k not in given}
        differ[node] = mismatches(dump(ros2, f"/{node}"), expected)
    differ = {node: d for node, d in differ.items() if d}
    assert not differ, f"built-in defaults (dump) vs the shipped YAML: {differ}"


def test_readme_example_nodes_stop_on_ctrl_c(readme_examples):
    for ros2 in readme_examples.values():
        stop_all_cleanly(ros2)


# --- ros2 launch, plain and namespace:=st1 params_file:=my.yaml ---------------------------------

@pytest.fixture(scope="module", params=["", "st1"], ids=["launch", "launch_namespace_st1"])
def launched(request, user_env, shipped_yaml, tmp_path_factory):
    """Run the README's launch line (the second with my.yaml); wait for the first attitude."""
    namespace = request.param
    log_dir = tmp_path_factory.mktemp(f"ros2_launch_{namespace or 'plain'}")
    ros2 = Ros2(user_env, DOMAIN_LAUNCH[namespace], log_dir)
    plain, with_namespace = readme_commands("launch")
    command, rate_hz = plain, shipped_yaml["/**/camera_simulator"]["ros__parameters"]["rate_hz"]
    if namespace:
        mine = copy.deepcopy(shipped_yaml)
        mine["/**/camera_simulator"]["ros__parameters"]["rate_hz"] = rate_hz = MY_YAML_CAMERA_RATE_HZ
        (log_dir / "my.yaml").write_text(yaml.safe_dump(mine, sort_keys=False))
        command = with_namespace.replace("/path/to/my.yaml", str(log_dir / "my.yaml"))
        assert f"namespace:={namespace}" in command
    ros2.namespace, ros2.rate_hz, ros2.command = (f"/{namespace}" if namespace else ""), rate_hz, command
    try:
        started = time.monotonic()
        ros2.start("launch", command)
        ros2.one_message(f"{ros2.namespace}/attitude", "geometry_msgs/msg/QuaternionStamped")
        # Informative only (issue 18's goal: <= 15 s on a warm install); never asserted.
        print(f"{command}: first attitude {time.monotonic() - started:.1f} s after the launch")
        yield ros2
    finally:
        ros2.kill_all()


def test_ros2_launch_attitudes_at_the_camera_rate(launched):
    """
    `ros2 topic hz` fills its window; with the 2 Hz camera the rate is within a wide band of it.

    The plain launch runs the shipped 10 Hz camera, which a loaded 2-core host may not keep up
    with (frames dropped, counted): there it is judged by the messages seen alone.
    """
    rate = launched.hz(f"{launched.namespace}/attitude")
    print(f"{launched.command}: ros2 topic hz {launched.namespace}/attitude: {rate:.2f} Hz "
          f"(camera {launched.rate_hz} Hz)")
    assert rate > 0.0
    if launched.namespace:
        assert 0.5 * launched.rate_hz <= rate <= 1.5 * launched.rate_hz, (rate, launched.rate_hz)


def test_ros2_launch_names_nodes_and_topics_in_its_namespace(launched):
    ns = launched.namespace
    nodes = launched("node", "list").split()
    assert {f"{ns}/{n}" for n in NODES} <= set(nodes), nodes
    topics = launched("topic", "list").split()
    assert f"{ns}/attitude" in topics and f"{ns}/image_raw" in topics and "/diagnostics" in topics, topics
    out = launched("param", "get", f"{ns}/camera_simulator", "rate_hz")
    assert same_value(float(out.split(":")[1]), launched.rate_hz), out  # params_file applied in the namespace


def test_ros2_launch_lifecycle_and_reset(launched):
    ns = launched.namespace
    if not launched.has_lifecycle(f"{ns}/identifier"):
        pytest.fail(f"{ns}/identifier has no lifecycle services")
    for node in NODES:
        assert launched("lifecycle", "get", f"{ns}/{node}").strip() == "active [3]"
    out = launched("service", "call", f"{ns}/identifier/reset", "std_srvs/srv/Trigger")
    assert "success=True" in out, out


def test_ros2_launch_stops_on_ctrl_c(launched):
    code = launched.ctrl_c("launch")
    text = launched.logs["launch"].read_text(errors="replace")
    assert code == 0, f"ros2 launch exit {code} after Ctrl-C:\n{launched.tail('launch')}"
    assert text.count("process has finished cleanly") == len(NODES), launched.tail("launch")
    assert "Traceback" not in text, launched.tail("launch")
