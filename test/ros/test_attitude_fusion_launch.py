# SPDX-License-Identifier: Apache-2.0
"""
launch/multi_head.launch.py: its mountings and head attitudes, and the real `ros2 launch` of the colcon-built package.

The launch tests need the upstream `ros2` CLI, launch and launch_ros (`make ros2cli` installs
them from the workplace's `../shared/ros2cli`, as for test/package/test_ros2_cli.py): where
they are absent every test here is skipped with the reason. `ros2 launch` runs what a user
runs after `colcon build` and `source install/setup.bash` (test/conftest.py
`colcon_workspace`), on a private localhost-only domain, and is stopped with Ctrl-C (SIGINT to
its process group). Judged by the fused attitude against the launched body attitude and by
the processes' exits, never by host speed.
"""
from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import sourced_ros_environment

REPO = Path(__file__).resolve().parents[2]
ROS2CLI = REPO.parent / "shared" / "ros2cli"
LAUNCH_FILE = REPO / "launch" / "multi_head.launch.py"
SHIPPED_YAML = REPO / "config" / "star_tracker.yaml"
CAMERA_RATE_HZ = 2.0  # seven processes on a 2-core host: a slow camera keeps every frame
FUSIONS = 5  # fused attitudes of both heads judged
START_TIMEOUT_S = 400.0  # cold kernels and a first database build under load
STOP_TIMEOUT_S = 60.0
BODY_DEG = (80.0, 20.0, 30.0)  # body_ra_deg, body_dec_deg, body_roll_deg given to the launch


def launch_module():
    """Return multi_head.launch.py as a module (it imports launch and launch_ros: skip without them)."""
    pytest.importorskip("launch_ros", reason="launch_ros is installed with the ros2 CLI (`make ros2cli`)")
    spec = importlib.util.spec_from_file_location("multi_head_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def boresight_in_body(quaternion) -> np.ndarray:
    from star_tracker.models.attitude import quaternion_to_matrix

    return quaternion_to_matrix(np.asarray(quaternion, dtype=float)) @ [0.0, 0.0, 1.0]


def test_launch_mountings_come_from_the_params_file_else_built_in_ones():
    launch = launch_module()
    shipped = yaml.safe_load(SHIPPED_YAML.read_text())
    two = launch.mountings_for(launch.head_names(2), shipped)
    assert two == {"head1": [0.0, 0.0, 0.0, 1.0], "head2": [0.5, 0.5, 0.5, 0.5]}  # the shipped YAML's
    three = launch.mountings_for(launch.head_names(3), shipped)
    for head, axis in (("head1", [0, 0, 1]), ("head2", [1, 0, 0]), ("head3", [0, 1, 0])):
        assert np.allclose(boresight_in_body(three[head]), axis), head
    mine = {"/**/attitude_fusion": {"ros__parameters": {"mounting": {"head2": [0.0, 0.0, 1.0, 0.0]},
                                                        "mounting.head4": [1.0, 0.0, 0.0, 0.0]}}}
    four = launch.mountings_for(launch.head_names(4), mine)
    assert four["head2"] == [0.0, 0.0, 1.0, 0.0] and four["head4"] == [1.0, 0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"no mounting for \['head4'\]"):
        launch.mountings_for(launch.head_names(4), shipped)
    with pytest.raises(ValueError, match="at least one head"):
        launch.head_names(0)


def test_each_launched_camera_sees_the_body_through_its_mounting():
    """A camera given the body attitude and head.mounting_quaternion renders R_body R(q): the body's mounted axis."""
    from star_tracker.models.attitude import radec_roll_to_matrix
    from star_tracker.ros.camera_simulator_orbit import ORBIT_PARAMETERS, orbit_setup_from
    from star_tracker.ros.camera_simulator_world import CameraWorld
    from star_tracker.sim.motion import ConstantRateMotion

    body = radec_roll_to_matrix(*np.radians(BODY_DEG))
    for mounting, body_axis in (([0.0, 0.0, 0.0, 1.0], [0, 0, 1]), ([0.5, 0.5, 0.5, 0.5], [1, 0, 0])):
        values = {spec.name: spec.default for spec in ORBIT_PARAMETERS}
        values["head.mounting_quaternion"] = mounting
        world = CameraWorld(orbit_setup_from(values), "fixed")
        world.configure(0.0)
        head = world.head_motion(ConstantRateMotion(body, np.zeros(3))).rotation_at(0.0)
        assert np.allclose(head[:, 2], body @ body_axis)


# --- the real `ros2 launch` -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def ros2_exe() -> Path:
    """Return the venv's `ros2`, or skip with the reason it is not there."""
    if not (ROS2CLI / "install.sh").is_file():
        pytest.skip(f"{ROS2CLI} is absent (a clone outside the workplace): the tests of the real ros2 CLI need it")
    exe = Path(sys.executable).with_name("ros2")
    if not exe.is_file():
        pytest.skip(f"no ros2 CLI in this venv ({exe}): run `make ros2cli` (make test does)")
    return exe


@pytest.fixture(scope="module")
def user_env(ros2_exe, colcon_workspace) -> dict[str, str]:
    """Return the environment after `source install/setup.bash`, the venv on PATH (conftest)."""
    return sourced_ros_environment(ros2_exe, colcon_workspace)


def _default_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a terminal's Ctrl-C must work in the launched shell
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


@pytest.mark.integration
@pytest.mark.slow  # a colcon build (shared per session) and seven node processes
@pytest.mark.timeout(1200)
def test_ros2_launch_multi_head_fuses_both_heads_and_stops_on_ctrl_c(user_env, tmp_path, monkeypatch):
    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import QuaternionStamped

    from conftest import join_isolated_ros_domain
    from star_tracker.models.attitude import (ARCSEC, matrix_to_rotation_vector, quaternion_to_matrix,
                                              radec_roll_to_matrix)
    from star_tracker.ros import convert
    from star_tracker.ros.pipeline import MONITOR_RESULT_QOS

    env = join_isolated_ros_domain(monkeypatch)
    params = yaml.safe_load(SHIPPED_YAML.read_text())
    params["/**/camera_simulator"]["ros__parameters"]["rate_hz"] = CAMERA_RATE_HZ
    my_yaml = tmp_path / "my.yaml"
    my_yaml.write_text(yaml.safe_dump(params, sort_keys=False))
    ra, dec, roll = BODY_DEG
    command = (f"ros2 launch star_tracker multi_head.launch.py params_file:={my_yaml} body_ra_deg:={ra} "
               f"body_dec_deg:={dec} body_roll_deg:={roll}")
    log_path = tmp_path / "launch.log"
    monitor = rclpy.create_node("multi_head_monitor")
    fused, statuses = {}, []
    monitor.create_subscription(QuaternionStamped, "attitude", lambda m: fused.__setitem__(
        convert.stamp_to_ns(m.header.stamp), quaternion_to_matrix(convert.quaternion_from_msg(m))), MONITOR_RESULT_QOS)
    monitor.create_subscription(DiagnosticArray, "fusion_status", lambda m: statuses.append(
        (convert.stamp_to_ns(m.header.stamp), {s.name: {kv.key: kv.value for kv in s.values} for s in m.status})),
        MONITOR_RESULT_QOS)
    with open(log_path, "wb") as log:
        launch = subprocess.Popen(["bash", "-c", command], env=dict(user_env, ROS_DOMAIN_ID=env["ROS_DOMAIN_ID"]),
                                  cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True, preexec_fn=_default_signals)
    code = None
    try:
        def both() -> list:
            return [(stamp, s) for stamp, s in statuses if s["fused"].get("heads_used") == "head1,head2"]
        end = time.monotonic() + START_TIMEOUT_S
        while len(both()) < FUSIONS and time.monotonic() < end and launch.poll() is None:
            rclpy.spin_once(monitor, timeout_sec=0.1)
        names = {f"{ns.rstrip('/')}/{name}" for name, ns in monitor.get_node_names_and_namespaces()}
    finally:
        if launch.poll() is None:
            os.killpg(launch.pid, signal.SIGINT)  # Ctrl-C
        try:
            code = launch.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
        monitor.destroy_node()
        rclpy.try_shutdown()
    text = log_path.read_text(errors="replace")
    judged = [(stamp, s) for stamp, s in both() if stamp in fused]
    assert len(judged) >= FUSIONS, f"{len(judged)} fusions of both heads; launch log:\n{text[-6000:]}"
    expected = {f"/head{i}/{n}" for i in (1, 2) for n in ("camera_simulator", "centroider", "identifier")}
    assert expected | {"/attitude_fusion"} <= names, names
    body = radec_roll_to_matrix(*np.radians(BODY_DEG))
    errors = np.array([matrix_to_rotation_vector(body.T @ fused[stamp]) for stamp, _ in judged]) / ARCSEC
    print(f"\n{command}: {len(judged)} fusions of both heads, max |error| per body axis "
          f"{np.round(np.abs(errors).max(axis=0), 2)}\"")
    assert np.all(np.abs(errors) < 5.0), errors
    assert code == 0, f"ros2 launch exit {code} after Ctrl-C:\n{text[-6000:]}"
    assert text.count("process has finished cleanly") == 7, text[-6000:]
    assert "Traceback" not in text, text[-6000:]
