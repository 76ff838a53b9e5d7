"""A geometric stage-2 baseline: the class of a proposal from the size of its box, no learning.

The box is fitted to the proposal's points above its lowest `ground_margin` metres (stage 1's enlarged
boxes take in a ring of ground points that would inflate length and width). Those upper points get the
proposal's class with confidence 1; the low points are background with confidence 0.5, so a foreground
claim from an overlapping proposal wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pass3d_ros.classes import BACKGROUND, CAR, CYCLIST, PEDESTRIAN
from pass3d_ros.core.stage2 import canonical
from pass3d_ros.core.stage2.segmentation import (
    DEFAULT_MAX_PROPOSALS,
    SegmentResult,
    nearest_first,
    scatter_predictions,
)


@dataclass
class SizeRules:
    """Ranges (metres, inclusive) of box length >= width and height per class; anything else is background."""

    car_length: tuple[float, float] = (2.0, 6.5)
    car_width: tuple[float, float] = (1.1, 2.8)
    car_height: tuple[float, float] = (0.9, 2.4)
    pedestrian_length: tuple[float, float] = (0.0, 1.3)
    pedestrian_width: tuple[float, float] = (0.0, 1.1)
    pedestrian_height: tuple[float, float] = (1.0, 2.3)
    cyclist_length: tuple[float, float] = (1.3, 2.4)
    cyclist_width: tuple[float, float] = (0.0, 1.1)
    cyclist_height: tuple[float, float] = (1.1, 2.3)
    ground_margin: float = 0.2

    def classify(self, size: np.ndarray) -> np.ndarray:
        """Class ids (P,) for box sizes (P, 3) = (length, width, height)."""
        size = np.asarray(size, dtype=np.float64).reshape(-1, 3)

        def within(column: int, bounds: tuple[float, float]) -> np.ndarray:
            return (size[:, column] >= bounds[0]) & (size[:, column] <= bounds[1])

        out = np.full(len(size), BACKGROUND, dtype=np.int16)
        rules = (
            (CAR, self.car_length, self.car_width, self.car_height),
            (CYCLIST, self.cyclist_length, self.cyclist_width, self.cyclist_height),
            (PEDESTRIAN, self.pedestrian_length, self.pedestrian_width, self.pedestrian_height),
        )
        for label, length, width, height in rules:
            hit = (out == BACKGROUND) & within(0, length) & within(1, width) & within(2, height)
            out[hit] = label
        return out


class SizeRuleClassifier:
    """Stage-2 classifier with the network's segment() shape, deciding by box size alone."""

    kind = "size_rules"
    weights: str | None = None

    def __init__(self, rules: SizeRules | None = None, max_proposals: int = DEFAULT_MAX_PROPOSALS) -> None:
        self.rules = rules or SizeRules()
        self.max_proposals = max_proposals

    def upper_points(self, points: np.ndarray, member: np.ndarray) -> np.ndarray:
        """The members above the lowest `ground_margin` of the proposal (all of them if fewer than 3 remain)."""
        z = points[member, 2]
        upper = member[z > z.min() + self.rules.ground_margin]
        return upper if len(upper) >= 3 else member

    def segment(self, points: np.ndarray, members: list[np.ndarray]) -> SegmentResult:
        """Labels (N,) uint8, confidences (N,) float32 and the class of each proposal (-1 when empty or beyond the
        nearest `max_proposals`)."""
        points = np.asarray(points, dtype=np.float32)
        proposal_class = np.full(len(members), -1, dtype=np.int16)
        chosen = nearest_first(points, members, self.max_proposals).tolist()
        if not chosen:
            return SegmentResult(*scatter_predictions(len(points), np.zeros(0, np.int64), np.zeros(0), np.zeros(0)),
                                 proposal_class)
        uppers = [self.upper_points(points, np.asarray(members[i], dtype=np.int64)) for i in chosen]
        boxes = canonical.fit_box_members(points, uppers)
        size = boxes.size.copy()
        size[:, 2] = [np.ptp(points[members[i], 2]) for i in chosen]
        classes = self.rules.classify(size)
        proposal_class[chosen] = classes
        index, labels, conf = [], [], []
        for i, cls, upper in zip(chosen, classes, uppers, strict=True):
            member = np.asarray(members[i], dtype=np.int64)
            is_upper = np.isin(member, upper)
            index.append(member)
            labels.append(np.where(is_upper, cls, BACKGROUND).astype(np.uint8))
            conf.append(np.where(is_upper & (cls != BACKGROUND), 1.0, 0.5).astype(np.float32))
        return SegmentResult(
            *scatter_predictions(len(points), np.concatenate(index), np.concatenate(labels), np.concatenate(conf)),
            proposal_class,
        )

    def warm_up(self) -> None:
        """Compile (or load) the box-fit kernels, so the first frame does not pay for it."""
        canonical.warm_up()
