"""The paper's per-property losses (Sec. 3.3), keyed by the name a `PropertySpec.loss` gives.

Each takes the rendered prediction, the label and a mask of rays whose label exists, and averages over those rays
only, so a frame without a label (or an unlabelled pixel) contributes nothing.
"""

from __future__ import annotations

from typing import Callable, Dict

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from torch import Tensor


def _masked(prediction: Tensor, label: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    return prediction[valid], label[valid]


def mse_loss(
    prediction: Float[Tensor, "rays c"], label: Float[Tensor, "rays c"], valid: Bool[Tensor, " rays"]
) -> Tensor:
    """Mean squared error (RGB, normals)."""
    if not valid.any():
        return prediction.sum() * 0.0
    return F.mse_loss(*_masked(prediction, label, valid))


def l1_loss(
    prediction: Float[Tensor, "rays c"], label: Float[Tensor, "rays c"], valid: Bool[Tensor, " rays"]
) -> Tensor:
    """Mean absolute error (shading, keypoints, edges)."""
    if not valid.any():
        return prediction.sum() * 0.0
    return F.l1_loss(*_masked(prediction, label, valid))


def planar_smoothness_loss(
    inverse_depth: Float[Tensor, "patches 3 3"], colours: Float[Tensor, "patches 9 c"], edge: float
) -> Tensor:
    """Mean over 3x3 pixel patches of |second differences| of the inverse z-depth along the middle row and column,
    over the centre's value, times exp(-edge * the patch's largest colour difference). A plane seen by a pinhole
    camera has an inverse z-depth affine in the pixel, so only bends cost, and less where the image has an edge (a
    depth edge is likely there)."""
    centre = inverse_depth[:, 1, 1]
    bend = ((inverse_depth[:, 0, 1] - 2 * centre + inverse_depth[:, 2, 1]).abs()
            + (inverse_depth[:, 1, 0] - 2 * centre + inverse_depth[:, 1, 2]).abs()) / centre.detach().clamp_min(1e-6)
    spread = (colours.amax(dim=1) - colours.amin(dim=1)).amax(dim=-1)
    return (bend * torch.exp(-edge * spread)).mean()


def colour_affinity_loss(
    probabilities: Float[Tensor, "patches 9 classes"], colours: Float[Tensor, "patches 9 c"],
    labelled: Bool[Tensor, "patches 9"], edge: float
) -> Tensor:
    """Mean over 3x3 pixel patches of the L1 distance between each neighbour's class probabilities and the centre's,
    times exp(-edge * their largest colour difference): a dense CRF's pairwise term on a patch, which spreads sparse
    labels over regions of like colour. A pair whose two pixels are both labelled costs nothing (its labels
    decide), so densely labelled data is left as it was."""
    centre = probabilities[:, 4:5]
    affinity = torch.exp(-edge * (colours - colours[:, 4:5]).abs().amax(dim=-1))
    affinity = affinity * ~(labelled & labelled[:, 4:5])
    return (affinity * (probabilities - centre).abs().sum(dim=-1)).mean()


def cross_entropy_loss(
    logits: Float[Tensor, "rays classes"], label: Float[Tensor, "rays 1"], valid: Bool[Tensor, " rays"]
) -> Tensor:
    """Cross-entropy of the softmax of volume-rendered logits against class ids (semantics)."""
    if not valid.any():
        return logits.sum() * 0.0
    return F.cross_entropy(logits[valid], label[valid][..., 0].long())


LOSSES: Dict[str, Callable[[Tensor, Tensor, Tensor], Tensor]] = {
    "mse": mse_loss,
    "l1": l1_loss,
    "cross_entropy": cross_entropy_loss,
}
