"""Synthetic KITTI-like scans. Importing the package registers the `synthetic:` dataset format (see
`pass3d_ros.synthetic.specs`); the generator itself loads when the first such spec is resolved."""

from __future__ import annotations

from pass3d_ros.data.spec import DatasetFormat, register_format


def _synthetic_format() -> DatasetFormat:
    from pass3d_ros.synthetic import specs

    return DatasetFormat(specs.read_synthetic, specs.count_frames, specs.read_shard)


register_format("synthetic", _synthetic_format)
