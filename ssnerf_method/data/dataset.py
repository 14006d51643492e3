"""Dataset that returns, with each RGB image, a label tensor per property (ignore-filled where a frame lacks it).

Labels are image-shaped, so nerfstudio's pixel sampler picks the same pixels from RGB and every property. When the
frames have depth maps, their z-depth in metres is returned too (`DEPTH_KEY`), for the depth metrics.
"""

from __future__ import annotations

from typing import Dict

import numpy as np
import torch
import torch.nn.functional as F

from nerfstudio.data.datasets.base_dataset import InputDataset
from nerfstudio.data.utils.data_utils import get_depth_image_from_path

from ssnerf_method.data.io import DatasetInputError
from ssnerf_method.data.validate import depth_fault
from ssnerf_method.properties import REGISTRY

DEPTH_KEY = "depth_metres"
"""Batch key of the ground-truth z-depth in metres (0 where the depth map has no value)."""


class SSNeRFDataset(InputDataset):
    """nerfstudio's `InputDataset` plus the property labels listed by `SSNeRFDataParser`."""

    def __init__(self, dataparser_outputs, scale_factor: float = 1.0) -> None:
        super().__init__(dataparser_outputs, scale_factor)
        self.property_files = self.metadata.get("property_files", {})
        self.label_sizes = self.metadata.get("label_sizes", [])
        self.num_classes = len(self.metadata.get("semantic_classes", []))
        self.depth_files = self.metadata.get("depth_filenames")
        self.depth_unit = self.metadata.get("depth_unit_scale_factor", 1e-3)

    def get_numpy_image(self, image_idx: int) -> np.ndarray:
        """nerfstudio's image reading, with one clear error for an image whose header reads but whose data does not
        (the validator reads headers only)."""
        try:
            return super().get_numpy_image(image_idx)
        except (OSError, ValueError, SyntaxError) as err:
            path = self._dataparser_outputs.image_filenames[image_idx]
            raise DatasetInputError(f"{path}: image cannot be decoded ({err}). Re-export the file.") from err

    def get_metadata(self, data: Dict) -> Dict[str, torch.Tensor]:
        index = data["image_idx"]
        height, width = data["image"].shape[:2]
        labels = {}
        for name, files in self.property_files.items():
            kind = REGISTRY[name].kind
            path = files[index]
            if path is None:
                labels[name] = kind.missing(width, height, self.num_classes)
                continue
            expected = self.label_sizes[index] if all(self.label_sizes[index]) else (width, height)
            label = kind.read(path, *expected, self.num_classes)
            if label.shape[:2] != (height, width):  # images were downscaled: labels follow, nearest-neighbour
                label = F.interpolate(label.permute(2, 0, 1)[None], size=(height, width), mode="nearest")[0]
                label = label.permute(1, 2, 0)
            labels[name] = label
        if self.depth_files is not None:
            depth = get_depth_image_from_path(self.depth_files[index], height, width, self.depth_unit)
            if (fault := depth_fault(self.depth_files[index], depth.numpy())) is not None:
                raise DatasetInputError(fault)
            labels[DEPTH_KEY] = depth
        return labels
