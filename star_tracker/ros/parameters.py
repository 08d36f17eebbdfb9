# SPDX-License-Identifier: Apache-2.0
"""
Node parameters.

Declaration from their ParameterSpecs (star_tracker/parameter_spec.py: the one place a
parameter's default, unit, range, description and dynamic/read-only are written) with
descriptors and ranges, runtime `set_parameters` checks (all or none, refused with the reason,
reported in the log and on /diagnostics), and the report of parameter overrides no node
declares.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Iterable

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..parameter_spec import ParameterSpec
from .qos import is_qos_override

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics
    from .throttled_log import ThrottledLog


def ros_value(value):
    """Return a spec value as a ROS parameter value: tuples become lists."""
    return list(value) if isinstance(value, tuple) else value


def descriptor_for(spec: ParameterSpec) -> ParameterDescriptor:
    """
    Return the ParameterDescriptor `ros2 param describe` shows.

    Description with the unit (and the choices), the range, read-only unless the spec is
    dynamic; additional_constraints: the choices, an open end of the range, an array's range
    per value.
    """
    description = spec.full_description()
    is_list = isinstance(spec.default, (list, tuple))
    constraints = [f"one of: {', '.join(spec.choices)}"] if spec.choices else []
    if spec.has_range and (spec.low_open or spec.high_open or is_list):  # what a range descriptor cannot say
        constraints.append(f"{'each value ' if is_list else ''}in {spec.range_text()}")
        description += f"; {constraints[-1]}"
    descriptor = ParameterDescriptor(description=description, read_only=not spec.dynamic,
                                     additional_constraints="; ".join(constraints))
    if spec.has_range and not is_list and not isinstance(spec.default, (bool, str)):
        if isinstance(spec.default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=0)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(spec.low),
                                                                  to_value=float(spec.high), step=0.0)]
    return descriptor


def declare_parameters(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
    """
    Declare every spec's parameter (in order: the first bad value is the one reported) and return name -> value.

    Values outside a range are refused by rclpy at startup with a message naming the parameter,
    a list's elements outside the range here (ValueError naming it); a string not among the
    choices by the configuration or node code it goes to (its message says what the value
    selects, e.g. "unknown identification algorithm").
    """
    values = {}
    for spec in specs:
        value = node.declare_parameter(spec.name, ros_value(spec.default), descriptor_for(spec)).value
        problem = spec.problem(value) if isinstance(value, (list, tuple)) else None
        if problem:
            raise ValueError(problem)
        values[spec.name] = value
    return values


def declare(node: Node, name: str, default, description: str, low=None, high=None,
            read_only: bool = True):
    """
    Declare one parameter that has no ParameterSpec, with a descriptor (and range); return its value.

    Prefer a spec: it reaches the YAML and the docs.
    """
    return declare_parameters(node, [ParameterSpec(name, default, description, low=low, high=high,
                                                   dynamic=not read_only)])[name]


def _descriptor_problem(node: Node, param: Parameter) -> str | None:
    """Why rclpy will refuse `param` (undeclared, read-only, wrong type, out of range), or None."""
    if not node.has_parameter(param.name):
        return f"{param.name} is not a parameter of {node.get_name()}"
    descriptor = node.describe_parameter(param.name)
    if descriptor.read_only:
        return f"{param.name} is read-only (set it at startup)"
    if param.type_.value != descriptor.type:
        return f"{param.name} must be of type {Parameter.Type(descriptor.type).name}, got {param.type_.name}"
    ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
    if ranges and not (ranges[0].from_value <= param.value <= ranges[0].to_value):  # NaN fails too
        return f"{param.name}={param.value} is outside [{ranges[0].from_value}, {ranges[0].to_value}]"
    return None


def guard_parameter_changes(node: Node, apply: Callable[[dict], str | None], diag: "Diagnostics",
                            log: "ThrottledLog") -> None:
    """
    Runtime `set_parameters`.

    rclpy refuses read-only, mistyped and out-of-range values itself; `apply(changes)` then
    checks the new values together (building the new configuration) and either applies them,
    returning None, or returns the reason they are refused (a ValueError's message counts as
    one). A refused request keeps every old value, answers the caller with the reason, logs
    it and counts `parameter_changes_rejected`; an applied one is logged, counted
    (`parameter_changes_applied`) and shown on /diagnostics (`last_parameter_change`). Call
    after every parameter is declared.
    """

    def refused(reason: str) -> None:
        diag.count("parameter_changes_rejected")
        diag.set(DiagnosticStatus.WARN, f"parameter change refused: {reason}")
        log.warn("parameters", f"parameter change refused: {reason}")

    def audit(params: list[Parameter]) -> list[Parameter]:  # sees what rclpy alone will refuse
        problems = [p for p in (_descriptor_problem(node, param) for param in params) if p]
        if problems:
            refused("; ".join(problems))
        return params

    def validate(params: list[Parameter]) -> SetParametersResult:
        # QoS overrides are read-only: seen here only when rclpy declares them (qos.overridable).
        changes = {param.name: param.value for param in params if not is_qos_override(param.name)}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            reason = apply(changes)
        except ValueError as exc:
            reason = str(exc)
        if reason:
            refused(reason)
            return SetParametersResult(successful=False, reason=reason)
        diag.count("parameter_changes_applied")
        diag.value("last_parameter_change", ", ".join(f"{k}={v}" for k, v in changes.items()))
        node.get_logger().info(f"parameters changed: {changes}")
        return SetParametersResult(successful=True)

    node.add_pre_set_parameters_callback(audit)
    node.add_on_set_parameters_callback(validate)


def report_unknown_parameters(node: Node) -> list[str]:
    """
    Log the parameter overrides (command line, params file) this node does not declare.

    A misspelled name would otherwise be ignored without a word. Returns their names.
    """
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps them only privately
    unknown = sorted(name for name in overrides if not node.has_parameter(name))
    if unknown:
        node.get_logger().warning(f"ignored unknown parameter(s): {', '.join(unknown)}")
    return unknown
