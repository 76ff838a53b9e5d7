"""launch_configs/ parsed and checked: every executable, parameter and topic they name exists."""

from __future__ import annotations

import ast
import dataclasses
import re
from dataclasses import replace
from pathlib import Path

import pytest
import yaml
from helpers.ros import domain

from pass3d_ros.core.stage1 import Stage1Config
from pass3d_ros.ros import cluster_proposal_node, segmentation_node
from pass3d_ros.tools import params_yaml

ROOT = Path(__file__).resolve().parents[2]
LAUNCH = ROOT / "launch_configs"
PARAMS_FILE = LAUNCH / "pass3d_params.yaml"


def console_scripts() -> set[str]:
    """Executable names declared in setup.py's console_scripts."""
    text = (ROOT / "setup.py").read_text()
    return set(re.findall(r'"(\w+) = pass3d_ros\.[\w.]+:main"', text))


def declared_parameters() -> dict[str, set[str]]:
    """Parameter names each node declares, flattened with dots as ROS does."""
    declared = {}
    for spec in params_yaml.NODES:
        configs = {prefix + f.name for prefix, config in spec.configs.items() for f in dataclasses.fields(config)}
        declared[spec.node_name] = set(spec.table) | configs
    return declared


def flatten(tree: dict, prefix: str = "") -> dict[str, object]:
    """{'a': {'b': 1}} -> {'a.b': 1}."""
    flat: dict[str, object] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def test_every_executable_is_declared() -> None:
    scripts = console_scripts()
    assert {"cluster_proposal_node", "segmentation_node", "pass3d_pipeline", "pass3d_params_yaml"} <= scripts
    launch_yaml = yaml.safe_load((LAUNCH / "pass3d.launch.yaml").read_text())
    yaml_nodes = [entry["node"] for entry in launch_yaml["launch"] if "node" in entry]
    ours = [n["exec"] for n in yaml_nodes if n["pkg"] == "pass3d_ros"]
    assert ours == ["cluster_proposal_node", "segmentation_node"]
    assert set(ours) <= scripts

    tree = ast.parse((LAUNCH / "pass3d.launch.py").read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"]
    kwargs = [{k.arg: k.value for k in call.keywords} for call in calls]
    py_execs = [k["executable"].value for k in kwargs if k["package"].value == "pass3d_ros"]
    assert py_execs == ours


def test_parameter_yaml_names_only_declared_parameters_with_valid_values() -> None:
    data = {key.removeprefix("/**/"): body for key, body in yaml.safe_load(PARAMS_FILE.read_text()).items()}
    declared = declared_parameters()
    assert set(data) == set(declared)
    for node_name, body in data.items():
        values = flatten(body["ros__parameters"])
        unknown = set(values) - declared[node_name]
        assert not unknown, f"{node_name}: {unknown} are not declared by the node"
    stage1 = data["cluster_proposal_node"]["ros__parameters"]["stage1"]
    config = Stage1Config.from_mapping(stage1)
    assert config == Stage1Config(), "the YAML must carry the paper's defaults"


def test_parameter_yaml_is_generated_from_the_code() -> None:
    assert PARAMS_FILE.read_text() == params_yaml.render(), "run pass3d_params_yaml --out " + str(PARAMS_FILE)
    assert set(declared_parameters()["cluster_proposal_node"]) >= {"stage1.th_ring", "stage1.fit_stride"}
    values = flatten(yaml.safe_load(params_yaml.render())["/**/segmentation_node"]["ros__parameters"])
    assert values == {name: entry[0] for name, entry in segmentation_node.NODE_PARAMETERS.items()
                      if name not in params_yaml.LAUNCH_ARGUMENTS["segmentation_node"]}


def test_parameter_reference_is_generated_from_the_code() -> None:
    docs = ROOT / "docs" / "parameters.md"
    assert docs.read_text() == params_yaml.render_markdown(), "run pass3d_params_yaml --markdown --out " + str(docs)
    rows = {line.split("|")[1].strip().strip("`") for line in docs.read_text().splitlines() if line.startswith("| `")}
    declared = declared_parameters()
    assert rows == declared["cluster_proposal_node"] | declared["segmentation_node"]


def test_params_yaml_tool_writes_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "params.yaml"
    assert params_yaml.main(["--out", str(out)]) == 0
    assert out.read_text() == params_yaml.render()
    assert params_yaml.main([]) == 0
    assert capsys.readouterr().out == params_yaml.render()
    assert params_yaml.main(["--markdown", "--out", str(out)]) == 0
    assert out.read_text() == params_yaml.render_markdown()


# Every rclpy node declares use_sim_time itself.
BUILTIN_PARAMETERS = {"use_sim_time"}


def test_launch_files_set_only_declared_parameters() -> None:
    declared = {name: names | BUILTIN_PARAMETERS for name, names in declared_parameters().items()}
    launch_yaml = yaml.safe_load((LAUNCH / "pass3d.launch.yaml").read_text())
    for entry in launch_yaml["launch"]:
        node = entry.get("node")
        if not node or node["pkg"] != "pass3d_ros":
            continue
        names = {p["name"] for p in node["param"] if "name" in p}
        assert names <= declared[node["name"]]
    tree = ast.parse((LAUNCH / "pass3d.launch.py").read_text())
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"):
        kw = {k.arg: k.value for k in call.keywords}
        if kw["package"].value != "pass3d_ros":
            continue
        assert "namespace" in kw, "both nodes follow the launch file's namespace argument"
        for item in kw["parameters"].elts:
            if isinstance(item, ast.Dict):
                assert {k.value for k in item.keys} <= declared[kw["name"].value]


def test_rviz_config_shows_the_nodes_topics() -> None:
    rviz = yaml.safe_load((LAUNCH / "pass3d.rviz").read_text())
    displays = {d["Name"]: d for d in rviz["Visualization Manager"]["Displays"]}
    cloud = displays["Labeled cloud"]
    assert cloud["Class"] == "rviz_default_plugins/PointCloud2"
    assert cloud["Color Transformer"] == "RGB8"
    def resolved(name: str) -> str:  # the nodes' topics are relative names; rviz shows them without a namespace
        return name if name.startswith("/") else "/" + name

    assert cloud["Topic"]["Value"] == resolved(segmentation_node.NODE_PARAMETERS["labeled_topic"][0])
    assert displays["Objects"]["Topic"]["Value"] == resolved(segmentation_node.NODE_PARAMETERS["objects_topic"][0])
    assert displays["Proposals"]["Topic"]["Value"] == resolved(
        cluster_proposal_node.NODE_PARAMETERS["boxes_topic"][0])


@pytest.mark.ros
@pytest.mark.parametrize("namespace", [None, "/car1"])
def test_a_real_node_loads_the_parameter_file(tmp_path: Path, namespace: str | None) -> None:
    """The shipped YAML reaches a real node, also under a namespace (the file keys nodes as /**/NAME)."""
    import rclpy
    from rclpy.context import Context

    shipped = PARAMS_FILE.read_text()
    changed = shipped.replace("th_ring: 0.5", "th_ring: 0.45", 1)
    assert changed != shipped, "the shipped file should hold th_ring: 0.5"
    params = tmp_path / "params.yaml"
    params.write_text(changed)
    args = ["--ros-args", "--params-file", str(params)] + (["-r", f"__ns:={namespace}"] if namespace else [])
    context = Context()
    rclpy.init(args=args, context=context, domain_id=domain())
    try:
        node = cluster_proposal_node.ClusterProposalNode(context=context)
        try:
            assert node.get_namespace() == (namespace or "/")
            assert node.get_parameter("stage1.th_ring").value == 0.45
            assert node.get_parameter("stage1.fit_stride").value == Stage1Config().fit_stride
            assert node.config == replace(Stage1Config(), th_ring=0.45)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_fastdds_profile_fits_a_large_cloud_in_shared_memory() -> None:
    """The shipped Fast DDS profile parses and its shared-memory segment holds a 120k-point cloud (~2 MB) with room:
    the default 512 KB segment is what made best-effort readers lose frames between processes."""
    import xml.etree.ElementTree as ET

    ns = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    root = ET.parse(LAUNCH / "fastdds_large_clouds.xml").getroot()
    shm = [t for t in root.iterfind(".//f:transport_descriptor", ns) if t.findtext("f:type", namespaces=ns) == "SHM"]
    assert len(shm) == 1 and int(shm[0].findtext("f:segment_size", namespaces=ns)) >= 8 * 120_000 * 16
    used = {t.text for t in root.iterfind(".//f:userTransports/f:transport_id", ns)}
    assert shm[0].findtext("f:transport_id", namespaces=ns) in used
    assert root.findtext(".//f:useBuiltinTransports", namespaces=ns) == "false"


def test_launch_files_give_every_process_the_shipped_fastdds_profile_unless_the_user_set_one() -> None:
    """Both launch files set FASTRTPS_DEFAULT_PROFILES_FILE before starting anything: the user's value when set, else
    the profile setup.py installs under share/pass3d_ros/config."""
    from pass3d_ros.ros.dds_profile import PROFILE_NAME, PROFILE_VARIABLE

    assert re.search(rf'share/{{PACKAGE}}/config".*"launch_configs/{PROFILE_NAME}"', (ROOT / "setup.py").read_text(),
                     re.S), "setup.py must install the profile into share/pass3d_ros/config"

    entries = yaml.safe_load((LAUNCH / "pass3d.launch.yaml").read_text())["launch"]
    kinds = [next(iter(entry)) for entry in entries]
    assert [entry["set_env"] for entry in entries if "set_env" in entry] == [
        {"name": PROFILE_VARIABLE, "value": "$(var fastdds_profile)"}]
    assert kinds.index("set_env") < kinds.index("node"), "the variable must be set before the nodes start"
    args = {entry["arg"]["name"]: entry["arg"] for entry in entries if "arg" in entry}
    assert args["fastdds_profile"]["default"] == (
        f"$(env {PROFILE_VARIABLE} $(find-pkg-share pass3d_ros)/config/{PROFILE_NAME})")

    tree = ast.parse((LAUNCH / "pass3d.launch.py").read_text())
    constants = {node.targets[0].id: ast.literal_eval(node.value) for node in tree.body
                 if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant)}
    assert constants["PROFILE_VARIABLE"] == PROFILE_VARIABLE
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    set_env = [c for c in calls if c.func.id == "SetEnvironmentVariable"]
    assert len(set_env) == 1
    name, value = set_env[0].args
    assert name.id == "PROFILE_VARIABLE" and ast.unparse(value) == "LaunchConfiguration('fastdds_profile')"
    assert set_env[0].lineno < min(c.lineno for c in calls if c.func.id == "Node")
    declared = {c.args[0].value: {k.arg: k.value for k in c.keywords} for c in calls
                if c.func.id == "DeclareLaunchArgument"}
    default = declared["fastdds_profile"]["default_value"]
    assert ast.unparse(default) == "EnvironmentVariable(PROFILE_VARIABLE, default_value=shipped_profile)"
    shipped = next(n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                   and getattr(n.targets[0], "id", "") == "shipped_profile")
    assert ast.unparse(shipped) == f"PathJoinSubstitution([config_dir, '{PROFILE_NAME}'])"


def test_a_parameter_file_that_sets_input_topic_or_weights_wins_over_the_launch_arguments() -> None:
    """Both launch files give the input_topic and weights arguments before the parameter file (launch_ros passes the
    list in order as --params-file files, the later winning), and the shipped file leaves both to the arguments: so
    pass3d_adapt's file, which sets them, is not overridden by the arguments' defaults."""
    launch_yaml = yaml.safe_load((LAUNCH / "pass3d.launch.yaml").read_text())
    nodes = {e["node"]["name"]: e["node"]["param"] for e in launch_yaml["launch"] if "node" in e}
    for name, argument in (("cluster_proposal_node", "input_topic"), ("segmentation_node", "weights")):
        order = [p.get("name", "file" if "from" in p else None) for p in nodes[name]]
        assert order.index(argument) < order.index("file"), name
    tree = ast.parse((LAUNCH / "pass3d.launch.py").read_text())
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"):
        kw = {k.arg: k.value for k in call.keywords}
        if kw["package"].value != "pass3d_ros":
            continue
        items = kw["parameters"].elts
        given = next(i for i, item in enumerate(items) if isinstance(item, ast.Dict)
                     and {k.value for k in item.keys} & {"input_topic", "weights"})
        file = next(i for i, item in enumerate(items) if isinstance(item, ast.Name) and item.id == "params_file")
        assert given < file, kw["name"].value
    shipped = flatten(yaml.safe_load(PARAMS_FILE.read_text()))
    assert "/**/cluster_proposal_node.ros__parameters.input_topic" not in shipped
    assert "/**/segmentation_node.ros__parameters.weights" not in shipped
    assert "/**/segmentation_node.ros__parameters.input_topic" in shipped  # its own input, no launch argument


@pytest.mark.ros
def test_a_later_parameter_file_wins(tmp_path: Path) -> None:
    """What the launch files' order relies on: of two --params-file files, rclpy keeps the later one's value."""
    import rclpy
    from rclpy.context import Context

    argument, file = tmp_path / "argument.yaml", tmp_path / "file.yaml"
    argument.write_text('/**/segmentation_node:\n  ros__parameters:\n    weights: ""\n')
    file.write_text('/**/segmentation_node:\n  ros__parameters:\n    weights: "/adapted/weights.pt"\n')
    context = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(argument), "--params-file", str(file)], context=context,
               domain_id=domain())
    try:
        node = rclpy.create_node("segmentation_node", context=context,
                                 automatically_declare_parameters_from_overrides=True)
        try:
            assert node.get_parameter("weights").value == "/adapted/weights.pt"
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
