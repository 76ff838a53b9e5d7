"""The stage-1 sample caches are named after every file stage 1 runs, found from the imports: an edit to any of
them (split.py, protrusion.py, the held laser lines were once left out of a hand-written list) gives a new name."""

from __future__ import annotations

import shutil
from pathlib import Path

from pass3d_ros.training.samples import (
    PACKAGE_ROOT,
    STAGE1_PACKAGES,
    package_modules,
    source_closure,
    stage1_identity,
)


def closure(root: Path = PACKAGE_ROOT) -> list[Path]:
    return source_closure([name for package in STAGE1_PACKAGES for name in package_modules(package, root)], root)


def test_the_closure_holds_every_file_of_the_stage1_package() -> None:
    files = closure()
    for package in ("stage1", "stream"):
        assert set((PACKAGE_ROOT / "core" / package).glob("*.py")) <= set(files)
    assert {"lines.py", "mounting.py", "split.py", "protrusion.py", "ring_field.py"} <= {path.name for path in files}
    assert not any("stage2" in path.parts or path.name == "trainer.py" for path in files), \
        "stage 2 and training do not change the proposals"


def test_an_edit_to_a_copy_of_each_stage1_module_gives_a_new_identity(tmp_path: Path) -> None:
    root = tmp_path / "pass3d_ros"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__", "*.pt"))
    before = stage1_identity(root)
    assert before == stage1_identity(PACKAGE_ROOT)
    seen = {before}
    for path in closure(root):
        original = path.read_text()
        path.write_text(original + "\n# edited\n")
        seen.add(stage1_identity(root))
        path.write_text(original)
        assert stage1_identity(root) == before
    assert len(seen) == len(closure(root)) + 1
