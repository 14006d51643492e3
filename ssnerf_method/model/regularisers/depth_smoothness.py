"""Planar depth smoothness: flat surfaces kept flat where no depth is known (RegNeRF's depth smoothness, made planar),
for a model whose rendered depth makes normals (`ssnerf-label --depth-from`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Type

import torch
from torch import Tensor

from nerfstudio.model_components.renderers import DepthRenderer

from ssnerf_method.data.pixel_sampler import PATCH_RAYS, SMOOTHNESS_PATCHES_KEY
from ssnerf_method.model.losses import planar_smoothness_loss
from ssnerf_method.model.regularisers.base import PatchRequest, Regulariser, RegulariserConfig, patch_colours
from ssnerf_method.rendering.sampling import SamplingResult


@dataclass
class DepthSmoothnessConfig(RegulariserConfig):
    """Off by default. On `patches` 3x3 pixel patches of each batch, the second differences of the rendered inverse
    z-depth, which vanish on any plane, relative to the patch centre's and weighted down across colour edges. Turn it
    on (e.g. 0.1) for a depthless capture of mostly flat surfaces whose rendered depth is noisy."""

    _target: Type = field(default_factory=lambda: DepthSmoothness)
    name = "depth_smoothness"
    edge: float = 10.0
    """How fast the weight falls with the largest colour difference within a patch (RGB in [0, 1])."""
    patches: int = 32
    """Patches per batch (9 rays each, in place of uniform rays)."""

    def pixel_patches(self) -> Optional[PatchRequest]:
        return PatchRequest(self.patches) if self.mult > 0 else None


class DepthSmoothness(Regulariser):
    """`planar_smoothness_loss` on the batch's patches, from the field's expected depth (differentiable, unlike the
    rendered median)."""

    config: DepthSmoothnessConfig

    def __init__(self, config: DepthSmoothnessConfig) -> None:
        super().__init__(config)
        self.renderer = DepthRenderer(method="expected")

    def outputs(self, model, result: SamplingResult) -> Dict[str, Any]:
        final = result.levels[-1]
        return {"expected_depth": self.renderer(weights=final.weights, ray_samples=final.ray_samples)}

    def loss(self, model, outputs: Dict[str, Any], batch: Dict[str, Tensor]) -> Optional[Tensor]:
        patches = int(batch.get(SMOOTHNESS_PATCHES_KEY, 0))
        if patches == 0:
            return None
        rays = patches * PATCH_RAYS
        distance = outputs["expected_depth"][:rays]
        norm = outputs["directions_norm"][:rays] if "directions_norm" in outputs else torch.ones_like(distance)
        inverse = (norm / distance.clamp_min(1e-3)).view(patches, 3, 3)
        return self.config.mult * planar_smoothness_loss(inverse, patch_colours(model, batch, patches),
                                                         self.config.edge)
