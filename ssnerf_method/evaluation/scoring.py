"""Scoring any predictor of scene properties (SS-NeRF, a baseline) on a dataset's views with the split-level metrics."""

from __future__ import annotations

from typing import Callable, Dict, Mapping, Optional, Sequence

from jaxtyping import Bool
from torch import Tensor

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.metrics import METRICS, Statistics, add_statistics, summarize
from ssnerf_method.properties import PropertySpec

Predictor = Callable[[Cameras, int], Dict[str, Tensor]]
"""(cameras, index) -> property name -> prediction for that view, in the model's prediction layout."""


def score_predictor(
    predict: Predictor, dataset: SSNeRFDataset, specs: Sequence[PropertySpec], num_classes: int,
    views: Optional[Sequence[int]] = None, pixels: Optional[Mapping[int, Bool[Tensor, "h w"]]] = None,
) -> Dict[str, float]:
    """Split-level metrics (`metrics`) of `predict` on the views of `dataset` (`views`, default every one), for the
    properties it predicts among `specs`; with `pixels`, on each view's labelled pixels that its mask keeps."""
    return summarize(predictor_statistics(predict, dataset, specs, num_classes, views, pixels), specs)


def predictor_statistics(
    predict: Predictor, dataset: SSNeRFDataset, specs: Sequence[PropertySpec], num_classes: int,
    views: Optional[Sequence[int]] = None, pixels: Optional[Mapping[int, Bool[Tensor, "h w"]]] = None,
) -> Dict[str, Statistics]:
    """What `score_predictor` summarizes: each predicted property's statistics added up over the views (a class
    property's confusion matrix, for one)."""
    totals: Dict[str, Statistics] = {}
    for index in range(len(dataset)) if views is None else views:
        predictions = predict(dataset.cameras, index)
        item = dataset[index]
        for spec in specs:
            if spec.name not in predictions:
                continue
            label = spec.label(item, num_classes)
            prediction = predictions[spec.name].to(label.device)
            valid = spec.kind.valid(label)
            if pixels is not None:
                valid = valid & pixels[index].to(valid.device)
            view = METRICS[spec.metric].statistics(prediction, label, valid, num_classes)
            totals[spec.name] = add_statistics(totals.get(spec.name, {}), view)
    return totals
