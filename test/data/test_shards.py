"""Data-parallel shards: every frame position goes to exactly one rank, and a synthetic shard generates only its
own frames (generation is the expensive part of building training samples)."""

from __future__ import annotations

import pytest

from pass3d_ros.data.spec import open_datasets_shard
from pass3d_ros.synthetic import dataset, specs

SPECS = ["synthetic:frames=3,seed=4", "synthetic:frames=2,seed=5,start=7"]


def test_shards_partition_the_frames_and_skip_generation(monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[tuple[int, int]] = []
    real = dataset.generate_frame

    def counting(seed: int, index: int, *args: object, **kwargs: object):
        made.append((seed, index))
        return real(seed, index, *args, **kwargs)

    monkeypatch.setattr(specs, "generate_frame", counting)  # where the spec's reader calls it
    by_rank = {rank: list(open_datasets_shard(SPECS, rank, 2)) for rank in (0, 1)}
    assert [len(frames) for frames in by_rank.values()] == [5, 5]
    for position in range(5):
        owners = [rank for rank, frames in by_rank.items() if frames[position] is not None]
        assert owners == [position % 2]
    assert sorted(made) == [(4, 0), (4, 1), (4, 2), (5, 7), (5, 8)], "each frame generated once, by its owner"
    assert by_rank[1][3].name == real(5, 7).name
