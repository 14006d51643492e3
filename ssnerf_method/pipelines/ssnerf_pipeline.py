"""The SS-NeRF pipeline: nerfstudio's `VanillaPipeline` with split-level evaluation for `ns-eval`.

Evaluation renders with `SSNeRFModel.render_camera` (every output, predictions included); nerfstudio's own calls of
`get_outputs_for_camera` (viewer, `ns-render`) get only the display images.

nerfstudio averages each metric over the evaluated views. For the property metrics that is not what the paper
reports: mIoU comes from the confusion matrix accumulated over the split, and the errors are averaged over all
labelled pixels (a view without a label for a property must not make the split's value NaN). So this pipeline sums
each view's metric statistics (`SSNeRFModel.get_image_statistics`) and summarises the sums once; PSNR and SSIM stay
per-view averages. `semantics_miou_per_view` (the mean of per-view mIoUs) is reported too, for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from time import time
from typing import Callable, Dict, List, Optional, Type

import numpy as np
import torch
import torchvision.utils as vutils
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from torch import Tensor

from nerfstudio.cameras.cameras import Cameras
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig

from ssnerf_method.errors import UserError
from ssnerf_method.metrics import METRICS, Statistics, add_statistics
from ssnerf_method.viewer.host import serve_locally_by_default
from ssnerf_method.viewer.label_panel import add_label_panel


@dataclass
class SSNeRFPipelineConfig(VanillaPipelineConfig):
    """nerfstudio's vanilla pipeline with split-level property metrics."""

    _target: Type = field(default_factory=lambda: SSNeRFPipeline)


ViewHook = Callable[[int, Cameras, Dict[str, Tensor], Dict[str, Tensor]], None]
"""Called with (view index, camera, batch, outputs) for each evaluated view, e.g. to save its renders without
rendering the view a second time."""


class TrainingDiverged(UserError):
    """A loss or an evaluation metric is NaN or infinite: the model is broken and nothing it gives can be used."""


def hand_patches_to_sampler(config: SSNeRFPipelineConfig) -> None:
    """The model's regularisers that train on 3x3 pixel patches (`RegulariserConfig.pixel_patches`) get them from the
    pixel sampler: the most patches any asks for; drawn on every batch if one of them wants that, else only while the
    class labels are sparse, at that term's stride."""
    sampler = getattr(config.datamanager, "pixel_sampler", None)
    terms = getattr(config.model, "regularisers", {}).values()
    requests = [request for request in (term.pixel_patches() for term in terms) if request is not None]
    if not requests or not hasattr(sampler, "smoothness_patches"):
        return
    sampler.smoothness_patches = max(request.count for request in requests)  # type: ignore[union-attr]
    sampler.patches_while_class_sparse = all(r.only_while_class_sparse for r in requests)  # type: ignore[union-attr]
    strides = [request.stride for request in requests if request.stride is not None]
    if sampler.patches_while_class_sparse and strides:  # type: ignore[union-attr]
        sampler.smoothness_patch_stride = strides[0]  # type: ignore[union-attr]


class SSNeRFPipeline(VanillaPipeline):
    """Evaluates a split by summing per-view metric statistics (see the module docstring), and stops at the first
    non-finite loss (nerfstudio would go on and save NaN checkpoints)."""

    config: SSNeRFPipelineConfig

    def __init__(self, config: SSNeRFPipelineConfig, device: str, test_mode: str = "val", *args, **kwargs) -> None:
        hand_patches_to_sampler(config)
        serve_locally_by_default()  # (the viewer, made after the pipeline, may write into the dataset)
        super().__init__(config, device, test_mode, *args, **kwargs)
        strokes = getattr(self.datamanager, "strokes", None)
        if strokes is not None and getattr(self.model, "semantic_classes", None) is not None:
            height = int(self.datamanager.train_dataset.cameras.height.max())
            add_label_panel(self.model, strokes, self.datamanager.world_frame, height, training=test_mode == "val")

    def get_train_loss_dict(self, step: int):
        """nerfstudio's training step, then one check (a single device sync) that every loss is finite."""
        model_outputs, loss_dict, metrics_dict = super().get_train_loss_dict(step)
        if loss_dict and not bool(torch.stack([loss.detach().sum() for loss in loss_dict.values()]).isfinite().all()):
            bad = [name for name, loss in loss_dict.items() if not bool(loss.detach().isfinite().all())]
            raise TrainingDiverged(
                f"step {step}: loss {', '.join(bad)} is not finite (NaN or Inf); training stopped before this step's "
                "update, so the saved checkpoints are the last good ones. Check the data (`ssnerf-check DATA`) or "
                "lower the learning rate."
            )
        return model_outputs, loss_dict, metrics_dict

    @torch.no_grad()
    def get_eval_image_metrics_and_images(self, step: int):
        """One eval view's metrics and images during training (the model's full outputs, not the display ones)."""
        self.eval()
        camera, batch = self.datamanager.next_eval_image(step)
        metrics, images = self.model.get_image_metrics_and_images(self.model.render_camera(camera), batch)
        metrics["num_rays"] = (camera.height * camera.width * camera.size).item()
        self.train()
        return metrics, images

    @torch.no_grad()
    def get_average_image_metrics(
        self,
        data_loader,
        image_prefix: str,
        step: Optional[int] = None,
        output_path: Optional[Path] = None,
        get_std: bool = False,
        on_view: Optional[ViewHook] = None,
    ) -> Dict[str, float]:
        """Split-level metrics of every view in `data_loader` (nerfstudio's signature; `ns-eval` calls this), and
        `on_view` on each view's outputs (the demo writes its PNGs so, from the one render the metrics use)."""
        self.eval()
        model = self.model
        totals: Dict[str, Statistics] = {}
        per_view: List[Dict[str, float]] = []
        if output_path is not None:
            output_path.mkdir(exist_ok=True, parents=True)
        columns = (TextColumn("[progress.description]{task.description}"), BarColumn(), TimeElapsedColumn(),
                   MofNCompleteColumn())
        with Progress(*columns, transient=True) as progress:
            task = progress.add_task("[green]Evaluating all images...", total=len(data_loader))
            for index, (camera, batch) in enumerate(data_loader):
                start = time()
                outputs = model.render_camera(camera)
                statistics = model.get_image_statistics(outputs, batch)
                seconds = time() - start
                for name, values in statistics.items():
                    totals[name] = add_statistics(totals.get(name, {}), values)
                metrics = model.metrics_from_statistics(statistics)
                num_rays = int(camera.height.item() * camera.width.item())
                metrics["num_rays_per_sec"] = num_rays / seconds
                metrics["fps"] = 1.0 / seconds
                per_view.append(metrics)
                if output_path is not None:
                    _, images = model.get_image_metrics_and_images(outputs, batch)
                    for key, image in images.items():
                        path = output_path / f"{image_prefix}_{key}_{index:04d}.png"
                        vutils.save_image(image.permute(2, 0, 1).cpu(), path)
                if on_view is not None:
                    on_view(index, camera, batch, outputs)
                progress.advance(task)
        self.train()

        results = model.metrics_from_statistics(totals)
        if "psnr" in results and not np.isfinite(results["psnr"]):
            raise TrainingDiverged(
                f"evaluation: the model renders NaN or infinite colours (PSNR {results['psnr']}); its "
                "checkpoint is broken, so no metrics were written. Retrain it (training stops at a non-finite loss)."
            )
        for key in ("num_rays_per_sec", "fps"):
            results[key] = float(np.mean([metrics[key] for metrics in per_view]))
        for spec in model.specs:  # class metrics come from the split's confusion matrix: the mean of views' beside it
            key = spec.metric_prefix + METRICS[spec.metric].reported[0][0]
            if spec.kind.categorical and key in results:
                results[f"{key}_per_view"] = _nan_mean([metrics[key] for metrics in per_view])
        if get_std:
            for key in list(results):
                values = np.array([metrics[key] for metrics in per_view if key in metrics], dtype=np.float64)
                if len(values):
                    results[f"{key}_std"] = float(np.std(values[~np.isnan(values)])) if (~np.isnan(values)).any() \
                        else float("nan")
        return results


def _nan_mean(values: List[float]) -> float:
    """Mean of the values that are not NaN (NaN when there are none), without numpy's empty-slice warning."""
    kept = [value for value in values if not np.isnan(value)]
    return float(np.mean(kept)) if kept else float("nan")
