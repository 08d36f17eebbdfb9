# SPDX-License-Identifier: Apache-2.0
"""
Start N simulated optical heads on one spacecraft body and the attitude fusion.

    ros2 launch star_tracker multi_head.launch.py                      # two heads, 90 deg apart
    ros2 launch star_tracker multi_head.launch.py heads:=3 params_file:=/path/to/my.yaml
    ros2 launch star_tracker multi_head.launch.py body_ra_deg:=120 body_dec_deg:=-30 body_roll_deg:=15
    ros2 launch star_tracker multi_head.launch.py scenario:=leo       # two heads in orbit (leo_scenario.py)

Head i (1..N) is a camera_simulator, centroider and identifier in namespace `head<i>` (below
`namespace`); attitude_fusion runs in `namespace` with `heads: [head1, ..., headN]`. Every node
loads `params_file` (default: the shipped config/star_tracker.yaml).

scenario:=rest (default): the body at rest at `body_ra_deg`, `body_dec_deg`, `body_roll_deg` (where
body +Z points, and the roll about it); mountings: `mounting.head<i>` of the params file's
`/**/attitude_fusion` section where it has one, else head1 along body +Z, head2 along body +X,
head3 along body +Y (HEAD_MOUNTINGS); more heads need theirs in the params file. Each camera
renders the body through its mounting (`head.mounting_quaternion`). A body rate is not offered:
each camera's motion would start at its own first exposure, and the heads would disagree; the
fusion is told the body is at rest (`body_rate_source`, default none).

scenario:=leo: the heads on a nadir-pointing spacecraft on a 550 km sun-synchronous orbit
(star_tracker/ros/leo_scenario.py: one orbit epoch for every head, the launch's time), each
identifier reading its camera's truth/odometry, the fusion the heads' rates; the mountings are
the scenario's.
"""
import os
import time

import numpy as np
import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from star_tracker.models.attitude import matrix_to_quaternion, radec_roll_to_matrix
from star_tracker.ros import leo_scenario
from star_tracker.ros.attitude_fusion_parameters import DEFAULT_MOUNTINGS

PACKAGE = "star_tracker"
HEAD_NODES = ("camera_simulator", "centroider", "identifier")
# Head frame orientation in the body frame (x, y, z, w): the node's defaults, and head3 along body +Y.
HEAD_MOUNTINGS = {**DEFAULT_MOUNTINGS, "head3": (-0.5, -0.5, -0.5, 0.5)}
FUSION_KEYS = ("/**/attitude_fusion", "attitude_fusion", "/attitude_fusion")  # params-file sections it reads


def head_names(count: int) -> list[str]:
    if count < 1:
        raise ValueError(f"heads:={count}: at least one head")
    return [f"head{i}" for i in range(1, count + 1)]


def file_mountings(params: dict) -> dict[str, list[float]]:
    """Return the `mounting.<head>` values of a params file's attitude_fusion section (nested or dotted keys)."""
    found = {}
    for key in FUSION_KEYS:
        section = (params.get(key) or {}).get("ros__parameters") or {}
        found.update(section.get("mounting") or {})
        found.update({name.split(".", 1)[1]: value for name, value in section.items()
                      if name.startswith("mounting.")})
    return found


def mountings_for(heads: list[str], params: dict) -> dict[str, list[float]]:
    """Return each head's mounting quaternion: the params file's, else HEAD_MOUNTINGS; ValueError for a head without."""
    given = {**HEAD_MOUNTINGS, **file_mountings(params)}
    missing = [head for head in heads if head not in given]
    if missing:
        raise ValueError(f"no mounting for {missing}: give mounting.<head> in params_file's /**/attitude_fusion "
                         "section")
    return {head: [float(v) for v in given[head]] for head in heads}


def make_nodes(context, *args, **kwargs):
    """Return the heads' nodes and the fusion node for the launch arguments (an OpaqueFunction)."""
    def value(name: str) -> str:
        return LaunchConfiguration(name).perform(context)

    params_file = value("params_file")
    with open(params_file) as stream:
        params = yaml.safe_load(stream) or {}
    leo = value("scenario") == "leo"
    heads = leo_scenario.head_names(int(value("heads"))) if leo else head_names(int(value("heads")))
    mountings = {h: list(leo_scenario.LEO_MOUNTINGS[h]) for h in heads} if leo else mountings_for(heads, params)
    body = radec_roll_to_matrix(*np.radians([float(value(f"body_{a}_deg")) for a in ("ra", "dec", "roll")]))
    namespace = value("namespace").strip("/")
    autostart = value("autostart").lower() == "true"
    epoch = leo_scenario.epoch_utc(time.time())
    nodes = []
    for index, head in enumerate(heads):
        if leo:
            camera = leo_scenario.camera_parameters(head, index, float(value("rate_hz")), epoch)
        else:
            camera = {"attitude.profile": "fixed",
                      "attitude.quaternion": [float(v) for v in matrix_to_quaternion(body)],
                      "head.mounting_quaternion": mountings[head], "frame_id": f"{head}_optical",
                      "seed": index, "fixed_pattern_seed": index}
        own = {"camera_simulator": camera, "centroider": leo_scenario.CENTROIDER if leo else {},
               "identifier": leo_scenario.IDENTIFIER if leo else {}}
        for name in HEAD_NODES:
            remaps = list(leo_scenario.REMAPS.get(name, {}).items()) if leo else []
            nodes.append(Node(package=PACKAGE, executable=name, name=name,
                              namespace=f"{namespace}/{head}" if namespace else head, remappings=remaps,
                              parameters=[params_file, {**own.get(name, {}), "autostart": autostart}],
                              output="screen", emulate_tty=True))
    fusion = {"heads": heads, **{f"mounting.{head}": q for head, q in mountings.items()},
              "body_rate.source": value("body_rate_source"), "autostart": autostart}
    if leo:
        fusion = {**leo_scenario.fusion_parameters(heads), "autostart": autostart}
    remaps = list(leo_scenario.REMAPS["attitude_fusion"].items()) if leo else []
    nodes.append(Node(package=PACKAGE, executable="attitude_fusion", name="attitude_fusion", namespace=namespace,
                      remappings=remaps, parameters=[params_file, fusion], output="screen", emulate_tty=True))
    return nodes


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "star_tracker.yaml")
    arguments = [
        ("heads", "2", "number of heads: namespaces head1 .. headN"),
        ("params_file", default_params, "ros2 parameter file for every node (its /**/attitude_fusion mounting.<head> "
                                        "set the heads' mountings)"),
        ("namespace", "", "namespace of the fusion; the heads are head<i> below it (/diagnostics stays global)"),
        ("autostart", "true", "configure and activate each node on start; false = wait for `ros2 lifecycle set`"),
        ("body_ra_deg", "80.0", "body attitude: right ascension of body +Z [deg]"),
        ("body_dec_deg", "20.0", "body attitude: declination of body +Z [deg]"),
        ("body_roll_deg", "0.0", "body attitude: roll about body +Z [deg] (as the camera_simulator's roll_deg)"),
        ("body_rate_source", "none", "the fusion's body_rate.source: none (the simulated body is at rest), heads or "
                                     "topic (scenario rest)"),
        ("scenario", "rest", "rest: the body at rest at body_*_deg; leo: the heads on a nadir-pointing spacecraft "
                             "in a 550 km sun-synchronous orbit"),
        ("rate_hz", "10.0", "camera frame rate (scenario leo)"),
    ]
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in arguments],
        OpaqueFunction(function=make_nodes),
    ])
