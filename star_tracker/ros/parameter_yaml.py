# SPDX-License-Identifier: Apache-2.0
"""
config/star_tracker.yaml, generated from the nodes' ParameterSpecs (ROS-free).

    python -m star_tracker.ros.parameter_yaml            # print it
    python -m star_tracker.ros.parameter_yaml --write    # rewrite config/star_tracker.yaml
    python -m star_tracker.ros.parameter_yaml --check    # exit 1 when the shipped file differs

Every parameter of every node with its default, under a comment with its description, unit,
range and whether it may change while the node runs (test/ros/test_parameter_spec.py proves the
shipped file equal to this output).
"""
from __future__ import annotations

import argparse
import json
import sys
import textwrap
from pathlib import Path

import yaml

from ..parameter_spec import ParameterSpec

SHIPPED = Path(__file__).resolve().parents[2] / "config" / "star_tracker.yaml"
WIDTH = 110  # comment lines are wrapped to this width

HEADER = """\
# star_tracker parameters in ros2 param-file format, GENERATED from the parameter specs
# (star_tracker/parameter_spec.py, the core configs' field metadata and star_tracker/ros/*_parameters.py):
#   python -m star_tracker.ros.parameter_yaml --write
# Use:  ros2 run star_tracker identifier --ros-args --params-file config/star_tracker.yaml
# These are the nodes' built-in defaults (a node started without this file runs the same values):
# a fixed attitude, camera_simulator's attitude.profile constant_rate at zero body rate
# (`star-tracker demo` adds a body rate per --scenario). Keys use /**/<node> so they apply in any
# namespace. [unit]; range; "runtime" = settable while the node runs (ros2 param set), else
# read-only. `ros2 param describe` shows the same.
"""


def node_parameters() -> dict[str, list[ParameterSpec]]:
    """Each node's parameter specs, in declaration order."""
    from .attitude_fusion_parameters import ATTITUDE_FUSION_PARAMETERS
    from .camera_simulator_parameters import CAMERA_SIMULATOR_PARAMETERS
    from .centroider_parameters import CENTROIDER_PARAMETERS
    from .identifier_parameters import IDENTIFIER_PARAMETERS

    return {"camera_simulator": CAMERA_SIMULATOR_PARAMETERS, "centroider": CENTROIDER_PARAMETERS,
            "identifier": IDENTIFIER_PARAMETERS, "attitude_fusion": ATTITUDE_FUSION_PARAMETERS}


def yaml_value(value) -> str:
    """
    Return a value as ros2 param-file YAML that reads back with the same type.

    Floats always with a decimal point (1.0, 2.0e-05), lists in flow style, strings plain (quoted where YAML
    would retype them).
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        text = repr(value)
        if "e" in text and "." not in text.split("e")[0]:
            mantissa, exponent = text.split("e")
            text = f"{mantissa}.0e{exponent}"
        return text
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    text = str(value)
    # Plain unless YAML would read it as something else ("" as null, "true" as a bool, "1" as an int).
    return text if text and yaml.safe_load(text) == text else json.dumps(text)


def comment_lines(spec: ParameterSpec, width: int) -> list[str]:
    """Return the comment above a parameter, wrapped: description [unit]; range; runtime (the range is never split)."""
    lines = textwrap.wrap(spec.full_description(), width, break_on_hyphens=False)
    suffix = "".join(f"; {part}" for part in (spec.range_text(), "runtime" if spec.dynamic else "") if part)
    if suffix:
        if lines and len(lines[-1]) + len(suffix) <= width:
            lines[-1] += suffix
        else:
            lines.append(suffix[2:])
    return lines


def _nest(specs: list[ParameterSpec]) -> dict:
    """Dotted names as nested groups, in first-appearance order."""
    tree: dict = {}
    for spec in specs:
        *groups, leaf = spec.name.split(".")
        node = tree
        for group in groups:
            node = node.setdefault(group, {})
        node[leaf] = spec
    return tree


def _lines(tree: dict, indent: int) -> list[str]:
    lines = []
    pad = " " * indent
    for key, item in tree.items():
        if isinstance(item, dict):
            lines.append(f"{pad}{key}:")
            lines.extend(_lines(item, indent + 2))
        else:
            lines.extend(f"{pad}# {line}" for line in comment_lines(item, WIDTH - indent - 2))
            lines.append(f"{pad}{key}: {yaml_value(item.default)}")
    return lines


def generate() -> str:
    """Return the whole file."""
    parts = [HEADER]
    for node, specs in node_parameters().items():
        parts.append(f"/**/{node}:\n  ros__parameters:\n" + "\n".join(_lines(_nest(specs), 4)) + "\n")
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--write", action="store_true", help=f"rewrite {SHIPPED}")
    group.add_argument("--check", action="store_true", help="exit 1 when the shipped file differs")
    args = parser.parse_args(argv)
    text = generate()
    if args.write:
        SHIPPED.write_text(text)
        print(f"wrote {SHIPPED}")
    elif args.check:
        if SHIPPED.read_text() != text:
            print(f"{SHIPPED} differs from the parameter specs: run python -m star_tracker.ros.parameter_yaml --write")
            return 1
        print(f"{SHIPPED} matches the parameter specs")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
