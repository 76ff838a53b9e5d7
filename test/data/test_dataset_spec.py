"""`FORMAT:PATH` specs resolved once into a Dataset: the format registry, a data layer that loads nothing above it,
and `pass3d_evaluate` parsing each spec once and opening a bag once (offline: metadata count + one read)."""

from __future__ import annotations

import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from pass3d_ros.core.stage1 import synthetic_scan
from pass3d_ros.data import bag as bag_module
from pass3d_ros.data import spec
from pass3d_ros.data.bag_convert import convert
from pass3d_ros.data.frame import Frame
from pass3d_ros.data.spec import Dataset, DatasetError, DatasetFormat, register_format, resolve_dataset
from pass3d_ros.tools import evaluate

FRAMES = 2

# Imports every data-layer module, then reports what of pass3d_ros above the data layer got loaded, what a
# synthetic spec does before and after `import pass3d_ros.synthetic`, and when the generator itself loads.
DATA_LAYER_ONLY = """
import importlib, pkgutil, sys
import pass3d_ros.data
for info in pkgutil.iter_modules(pass3d_ros.data.__path__):
    importlib.import_module(f"pass3d_ros.data.{info.name}")
from pass3d_ros.data.spec import DatasetError, resolve_dataset
below = ("pass3d_ros.data", "pass3d_ros.msgs", "pass3d_ros.classes", "pass3d_ros.msgs.errors")
print("above:", sorted(m for m in sys.modules if m.startswith("pass3d_ros.") and not m.startswith(below)))
try:
    resolve_dataset("synthetic:frames=2")
except DatasetError as exc:
    print("before:", exc)
import pass3d_ros.synthetic
print("generator on import:", "pass3d_ros.synthetic.dataset" in sys.modules)
print("count:", resolve_dataset("synthetic:frames=2").count())
print("generator after resolve:", "pass3d_ros.synthetic.dataset" in sys.modules)
"""


def test_the_data_layer_loads_nothing_above_it_and_synthetic_registers_itself() -> None:
    out = subprocess.run([sys.executable, "-c", DATA_LAYER_ONLY], capture_output=True, text=True, timeout=120,
                         check=True).stdout.splitlines()
    assert out[0] == "above: []", out
    assert out[1].startswith("before: dataset spec 'synthetic:frames=2': unknown format 'synthetic'"), out
    assert out[2:] == ["generator on import: False", "count: 2", "generator after resolve: True"], out


def test_unknown_and_malformed_specs_name_the_registered_formats() -> None:
    import pass3d_ros.synthetic  # noqa: F401

    with pytest.raises(DatasetError, match=r"unknown format 'nosuch', formats: kitti_object, .*bag.*synthetic"):
        resolve_dataset("nosuch:/x")
    with pytest.raises(DatasetError, match="expected FORMAT:PATH"):
        resolve_dataset("kitti_object")


def _frames(path: str) -> Iterator[Frame]:
    points = np.zeros((64 * 360, 4), dtype=np.float32)
    points[:, :3] = synthetic_scan(points_per_ring=360)[:, :3]
    for k in range(FRAMES):
        labels = np.zeros(len(points), dtype=np.uint8)
        yield Frame(name=f"{path}{k}", points=points.copy(), stamp_ns=0, labels=labels)


@pytest.fixture
def counted(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """A `counted:` format whose loader, reader and counter count their calls, plus `parsed`: one per Dataset
    made from a string (resolve_dataset makes one per parse)."""
    monkeypatch.setattr(spec, "_LOADERS", dict(spec._LOADERS))
    monkeypatch.setattr(spec, "_LOADED", {})
    calls: Counter = Counter()

    def read(path: str) -> Iterator[Frame]:
        calls["read"] += 1
        return _frames(path)

    def count(path: str) -> int:
        calls["count"] += 1
        return FRAMES

    def loader() -> DatasetFormat:
        calls["loader"] += 1
        return DatasetFormat(read, count)

    class Counted(Dataset):
        def __init__(self, *args: object, **kwargs: object) -> None:
            calls["parsed"] += 1
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(spec, "Dataset", Counted)
    register_format("counted", loader)
    return calls


def test_a_dataset_reads_counts_and_shards_with_its_reader_looked_up_once(counted: Counter) -> None:
    first, again = resolve_dataset("counted:a"), resolve_dataset("counted:b")
    assert (str(first), first.format, first.path) == ("counted:a", "counted", "a")
    assert resolve_dataset(first) is first
    assert counted == {"loader": 1, "parsed": 2}
    assert first.count() == FRAMES and [f.name for f in first.frames()] == ["a0", "a1"]
    shard = list(again.shard(lambda k: k == 1))  # no read_shard: frames made, then dropped
    assert shard[0] is None and shard[1].name == "b1"
    assert counted == {"loader": 1, "parsed": 2, "count": 1, "read": 2}


@pytest.mark.parametrize("mode", [["--stage1-only"], ["--classifier", "size_rules"]])
def test_evaluate_parses_each_spec_once(counted: Counter, mode: list[str], capsys: pytest.CaptureFixture) -> None:
    assert evaluate.main(["--data", "counted:a", "--data", "counted:b", "--no-progress", *mode]) == 0
    assert "over 4 frame(s)" in capsys.readouterr().out
    assert counted == {"loader": 1, "parsed": 2, "count": 2, "read": 2}


@pytest.fixture
def bag_opens(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Every path the bag module opens with rosbags, in order."""
    opened: list[Path] = []
    real = bag_module._open_reader

    def counting(path: Path) -> object:
        opened.append(Path(path))
        return real(path)

    monkeypatch.setattr(bag_module, "_open_reader", counting)
    return opened


@pytest.mark.ros
def test_evaluate_opens_a_bag_once_live_and_twice_offline(counted: Counter, bag_opens: list[Path],
                                                           tmp_path: Path) -> None:
    bag = tmp_path / "labelled"
    convert(["counted:c"], bag, with_labels=True, progress=False, log=lambda _: None)
    bag_opens.clear()
    live = ["--live", "--lockstep", "--classifier", "size_rules", "--no-progress"]
    assert evaluate.main(["--data", f"bag:{bag}", *live]) == 0
    assert bag_opens == [bag], "live: topic, count, label check and replay share one open"
    bag_opens.clear()
    assert evaluate.main(["--data", f"bag:{bag}", "--classifier", "size_rules", "--no-progress"]) == 0
    assert bag_opens == [bag, bag], "offline: the count from the metadata, then one read"
    bag_opens.clear()
    assert evaluate.main(["--data", "counted:d", *live]) == 0
    assert len(bag_opens) == 1 and bag_opens[0].name == "input_bag", "the converted bag, opened once"
    assert counted["parsed"] == 4 and counted["loader"] == 1
