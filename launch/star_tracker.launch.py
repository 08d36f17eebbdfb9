# SPDX-License-Identifier: Apache-2.0
"""
Start the star tracker: camera_simulator -> centroider -> identifier.

    ros2 launch star_tracker star_tracker.launch.py
    ros2 launch star_tracker star_tracker.launch.py namespace:=st1 params_file:=/path/to/my.yaml
    ros2 launch star_tracker star_tracker.launch.py autostart:=false   # then: ros2 lifecycle set ...

Every node loads `params_file` (default: share/star_tracker/config/star_tracker.yaml, whose
`/**/<node>` keys apply in any namespace). The nodes are lifecycle nodes that configure and
activate themselves (`autostart`, default true); with autostart:=false they wait unconfigured
for `ros2 lifecycle set /<namespace>/<node> configure` and `activate`.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "star_tracker"
NODES = ("camera_simulator", "centroider", "identifier")


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "star_tracker.yaml")
    params_file = LaunchConfiguration("params_file")
    namespace = LaunchConfiguration("namespace")
    autostart = ParameterValue(LaunchConfiguration("autostart"), value_type=bool)
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ros2 parameter file for camera_simulator, centroider and identifier"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="namespace for the three nodes and their topics (/diagnostics stays global)"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure and activate each node on start; false = wait for "
                                          "`ros2 lifecycle set`"),
        *[Node(package=PACKAGE, executable=name, name=name, namespace=namespace,
               parameters=[params_file, {"autostart": autostart}], output="screen", emulate_tty=True)
          for name in NODES],
    ])
