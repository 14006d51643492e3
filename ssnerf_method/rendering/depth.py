"""Depth as the datasets store it, from what the model renders."""

from __future__ import annotations

from typing import Dict

from jaxtyping import Float
from torch import Tensor


def rendered_z_depth(outputs: Dict[str, Tensor]) -> Float[Tensor, "*bs 1"]:
    """z-depth (scene units) of a render: nerfstudio's `depth` is the distance along the unit ray, so z-depth divides
    it by the camera-frame ray's length (`directions_norm`, which the model passes through)."""
    return outputs["depth"] / outputs["directions_norm"]
