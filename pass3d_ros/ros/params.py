"""Declare ROS parameters from a config dataclass and validate run-time changes against it."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

C = TypeVar("C")


def describe(description: str, value_range: tuple[float, float] | None, default: Any) -> ParameterDescriptor:
    """A descriptor with a description and, for numbers, the allowed closed range."""
    descriptor = ParameterDescriptor(description=description)
    if value_range is None or isinstance(default, bool):
        return descriptor
    if isinstance(default, int):
        descriptor.integer_range = [IntegerRange(from_value=int(value_range[0]), to_value=int(value_range[1]), step=0)]
    elif isinstance(default, float):
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(value_range[0]), to_value=float(value_range[1]), step=0.0)
        ]
    return descriptor


def declare_config(node: Node, config: Any, prefix: str = "") -> None:
    """Declare one parameter per dataclass field; field metadata gives `description` and `range`."""
    for field in dataclasses.fields(config):
        default = getattr(config, field.name)
        if isinstance(default, tuple):
            default = list(default)
        descriptor = describe(field.metadata.get("description", field.name), field.metadata.get("range"), default)
        node.declare_parameter(prefix + field.name, default, descriptor)


def read_config(node: Node, config_type: type[C], prefix: str = "", overrides: dict[str, Any] | None = None) -> C:
    """Build the dataclass from the node's current parameter values (plus pending `overrides`)."""
    values: dict[str, Any] = {}
    for field in dataclasses.fields(config_type):  # type: ignore[arg-type]
        name = prefix + field.name
        value = (overrides or {}).get(name, node.get_parameter(name).value)
        default = getattr(config_type(), field.name)
        if isinstance(default, tuple):
            value = tuple(value)
        elif isinstance(default, float) and isinstance(value, int):
            value = float(value)
        values[field.name] = value
    return config_type(**values)


def validate_changes(
    node: Node, config_type: type[C], params: list[Parameter], prefix: str = ""
) -> tuple[C | None, str]:
    """The config the changed parameters would give, or None and the reason it is invalid."""
    overrides = {p.name: p.value for p in params if p.name.startswith(prefix)}
    try:
        config = read_config(node, config_type, prefix, overrides)
        check = getattr(config, "validate", None)
        if check is not None:
            check()
    except (TypeError, ValueError) as exc:
        return None, str(exc)
    return config, ""


def result(ok: bool, reason: str = "") -> SetParametersResult:
    """A SetParametersResult with a reason on refusal."""
    return SetParametersResult(successful=ok, reason=reason)
