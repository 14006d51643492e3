"""Gradient scaling: a tensor whose forward value is unchanged and whose backward gradient is multiplied.

Multi-task training sends every property's loss into the shared field through two paths: the rendering weights
(density, i.e. geometry) and the feature e_x. `scale_gradient` lets the model turn each path down per loss without
changing what is rendered.
"""

from __future__ import annotations

from torch import Tensor


def scale_gradient(tensor: Tensor, scale: float) -> Tensor:
    """`tensor` in the forward pass; `scale` times the incoming gradient in the backward pass (0: detached)."""
    if scale == 1.0:
        return tensor
    if scale == 0.0:
        return tensor.detach()
    detached = tensor.detach()
    return detached + scale * (tensor - detached)
