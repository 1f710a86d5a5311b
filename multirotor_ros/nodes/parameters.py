"""Node parameters: one :class:`NodeParameter` row per parameter, declared with a full descriptor.

``declare_parameters(node, rows)`` declares every row with a descriptor (type, range, unit in the
description, read-only when it cannot change at run time) and refuses a bad start-up value with a
ValueError naming the parameter. ``check_parameters(rows, parameters)`` is the body of the on-set
callback: it refuses a wrong type, a non-finite number, a value outside the range or a change to a
read-only parameter, with the reason; nodes apply accepted values in their post-set callback.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node

_PARAMETER_TYPES = {
    bool: ParameterType.PARAMETER_BOOL,
    int: ParameterType.PARAMETER_INTEGER,
    float: ParameterType.PARAMETER_DOUBLE,
    str: ParameterType.PARAMETER_STRING,
}


@dataclass(frozen=True)
class NodeParameter:
    """One declared parameter: default (its type is the parameter's type), range, unit, meaning."""

    name: str
    default: float | int | bool | str
    description: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    read_only: bool = False
    low_exclusive: bool = False

    def full_description(self) -> str:
        """The description with its unit, as ``ros2 param describe`` shows it."""
        return f"{self.description} [{self.unit}]" if self.unit else self.description

    def check(self, value: Any) -> str | None:
        """None if ``value`` is acceptable, else the reason."""
        expected = type(self.default)
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not expected:
            return f"{self.name} must be a {expected.__name__}, got {type(value).__name__} {value!r}"
        if isinstance(value, float) and not math.isfinite(value):
            return f"{self.name} must be finite, got {value}"
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if self.low is not None and (value < self.low or (self.low_exclusive and value == self.low)):
                relation = ">" if self.low_exclusive else ">="
                return (
                    f"{self.name} must be {relation} {self.low:g} {self.unit}".rstrip() + f", got {value:g}"
                )
            if self.high is not None and value > self.high:
                return f"{self.name} must be <= {self.high:g} {self.unit}".rstrip() + f", got {value:g}"
        return None

    def descriptor(self) -> ParameterDescriptor:
        """The rcl_interfaces ParameterDescriptor of this parameter."""
        descriptor = ParameterDescriptor(
            name=self.name,
            type=_PARAMETER_TYPES[type(self.default)],
            description=self.full_description(),
            read_only=self.read_only,
        )
        if self.low is None or self.high is None:
            return descriptor
        if isinstance(self.default, float):
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high))
            ]
        elif isinstance(self.default, int) and not isinstance(self.default, bool):
            descriptor.integer_range = [
                IntegerRange(from_value=int(self.low), to_value=int(self.high), step=1)
            ]
        return descriptor


def declare_parameters(
    node: Node, rows: Iterable[NodeParameter], defaults: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """Declare every row on ``node`` (``defaults`` overrides a row's default); return name -> value.

    A value given at start-up (``-p name:=value``) that fails the row's check raises ValueError with
    the reason, so a node started with a bad parameter stops at once with a clear message.
    """
    values = {}
    for row in rows:
        default = (defaults or {}).get(row.name, row.default)
        value = node.declare_parameter(row.name, default, row.descriptor()).value
        reason = row.check(value)
        if reason is not None:
            raise ValueError(f"parameter {reason}")
        values[row.name] = float(value) if isinstance(row.default, float) else value
    return values


def check_parameters(rows: Mapping[str, NodeParameter], parameters: Iterable[Any]) -> SetParametersResult:
    """On-set callback body: a SetParametersResult refusing the first invalid value with its reason."""
    for parameter in parameters:
        row = rows.get(parameter.name)
        if row is None:
            continue  # use_sim_time and other standard parameters: rclpy checks those itself.
        if row.read_only:
            return SetParametersResult(
                successful=False, reason=f"{row.name} is read-only: set it at start-up"
            )
        reason = row.check(parameter.value)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
    return SetParametersResult(successful=True)
