"""Node parameters: declaration with descriptors and ranges, runtime `set_parameters` checks
(all or none, refused with the reason), and the report of parameter overrides no node declares."""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from .qos import is_qos_override

if TYPE_CHECKING:  # annotations only
    from .diagnostics import Diagnostics
    from .throttled_log import ThrottledLog


def declare(node: Node, name: str, default, description: str, low=None, high=None,
            read_only: bool = True):
    """Declare a parameter with a descriptor (and range) and return its value.

    Values outside the range are rejected by rclpy at startup with a message naming the
    parameter; read-only parameters cannot be changed while the node runs."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        elif isinstance(default, float):
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return node.declare_parameter(name, default, descriptor).value


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
    """Runtime `set_parameters`: rclpy refuses read-only, mistyped and out-of-range values
    itself; `apply(changes)` then checks the new values together (building the new
    configuration) and either applies them, returning None, or returns the reason they are
    refused (a ValueError's message counts as one). A refused request keeps every old value,
    answers the caller with the reason, logs it and counts `parameter_changes_rejected`.
    Call after every parameter is declared."""

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
        node.get_logger().info(f"parameters changed: {changes}")
        return SetParametersResult(successful=True)

    node.add_pre_set_parameters_callback(audit)
    node.add_on_set_parameters_callback(validate)


def report_unknown_parameters(node: Node) -> list[str]:
    """Log the parameter overrides (command line, params file) this node does not declare: a
    misspelled name would otherwise be ignored without a word. Returns their names."""
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps them only privately
    unknown = sorted(name for name in overrides if not node.has_parameter(name))
    if unknown:
        node.get_logger().warning(f"ignored unknown parameter(s): {', '.join(unknown)}")
    return unknown
