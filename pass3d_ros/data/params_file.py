"""The nodes' `--params-file` YAML, written and read here.

`node_params_yaml` writes one for both nodes (`pass3d_adapt`'s pass3d_params.yaml). `read_params_file` reads one for
the offline tools (`pass3d_evaluate --params-file`), so a folder written by `pass3d_adapt` (or a copy of
launch_configs/pass3d_params.yaml) is scored with the settings the nodes would run with: `cluster_proposal_node`'s
`stage1.*` and `segmentation_node`'s `weights`. Other parameters are the nodes' own (topics, QoS) or learned from the
scans offline as live (intensity scale), and are not read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml

from pass3d_ros.msgs.errors import UserError

STAGE1_NODE = "cluster_proposal_node"
STAGE2_NODE = "segmentation_node"


@dataclass(frozen=True)
class NodeSettings:
    """What the offline tools take from a parameter file."""

    stage1: list[str] = field(default_factory=list)  # `stage1.KEY=VALUE` items, as --param takes them
    weights: str | None = None  # segmentation_node's weights (None: not set, or empty = the shipped ones)


def node_params_yaml(cluster_proposal: dict, segmentation: dict, head: str = "") -> str:
    """A parameter file for both nodes, under any namespace (`/**/NODE`), as `--ros-args --params-file` and the launch
    files read it: `head` (comment lines) then each node's `ros__parameters`, in the order given."""
    doc = {f"/**/{STAGE1_NODE}": {"ros__parameters": cluster_proposal},
           f"/**/{STAGE2_NODE}": {"ros__parameters": segmentation}}
    return head + yaml.safe_dump(doc, sort_keys=False)


def read_params_file(path: Path) -> NodeSettings:
    """The stage-1 parameters and the weights of a nodes' parameter file; UserError naming it when it cannot be read
    or is not one (no `.../cluster_proposal_node` or `.../segmentation_node` section with `ros__parameters`)."""
    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise UserError(f"--params-file {path}: cannot be read ({exc})") from None
    sections = {node: _node_parameters(doc, node, path) for node in (STAGE1_NODE, STAGE2_NODE)}
    if not any(section is not None for section in sections.values()):
        raise UserError(f"--params-file {path}: no {STAGE1_NODE} or {STAGE2_NODE} ros__parameters in it")
    stage1 = (sections[STAGE1_NODE] or {}).get("stage1", {})
    if not isinstance(stage1, dict):
        raise UserError(f"--params-file {path}: {STAGE1_NODE}'s stage1 is not a mapping")
    weights = (sections[STAGE2_NODE] or {}).get("weights")
    if weights is not None and not isinstance(weights, str):
        raise UserError(f"--params-file {path}: {STAGE2_NODE}'s weights is not a path")
    return NodeSettings([f"stage1.{key}={_text(value)}" for key, value in stage1.items()], weights or None)


def _node_parameters(doc: object, node: str, path: Path) -> dict | None:
    """The ros__parameters of the section whose name ends in `node` (`/**/node`, `node`, `/ns/node`), or None."""
    if not isinstance(doc, dict):
        return None
    for name, section in doc.items():
        if str(name).rstrip("/").split("/")[-1] == node:
            parameters = section.get("ros__parameters") if isinstance(section, dict) else None
            if not isinstance(parameters, dict):
                raise UserError(f"--params-file {path}: section {name} has no ros__parameters mapping")
            return parameters
    return None


def _text(value: object) -> str:
    """A YAML value as --param's text: lists comma-separated, booleans lower case."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return ",".join(_text(v) for v in value)
    return str(value)
