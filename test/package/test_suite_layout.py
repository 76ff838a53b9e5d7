"""The suite's own shape (issue 36): shared code lives in test/helpers and conftest.py, no test module imports another,
each fixture is declared once, and CI runs every test although `make test` leaves the slow ones out."""

from __future__ import annotations

import ast
import re
from pathlib import Path

TEST_DIR = Path(__file__).resolve().parents[1]
ROOT = TEST_DIR.parent


def modules() -> list[Path]:
    return sorted(TEST_DIR.rglob("*.py"))


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
    offending = {path.name: sorted(n for n in imported(path) if n.startswith("test_") or n == "conftest")
                 for path in modules()}
    offending = {name: found for name, found in offending.items() if found}
    assert not offending, f"move what they share into test/helpers or conftest.py: {offending}"


def test_each_fixture_is_declared_once() -> None:
    where: dict[str, list[str]] = {}
    for path in modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any(is_fixture(d) for d in node.decorator_list):
                where.setdefault(node.name, []).append(path.name)
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
