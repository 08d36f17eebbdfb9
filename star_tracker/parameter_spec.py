# SPDX-License-Identifier: Apache-2.0
"""
One declaration per parameter.

Default, unit, range, description and whether it may change while a node runs, written once
and read by everything that needs it (ROS-free).

A core configuration dataclass declares its tunable fields with `parameter(...)` (dataclass
field metadata); its `__post_init__` checks them with `range_problems(self)` (plus the checks
that relate two fields). The ROS nodes declare their parameters from the same records
(`field_specs` turns a dataclass's fields into `ParameterSpec`s, renamed and with other
defaults where a node needs them; node-only parameters are `ParameterSpec`s in the node's
`*_parameters.py`), and `config/star_tracker.yaml` is generated from them
(`python -m star_tracker.ros.parameter_yaml`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Iterable

SPEC_KEY = "parameter"  # the dataclass field metadata key holding a field's ParameterSpec


@dataclass(frozen=True)
class ParameterSpec:
    """
    One parameter.

    name: the node parameter's name (dotted for groups, e.g. "sensor.exposure_s"); default:
    bool, int, float, str, or a tuple/list of one of them; description: what it is and what a
    special value means (the unit is given apart); unit: SI unit ("s", "px", "e-/ADU"), "-"
    for dimensionless, "" when it has none; low/high: the accepted range, inclusive unless
    low_open/high_open (a ROS descriptor can only say inclusive: it gives [low, high] and the
    configuration refuses the open end itself); choices: the accepted strings; dynamic: may
    change while the node runs; field: the configuration dataclass field it sets (None for a
    node-only parameter).
    """

    name: str
    default: Any
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    dynamic: bool = False
    field: str | None = None

    def __post_init__(self) -> None:
        if (self.low is None) != (self.high is None):
            raise ValueError(f"{self.name}: give both ends of the range or neither")
        problem = self.problem(self.default)
        if problem:
            raise ValueError(f"default of {problem}")

    @property
    def has_range(self) -> bool:
        return self.low is not None

    def range_text(self) -> str:
        """Return the range in interval notation, e.g. "(0, 20]"; "" without one."""
        if not self.has_range:
            return ""

        def text(v) -> str:
            return str(v) if isinstance(v, int) else f"{v:g}"
        return f"{'(' if self.low_open else '['}{text(self.low)}, {text(self.high)}{')' if self.high_open else ']'}"

    def full_description(self) -> str:
        """Return the description with the unit and the choices, as `ros2 param describe` shows it."""
        text = self.description
        if self.unit:
            text += f" [{self.unit}]"
        if self.choices:
            text += f"; one of: {', '.join(self.choices)}"
        return text

    def problem(self, value) -> str | None:
        """
        Why `value` is not acceptable ("name=value must be in [low, high]"), or None.

        Lists are checked element by element against the range.
        """
        if self.choices and value not in self.choices:
            return f"{self.name}={value!r} must be one of {self.choices}"
        if not self.has_range or isinstance(value, (bool, str)):
            return None
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            inside = (math.isfinite(v) and (self.low < v if self.low_open else self.low <= v)
                      and (v < self.high if self.high_open else v <= self.high))
            if not inside:
                return f"{self.name}={value} must be in {self.range_text()}"
        return None


def parameter(default, description: str, unit: str = "", low: float | None = None, high: float | None = None, *,
              low_open: bool = False, high_open: bool = False, choices: Iterable[str] = (),
              dynamic: bool = False) -> dataclasses.Field:
    """Make a dataclass field with its ParameterSpec (named after the field) in the metadata."""
    spec = ParameterSpec("", default, description, unit, low, high, low_open, high_open, tuple(choices), dynamic)
    return dataclasses.field(default=default, metadata={SPEC_KEY: spec})


def field_specs(config_class, prefix: str = "", names: dict[str, str] | None = None, defaults=None,
                dynamic: Iterable[str] | None = None, only: Iterable[str] | None = None) -> list[ParameterSpec]:
    """
    Return the ParameterSpecs of a configuration dataclass's declared fields, in field order.

    prefix: put before each field name ("tracking."); names: field -> parameter name where it
    differs; defaults: an instance whose values replace the field defaults (a node that ships
    other values than the core's); dynamic: field names runtime-settable in this node (None:
    each field's own `dynamic`); only: the fields to take (None: every declared field).
    """
    names, dynamic = names or {}, None if dynamic is None else set(dynamic)
    chosen = None if only is None else set(only)
    specs = []
    for f in dataclasses.fields(config_class):
        spec = f.metadata.get(SPEC_KEY)
        if spec is None or (chosen is not None and f.name not in chosen):
            continue
        specs.append(dataclasses.replace(
            spec, name=names.get(f.name, prefix + f.name), field=f.name,
            default=spec.default if defaults is None else getattr(defaults, f.name),
            dynamic=spec.dynamic if dynamic is None else f.name in dynamic))
    return specs


def field_values(specs: Iterable[ParameterSpec], values: dict[str, Any]) -> dict[str, Any]:
    """
    Keyword arguments for the configuration dataclass.

    field -> value for every spec with a field whose parameter is in `values` (lists become
    tuples where the default is a tuple).
    """
    kwargs = {}
    for spec in specs:
        if spec.field is not None and spec.name in values:
            value = values[spec.name]
            kwargs[spec.field] = tuple(value) if isinstance(spec.default, tuple) else value
    return kwargs


def range_problems(config) -> list[str]:
    """
    List what is out of range or not among the choices in a configuration dataclass instance.

    One message per field ("detection_sigma=0.5 must be in [1, 100]"); [] when all is well.
    """
    problems = []
    for f in dataclasses.fields(config):
        spec = f.metadata.get(SPEC_KEY)
        if spec is not None:
            problem = dataclasses.replace(spec, name=f.name).problem(getattr(config, f.name))
            if problem:
                problems.append(problem)
    return problems


def dotted_names(tree: dict, prefix: str = "") -> dict[str, Any]:
    """
    Flatten a nested ros__parameters mapping into {dotted.name: value}.

    A params file nests groups ("sensor": {"exposure_s": 0.1}); node parameters are named
    "sensor.exposure_s".
    """
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(dotted_names(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat
