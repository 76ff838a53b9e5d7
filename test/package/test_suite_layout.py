"""The suite's own shape (issue 36): the test folders mirror pass3d_ros/ (test/package/ for the package as a whole),
shared code lives in test/helpers and the conftest.py files, no test module imports another, each fixture is declared
once, and CI runs every test although `make test` leaves the slow ones out."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TEST_DIR = Path(__file__).resolve().parents[1]
ROOT = TEST_DIR.parent
PACKAGE = ROOT / "pass3d_ros"
WHOLE_PACKAGE = "package"  # test/package/: docs, launch configs, dependencies, this layout


def modules() -> list[Path]:
    return sorted(TEST_DIR.rglob("*.py"))


def files_of_tests() -> list[Path]:
    return sorted(TEST_DIR.rglob("test_*.py"))


def test_each_test_module_lives_where_its_package_does() -> None:
    """test/core/stage1/test_x.py tests pass3d_ros/core/stage1/: every test folder is a pass3d_ros package's path (or
    test/package/), and none sits directly in test/."""
    misplaced = []
    for path in files_of_tests():
        folder = path.parent.relative_to(TEST_DIR)
        mirrors = folder.parts and (PACKAGE / folder / "__init__.py").is_file()
        if not (mirrors or folder == Path(WHOLE_PACKAGE)):
            misplaced.append(str(path.relative_to(TEST_DIR)))
    assert not misplaced, f"move them under the folder of the pass3d_ros package they test: {misplaced}"
    assert not (PACKAGE / WHOLE_PACKAGE).exists(), "test/package/ would shadow a pass3d_ros package of that name"


def test_test_module_names_are_unique_without_init_files() -> None:
    """pytest's default (prepend) imports need one basename per test module while the folders have no __init__.py."""
    seen: dict[str, list[str]] = {}
    for path in files_of_tests():
        seen.setdefault(path.name, []).append(str(path.relative_to(TEST_DIR)))
    assert not {name: paths for name, paths in seen.items() if len(paths) > 1}
    inits = [p for p in TEST_DIR.rglob("__init__.py") if p.parent != TEST_DIR / "helpers"]
    assert not inits, f"test folders are no packages: {inits}"


def imported(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def is_fixture(decorator: ast.expr) -> bool:
    target = decorator.func if isinstance(decorator, ast.Call) else decorator
    return ast.unparse(target) in ("pytest.fixture", "fixture")


def test_no_test_module_imports_another_or_conftest() -> None:
    offending = {str(path.relative_to(TEST_DIR)): sorted(n for n in imported(path)
                                                         if n.startswith("test_") or n == "conftest")
                 for path in modules()}
    offending = {name: found for name, found in offending.items() if found}
    assert not offending, f"move what they share into test/helpers or conftest.py: {offending}"


def test_each_fixture_is_declared_once() -> None:
    where: dict[str, list[str]] = {}
    for path in modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(is_fixture(d) for d in node.decorator_list):
                where.setdefault(node.name, []).append(str(path.relative_to(TEST_DIR)))
    twice = {name: files for name, files in where.items() if len(files) > 1}
    assert not twice, f"one declaration in conftest.py, or distinct names where they differ: {twice}"
    assert {"ros", "frame", "proposal_columns", "shipped"} <= where.keys()


def test_ci_runs_every_test() -> None:
    """`make test` leaves out exactly the tests marked slow, `make test-slow` runs exactly those, CI runs both."""
    makefile = (ROOT / "Makefile").read_text()
    recipes = dict(re.findall(r"^([\w-]+): setup\n\t(.+)$", makefile, re.MULTILINE))
    assert recipes["test"].endswith('-m "not slow" test'), recipes["test"]
    assert recipes["test-slow"].endswith("-m slow test"), recipes["test-slow"]
    commands = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert "make test" in commands and "make test-slow" in commands
    assert "slow:" in (ROOT / "setup.cfg").read_text(), "the marker is declared"
