# SPDX-License-Identifier: Apache-2.0
"""
Each node started without a params file (a real process over DDS, isolated domain).

Read from outside with a parameter client: every parameter equals config/star_tracker.yaml's
value, `describe` gives the spec's range and read-only flag, a runtime change is applied and
reported, and an invalid combination is refused with the reason and nothing of it applied. No
ROS mocks.
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.slow  # every test here starts a node process

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.srv import ListParameters  # noqa: E402
from rclpy.parameter import Parameter, parameter_value_to_python  # noqa: E402
from service_calls import answered, primed_parameter_client  # noqa: E402

from star_tracker.parameter_spec import dotted_names  # noqa: E402
from star_tracker.ros.pipeline import NodeProcesses, isolated_ros_environment  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DOMAINS = {"camera_simulator": 201, "centroider": 202, "identifier": 203}  # this file's ROS_DOMAIN_IDs
IGNORED = ("use_sim_time", "start_type_description_service", "qos_overrides.")  # rclpy's own


def shipped_values(node: str) -> dict:
    shipped = yaml.safe_load((REPO / "config" / "star_tracker.yaml").read_text())
    return dotted_names(shipped[f"/**/{node}"]["ros__parameters"])


class Probe:
    """This test's own node: a parameter client on the node under test, and its /diagnostics."""

    def __init__(self, target: str):
        self.node = rclpy.create_node(f"{target}_parameter_probe")
        self.target = target
        self.client = primed_parameter_client(self.node, target, timeout_s=30.0)  # no answer lost
        self.diagnostics: dict[str, str] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("/" + self.target):
                self.diagnostics = {kv.key: kv.value for kv in status.values}

    def wait(self, future, timeout_s: float = 20.0):
        end = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.05)
        assert future.done(), f"no answer from {self.target} within {timeout_s} s"
        return future.result()

    def spin_until(self, condition, timeout_s: float = 20.0) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.05)
            if condition():
                return True
        return condition()

    def read(self, send):
        """Answer to a request that changes nothing (sent again if its answer is lost)."""
        return answered(self.node, send)

    def all_values(self) -> dict:
        names = self.read(lambda: self.client.list_parameters([], ListParameters.Request.DEPTH_RECURSIVE)).result.names
        names = [n for n in names if not n.startswith(IGNORED)]
        values = self.read(lambda: self.client.get_parameters(names)).values
        return {name: parameter_value_to_python(value) for name, value in zip(names, values)}

    def get(self, *names: str) -> list:
        return [parameter_value_to_python(v) for v in self.read(lambda: self.client.get_parameters(list(names))).values]

    def describe(self, name: str):
        return self.read(lambda: self.client.describe_parameters([name])).descriptors[0]

    def set(self, **values) -> list:
        """set_parameters_atomically (all or none): [(successful, reason)]."""
        params = [Parameter(k.replace("__", "."), value=v) for k, v in values.items()]
        result = self.wait(self.client.set_parameters_atomically(params)).result
        return result.successful, result.reason


@pytest.fixture
def started(request, monkeypatch, tmp_path):
    """Start the node `request.param` without a params file; yields (probe, processes)."""
    node = request.param
    env = isolated_ros_environment(DOMAINS[node])
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
        monkeypatch.setenv(key, env[key])
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    rclpy.init(args=[])
    processes = NodeProcesses(env, tmp_path / "logs", nodes=(node,))
    probe = None
    try:
        processes.start()
        processes.wait_ready(timeout_s=300)
        probe = Probe(node)
        yield probe, processes
    finally:
        if probe is not None:
            probe.node.destroy_node()
        codes = processes.stop()
        rclpy.try_shutdown()
    assert all(code == 0 for code in codes.values()), codes


def check_defaults(probe: Probe) -> None:
    values, shipped = probe.all_values(), shipped_values(probe.target)
    assert set(values) == set(shipped), (sorted(set(values) - set(shipped)), sorted(set(shipped) - set(values)))
    differ = {name: (values[name], shipped[name]) for name in shipped
              if values[name] != shipped[name] or type(values[name]) is not type(shipped[name])}
    assert not differ, f"node default != YAML: {differ}"


def check_range(descriptor, low, high, read_only: bool) -> None:
    ranges = list(descriptor.floating_point_range) or list(descriptor.integer_range)
    assert (ranges[0].from_value, ranges[0].to_value) == (low, high)
    assert descriptor.read_only is read_only
    assert "[" in descriptor.description  # the unit


def check_reported(probe: Probe, applied_before: int, text: str) -> None:
    assert probe.spin_until(lambda: int(probe.diagnostics.get("parameter_changes_applied", 0)) > applied_before
                            and text in probe.diagnostics.get("last_parameter_change", "")), probe.diagnostics


@pytest.mark.parametrize("started", ["centroider"], indirect=True)
def test_centroider_parameters(started):
    probe, _ = started
    check_defaults(probe)
    check_range(probe.describe("detection_sigma"), 1.0, 100.0, read_only=False)
    assert probe.describe("queue_depth").read_only
    probe.spin_until(lambda: probe.diagnostics, 5.0)
    applied = int(probe.diagnostics.get("parameter_changes_applied", 0))
    assert probe.set(detection_sigma=6.0, exposure_time_s=0.05) == (True, "")
    assert probe.get("detection_sigma", "exposure_time_s") == [6.0, 0.05]
    check_reported(probe, applied, "detection_sigma=6.0")
    ok, reason = probe.set(detection_sigma=7.0, min_area=50, max_area=10)  # each in range, together invalid
    assert not ok and "min_area (50) <= max_area (10)" in reason
    assert probe.get("detection_sigma", "min_area", "max_area") == [6.0, 2, 20000]
    ok, reason = probe.set(queue_depth=2)
    assert not ok and "read-only" in reason
    assert probe.spin_until(lambda: int(probe.diagnostics.get("parameter_changes_rejected", 0)) >= 1)


@pytest.mark.parametrize("started", ["identifier"], indirect=True)
def test_identifier_parameters(started):
    probe, _ = started
    check_defaults(probe)
    check_range(probe.describe("database.magnitude_limit"), -2.0, 12.0, read_only=True)
    check_range(probe.describe("max_time_s"), 1e-3, 60.0, read_only=False)
    assert probe.describe("algorithm").additional_constraints.startswith("one of: angle_pivot, composite, hybrid")
    assert probe.describe("angle_tolerance_floor_rad").additional_constraints == "in [0, 0.01)"  # open end
    probe.spin_until(lambda: probe.diagnostics, 5.0)
    applied = int(probe.diagnostics.get("parameter_changes_applied", 0))
    assert probe.set(max_time_s=0.25, sigma_multiplier=3.5, match_radius_px=2.0) == (True, "")
    assert probe.get("max_time_s", "sigma_multiplier", "match_radius_px") == [0.25, 3.5, 2.0]
    check_reported(probe, applied, "max_time_s=0.25")
    # angle_tolerance_floor_rad's range is [0, 0.01) (the descriptor can only say [0, 0.01]).
    ok, reason = probe.set(max_time_s=0.3, angle_tolerance_floor_rad=0.01)
    assert not ok and "angle_tolerance_floor_rad=0.01 must be in [0, 0.01)" in reason
    assert probe.get("max_time_s", "angle_tolerance_floor_rad") == [0.25, 2e-5]
    ok, reason = probe.set(**{"database__magnitude_limit": 6.0})
    assert not ok and "read-only" in reason


@pytest.mark.parametrize("started", ["camera_simulator"], indirect=True)
def test_camera_simulator_parameters(started):
    probe, _ = started
    check_defaults(probe)
    check_range(probe.describe("sensor.exposure_s"), 1e-6, 10.0, read_only=False)
    check_range(probe.describe("image.width"), 16, 8192, read_only=True)
    assert probe.spin_until(lambda: int(probe.diagnostics.get("frames_published", 0)) > 0, 30.0)
    applied = int(probe.diagnostics.get("parameter_changes_applied", 0))
    assert probe.set(sensor__exposure_s=0.05, sensor__gain_e_per_adu=2.0, sensor__read_noise_e=5.0) == (True, "")
    assert probe.get("sensor.exposure_s", "sensor.gain_e_per_adu") == [0.05, 2.0]
    check_reported(probe, applied, "sensor.exposure_s=0.05")
    published = int(probe.diagnostics.get("frames_published", 0))
    assert probe.spin_until(lambda: int(probe.diagnostics.get("frames_published", 0)) > published + 2)  # renders on
    # 0.2 s is inside the range, but longer than the 10 Hz frame period: refused, the gain too.
    ok, reason = probe.set(sensor__exposure_s=0.2, sensor__gain_e_per_adu=3.0)
    assert not ok and "longer than the frame period" in reason
    assert probe.get("sensor.exposure_s", "sensor.gain_e_per_adu") == [0.05, 2.0]
    ok, reason = probe.set(image__width=512)
    assert not ok and "read-only" in reason
