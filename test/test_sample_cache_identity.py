"""The stage-1 sample caches are named after every file stage 1 runs, found from the imports: an edit to any of
them (split.py, protrusion.py, held_lines.py were once left out of a hand-written list) gives a new name."""

from __future__ import annotations

import shutil
from pathlib import Path

from pass3d_ros.training.samples import PACKAGE_ROOT, STAGE1_ENTRY, source_closure, stage1_identity


def test_the_closure_holds_every_stage1_module() -> None:
    names = {path.name for path in source_closure(STAGE1_ENTRY)}
    assert {"stage1.py", "held_lines.py", "split.py", "protrusion.py", "ring.py", "ring_field.py", "ground.py",
            "scanline.py", "refinement.py", "config.py"} <= names
    assert "pointnet2.py" not in names and "trainer.py" not in names, "stage 2 and training do not change proposals"


def test_an_edit_to_a_copy_of_each_stage1_module_gives_a_new_identity(tmp_path: Path) -> None:
    root = tmp_path / "pass3d_ros"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__", "*.pt"))
    before = stage1_identity(root)
    assert before == stage1_identity(PACKAGE_ROOT)
    seen = {before}
    for path in source_closure(STAGE1_ENTRY, root):
        original = path.read_text()
        path.write_text(original + "\n# edited\n")
        seen.add(stage1_identity(root))
        path.write_text(original)
        assert stage1_identity(root) == before
    assert len(seen) == len(source_closure(STAGE1_ENTRY, root)) + 1
