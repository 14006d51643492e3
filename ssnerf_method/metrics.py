"""Image metrics keyed by `PropertySpec.metric`, for one view and for a whole split.

A metric turns (prediction, label, labelled mask) into additive statistics, summed over a split's views as the paper's
Table 1 (errors over all its labelled pixels, mIoU from its confusion matrix), then into values; PSNR/SSIM per view.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Dict, Sequence, Tuple

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from torch import Tensor
from torchmetrics.functional import structural_similarity_index_measure

from ssnerf_method.label_makers.encoding import decode_normals
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

    reported: Tuple[Tuple[str, bool], ...] = ()
    """The values reports show, as (name, higher is better): the paper's headline number first."""
    decides: Tuple[str, ...] = ()
    """Which of `reported` decide whether one method beats another (a win needs every one); empty: the headline."""

    @abstractmethod
    def statistics(self, prediction: Tensor, label: Tensor, valid: Bool[Tensor, "h w"], num_classes: int) -> Statistics:
        """Additive statistics of one view (summing them over views gives the split's)."""

    @abstractmethod
    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        """Named values from (summed) statistics; NaN where nothing was labelled."""

    def __call__(self, prediction: Tensor, label: Tensor, valid: Tensor, num_classes: int) -> Dict[str, float]:
        return self.summarize(self.statistics(prediction, label, valid, num_classes))


class PSNRMetric(Metric):
    """PSNR and SSIM of RGB in [0, 1] over all pixels, averaged per view over a split."""

    reported = (("psnr", True),)

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


def class_iou(confusion: Float[Tensor, "classes classes"]) -> Float[Tensor, " classes"]:
    """Each class's IoU; NaN for a class absent from the labels (whatever was predicted as it)."""
    true_positive = confusion.diag()
    label_count = confusion.sum(dim=1)
    union = label_count + confusion.sum(dim=0) - true_positive
    return torch.where(label_count > 0, true_positive / union.clamp(min=1), torch.nan)


def miou_from_confusion(confusion: Tensor) -> Dict[str, float]:
    """Mean IoU over the classes present in the labels (even if others are predicted), and pixel accuracy; or NaN."""
    iou = class_iou(confusion)
    present = ~iou.isnan()
    if not present.any():
        return {"miou": _nan(), "acc": _nan()}
    return {"miou": float(iou[present].mean()), "acc": float(confusion.diag().sum() / confusion.sum())}


class MIoUMetric(Metric):
    """Semantic mIoU and pixel accuracy; prediction = logits or probabilities, unlabelled pixels ignored."""

    reported = (("miou", True),)

    def statistics(
        self, prediction: Float[Tensor, "h w classes"], label: Float[Tensor, "h w 1"], valid: Tensor, num_classes: int
    ) -> Statistics:
        return {"confusion": confusion_matrix(prediction.argmax(-1), label[..., 0], valid, num_classes).cpu()}

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        return miou_from_confusion(statistics["confusion"])


class L1Metric(Metric):
    """Mean absolute error over labelled pixels and channels, in the stored [0, 1] encoding (paper Table 1)."""

    reported = (("l1", False),)

    def statistics(
        self, prediction: Float[Tensor, "h w c"], label: Float[Tensor, "h w c"], valid: Tensor, num_classes: int
    ) -> Statistics:
        error = torch.abs(prediction[valid] - label[valid]).double()
        return {"abs_sum": error.sum().cpu(), "count": torch.tensor(float(error.numel()), dtype=torch.float64)}

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        count = float(statistics["count"])
        return {"l1": float(statistics["abs_sum"]) / count if count else _nan()}


SPARSE_THRESHOLDS = torch.arange(1, 101, dtype=torch.float64) / 100.0
"""Thresholds 0.01 ... 1.00 cutting a sparse map (edges, keypoints); the split's F1 is the best over them (ODS)."""
EDGE_TOLERANCE_PX = 1
"""An edge pixel matches if the other map has an edge pixel within this many pixels (8-neighbourhood)."""
KEYPOINT_LABEL_PEAK = 0.5
"""Ground-truth keypoints are the label's local maxima above this value."""
KEYPOINT_TOLERANCE_PX = 3.0
"""A predicted keypoint is a hit if an unmatched ground-truth keypoint lies within this many pixels (Euclidean)."""


def precision_recall_summary(
    predicted: Tensor, predicted_hits: Tensor, truth: Tensor, truth_hits: Tensor
) -> Dict[str, float]:
    """ODS F1, its threshold and average precision from per-threshold counts summed over a split (NaN if no truth)."""
    if float(truth) == 0:
        return {"f1": _nan(), "f1_threshold": _nan(), "ap": _nan()}
    precision = torch.where(predicted > 0, predicted_hits / predicted.clamp_min(1), torch.zeros_like(predicted))
    recall = truth_hits / truth
    f1 = torch.where(precision + recall > 0, 2 * precision * recall / (precision + recall).clamp_min(1e-12),
                     torch.zeros_like(precision))
    best = int(torch.argmax(f1))
    descending_recall = recall.flip(0)
    gained = torch.diff(descending_recall, prepend=descending_recall.new_zeros(1)).clamp_min(0)
    return {"f1": float(f1[best]), "f1_threshold": float(SPARSE_THRESHOLDS[best]),
            "ap": float((gained * precision.flip(0)).sum())}


def dilate(mask: Bool[Tensor, "*bs h w"], radius: int) -> Bool[Tensor, "*bs h w"]:
    """Pixels within `radius` (8-neighbourhood steps) of a set pixel."""
    flat = mask.reshape(-1, 1, *mask.shape[-2:]).float()
    grown = F.max_pool2d(flat, kernel_size=2 * radius + 1, stride=1, padding=radius)
    return grown.reshape(mask.shape) > 0


class SparseMapMetric(L1Metric):
    """L1 plus F1 and AP of a sparse map, from per-threshold counts a subclass gives (`precision_recall_summary`)."""

    reported = (("l1", False), ("f1", True), ("ap", True))
    decides = ("f1", "ap")  # an empty map's L1 ties a good one's, so L1 cannot tell methods apart on sparse maps

    def summarize(self, statistics: Statistics) -> Dict[str, float]:
        values = super().summarize(statistics)
        values.update(precision_recall_summary(statistics["predicted"], statistics["predicted_hits"],
                                               statistics["truth"], statistics["truth_hits"]))
        return values


class EdgeMetric(SparseMapMetric):
    """L1 (the paper's) plus boundary F1 and AP: the map cut at each threshold is matched to the label's edges
    (>= 0.5) within `EDGE_TOLERANCE_PX`, so an empty map scores 0 and a one-pixel shift of the label still 1."""

    def statistics(
        self, prediction: Float[Tensor, "h w 1"], label: Float[Tensor, "h w 1"], valid: Tensor, num_classes: int
    ) -> Statistics:
        statistics = super().statistics(prediction, label, valid, num_classes)
        thresholds = SPARSE_THRESHOLDS.to(prediction.device, prediction.dtype)
        truth = (label[..., 0] >= 0.5) & valid
        predicted = (prediction[..., 0][None] >= thresholds[:, None, None]) & valid[None]
        near_truth = dilate(truth, EDGE_TOLERANCE_PX)
        near_predicted = dilate(predicted, EDGE_TOLERANCE_PX)
        statistics.update(
            predicted=predicted.sum(dim=(1, 2)).double().cpu(),
            predicted_hits=(predicted & near_truth[None]).sum(dim=(1, 2)).double().cpu(),
            truth=truth.sum().double().cpu(),
            truth_hits=(near_predicted & truth[None]).sum(dim=(1, 2)).double().cpu(),
        )
        return statistics


def local_maxima(values: Float[Tensor, "h w"], valid: Bool[Tensor, "h w"], floor: float) -> Tuple[Tensor, Tensor]:
    """Peaks of a map: labelled pixels above `floor` that are the largest in their 3x3 neighbourhood (ties broken
    by raster order, so a flat-topped peak counts once). Returns their (N, 2) (row, column) positions and values."""
    height, width = values.shape
    order = torch.arange(height * width, dtype=torch.float64, device=values.device).reshape(height, width)
    # a tie-break far below the 8-bit label step: among equal values the earlier pixel wins
    keyed = torch.where(valid, values.double() - order * 1e-9 / (height * width), torch.full_like(order, -1.0))
    neighbourhood = F.max_pool2d(keyed[None, None], kernel_size=3, stride=1, padding=1)[0, 0]
    peaks = (keyed == neighbourhood) & valid & (values > floor)
    positions = torch.nonzero(peaks)
    return positions, values[peaks]


def match_keypoints(predicted: Tensor, scores: Tensor, truth: Tensor, tolerance: float) -> Bool[Tensor, " n"]:
    """Per prediction, whether it is a hit: in descending score each takes the nearest unmatched true keypoint within
    `tolerance` pixels (so the hits above any threshold are those matching only them would give)."""
    hits = torch.zeros(len(predicted), dtype=torch.bool)
    if len(predicted) == 0 or len(truth) == 0:
        return hits
    distances = torch.cdist(predicted.double().cpu(), truth.double().cpu())
    taken = torch.zeros(len(truth), dtype=torch.bool)
    for index in torch.argsort(scores.cpu(), descending=True, stable=True).tolist():
        candidates = distances[index].masked_fill(taken, math.inf)
        nearest = int(torch.argmin(candidates))
        if candidates[nearest] <= tolerance:
            taken[nearest] = True
            hits[index] = True
    return hits


class KeypointMetric(SparseMapMetric):
    """L1 (the paper's) plus keypoint F1 and AP over the local maxima of label and render (`match_keypoints`): they
    tell an empty map (0) from the label (1), which L1 cannot on a mostly zero map."""

    def statistics(
        self, prediction: Float[Tensor, "h w 1"], label: Float[Tensor, "h w 1"], valid: Tensor, num_classes: int
    ) -> Statistics:
        statistics = super().statistics(prediction, label, valid, num_classes)
        truth, _ = local_maxima(label[..., 0], valid, KEYPOINT_LABEL_PEAK)
        predicted, scores = local_maxima(prediction[..., 0], valid, float(SPARSE_THRESHOLDS[0]) - 1e-9)
        hits = match_keypoints(predicted, scores, truth, KEYPOINT_TOLERANCE_PX)
        above = scores.double().cpu()[None] >= SPARSE_THRESHOLDS[:, None] - 1e-9
        matched = (above & hits[None]).sum(dim=1).double()  # one-to-one: hits are matched keypoints too
        statistics.update(
            predicted=above.sum(dim=1).double(),
            predicted_hits=matched,
            truth=torch.tensor(float(len(truth)), dtype=torch.float64),
            truth_hits=matched,
        )
        return statistics


class NormalMetric(L1Metric):
    """L1 on the (n+1)/2 encoding (the paper's) plus angular errors in degrees; zero vectors count for L1 only."""

    def statistics(
        self, prediction: Float[Tensor, "h w 3"], label: Float[Tensor, "h w 3"], valid: Tensor, num_classes: int
    ) -> Statistics:
        statistics = super().statistics(prediction, label, valid, num_classes)
        predicted, true = decode_normals(prediction[valid].double()), decode_normals(label[valid].double())
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
    """The median of values binned `ANGLE_BIN_DEG` wide from 0 (linear within a bin; the lower middle if even)."""
    cumulative = torch.cumsum(histogram, 0)
    half = float(cumulative[-1]) / 2.0
    index = int(torch.searchsorted(cumulative, torch.tensor(half, dtype=cumulative.dtype)))
    before = float(cumulative[index - 1]) if index > 0 else 0.0
    inside = float(histogram[index])
    fraction = (half - before) / inside if inside > 0 else 0.0
    return (index + fraction) * ANGLE_BIN_DEG


class DepthMetric(Metric):
    """L1 and RMSE of z-depth in metres over pixels with valid (> 0, finite) ground truth."""

    reported = (("l1", False),)

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
"""Metric (and name prefix) of rendered depth against the data's depth maps."""


def summarize(statistics: Dict[str, Statistics], specs: Sequence[PropertySpec]) -> Dict[str, float]:
    """Named metrics (`psnr`, `semantics_miou`, `depth_l1`, ...) from per-property statistics of a view or split."""
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
    "edge": EdgeMetric(),
    "keypoint": KeypointMetric(),
    "normal": NormalMetric(),
    "depth": DepthMetric(),
}
"""Metric of each `PropertySpec.metric` name (and `depth`, scored when the data has depth maps)."""
