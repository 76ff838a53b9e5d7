"""The one object concept, checked: every road-user point of a labelled cloud has the (cluster id, class) of exactly
one object, and every object has points (docs/outputs.md)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from pass3d_ros.classes import FOREGROUND


def assert_one_object_per_point_group(labels: np.ndarray, cluster_id: np.ndarray,
                                      objects: Iterable[tuple[str | int, int]]) -> None:
    """`objects`: (id, class id) of each object (a string id as in vision_msgs, or an int); `labels`, `cluster_id`:
    the labelled cloud's columns."""
    keys = [(int(object_id), int(label)) for object_id, label in objects]
    assert len(set(keys)) == len(keys), f"two objects share an id and class: {sorted(keys)}"
    assert len({object_id for object_id, _ in keys}) == len(keys), f"two objects share an id: {sorted(keys)}"
    road = np.isin(labels, FOREGROUND)
    assert (cluster_id[road] >= 0).all(), "a road-user point outside every proposal"
    groups = {(int(c), int(k)) for c, k in zip(cluster_id[road], labels[road], strict=True)}
    assert groups == set(keys), (f"points without an object: {sorted(groups - set(keys))}; objects without points: "
                                 f"{sorted(set(keys) - groups)}")
