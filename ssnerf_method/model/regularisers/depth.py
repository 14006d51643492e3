"""Depth supervision: nerfstudio's depth-nerfacto loss on the rays whose frame has a depth map (`depth_file_path`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Type

import torch
from torch import Tensor

from nerfstudio.model_components.losses import DepthLossType, depth_loss

from ssnerf_method.data.dataset import DEPTH_KEY
from ssnerf_method.model.regularisers.base import Regulariser, RegulariserConfig
from ssnerf_method.rendering.sampling import SamplingResult


@dataclass
class DepthLossConfig(RegulariserConfig):
    """Off by default: depth is scored, never trained (the paper's data has no depth). Turn it on for a capture whose
    depth maps you trust (an RGB-D sensor): it pulls every level's weights, the proposal networks' too, to the
    measured surface."""

    _target: Type = field(default_factory=lambda: DepthLoss)
    name = "depth"
    loss_type: DepthLossType = DepthLossType.DS_NERF
    """DS-NeRF's loss (weights pulled into a narrow window around the true depth) or URF's."""
    sigma: float = 0.01
    """Width of the window around the true depth, in scene units (as nerfstudio's `depth_sigma`)."""


class DepthLoss(Regulariser):
    """nerfstudio's depth loss against the frames' z-depth maps, averaged over the levels (as depth-nerfacto); pixels
    without depth (0) carry none."""

    config: DepthLossConfig

    def outputs(self, model, result: SamplingResult) -> Dict[str, Any]:
        levels = result.levels
        return {"depth_weights_list": result.weights_list or [level.weights for level in levels],
                "depth_ray_samples_list": result.ray_samples_list or [level.ray_samples for level in levels]}

    def loss(self, model, outputs: Dict[str, Any], batch: Dict[str, Tensor]) -> Optional[Tensor]:
        if DEPTH_KEY not in batch:
            return None
        truth = batch[DEPTH_KEY].to(model.device) * model.dataparser_scale
        truth = torch.where(torch.isfinite(truth), truth, torch.zeros_like(truth))
        levels = list(zip(outputs["depth_weights_list"], outputs["depth_ray_samples_list"]))
        sigma = torch.tensor([self.config.sigma], device=model.device)
        total = sum(
            depth_loss(weights=weights, ray_samples=ray_samples, termination_depth=truth,
                       predicted_depth=outputs["depth"], sigma=sigma, directions_norm=outputs["directions_norm"],
                       is_euclidean=False, depth_loss_type=self.config.loss_type)
            for weights, ray_samples in levels
        )
        return self.config.mult * total / len(levels)
