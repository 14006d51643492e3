"""A pixel sampler that gives sparse labels their share of every batch.

Uniform rays almost never hit labels on a few pixels or frames. Below `sparse_label_fraction` coverage, a property's
labelled pixels replace `labelled_rays_per_batch` uniform rays; dense data is sampled as nerfstudio's `PixelSampler`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple, Type

import torch
from jaxtyping import Int
from torch import Tensor

from nerfstudio.data.pixel_samplers import PixelSampler, PixelSamplerConfig

from ssnerf_method.properties import REGISTRY, class_property

PATCH_RAYS = 9
"""Rays of one smoothness patch (3x3)."""
SMOOTHNESS_PATCHES_KEY = "smoothness_patches"
"""Batch key: how many smoothness patches open the batch (a 0-d tensor)."""


@dataclass
class LabelledPixelSamplerConfig(PixelSamplerConfig):
    """nerfstudio's pixel sampler, plus a share of labelled pixels for sparsely labelled properties."""

    _target: Type = field(default_factory=lambda: LabelledPixelSampler)
    labelled_rays_per_batch: int = 256
    """Rays per batch drawn from sparsely labelled properties' labelled pixels (shared; at most half the batch)."""
    sparse_label_fraction: float = 0.5
    """A property whose labels cover less than this fraction of the training pixels counts as sparsely labelled."""
    smoothness_patches: int = 0
    """3x3 pixel patches opening each batch (9 rays each, replacing uniform rays) for the depth smoothness and
    semantic affinity losses (set by the pipeline from the model's `pixel_patches`); 0: none."""
    patches_while_class_sparse: bool = False
    """Draw patches only while class labels are sparse, in images partly labelled: all the semantic affinity alone
    needs (it spreads a frame's labels over that frame), so fully labelled frames are sampled as without it."""
    smoothness_patch_stride: int = 4
    """Pixels between neighbouring rays of a patch: a wider patch smooths the depth over a longer span."""


class LabelledPixelSampler(PixelSampler):
    """Uniform pixels, plus pixels drawn from the labelled ones of sparsely labelled properties."""

    config: LabelledPixelSamplerConfig

    def __init__(self, config: LabelledPixelSamplerConfig, **kwargs) -> None:
        super().__init__(config, **kwargs)
        self._cache: Optional[Tuple[int, Tuple[int, ...], Dict[str, Tensor], Tensor]] = None

    def sparse_pixels(self, image_batch: Dict) -> Dict[str, Int[Tensor, "pixels 3"]]:
        """Per sparsely labelled property, its labelled pixels as (image in batch, row, column)."""
        return self._labelled(image_batch)[0]

    def partly_labelled_frames(self, image_batch: Dict) -> Int[Tensor, " frames"]:
        """Batch indices of the images partly class-labelled (within their mask), while class labels are sparse."""
        return self._labelled(image_batch)[1]

    def _labelled(self, image_batch: Dict) -> Tuple[Dict[str, Tensor], Tensor]:
        """`sparse_pixels` and `partly_labelled_frames`, once per cached batch (nerfstudio reuses it every step)."""
        images = image_batch["image"]
        key = (id(images), tuple(images.shape))
        if self._cache is not None and self._cache[:2] == key:
            return self._cache[2], self._cache[3]
        sparse = {}
        partly = torch.zeros(0, dtype=torch.long, device=images.device)
        mask = image_batch.get("mask")
        for spec in REGISTRY.values():
            if spec.file_key is None or spec.name not in image_batch:
                continue
            valid = spec.kind.valid(image_batch[spec.name])
            if mask is not None:  # (pixels a mask excludes are never sampled)
                valid = valid & mask[..., 0].bool()
            fraction = float(valid.float().mean())
            if 0.0 < fraction < self.config.sparse_label_fraction:
                sparse[spec.name] = torch.nonzero(valid)
                if spec.name == class_property().name:
                    counts = valid.flatten(1).sum(-1)
                    pixels = mask[..., 0].bool().flatten(1).sum(-1) if mask is not None else valid[0].numel()
                    partly = torch.nonzero((counts > 0) & (counts < pixels))[:, 0]
        self._cache = (*key, sparse, partly)
        return sparse, partly

    def sample(self, image_batch: Dict) -> Dict:
        patches = self.config.smoothness_patches
        if patches <= 0 or not isinstance(image_batch["image"], Tensor):
            return self.sample_rays(image_batch)
        frames = self.partly_labelled_frames(image_batch) if self.config.patches_while_class_sparse else None
        if frames is not None and len(frames) == 0:
            return self.sample_rays(image_batch)
        rays = patches * PATCH_RAYS
        uniform = self.num_rays_per_batch
        self.num_rays_per_batch = max(uniform - rays, 1)
        try:
            batch = self.sample_rays(image_batch)
        finally:
            self.num_rays_per_batch = uniform
        return prepend(self.patch_rays(image_batch, patches, frames), batch)

    def patch_rays(self, image_batch: Dict, patches: int, frames: Optional[Int[Tensor, " frames"]] = None) -> Dict:
        """Up to `patches` random 3x3 patches (rows of 9 rays) of images (of `frames` if given) clear of masked pixels;
        their number goes under `SMOOTHNESS_PATCHES_KEY`."""
        images = image_batch["image"]
        count, height, width = images.shape[:3]
        stride = max(1, min(self.config.smoothness_patch_stride, (min(height, width) - 1) // 2))
        device = images.device
        drawn = patches if image_batch.get("mask") is None else 4 * patches  # spares for patches a mask hits
        index = torch.randint(count, (drawn, 1, 1), device=device) if frames is None else frames.to(device)[
            torch.randint(len(frames), (drawn, 1, 1), device=device)]
        offsets = torch.arange(-1, 2, device=device) * stride
        rows = torch.randint(stride, height - stride, (drawn, 1, 1), device=device) + offsets[None, :, None]
        columns = torch.randint(stride, width - stride, (drawn, 1, 1), device=device) + offsets[None, None, :]
        index, rows, columns = (value.expand(drawn, 3, 3).reshape(drawn, PATCH_RAYS)
                                for value in (index, rows, columns))
        if image_batch.get("mask") is not None:
            kept = image_batch["mask"][index, rows, columns, 0].bool().all(dim=-1).nonzero()[:patches, 0]
            index, rows, columns, patches = index[kept], rows[kept], columns[kept], len(kept)
        batch = pixels_at(image_batch, index.reshape(-1), rows.reshape(-1), columns.reshape(-1))
        batch[SMOOTHNESS_PATCHES_KEY] = torch.tensor(patches)
        return batch

    def sample_rays(self, image_batch: Dict) -> Dict:
        """Uniform rays, plus the labelled pixels of sparsely labelled properties."""
        if not isinstance(image_batch["image"], Tensor) or self.config.labelled_rays_per_batch <= 0:
            return super().sample(image_batch)
        sparse = self.sparse_pixels(image_batch)
        if not sparse:
            return super().sample(image_batch)
        mixed = min(self.config.labelled_rays_per_batch, self.num_rays_per_batch // 2)
        batch = self.collate_image_dataset_batch(image_batch, self.num_rays_per_batch - mixed,
                                                 keep_full_image=self.config.keep_full_image)
        shares = torch.tensor_split(torch.arange(mixed), len(sparse))
        picks = torch.cat([pixels[torch.randint(len(pixels), (len(share),), device=pixels.device)]
                           for pixels, share in zip(sparse.values(), shares)])
        return joined(batch, pixels_at(image_batch, *picks.unbind(-1)))


def pixels_at(
    image_batch: Dict, index: Int[Tensor, " rays"], rows: Int[Tensor, " rays"], columns: Int[Tensor, " rays"]
) -> Dict[str, Tensor]:
    """Every per-pixel value of the cached images at (image, row, column), with nerfstudio's `indices`."""
    pixels = {key: value[index, rows, columns] for key, value in image_batch.items()
              if key != "image_idx" and isinstance(value, Tensor)}
    pixels["indices"] = torch.stack([image_batch["image_idx"][index.cpu()].to(rows), rows, columns], dim=-1)
    return pixels


def joined(first: Dict, second: Dict) -> Dict:
    """The rays of `first` followed by those of `second`, key by key; a key only one of them has keeps its value
    (`second`'s where both have a non-ray value)."""
    both = {key: torch.cat([first[key].to(value), value]) for key, value in second.items()
            if isinstance(value, Tensor) and value.ndim > 0 and isinstance(first.get(key), Tensor)}
    return {**first, **second, **both}


def prepend(patches: Dict, batch: Dict) -> Dict:
    """The patch rays followed by the batch's rays (keys the batch lacks are dropped, but for the patch count)."""
    return {**joined({key: patches[key] for key in batch if key in patches}, batch),
            SMOOTHNESS_PATCHES_KEY: patches[SMOOTHNESS_PATCHES_KEY]}
