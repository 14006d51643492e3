"""Image metrics keyed by the name a `PropertySpec.metric` gives, defined once for one view and for a whole split.

A metric turns (prediction, label, mask of labelled pixels) into additive *statistics* (sums and counts: a confusion
matrix, a sum of absolute errors, a histogram of angles) and turns statistics into named values. One view's metric
is the summary of its own statistics; a split's is the summary of the statistics summed over its views, so every
error is averaged over all labelled pixels of the split and mIoU comes from the split's accumulated confusion matrix
(the paper's Table 1 numbers are split-level). PSNR and SSIM are the exception, averaged per view as is customary.
The model prefixes names with the property (`semantics_miou`, `normals_l1`; RGB's are plain `psnr`, `ssim`).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Dict, Sequence

import torch
from jaxtyping import Bool, Float
from torch import Tensor
from torchmetrics.functional import structural_similarity_index_measure

from ssnerf_method.properties import PropertySpec

Statistics = Dict[str, Tensor]

ANGLE_BIN_DEG = 0.1
"""Width of the angular-error histogram bins: medians are exact to within this."""
ANGLE_THRESHOLDS_DEG = (11.25, 22.5, 30.0)
"""The customary normal-estimation thresholds: share of pixels whose angular error is below each."""


def _nan() -> float:
    return float("nan")


class Metric(ABC):
    """A metric of one property, computable per view and over a split from the same additive statistics."""

    @abstractmethod
    def statistics(self, prediction: Tensor, label: Tensor, valid: Bool[Tensor, "h w"], num_classes: int) -> Statistics:
        """Additive statistics of one view (summing them over views gives the split's)."""

    @abstractmethod
    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        """Named values from (summed) statistics; NaN where nothing was labelled."""

    def __call__(self, prediction: Tensor, label: Tensor, valid: Tensor, num_classes: int) -> Dict[str, float]:
        """The metric of one view."""
        return self.summarize(self.statistics(prediction, label, valid, num_classes))


class PSNRMetric(Metric):
    """PSNR and SSIM of RGB in [0, 1] over all pixels, averaged per view over a split."""

    def statistics(
        self, prediction: Float[Tensor, "h w 3"], label: Float[Tensor, "h w 3"], valid: Tensor, num_classes: int
    ) -> Statistics:
        prediction = prediction.clamp(0, 1)
        mse = torch.mean((prediction - label) ** 2)
        psnr = -10.0 * torch.log10(mse.clamp_min(1e-10))
        ssim = structural_similarity_index_measure(
            prediction.permute(2, 0, 1)[None], label.permute(2, 0, 1)[None], data_range=1.0
        )
        one = torch.ones((), dtype=torch.float64)
        return {"psnr_sum": psnr.double().cpu(), "ssim_sum": ssim.double().cpu(), "views": one}  # type: ignore

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        views = float(statistics["views"])
        return {"psnr": float(statistics["psnr_sum"]) / views, "ssim": float(statistics["ssim_sum"]) / views}


def confusion_matrix(
    predicted_ids: Tensor, label_ids: Tensor, valid: Tensor, num_classes: int
) -> Float[Tensor, "classes classes"]:
    """Counts[label, prediction] over the labelled pixels."""
    index = label_ids[valid].long() * num_classes + predicted_ids[valid].long()
    return torch.bincount(index, minlength=num_classes * num_classes).reshape(num_classes, num_classes).double()


def miou_from_confusion(confusion: Tensor) -> Dict[str, float]:
    """Mean IoU over the classes present in the labels (a class absent from the ground truth is left out even if
    predicted), and pixel accuracy. NaN when nothing is labelled."""
    true_positive = confusion.diag()
    label_count = confusion.sum(dim=1)
    union = label_count + confusion.sum(dim=0) - true_positive
    present = label_count > 0
    if not present.any():
        return {"miou": _nan(), "acc": _nan()}
    iou = true_positive[present] / union[present]
    return {"miou": float(iou.mean()), "acc": float(true_positive.sum() / confusion.sum())}


class MIoUMetric(Metric):
    """Semantic mIoU and pixel accuracy; prediction = logits or probabilities, unlabelled pixels ignored."""

    def statistics(
        self, prediction: Float[Tensor, "h w classes"], label: Float[Tensor, "h w 1"], valid: Tensor, num_classes: int
    ) -> Statistics:
        return {"confusion": confusion_matrix(prediction.argmax(-1), label[..., 0], valid, num_classes).cpu()}

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        return miou_from_confusion(statistics["confusion"])


class L1Metric(Metric):
    """Mean absolute error over labelled pixels and channels, in the stored [0, 1] encoding (paper Table 1)."""

    def statistics(
        self, prediction: Float[Tensor, "h w c"], label: Float[Tensor, "h w c"], valid: Tensor, num_classes: int
    ) -> Statistics:
        error = torch.abs(prediction[valid] - label[valid]).double()
        return {"abs_sum": error.sum().cpu(), "count": torch.tensor(float(error.numel()), dtype=torch.float64)}

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        count = float(statistics["count"])
        return {"l1": float(statistics["abs_sum"]) / count if count else _nan()}


class NormalMetric(L1Metric):
    """L1 on the (n+1)/2 encoding (as the paper reports) plus angular errors in degrees: mean, median and the share
    of pixels within 11.25, 22.5 and 30 degrees. Pixels where the prediction or the label is a zero vector (no
    direction) count for L1 but not for the angles."""

    def statistics(
        self, prediction: Float[Tensor, "h w 3"], label: Float[Tensor, "h w 3"], valid: Tensor, num_classes: int
    ) -> Statistics:
        statistics = super().statistics(prediction, label, valid, num_classes)
        predicted, true = prediction[valid].double() * 2 - 1, label[valid].double() * 2 - 1
        norms = predicted.norm(dim=-1) * true.norm(dim=-1)
        directed = norms > 1e-6
        cosine = (predicted * true).sum(-1)[directed] / norms[directed]
        angles = torch.rad2deg(torch.arccos(cosine.clamp(-1.0, 1.0)))
        bins = int(round(180.0 / ANGLE_BIN_DEG))
        histogram = torch.histc(angles, bins=bins, min=0.0, max=180.0) if angles.numel() else torch.zeros(bins)
        statistics.update(
            {
                "angle_sum": angles.sum().cpu(),
                "angle_count": torch.tensor(float(angles.numel()), dtype=torch.float64),
                "angle_histogram": histogram.double().cpu(),
                **{f"within_{t:g}": (angles < t).sum().double().cpu() for t in ANGLE_THRESHOLDS_DEG},
            }
        )
        return statistics

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        values = super().summarize(statistics)
        count = float(statistics["angle_count"])
        values["angle_mean_deg"] = float(statistics["angle_sum"]) / count if count else _nan()
        values["angle_median_deg"] = histogram_median(statistics["angle_histogram"]) if count else _nan()
        for threshold in ANGLE_THRESHOLDS_DEG:
            name = f"within_{str(threshold).replace('.', '_').removesuffix('_0')}_deg"
            values[name] = float(statistics[f"within_{threshold:g}"]) / count if count else _nan()
        return values


def histogram_median(histogram: Tensor) -> float:
    """The value below which half of the binned values lie (`ANGLE_BIN_DEG`-wide bins from 0, linear within a bin).

    Exact to a bin for any count; for an even count it is the lower of the two middle values, not their mean.
    """
    cumulative = torch.cumsum(histogram, 0)
    half = float(cumulative[-1]) / 2.0
    index = int(torch.searchsorted(cumulative, torch.tensor(half, dtype=cumulative.dtype)))
    before = float(cumulative[index - 1]) if index > 0 else 0.0
    inside = float(histogram[index])
    fraction = (half - before) / inside if inside > 0 else 0.0
    return (index + fraction) * ANGLE_BIN_DEG


class DepthMetric(Metric):
    """L1 and RMSE of z-depth in metres over pixels with valid (> 0, finite) ground truth."""

    def statistics(
        self, prediction: Float[Tensor, "h w 1"], label: Float[Tensor, "h w 1"], valid: Tensor, num_classes: int
    ) -> Statistics:
        error = (prediction[valid] - label[valid]).double()
        return {
            "abs_sum": error.abs().sum().cpu(),
            "square_sum": (error**2).sum().cpu(),
            "count": torch.tensor(float(error.numel()), dtype=torch.float64),
        }

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        count = float(statistics["count"])
        if not count:
            return {"l1": _nan(), "rmse": _nan()}
        return {"l1": float(statistics["abs_sum"]) / count, "rmse": math.sqrt(float(statistics["square_sum"]) / count)}


def add_statistics(total: Statistics, more: Statistics) -> Statistics:
    """Sum of two views' (or partial splits') statistics."""
    return {key: total[key] + more[key] for key in total} if total else dict(more)


DEPTH_METRIC = "depth"
"""Metric (and metric-name prefix) of rendered depth against the data's depth maps; depth is scored, not trained."""


def summarize(statistics: Dict[str, Statistics], specs: Sequence[PropertySpec]) -> Dict[str, float]:
    """Named metrics (`psnr`, `semantics_miou`, `normals_angle_mean_deg`, `depth_l1`, ...) from per-property
    statistics of one view or summed over a split; `specs` give each property's metric and name prefix."""
    by_name = {spec.name: spec for spec in specs}
    metrics: Dict[str, float] = {}
    for name, values in statistics.items():
        spec = by_name.get(name)
        metric, prefix = (spec.metric, spec.metric_prefix) if spec is not None else (name, f"{name}_")
        metrics.update({prefix + key: value for key, value in METRICS[metric].summarize(values).items()})
    return metrics


METRICS: Dict[str, Metric] = {
    "psnr": PSNRMetric(),
    "miou": MIoUMetric(),
    "l1": L1Metric(),
    "normal": NormalMetric(),
    "depth": DepthMetric(),
}
"""Metric of each `PropertySpec.metric` name (and `depth`, scored when the data has depth maps)."""
