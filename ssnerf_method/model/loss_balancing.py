"""Gradient-norm balancing of the property losses against RGB's, on the shared encoder F_enc.

Every property's loss reaches F_enc (through its decoder and through the rendering weights). Measured on the
all-properties `ssnerf-lite` at step 0 on the default scene, the properties send gradients 2 (shading) to 45
(keypoints) times larger than RGB's into it; Adam
normalises each parameter's update by the size of its whole gradient, so the properties then set the direction of
F_enc's updates and RGB learns at a fraction of its rate. The balancer measures, every few steps, the norm of each
loss's gradient with respect to F_enc's parameters and scales each property's loss so that its norm is at most
`ratio` times RGB's (never above the paper's weight: the multiplier is at most 1). The heads and decoders only a
property trains learn as before (Adam is blind to the scale of a gradient that only one loss sends).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence

import torch
from torch import Tensor, nn


class LossBalancer(nn.Module):
    """Per-property loss multipliers in (0, 1], from smoothed gradient norms on the shared encoder.

    Args:
        names: the balanced properties (RGB excluded).
        ratio: the largest gradient norm on F_enc a property may have, as a multiple of RGB's.
        momentum: smoothing of the measured norms across measurements (0 keeps only the latest).
    """

    def __init__(self, names: Sequence[str], ratio: float, momentum: float = 0.5) -> None:
        super().__init__()
        self.names = list(names)
        self.ratio = ratio
        self.momentum = momentum
        self.register_buffer("norms", torch.zeros(len(self.names)))
        self.register_buffer("rgb_norm", torch.zeros(()))
        self.register_buffer("factors", torch.ones(len(self.names)))

    def multiplier(self, name: str) -> Tensor:
        """The current multiplier of a property's loss (1 before the first measurement)."""
        return self.factors[self.names.index(name)]

    @staticmethod
    def gradient_norm(loss: Tensor, parameters: List[nn.Parameter]) -> float:
        """The norm of `loss`'s gradient with respect to `parameters` (the graph is kept for the training step)."""
        if not loss.requires_grad:
            return 0.0
        gradients = torch.autograd.grad(loss, parameters, retain_graph=True, allow_unused=True)
        return float(sum(float((g.detach() ** 2).sum()) for g in gradients if g is not None)) ** 0.5

    def update(self, rgb_loss: Tensor, losses: Dict[str, Tensor], parameters: List[nn.Parameter]) -> None:
        """Measure the gradient norms of RGB's and each property's (unscaled, λ-weighted) loss on `parameters` and
        set the multipliers. Without an RGB gradient (RGB's weight 0) every multiplier stays 1."""
        rgb = self.gradient_norm(rgb_loss, parameters)
        norms = torch.tensor([self.gradient_norm(losses[name], parameters) for name in self.names])
        first = bool(self.rgb_norm == 0)
        keep = 0.0 if first else self.momentum
        self.rgb_norm.fill_(keep * float(self.rgb_norm) + (1.0 - keep) * rgb)
        self.norms.copy_(keep * self.norms + (1.0 - keep) * norms.to(self.norms))
        if float(self.rgb_norm) == 0.0:
            self.factors.fill_(1.0)
            return
        allowed = self.ratio * self.rgb_norm / self.norms.clamp_min(1e-12)
        self.factors.copy_(allowed.clamp(max=1.0))

    def scale(self, losses: Dict[str, Tensor], rgb_name: str, prefixes: Sequence[str], parameters: List[nn.Parameter],
              measure: bool) -> None:
        """Scale each balanced property's `<prefix><name>_loss` in `losses` (every level's) by its multiplier, after
        re-measuring the gradient norms on `parameters` (F_enc's) from the final level's losses if `measure`."""
        if measure:
            self.update(losses[f"{rgb_name}_loss"], {name: losses[f"{name}_loss"] for name in self.names}, parameters)
        for name in self.names:
            for prefix in prefixes:
                losses[f"{prefix}{name}_loss"] = losses[f"{prefix}{name}_loss"] * self.multiplier(name)


@dataclass
class LossBalancerConfig:
    """Gradient-norm balancing (`LossBalancer`): off (`ratio` None) trains the paper's fixed weighted sum."""

    ratio: Optional[float] = None
    """If set, every `every` steps each property's loss is scaled (by at most 1) so that its gradient into F_enc is at
    most this multiple of RGB's."""
    every: int = 100
    """Steps between two measurements of the gradient norms (each costs one backward pass per loss)."""
