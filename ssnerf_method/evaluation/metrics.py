"""Image metrics keyed by the name a `PropertySpec.metric` gives.

Each metric takes one predicted image, its label and the mask of labelled pixels, and returns named floats; the
model prefixes them with the property name (`semantics_miou`, `normals_l1`, ...; RGB's are plain `psnr`, `ssim`).
"""

from __future__ import annotations

from typing import Callable, Dict

import torch
from jaxtyping import Bool, Float
from torch import Tensor
from torchmetrics.functional import structural_similarity_index_measure


def psnr_metrics(
    prediction: Float[Tensor, "h w 3"], label: Float[Tensor, "h w 3"], valid: Bool[Tensor, "h w"], num_classes: int
) -> Dict[str, float]:
    """PSNR and SSIM of images in [0, 1] (all pixels: RGB has no unlabelled pixels)."""
    mse = torch.mean((prediction.clamp(0, 1) - label) ** 2)
    psnr = -10.0 * torch.log10(mse.clamp_min(1e-10))
    ssim = structural_similarity_index_measure(
        prediction.clamp(0, 1).permute(2, 0, 1)[None], label.permute(2, 0, 1)[None], data_range=1.0
    )
    return {"psnr": float(psnr), "ssim": float(ssim)}  # type: ignore[arg-type]


def confusion_matrix(
    predicted_ids: Tensor, label_ids: Tensor, valid: Tensor, num_classes: int
) -> Float[Tensor, "classes classes"]:
    """Counts[label, prediction] over the labelled pixels."""
    index = label_ids[valid].long() * num_classes + predicted_ids[valid].long()
    return torch.bincount(index, minlength=num_classes * num_classes).reshape(num_classes, num_classes).double()


def miou_from_confusion(confusion: Tensor) -> Dict[str, float]:
    """Mean IoU over the classes present in the labels, and pixel accuracy. NaN when nothing is labelled."""
    true_positive = confusion.diag()
    label_count = confusion.sum(dim=1)
    union = label_count + confusion.sum(dim=0) - true_positive
    present = label_count > 0
    if not present.any():
        return {"miou": float("nan"), "acc": float("nan")}
    iou = true_positive[present] / union[present]
    return {"miou": float(iou.mean()), "acc": float(true_positive.sum() / confusion.sum())}


def miou_metrics(
    prediction: Float[Tensor, "h w classes"], label: Float[Tensor, "h w 1"], valid: Bool[Tensor, "h w"], num_classes: int
) -> Dict[str, float]:
    """Per-image mIoU (classes present in this image's labels) and pixel accuracy; prediction = logits/probs."""
    return miou_from_confusion(confusion_matrix(prediction.argmax(-1), label[..., 0], valid, num_classes))


def l1_metrics(
    prediction: Float[Tensor, "h w c"], label: Float[Tensor, "h w c"], valid: Bool[Tensor, "h w"], num_classes: int
) -> Dict[str, float]:
    """Mean absolute error over labelled pixels and channels, in the stored [0, 1] encoding (paper Table 1)."""
    if not valid.any():
        return {"l1": float("nan")}
    return {"l1": float(torch.mean(torch.abs(prediction[valid] - label[valid])))}


METRICS: Dict[str, Callable[[Tensor, Tensor, Tensor, int], Dict[str, float]]] = {
    "psnr": psnr_metrics,
    "miou": miou_metrics,
    "l1": l1_metrics,
}
