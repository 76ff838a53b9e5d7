"""Both nodes in one process, joined in memory: stage 1 hands each frame's arrays to stage 2.

The cluster node gives a `ProposalFrame` to a sink (the segmentation node's `submit_proposals`) instead of
serialising 120k points into /pass3d/proposals and deserialising them again; it still publishes that cloud
(and the marker arrays) while something else subscribes. The two-process layout keeps the message path. The frame
also carries the decoded input (`source`, a view of the message: no copy), so the segmentation node's `output_layout`
as_input and `publish_background` work here whatever the cluster node's own values (pass3d_ros.ros.input_layout).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from pass3d_ros.ros.cluster_proposal_node import ClusterProposalNode
from pass3d_ros.ros.proposals import ProposalFrame
from pass3d_ros.ros.segmentation_node import SegmentationNode


def in_memory_factories() -> list[Callable[..., Node]]:
    """Factories of the cluster node and the segmentation node, in this order, joined in memory.

    Each takes the node constructor's keywords (context, parameter_overrides); a frame the cluster node finishes
    before the segmentation node exists is dropped.
    """
    segmenter: list[SegmentationNode] = []

    def sink(frame: ProposalFrame) -> None:
        if segmenter:
            segmenter[0].submit_proposals(frame)

    def cluster(**kwargs: Any) -> ClusterProposalNode:
        return ClusterProposalNode(sink=sink, **kwargs)

    def segmentation(**kwargs: Any) -> SegmentationNode:
        segmenter.append(SegmentationNode(in_memory=True, **kwargs))
        return segmenter[-1]

    # named after the node classes: `pass3d_pipeline --help` lists them by name and module summary
    return [functools.update_wrapper(cluster, ClusterProposalNode, updated=()),
            functools.update_wrapper(segmentation, SegmentationNode, updated=())]
