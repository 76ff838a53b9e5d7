"""`warm_up` compiles every numba kernel stage 1 calls, with the types real scans bring: a node's first scans then run
compiled code (a kernel first compiled on a live scan held it for 0.5-2 s on a fresh install)."""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import pass3d_ros
import pass3d_ros.core.stage1 as stage1_package
import pass3d_ros.synthetic  # registers the synthetic: format
from pass3d_ros.core.stage1 import Stage1Config, propose, warm_up
from pass3d_ros.data.spec import open_dataset


def tilt(roll_deg: float, pitch_deg: float) -> np.ndarray:
    """A rotation about x, then y."""
    r, p = np.deg2rad(roll_deg), np.deg2rad(pitch_deg)
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(r), -np.sin(r)], [0.0, np.sin(r), np.cos(r)]])
    about_y = np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])
    return about_y @ about_x


def compiled(package=stage1_package) -> dict[str, int]:
    """Signatures compiled (or loaded from the cache) so far, per numba kernel of the package's modules."""
    counts = {}
    for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                counts[f"{info.name}.{name}"] = len(value.signatures)
    return counts


@pytest.mark.parametrize("sensor", ["vlp32c", "hdl64e"])
def test_no_kernel_compiles_after_warm_up(sensor: str) -> None:
    warm_up()
    before = compiled()
    frame = next(iter(open_dataset(f"synthetic:sensor={sensor},frames=1,seed=11")))
    points = frame.points
    config = Stage1Config()
    first = propose(points, frame.ring, config)  # the driver's ring field, or (KITTI) the firing order
    lines = propose(points[::-1].copy(), None, config).lines  # no firing order: laser lines searched
    shuffled = np.random.default_rng(0).permutation(len(points))
    propose(points[shuffled], None, config, lines)  # held lines, the ground on two threads, canonical order
    propose(points, frame.ring, config, level=tilt(3.0, -2.0),
            scale=first.sensor)  # levelled, the sensor's scale held
    grew = {name: (count, compiled()[name]) for name, count in before.items() if compiled()[name] != count}
    assert grew == {}, f"compiled after warm_up (kernel: signatures before, after): {grew}"


def test_no_core_kernel_compiles_after_the_nodes_warm_ups() -> None:
    """The segmentation node's warm-ups (objects, tracker, shapes, checks, stage 2) and stage 1's, then a tracked
    synthetic drive with poses: no kernel of the core compiles."""
    from pass3d_ros.core import scan_checks, tracked_scan
    from pass3d_ros.core.objects import warm_up as warm_up_objects
    from pass3d_ros.core.stage2 import open_classifier
    from pass3d_ros.core.stream import shapes
    from pass3d_ros.evaluation.tracking import evaluate_tracking

    classifier = open_classifier(None)
    warm_up()
    for step in (scan_checks.warm_up, shapes.warm_up, warm_up_objects, tracked_scan.warm_up, classifier.warm_up):
        step()
    before = compiled(pass3d_ros.core)
    spec = "synthetic:drive=3,seed=7,sensor=vlp16"
    evaluate_tracking(((spec, frame) for frame in open_dataset(spec)), Stage1Config(), classifier, scan_rate_hz=10)
    after = compiled(pass3d_ros.core)
    grew = {name: (count, after[name]) for name, count in before.items() if after[name] != count}
    assert grew == {}, f"compiled after the warm-ups (kernel: signatures before, after): {grew}"
