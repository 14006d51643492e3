"""The paper's Hybrid baseline: a NeRF renders novel-view RGB, and per property a separate image-to-property network
(a Taskonomy-style encoder-decoder) annotates the rendered image.

Each network is trained on the training views' ground-truth RGB and labels, with the property's own loss from the
registry (cross-entropy for semantics, MSE for normals, ...); at test time it is applied to the RGB the RGB-only NeRF
renders for the test camera. Normals are predicted as their camera-frame (n+1)/2 encoding. The sizes are small, so
that five networks train on a CPU in about a minute for the default scene.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Dict, List, Optional, Sequence, Union

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.cameras.cameras import Cameras

from ssnerf_method.data.dataset import SSNeRFDataset
from ssnerf_method.model.losses import LOSSES
from ssnerf_method.properties import PropertySpec


class EncoderDecoder(nn.Module):
    """Image-to-image network: `depth` stride-2 conv blocks down, as many bilinear-upsampling conv blocks up, no skip
    connections (the Taskonomy encoder-decoder shape, at a CPU-friendly size)."""

    def __init__(self, out_channels: int, width: int = 32, depth: int = 3) -> None:
        super().__init__()
        self.depth = depth
        down, channels = [], 3
        for level in range(depth):
            out = width * 2**level
            down += [nn.Conv2d(channels, out, 3, stride=2, padding=1), nn.ReLU(),
                     nn.Conv2d(out, out, 3, padding=1), nn.ReLU()]
            channels = out
        up = []
        for level in reversed(range(depth)):
            out = width * 2 ** max(level - 1, 0)
            up += [nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                   nn.Conv2d(channels, out, 3, padding=1), nn.ReLU()]
            channels = out
        self.encoder = nn.Sequential(*down)
        self.decoder = nn.Sequential(*up, nn.Conv2d(channels, out_channels, 3, padding=1))

    def forward(self, rgb: Float[Tensor, "batch 3 h w"]) -> Float[Tensor, "batch c h w"]:
        height, width = rgb.shape[-2:]
        multiple = 2**self.depth
        padded = F.pad(rgb, (0, -width % multiple, 0, -height % multiple), mode="replicate")
        return self.decoder(self.encoder(padded))[..., :height, :width]


@dataclass
class HybridBaselineConfig:
    """Sizes and schedule of the Hybrid baseline's per-property networks."""

    width: int = 32
    """Channels of the first encoder level (doubling per level)."""
    depth: int = 3
    """Encoder levels (each halves the resolution)."""
    steps: int = 400
    """Training steps per property network."""
    batch_size: int = 4
    """Training views per step."""
    learning_rate: float = 2e-3
    seed: int = 0


def annotator_spec(spec: PropertySpec) -> PropertySpec:
    """The property as an image annotator predicts it (`PropertyKind.per_pixel`: normals as the camera-frame
    encoding, as the paper's pose-conditioned head predicts them; everything else as the registry says)."""
    return replace(spec, kind=spec.kind.per_pixel())


class HybridBaseline:
    """One trained encoder-decoder per property; predicts properties from (rendered) RGB images."""

    def __init__(
        self, train: Union[SSNeRFDataset, Sequence[SSNeRFDataset]], specs: Sequence[PropertySpec], num_classes: int,
        config: Optional[HybridBaselineConfig] = None,
    ) -> None:
        """`train`: the views to learn from; several datasets (of one image size) are pooled, as the data-augmentation
        study pools ground truth and SS-NeRF renders."""
        self.config = config or HybridBaselineConfig()
        self.specs = [annotator_spec(spec) for spec in specs if spec.file_key is not None]
        self.num_classes = num_classes
        datasets = [train] if isinstance(train, SSNeRFDataset) else list(train)
        items = [dataset[index] for dataset in datasets for index in range(len(dataset))]
        sizes = {tuple(item["image"].shape[:2]) for item in items}
        if len(sizes) != 1:
            raise ValueError(f"The annotators train on images of one size; these datasets have {sorted(sizes)} (H, W).")
        self.images = torch.stack([item["image"][..., :3] for item in items]).permute(0, 3, 1, 2)
        self.labels = {spec.name: torch.stack([spec.label(item, num_classes) for item in items]) for spec in self.specs}
        self.networks = nn.ModuleDict({
            spec.name: EncoderDecoder(spec.kind.head_channels(num_classes), self.config.width, self.config.depth)
            for spec in self.specs
        })

    def fit(self, on_step: Optional[Callable[[str, int], None]] = None) -> Dict[str, List[float]]:
        """Train every property's network on the training views; returns each one's loss per step."""
        history: Dict[str, List[float]] = {}
        generator = torch.Generator().manual_seed(self.config.seed)
        for spec in self.specs:
            torch.manual_seed(self.config.seed)
            network = self.networks[spec.name]
            optimizer = torch.optim.Adam(network.parameters(), lr=self.config.learning_rate)
            history[spec.name] = []
            for step in range(self.config.steps):
                batch = torch.randint(len(self.images), (self.config.batch_size,), generator=generator)
                label = self.labels[spec.name][batch].reshape(-1, self.labels[spec.name].shape[-1])
                prediction = self._activated(spec, network(self.images[batch])).reshape(label.shape[0], -1)
                loss = LOSSES[spec.loss](prediction, label, spec.kind.valid(label))
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                history[spec.name].append(float(loss))
                if on_step is not None:
                    on_step(spec.name, step)
        return history

    @staticmethod
    def _activated(spec: PropertySpec, raw: Float[Tensor, "batch c h w"]) -> Float[Tensor, "batch h w c"]:
        return spec.kind.activation(raw.permute(0, 2, 3, 1))

    @torch.no_grad()
    def predict_image(self, rgb: Float[Tensor, "h w 3"]) -> Dict[str, Tensor]:
        """Each property's prediction for one RGB image, in the model's prediction layout (semantics: logits)."""
        image = rgb[..., :3].permute(2, 0, 1)[None].float().cpu()
        return {spec.name: self._activated(spec, self.networks[spec.name](image))[0] for spec in self.specs}

    def predictor(self, render_rgb: Callable[[Cameras, int], Tensor]) -> Callable[[Cameras, int], Dict[str, Tensor]]:
        """A `scoring.Predictor`: annotate the RGB that `render_rgb` (the RGB-only NeRF) renders for a camera."""
        return lambda cameras, index: self.predict_image(render_rgb(cameras, index))
