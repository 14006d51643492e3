"""Class colours for displaying semantics: the dataset's `semantic_colors`, else a fixed distinct palette."""

from __future__ import annotations

import colorsys
from typing import Optional, Sequence

import torch
from jaxtyping import Float
from torch import Tensor


def default_palette(num_classes: int) -> Float[Tensor, "classes 3"]:
    """Distinct colours by stepping the hue by the golden ratio; class 0 (void) is black."""
    colors = [(0.0, 0.0, 0.0)]
    for index in range(1, num_classes):
        hue = (index * 0.618033988749895) % 1.0
        colors.append(colorsys.hsv_to_rgb(hue, 0.65 + 0.35 * (index % 2), 0.95 - 0.25 * ((index // 2) % 2)))
    return torch.tensor(colors[:num_classes], dtype=torch.float32)


def semantic_palette(num_classes: int, colors: Optional[Sequence[Sequence[int]]] = None) -> Float[Tensor, "classes 3"]:
    """Palette in [0, 1] from 0-255 triples when the dataset gives them; classes after the given colours (added in
    the viewer, or spare class slots) take `default_palette`'s."""
    palette = default_palette(num_classes)
    if colors:
        given = torch.tensor(colors, dtype=torch.float32)[:num_classes] / 255.0
        palette = torch.cat([given, palette[len(given):]]) if len(given) < num_classes else given
    return palette
