"""Datamanager: nerfstudio's `VanillaDataManager` serving `SSNeRFDataset` from `SSNeRFDataParser`, with sparse labels
given their share of each batch (`data/pixel_sampler.py`) and the viewer's strokes (`data/strokes.py`) mixed in."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple, Type

import torch
from torch import Tensor

from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager, VanillaDataManagerConfig
from nerfstudio.data.pixel_samplers import PixelSamplerConfig
from nerfstudio.utils.rich_utils import CONSOLE

from ssnerf_method.data.dataparser import STROKES_METADATA_KEY, SSNeRFDataParserConfig
from ssnerf_method.data.dataset import DEPTH_KEY, SSNeRFDataset
from ssnerf_method.data.pixel_sampler import LabelledPixelSamplerConfig
from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY
from ssnerf_method.data.strokes import LabelledRays, StrokeStore, WorldFrame, merged_classes
from ssnerf_method.properties import REGISTRY, class_property


@dataclass
class SSNeRFDataManagerConfig(VanillaDataManagerConfig):
    """Rays with RGB and every property label sampled at the same pixels, plus rays painted in the viewer."""

    _target: Type = field(default_factory=lambda: SSNeRFDataManager)
    dataparser: SSNeRFDataParserConfig = field(default_factory=SSNeRFDataParserConfig)
    pixel_sampler: PixelSamplerConfig = field(default_factory=LabelledPixelSamplerConfig)
    stroke_rays_per_batch: int = 256
    """Rays drawn from the strokes painted in the viewer (`DATA/ssnerf_labels/strokes.json`) added to every training
    batch, when there are strokes. They carry a class label and nothing else, so only the semantic loss sees them."""


class SSNeRFDataManager(VanillaDataManager[SSNeRFDataset]):
    """nerfstudio's datamanager; training batches also hold `stroke_rays_per_batch` rays of the strokes, whose store
    (`strokes`) the viewer's Label panel adds to while training runs."""

    config: SSNeRFDataManagerConfig

    def __init__(self, config: SSNeRFDataManagerConfig, device="cpu", test_mode="val", *args, **kwargs) -> None:
        super().__init__(config, device, test_mode, *args, **kwargs)
        metadata = self.train_dataset.metadata
        self.strokes: Optional[StrokeStore] = metadata.get(STROKES_METADATA_KEY)
        """The dataset's strokes, when it trains classes (None otherwise)."""
        self.world_frame = WorldFrame.of(self.train_dataparser_outputs)
        self._stroke_rays: Optional[LabelledRays] = None
        self._stroke_version = -1
        if self.strokes is not None and self.strokes.strokes and test_mode == "val":
            CONSOLE.print(f"{len(self.strokes.strokes)} strokes ({self.strokes.num_rays()} labelled rays) from "
                          f"{self.strokes.path}: {self.config.stroke_rays_per_batch} of them join every batch")

    def stroke_rays(self) -> Optional[LabelledRays]:
        """Every stroke's rays in this run's world frame (rebuilt when the store changed); None without strokes."""
        if self.strokes is None:
            return None
        if self.strokes.version != self._stroke_version:
            self._stroke_version = self.strokes.version
            # the run's classes, and those added in the viewer since it started (the panel numbers them alike)
            classes, _ = merged_classes(self.train_dataset.metadata.get("semantic_classes", []), self.strokes)
            ids = {name: index for index, name in enumerate(classes)}
            self._stroke_rays = self.strokes.labelled_rays(self.world_frame, ids)
        return self._stroke_rays

    def next_train(self, step: int) -> Tuple[RayBundle, Dict]:
        ray_bundle, batch = super().next_train(step)
        rays = self.stroke_rays()
        if rays is None or self.config.stroke_rays_per_batch <= 0:
            return ray_bundle, batch
        picks = torch.randint(len(rays), (self.config.stroke_rays_per_batch,))
        return append_rays(ray_bundle, rays, picks), append_labels(batch, rays.class_ids[picks])


def append_rays(bundle: RayBundle, rays: LabelledRays, picks: Tensor) -> RayBundle:
    """`bundle` followed by the rays `picks` of `rays` (camera index 0; metadata the strokes lack is zero)."""
    device = bundle.origins.device
    count = len(picks)
    own = {POSE_METADATA_KEY: rays.camera_to_world[picks], "directions_norm": rays.directions_norm[picks]}
    metadata = {}
    for key, value in (bundle.metadata or {}).items():
        extra = own.get(key, torch.zeros(count, *value.shape[1:], dtype=value.dtype))
        metadata[key] = torch.cat([value, extra.to(device=device, dtype=value.dtype)])
    indices = bundle.camera_indices
    return RayBundle(
        origins=torch.cat([bundle.origins, rays.origins[picks].to(device)]),
        directions=torch.cat([bundle.directions, rays.directions[picks].to(device)]),
        pixel_area=torch.cat([bundle.pixel_area, rays.pixel_area[picks].to(device)]),
        camera_indices=None if indices is None else torch.cat([indices, torch.zeros(count, 1).to(indices)]),
        metadata=metadata,
    )


def append_labels(batch: Dict[str, Tensor], class_ids: Tensor) -> Dict[str, Tensor]:
    """`batch` with a row per stroke ray: its class id under the class property, every other label unlabelled (the
    image NaN, depth 0, which the losses skip)."""
    count = len(class_ids)
    named = {spec.label_key: spec for spec in REGISTRY.values()}
    classes = class_property().label_key
    extended = {}
    for key, value in batch.items():
        if not isinstance(value, Tensor) or value.ndim == 0 or key == "full_image":
            extended[key] = value
            continue
        shape = (count, *value.shape[1:])
        if key == classes:
            extra = class_ids.reshape(shape)
        elif key in named:
            extra = torch.full(shape, named[key].kind.ignore_value)
        elif key == DEPTH_KEY or not value.is_floating_point():
            extra = torch.zeros(shape)
        else:
            extra = torch.full(shape, float("nan"))
        extended[key] = torch.cat([value, extra.to(device=value.device, dtype=value.dtype)])
    return extended
