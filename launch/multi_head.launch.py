# SPDX-License-Identifier: Apache-2.0
"""
Start N simulated optical heads on one spacecraft body and the attitude fusion.

    ros2 launch star_tracker multi_head.launch.py                      # two heads, 90 deg apart
    ros2 launch star_tracker multi_head.launch.py heads:=3 params_file:=/path/to/my.yaml
    ros2 launch star_tracker multi_head.launch.py body_ra_deg:=120 body_dec_deg:=-30 body_roll_deg:=15

Head i (1..N) is a camera_simulator, centroider and identifier in namespace `head<i>` (below
`namespace`); attitude_fusion runs in `namespace` with `heads: [head1, ..., headN]`. Every node
loads `params_file` (default: the shipped config/star_tracker.yaml).

Mountings: `mounting.head<i>` of the params file's `/**/attitude_fusion` section where it has
one, else head1 along body +Z, head2 along body +X, head3 along body +Y (HEAD_MOUNTINGS); more
heads need theirs in the params file. The camera_simulator does not know mountings yet, so
each head's camera gets `attitude.quaternion` = the body attitude composed with the head's
mounting (R_head = R_body R(q_mount)), with the body at rest: every head sees the same body.
The body attitude is given like a camera's (`body_ra_deg`, `body_dec_deg`, `body_roll_deg`:
where body +Z points, and the roll about it). A body rate is not offered: each camera's motion
would start at its own first exposure, and the heads would disagree. For the same reason the
fusion is told the body is at rest (`body_rate_source`, default none).
"""
import os

import numpy as np
import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from star_tracker.models.attitude import matrix_to_quaternion, quaternion_to_matrix, radec_roll_to_matrix
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


def camera_quaternion(body: np.ndarray, mounting: list[float]) -> list[float]:
    """Return a head's sensor -> ICRS quaternion (x, y, z, w): the body attitude composed with its mounting."""
    return [float(v) for v in matrix_to_quaternion(body @ quaternion_to_matrix(np.asarray(mounting)))]


def make_nodes(context, *args, **kwargs):
    """Return the heads' nodes and the fusion node for the launch arguments (an OpaqueFunction)."""
    def value(name: str) -> str:
        return LaunchConfiguration(name).perform(context)

    params_file = value("params_file")
    with open(params_file) as stream:
        params = yaml.safe_load(stream) or {}
    heads = head_names(int(value("heads")))
    mountings = mountings_for(heads, params)
    body = radec_roll_to_matrix(*np.radians([float(value(f"body_{a}_deg")) for a in ("ra", "dec", "roll")]))
    namespace = value("namespace").strip("/")
    autostart = value("autostart").lower() == "true"
    nodes = []
    for index, head in enumerate(heads):
        camera = {"attitude.quaternion": camera_quaternion(body, mountings[head]),
                  "attitude.body_rate_deg_s": [0.0, 0.0, 0.0], "frame_id": f"{head}_optical",
                  "seed": index, "fixed_pattern_seed": index}
        for name in HEAD_NODES:
            own = camera if name == "camera_simulator" else {}
            nodes.append(Node(package=PACKAGE, executable=name, name=name,
                              namespace=f"{namespace}/{head}" if namespace else head,
                              parameters=[params_file, {**own, "autostart": autostart}], output="screen",
                              emulate_tty=True))
    fusion = {"heads": heads, **{f"mounting.{head}": q for head, q in mountings.items()},
              "body_rate.source": value("body_rate_source"), "autostart": autostart}
    nodes.append(Node(package=PACKAGE, executable="attitude_fusion", name="attitude_fusion", namespace=namespace,
                      parameters=[params_file, fusion], output="screen", emulate_tty=True))
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
                                     "topic"),
    ]
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in arguments],
        OpaqueFunction(function=make_nodes),
    ])
