"""One list of dependencies: setup.py's INSTALL_REQUIRES and its ros-wheels, torch and test extras. package.xml names
the same runtime dependencies as rosdep keys, the README's Dependencies section names each, the Makefile installs
`-e .[ros-wheels,torch,test]` (after the pinned torch) and keeps no list of its own, and every third-party import
of the package is declared."""

from __future__ import annotations

import ast
import itertools
import re
import shlex
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Each third-party module the package imports: (the setup.py requirement that installs it, its package.xml rosdep key).
IMPORTS = {
    "numpy": ("numpy", "python3-numpy"),
    "numba": ("numba", "python3-numba"),
    "torch": ("torch", "python3-torch"),
    "tqdm": ("tqdm", "python3-tqdm"),
    "yaml": ("pyyaml", "python3-yaml"),
    "rosbags": ("rosbags", "python3-rosbags-pip"),
    "scipy": ("scipy", "python3-scipy"),
    "rclpy": ("ros-jazzy-rclpy", "rclpy"),
    "rcl_interfaces": ("ros-jazzy-rclpy", "rcl_interfaces"),
    "ament_index_python": ("ros-jazzy-rclpy", "ament_index_python"),
    **{name: ("ros-jazzy-common-interfaces", name) for name in (
        "builtin_interfaces", "std_msgs", "sensor_msgs", "geometry_msgs", "visualization_msgs", "diagnostic_msgs",
        "nav_msgs")},
}
# Imported only where guarded, never needed to run: not runtime dependencies.
OPTIONAL = {"rerun": "pass3d_view (the `view` extra)", "pypatchworkpp": "a benchmark's side-by-side peer",
            "vision_msgs": "/pass3d/detections and /pass3d/label_info (a ROS install's ros-jazzy-vision-msgs)"}
# package.xml keys a ROS install brings that PyPI has no wheel for (DESIGN.md): the launch files', rviz2's and the
# detections' message package.
ROS_INSTALL_ONLY = {"ros2launch", "launch_ros", "rviz2", "vision_msgs"}


def requirement_name(requirement: str) -> str:
    """'ros-jazzy-rclpy[fastrtps]==7.1.6' -> 'ros-jazzy-rclpy'."""
    match = re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", requirement)
    assert match, requirement
    return match.group(0).lower()


def setup_lists() -> dict[str, list[str]]:
    """setup.py's module-level lists (INSTALL_REQUIRES, TEST_REQUIRES, ...) without running setup()."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    return {node.targets[0].id: ast.literal_eval(node.value) for node in tree.body
            if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
            and isinstance(node.value, ast.List) and node.targets[0].id.endswith("_REQUIRES")}


def setup_keywords() -> dict[str, ast.expr]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setup"]
    assert len(calls) == 1
    return {keyword.arg: keyword.value for keyword in calls[0].keywords}


def exec_depends() -> set[str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {element.text.strip() for tag in ("exec_depend", "depend") for element in root.iter(tag)}


def third_party_imports(folder: Path) -> dict[str, set[str]]:
    """Top-level modules imported anywhere under `folder` that are neither the standard library nor pass3d_ros."""
    found: dict[str, set[str]] = {}
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                modules = [node.module]
            else:
                continue
            for module in modules:
                top = module.split(".")[0]
                if top not in sys.stdlib_module_names and top != "pass3d_ros":
                    found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def test_setup_passes_its_lists() -> None:
    lists = setup_lists()
    assert {"INSTALL_REQUIRES", "TEST_REQUIRES"} <= lists.keys()
    keywords = setup_keywords()
    assert ast.unparse(keywords["install_requires"]) == "INSTALL_REQUIRES"
    extras = keywords["extras_require"]
    assert isinstance(extras, ast.Dict)
    by_key = {ast.literal_eval(k): ast.unparse(v) for k, v in zip(extras.keys, extras.values, strict=True)}
    assert by_key["test"] == "TEST_REQUIRES", "colcon test and make setup install the `test` extra"


def test_every_import_of_the_package_is_declared() -> None:
    imports = third_party_imports(ROOT / "pass3d_ros")
    undeclared = {module: sorted(files) for module, files in imports.items()
                  if module not in IMPORTS and module not in OPTIONAL}
    assert not undeclared, f"add these to setup.py, package.xml and IMPORTS here: {undeclared}"


def runtime_requirements() -> list[str]:
    """What the package runs on: INSTALL_REQUIRES and the ros-wheels and torch extras (kept out of install_requires:
    the launcher scripts setuptools writes check install_requires, and a real Jazzy has no pip rclpy)."""
    lists = setup_lists()
    return lists["INSTALL_REQUIRES"] + lists["ROS_WHEELS_REQUIRES"] + lists["TORCH_REQUIRES"]


def test_ros_and_torch_are_extras_not_launch_requirements() -> None:
    names = {requirement_name(r) for r in setup_lists()["INSTALL_REQUIRES"]}
    assert not names & {"torch", "ros-jazzy-rclpy", "ros-jazzy-common-interfaces"}, names


def test_setup_requires_exactly_what_the_imports_need() -> None:
    required = {requirement_name(r) for r in runtime_requirements()}
    needed = {requirement for requirement, _ in IMPORTS.values()}
    assert required == needed, f"in setup.py only: {required - needed}; needed but missing: {needed - required}"


def test_package_xml_names_the_same_dependencies() -> None:
    declared = exec_depends()
    needed = {key for _, key in IMPORTS.values()} | ROS_INSTALL_ONLY
    assert declared == needed, f"in package.xml only: {declared - needed}; missing there: {needed - declared}"


def test_no_import_is_left_unused_in_the_table() -> None:
    """The table follows the code: a dependency the package no longer imports is dropped everywhere."""
    imported = third_party_imports(ROOT / "pass3d_ros")
    assert not IMPORTS.keys() - imported.keys(), IMPORTS.keys() - imported.keys()


def test_readme_names_each_runtime_dependency() -> None:
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Dependencies\n", 1)[1].split("\n## ", 1)[0]
    missing = [r for r in runtime_requirements() if f"`{requirement_name(r)}" not in section]
    assert not missing, f"README's Dependencies section does not name {missing}"
    torch = next(r for r in runtime_requirements() if requirement_name(r) == "torch")
    assert f"`{torch}`" in section, "the README gives torch's pin"


def test_makefile_installs_the_test_extra_after_the_pinned_torch() -> None:
    lines = (ROOT / "Makefile").read_text().splitlines()
    lists = setup_lists()
    torch = lists["TORCH_REQUIRES"][0]
    torch_line = next((i for i, line in enumerate(lines) if "pip install" in line and torch in line.split()), None)
    extras = "-e '.[ros-wheels,torch,test]'"
    extra_line = next((i for i, line in enumerate(lines) if "pip install" in line and extras in line), None)
    assert torch_line is not None, f"the Makefile installs {torch} (setup.py's pin) first"
    assert extra_line is not None, "the Makefile installs -e '.[ros-wheels,torch,test]'"
    assert torch_line < extra_line, "torch first: an unpinned torch would pull several GB of CUDA wheels"
    # nothing else: every other package comes from setup.py's lists
    installed = [token for line in lines if "pip install" in line
                 for token in line.split("pip install", 1)[1].split() if not token.startswith("-")]
    assert sorted(installed) == sorted(["pip", torch, "'.[ros-wheels,torch,test]'"]), installed


def test_the_test_tools_the_suite_relies_on_are_in_the_test_extra() -> None:
    test = {requirement_name(r) for r in setup_lists()["TEST_REQUIRES"]}
    assert {"pytest", "ruff"} <= test
    if re.search(r"^timeout\s*=", (ROOT / "setup.cfg").read_text(), re.MULTILINE):
        assert "pytest-timeout" in test
    if re.search(r"pytest .*-n ", (ROOT / "Makefile").read_text()):
        assert "pytest-xdist" in test


def readme_install_commands() -> tuple[list[str], list[str]]:
    """The README's install block ("On your robot"): the keys its `rosdep install` skips and what its `pip install`
    installs into the workspace's venv."""
    text = (ROOT / "README.md").read_text()
    block = text.split("\n## On your robot\n", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    rosdep = next(shlex.split(line) for line in block.splitlines() if line.startswith("rosdep install"))
    skipped = [key for flag, value in itertools.pairwise(rosdep) if flag == "--skip-keys"
               for key in value.split()]
    pip = next(shlex.split(line) for line in block.splitlines() if line.startswith("pip install"))
    return skipped, [token for token in pip[2:] if not token.startswith("-")]


def test_readme_rosdep_line_skips_what_the_venv_pip_installs() -> None:
    """A `-pip` rosdep key makes rosdep run pip on the system Python, which Jazzy's Ubuntu 24.04 refuses (PEP 668:
    externally managed) unless pip was told to break system packages: `rosdep install` fails. The README installs
    such a dependency, and the pinned torch, with pip into the venv instead, so its rosdep line must skip their keys;
    and it skips only keys package.xml names, each installed by its pip line."""
    skipped, pip = readme_install_commands()
    key_to_requirement = {key: requirement for requirement, key in IMPORTS.values()}
    pip_keys = {key for key in exec_depends() if key.endswith("-pip")}
    assert pip_keys, "package.xml names no pip key: drop this test's premise"
    assert pip_keys <= set(skipped), f"the README's rosdep line must skip {sorted(pip_keys - set(skipped))}"
    assert set(skipped) <= exec_depends(), f"the README skips keys package.xml lacks: {set(skipped) - exec_depends()}"
    installed = {requirement_name(token) for token in pip}
    for key in skipped:
        assert key_to_requirement[key] in installed, f"{key} is skipped but the README's pip line lacks it"
    torch = setup_lists()["TORCH_REQUIRES"][0]
    assert torch in pip, "the README pins torch as setup.py does"
