"""One stream state for every path: the input checks a live scan passes (absurd points left out, intensities read
as 0..1 on the stream's held scale, a ring field past the lasers not read) apply offline too."""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import pass3d_ros.core.stage1 as stage1
from pass3d_ros.core import scan_checks
from pass3d_ros.core.stage1 import Stage1Config, synthetic_scan
from pass3d_ros.core.stream import ScanStream
from pass3d_ros.data.frame import Frame
from pass3d_ros.evaluation.offline import evaluate_stage1


def test_prepare_repairs_a_scan_and_says_what_it_did() -> None:
    stream = ScanStream()
    pts = synthetic_scan(n_rings=16, points_per_ring=90)
    pts[:, 3] = np.linspace(0.0, 1.0, len(pts))
    bright = pts.copy()
    bright[:, 3] *= 255.0
    bright[0, :3] = [np.inf, 0.0, 0.0]
    ring = np.repeat(np.arange(16), 90).astype(np.uint16)
    scan = stream.prepare(bright, ring, Stage1Config(sensor="vlp16"))
    assert len(scan.points) == len(pts) - 1 and scan.kept[0] == 1
    np.testing.assert_allclose(scan.points[:, 3], pts[1:, 3], atol=1e-6)
    assert bright[5, 3] == pts[5, 3] * np.float32(255.0), "the caller's array is left as it was"
    assert {note.topic for note in scan.notes} == {"x/y/z", "intensity-scale"}
    np.testing.assert_array_equal(scan.ring, ring[1:])
    wide = stream.prepare(pts, (ring * 2).astype(np.uint16), Stage1Config(sensor="vlp16"))
    assert wide.ring is None and wide.field is not None and any(n.topic == "ring" for n in wide.notes)
    assert stream.first_notes(scan.notes) == scan.notes
    assert stream.first_notes(scan.notes) == []


def test_offline_stage1_reads_a_0_255_stream_as_the_node_does(capsys) -> None:
    pts = synthetic_scan()
    pts[:, 3] = np.linspace(0.0, 1.0, len(pts))
    bright = pts.copy()
    bright[:, 3] *= 255.0
    labels = np.zeros(len(pts), np.uint8)
    unit = evaluate_stage1(iter([("a", Frame("0", pts, labels=labels))]), Stage1Config())
    scaled = evaluate_stage1(iter([("b", Frame("0", bright, labels=labels))]), Stage1Config())
    assert unit["per_frame"][0]["proposals"] == scaled["per_frame"][0]["proposals"]
    err = capsys.readouterr().err
    assert "b: intensity: values 0..255 after intensity_scale 1, expected 0..1; divided by 255" in err
    assert "a: " not in err


def test_no_returns_at_the_origin_or_inside_min_range_are_left_out() -> None:
    """Ouster and Autoware drivers fill the grid with (0, 0, 0) for no-returns; the vehicle's own returns sit within
    min_range: neither reaches stage 1, and the kept indices say where the rest came from."""
    pts = synthetic_scan(n_rings=16, points_per_ring=90)
    pts[::10, :3] = 0.0
    pts[5, :3] = [0.2, 0.1, 0.0]
    scan = ScanStream().prepare(pts, None, Stage1Config(min_range=0.5))
    gone = np.zeros(len(pts), bool)
    gone[::10] = True
    gone[5] = True
    np.testing.assert_array_equal(scan.kept, np.flatnonzero(~gone))
    assert not [n for n in scan.notes if n.topic == "x/y/z"], "a driver's convention, not a warning"
    assert len(ScanStream().prepare(pts, None, Stage1Config(min_range=0.0)).points) == len(pts) - int(gone.sum()) + 1


def test_prepare_refuses_points_without_intensity_and_a_ring_field_of_another_length() -> None:
    """N x 3 points had their missing intensity column read out of bounds by the checks' compiled kernel (then an
    IndexError); a ring field shorter than the points was cut silently by the kept points (or an IndexError)."""
    pts = synthetic_scan(n_rings=16, points_per_ring=90)
    ring = np.repeat(np.arange(16), 90).astype(np.uint16)
    for bad in (pts[:, :3], pts[:, 0], pts[:, :, None]):
        with pytest.raises(ValueError, match="points must be N x 4"):
            ScanStream().prepare(bad, None, Stage1Config())
    with_no_return = np.vstack([pts, np.full((1, 4), np.nan, np.float32)])
    for bad_ring in (ring, ring[:, None], np.concatenate([ring, ring])):
        with pytest.raises(ValueError, match="ring field has shape"):
            ScanStream().prepare(with_no_return, bad_ring, Stage1Config())
    half = ScanStream().prepare(pts.astype(np.float16), ring, Stage1Config())  # no kernel reads float16: as float32
    assert half.points.dtype == np.float32 and len(half.points) == len(pts)


def _signatures() -> dict[str, int]:
    """Signatures compiled (or loaded) so far per numba kernel of stage 1 and the input checks."""
    found = pkgutil.walk_packages(stage1.__path__, f"{stage1.__name__}.")
    modules = [importlib.import_module(info.name) for info in found]
    counts = {}
    for module in [*modules, scan_checks]:
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                counts[f"{module.__name__}.{name}"] = len(value.signatures)
    return counts


def test_a_read_only_strided_or_float64_scan_compiles_no_kernel_after_warm_up() -> None:
    """The checks and stage 1 are compiled for contiguous, writeable float32 scans: a read-only scan (np.frombuffer
    over a message's bytes, a memory map) compiled a read-only variant of every kernel it reached (28 s on a fresh
    install), a float64 or strided one the checks' kernel again."""
    stage1.warm_up()
    scan_checks.warm_up()
    pts = synthetic_scan(n_rings=16, points_per_ring=90)
    ring = np.repeat(np.arange(16), 90).astype(np.uint16)
    read_only, read_only_ring = pts.copy(), ring.copy()
    read_only.setflags(write=False)
    read_only_ring.setflags(write=False)
    wide = np.zeros((len(pts), 6), np.float32)
    wide[:, :4] = pts
    config = Stage1Config(n_rings=16)
    reference = ScanStream().propose(ScanStream().prepare(pts, ring, config), config)
    before = _signatures()
    for points, field in ((read_only, read_only_ring), (pts.astype(np.float64), ring), (wide[:, :4], ring[::1])):
        stream = ScanStream()
        result = stream.propose(stream.prepare(points, field, config), config)
        np.testing.assert_array_equal(result.cluster_id, reference.cluster_id)
    after = _signatures()
    grew = {name: (count, after[name]) for name, count in before.items() if after[name] != count}
    assert grew == {}, f"compiled after warm_up (kernel: signatures before, after): {grew}"
