"""Stage 1 on two threads gives what it gives on one (rule P2, docs/experiments/sensors.md): clustering's search and
the ground fit split between the calling thread and the ground thread, the joins kept in ring order."""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import pass3d_ros.synthetic  # noqa: F401  (registers the synthetic: format)
from pass3d_ros.core.stage1 import Stage1Config, propose, scanline
from pass3d_ros.core.stage1 import ground as ground_module
from pass3d_ros.data.spec import open_dataset


class CountingPool(ThreadPoolExecutor):
    """One worker thread that counts what it was given."""

    def __init__(self) -> None:
        super().__init__(max_workers=1)
        self.submitted: list[str] = []

    def submit(self, fn, /, *args, **kwargs):
        self.submitted.append(getattr(fn, "__name__", str(fn)))
        return super().submit(fn, *args, **kwargs)


@pytest.fixture(scope="module")
def street() -> tuple[np.ndarray, np.ndarray]:
    frame = next(iter(open_dataset("synthetic:sensor=vlp32c,frames=1,seed=7")))
    assert frame.ring is not None
    return frame.points, frame.ring


def same(one, two) -> None:
    for field in ("ring", "ground", "cluster_id", "cluster_id2", "gives_way"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field), err_msg=field)
    assert [(*b.center, *b.size, b.yaw) for b in one.boxes] == [(*b.center, *b.size, b.yaw) for b in two.boxes]


def test_clustering_search_split_gives_the_same_labels(street) -> None:
    points, ring = street
    use = ~propose(points, ring).ground
    assert use.sum() >= scanline.TWO_THREADS_MIN_POINTS
    config = Stage1Config()
    with CountingPool() as pool:
        labels, n = scanline.cluster_scanlines(points, ring, use, config, pool)
        assert pool.submitted == ["_search_rings"]
    alone, n_alone = scanline.cluster_scanlines(points, ring, use, config)
    assert n == n_alone and n > 10
    np.testing.assert_array_equal(labels, alone)


def test_ground_split_gives_the_same_fit(street) -> None:
    points, _ = street
    config = Stage1Config()
    with CountingPool() as pool:
        two = ground_module.fit_ground(points, config, in_scan_order=False, pool=pool)
        assert sorted(pool.submitted) == ["_sample", "_test_and_count"]
    one = ground_module.fit_ground(points, config, in_scan_order=False)
    np.testing.assert_array_equal(two.ground, one.ground)
    np.testing.assert_array_equal(two.planes, one.planes)
    np.testing.assert_array_equal(two.local.hist, one.local.hist)


def test_planes_fitted_beside_then_tested_on_two_threads_give_the_same_fit(street) -> None:
    """The planes fitted alone (on the ground thread, beside the rings), the test then shared by both threads."""
    points, _ = street
    config = Stage1Config()
    planes = ground_module.fit_planes(points, config)
    with CountingPool() as pool:
        two = ground_module.ground_of_planes(planes, config, pool)
        assert pool.submitted == ["_test_and_count"]
    one = ground_module.fit_ground(points, config)
    np.testing.assert_array_equal(two.ground, one.ground)
    np.testing.assert_array_equal(two.planes, one.planes)
    np.testing.assert_array_equal(two.local.hist, one.local.hist)


@pytest.mark.parametrize("ring_field", [True, False])
def test_propose_on_two_threads_equals_one(street, ring_field: bool) -> None:
    points, ring = street
    ring = ring if ring_field else None
    one, two = Stage1Config(ground_thread=False), Stage1Config()
    same(propose(points, ring, one), propose(points, ring, two))
    if not ring_field:  # held laser lines: the ground fitted on both threads
        lines = propose(points, None, one).lines
        assert lines is not None and not lines.empty
        same(propose(points, None, one, lines), propose(points, None, two, lines))


def test_small_scans_stay_on_one_thread() -> None:
    rng = np.random.default_rng(0)
    points = np.zeros((2000, 4), dtype=np.float32)
    points[:, :3] = rng.uniform(-20, 20, (2000, 3))
    ring = rng.integers(0, 16, 2000).astype(np.uint16)
    with CountingPool() as pool:
        scanline.cluster_scanlines(points, ring, np.ones(2000, dtype=bool), Stage1Config(), pool)
        ground_module.fit_ground(points, Stage1Config(), pool=pool)
        assert pool.submitted == []


def _propose_in_child(points: np.ndarray, ring: np.ndarray, out) -> None:
    """A forked child's stage 1 on the ground thread: its proposal count, sent back."""
    out.put(propose(points, ring, Stage1Config()).n_proposals)


def test_a_forked_child_runs_stage_1_on_its_own_ground_thread(street) -> None:
    """The ground thread does not survive a fork: a child given the parent's pool waited on it for ever."""
    points, ring = street
    expected = propose(points, ring, Stage1Config()).n_proposals  # the parent's ground thread is started
    context = mp.get_context("fork")
    out = context.Queue()
    child = context.Process(target=_propose_in_child, args=(points, ring, out))
    child.start()
    child.join(60)
    if child.is_alive():
        child.kill()
        child.join()
        pytest.fail("stage 1 hung in a forked child")
    assert child.exitcode == 0
    assert out.get(timeout=10) == expected


@pytest.mark.parametrize(("ring", "problem"), [(np.float32, "integers"), (bool, "integers"), (70000, "up to 65535")])
def test_a_ring_field_stage_1_cannot_read_is_refused(street, ring, problem: str) -> None:
    """A float or bool ring field crashed deep in the ring-field reader (IndexError); an index past 65535 wrapped onto
    another laser silently. Both are refused, naming the problem."""
    points, field = street
    bad = field.astype(ring) if isinstance(ring, type) else field.astype(np.int64) + ring
    with pytest.raises(ValueError, match=problem):
        propose(points, bad)
