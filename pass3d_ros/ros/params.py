"""Declare ROS parameters from a node's table and config dataclasses, validate run-time changes against them,
and write them out as a `--params-file` YAML (so defaults are written once, in the code)."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from pass3d_ros.core.stage1.config import closest, is_auto_field

C = TypeVar("C")

# name -> (default, description, allowed closed range or None)
ParameterTable = Mapping[str, tuple[Any, str, tuple[float, float] | None]]


@dataclasses.dataclass(frozen=True)
class NodeParameters:
    """Everything one node declares: its name, its own parameter table, and config dataclasses whose fields
    become parameters under a prefix ("stage1." gives stage1.th_ring, a nested `stage1:` key in YAML)."""

    node_name: str
    table: ParameterTable
    configs: Mapping[str, type] = dataclasses.field(default_factory=dict)

    def declare(self, node: Node) -> None:
        """Declare the table's parameters, then each config's fields at their defaults."""
        for name, (default, description, value_range) in self.table.items():
            node.declare_parameter(name, default, describe(description, value_range, default))
        for prefix, config_type in self.configs.items():
            declare_config(node, config_type(), prefix)


# Overrides ROS itself reads when asked (rclpy's QoS overriding options), not parameters a node declares.
ROS_OVERRIDE_PREFIXES = ("qos_overrides.",)


def unknown_overrides(nodes: Sequence[Node]) -> list[tuple[Node, str]]:
    """(node, name) for each parameter given to a node (`-p`, `--params-file`) that no node of this process declares:
    a misspelt name ROS would ignore without a word. A name a sibling declares is a global override meant for it."""
    declared = {name for node in nodes for name in node._parameters}
    found: dict[str, Node] = {}  # a global override reaches every node: name it once
    for node in nodes:
        for name in sorted(node._parameter_overrides):
            if name not in declared and not name.startswith(ROS_OVERRIDE_PREFIXES):
                found.setdefault(name, node)
    return [(node, name) for name, node in found.items()]


def warn_unknown_overrides(nodes: Sequence[Node]) -> None:
    """Warn once per parameter given but declared by none of `nodes`, naming the nearest declared one."""
    declared = {name for node in nodes for name in node._parameters}
    for node, name in unknown_overrides(nodes):
        near = closest(name, declared)
        node.get_logger().warning(f"parameter {name!r} is declared by no node here and is ignored"
                                  + (f" (did you mean {near!r}?)" if near else ""))


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


def auto_descriptor(description: str, value_range: tuple[float, float]) -> ParameterDescriptor:
    """A descriptor of a number-or-auto field (`sensor_height`): dynamically typed, so a YAML's 0.6 (a double) and the
    default "auto" (a string) are both accepted; ROS checks a double against the range, the config the rest."""
    descriptor = describe(description, value_range, 0.0)
    descriptor.dynamic_typing = True
    return descriptor


def declare_config(node: Node, config: Any, prefix: str = "") -> None:
    """Declare one parameter per dataclass field; field metadata gives `description` and `range` (and `auto`: a field
    taking "auto" or a number, declared dynamically typed)."""
    for field in dataclasses.fields(config):
        default = getattr(config, field.name)
        if isinstance(default, tuple):
            default = list(default)
        description = field.metadata.get("description", field.name)
        if is_auto_field(field):
            descriptor = auto_descriptor(description, field.metadata["range"])
        else:
            descriptor = describe(description, field.metadata.get("range"), default)
        node.declare_parameter(prefix + field.name, default, descriptor)


def read_config(node: Node, config_type: type[C], prefix: str = "", overrides: dict[str, Any] | None = None) -> C:
    """Build the dataclass from the node's current parameter values (plus pending `overrides`); its constructor
    is the one check of the values."""
    values: dict[str, Any] = {}
    for field in dataclasses.fields(config_type):  # type: ignore[arg-type]
        name = prefix + field.name
        value = (overrides or {}).get(name, node.get_parameter(name).value)
        default = field.default
        if isinstance(default, tuple):
            value = tuple(value)
        elif isinstance(default, float) and isinstance(value, int):
            value = float(value)
        values[field.name] = value
    return config_type(**values)


def validate_changes(
    node: Node, config_type: type[C], params: list[Parameter], prefix: str = ""
) -> tuple[C | None, str]:
    """The config the changed parameters would give, or None and the reason it is invalid (the config's own check,
    which its constructor runs)."""
    overrides = {p.name: p.value for p in params if p.name.startswith(prefix)}
    try:
        return read_config(node, config_type, prefix, overrides), ""
    except (TypeError, ValueError) as exc:
        return None, str(exc)


def result(ok: bool, reason: str = "") -> SetParametersResult:
    """A SetParametersResult with a reason on refusal."""
    return SetParametersResult(successful=ok, reason=reason)


def _yaml_scalar(value: Any) -> str:
    """One default as a YAML flow value that ROS reads back with the same type (floats keep a '.')."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"cannot write the non-finite default {value} to a parameter file")
        text = repr(value)
        if "." not in text:
            mantissa, _, exponent = text.partition("e")
            text = f"{mantissa}.0" + (f"e{exponent}" if exponent else "")
        return text
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml_scalar(v) for v in value) + "]"
    raise TypeError(f"no YAML form for a parameter default of type {type(value).__name__}")


def _yaml_entry(depth: int, name: str, value: Any, description: str) -> str:
    """`name: value  # description`, indented two spaces per level."""
    return f"{'  ' * depth}{name}: {_yaml_scalar(value)}  # {' '.join(description.split())}"


def params_yaml(nodes: Sequence[NodeParameters], header: str = "",
                left_out: Mapping[str, Sequence[str]] | None = None) -> str:
    """A `--params-file` YAML with every parameter of `nodes` at its default, commented with its description;
    `header` lines become leading comments. A config prefix ("stage1.") becomes one nested key. Nodes are keyed
    `/**/NAME`, so the file applies in any namespace (`-r __ns:=/car1`, a launch file's `namespace`). `left_out`:
    node name -> parameters written only as a comment (a launch file's arguments set them; a value in the file would
    win over the argument)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    for spec in nodes:
        lines += [f"/**/{spec.node_name}:", "  ros__parameters:"]
        skipped = set((left_out or {}).get(spec.node_name, ()))
        for name, (default, description, _) in spec.table.items():
            if name in skipped:
                lines.append(f"    # {name}: from the launch argument {name} (a value set here wins over it)")
                continue
            lines.append(_yaml_entry(2, name, default, description))
        for prefix, config_type in spec.configs.items():
            lines.append(f"    {prefix.removesuffix('.')}:")
            defaults = config_type()
            for field in dataclasses.fields(config_type):
                description = field.metadata.get("description", field.name)
                lines.append(_yaml_entry(3, field.name, getattr(defaults, field.name), description))
    return "\n".join(lines) + "\n"


def _markdown_value(value: Any) -> str:
    """A default as a table cell: the YAML form in backticks, `""` for an empty string."""
    return f"`{_yaml_scalar(list(value) if isinstance(value, tuple) else value)}`"


def _markdown_range(value_range: tuple[float, float] | None, default: Any) -> str:
    """A closed range as `lo .. hi`, blank where the parameter has none (strings, booleans, lists; a string default
    with a range is a number-or-auto field: its numbers' range)."""
    if value_range is None or isinstance(default, (bool, list, tuple)):
        return ""
    return f"{value_range[0]:g} .. {value_range[1]:g}"


def _markdown_row(name: str, default: Any, value_range: tuple[float, float] | None, description: str) -> str:
    """One parameter as `| name | default | range | description |` (pipes in text escaped)."""
    text = " ".join(description.split()).replace("|", "\\|")
    return f"| `{name}` | {_markdown_value(default)} | {_markdown_range(value_range, default)} | {text} |"


def params_markdown(nodes: Sequence[NodeParameters], header: str = "") -> str:
    """The same parameters as `params_yaml`, as one Markdown table per node (name, default, range, description);
    a config prefix's fields are listed under their dotted names (`stage1.th_ring`) and can change at run time."""
    lines = [header.rstrip(), ""] if header else []
    for spec in nodes:
        lines += [f"## {spec.node_name}", "", "| parameter | default | range | description |", "|---|---|---|---|"]
        for name, (default, description, value_range) in spec.table.items():
            lines.append(_markdown_row(name, default, value_range, description))
        for prefix, config_type in spec.configs.items():
            defaults = config_type()
            for field in dataclasses.fields(config_type):
                lines.append(_markdown_row(prefix + field.name, getattr(defaults, field.name),
                                           field.metadata.get("range"), field.metadata.get("description", field.name)))
        lines.append("")
    return "\n".join(lines)
