"""Semantic affinity: sparse class labels in the frames (clicks, scribbles, partly annotated frames; not the viewer's
strokes, which are rays) spread over regions of like colour, a dense CRF's pairwise term on pixel patches."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Type

import torch
from torch import Tensor

from ssnerf_method.data.pixel_sampler import PATCH_RAYS, SMOOTHNESS_PATCHES_KEY
from ssnerf_method.model.losses import colour_affinity_loss
from ssnerf_method.model.regularisers.base import PatchRequest, Regulariser, RegulariserConfig, patch_colours


@dataclass
class SemanticAffinityConfig(RegulariserConfig):
    """On by default. On `patches` 3x3 pixel patches of each batch, a neighbour of like colour is pulled to the centre
    pixel's class probabilities; pairs of labelled pixels are left to their labels, and the patches are drawn only
    while the class labels are sparse and only from partly labelled frames, so densely labelled data trains as
    without it. Relative to the class loss (its weight and the gradient balancer's multiplier apply)."""

    _target: Type = field(default_factory=lambda: SemanticAffinity)
    name = "semantic_affinity"
    mult: float = 1.0
    edge: float = 10.0
    """How fast the affinity falls with the largest colour difference between two pixels (RGB in [0, 1])."""
    stride: int = 2
    """Pixels between neighbouring rays of a patch (with the depth smoothness on too, the patches are its)."""
    patches: int = 32
    """Patches per batch (9 rays each, in place of uniform rays)."""

    def pixel_patches(self) -> Optional[PatchRequest]:
        return PatchRequest(self.patches, self.stride, only_while_class_sparse=True) if self.mult > 0 else None


class SemanticAffinity(Regulariser):
    """`colour_affinity_loss` on the batch's patches, for a model that renders classes."""

    config: SemanticAffinityConfig

    def active(self, model) -> bool:
        return super().active(model) and model.class_spec is not None

    def loss(self, model, outputs: Dict[str, Any], batch: Dict[str, Tensor]) -> Optional[Tensor]:
        patches = int(batch.get(SMOOTHNESS_PATCHES_KEY, 0))
        if patches == 0:
            return None
        spec, rays = model.class_spec, patches * PATCH_RAYS
        probabilities = torch.softmax(outputs[spec.prediction_key][:rays].float(), dim=-1).view(patches, PATCH_RAYS, -1)
        label = spec.label(batch, model.num_classes).to(model.device)[:rays]
        labelled = spec.kind.valid(label).view(patches, PATCH_RAYS)
        balance = model.balancer.multiplier(spec.name) if model.balancer is not None else 1.0
        affinity = colour_affinity_loss(probabilities, patch_colours(model, batch, patches), labelled,
                                        self.config.edge)
        return self.config.mult * spec.weight * balance * affinity
