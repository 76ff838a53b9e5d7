"""Per-point losses for stage 2: cross entropy and focal loss (Lin et al., ICCV 2017).

Multi-class focal loss: FL = -alpha_t (1 - p_t)^gamma log p_t, with p_t the probability of the true class.
alpha follows RetinaNet's binary convention carried to classes: a scalar alpha weights every foreground
class (car, pedestrian, cyclist) by alpha and background by 1 - alpha (alpha 0.25: background 0.75, as the
paper's alpha 0.25 / gamma 2 come from RetinaNet, where alpha weights the rare positives). A per-class
sequence sets the weights directly; None weights every class 1 (then gamma 0 gives cross entropy).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch.nn import functional

from pass3d_ros.classes import BACKGROUND, NUM_CLASSES


def class_alpha(alpha: float | Sequence[float] | None, num_classes: int = NUM_CLASSES) -> torch.Tensor | None:
    """Per-class weights (K,) for focal loss's alpha (see the module docstring), or None for all ones."""
    if alpha is None:
        return None
    if isinstance(alpha, (int, float)):
        weights = torch.full((num_classes,), float(alpha))
        weights[BACKGROUND] = 1.0 - float(alpha)
        return weights
    weights = torch.as_tensor(list(alpha), dtype=torch.float32)
    if weights.shape != (num_classes,):
        raise ValueError(f"alpha needs {num_classes} class weights, got {len(weights)}")
    return weights


def focal_loss(
    logits: torch.Tensor,
    target: torch.Tensor,
    alpha: float | Sequence[float] | None = 0.25,
    gamma: float = 2.0,
) -> torch.Tensor:
    """Mean focal loss of logits (..., K) against integer targets (...)."""
    logits = logits.reshape(-1, logits.shape[-1]).float()
    target = target.reshape(-1).long()
    log_p = functional.log_softmax(logits, dim=-1).gather(1, target.unsqueeze(1)).squeeze(1)
    loss = -log_p if gamma == 0 else -((1.0 - log_p.exp()).clamp_min(0.0) ** gamma) * log_p
    weights = class_alpha(alpha, logits.shape[-1])
    if weights is not None:
        loss = loss * weights.to(loss.device)[target]
    return loss.mean()


def cross_entropy(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean cross entropy of logits (..., K) against integer targets (...)."""
    return functional.cross_entropy(logits.reshape(-1, logits.shape[-1]).float(), target.reshape(-1).long())


def make_loss(name: str, alpha: float | Sequence[float] | None = 0.25, gamma: float = 2.0):
    """The loss function by name: 'ce' or 'focal'."""
    if name == "ce":
        return cross_entropy
    if name == "focal":
        return lambda logits, target: focal_loss(logits, target, alpha=alpha, gamma=gamma)
    raise ValueError(f"unknown loss {name!r}: choose ce or focal")
