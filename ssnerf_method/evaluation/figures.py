"""Property images for people: predictions and labels as the viewer shows them (8-bit RGB), and grids of them: the
paper's Fig. 3 (rows of methods, columns of properties) and the studies' figures."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from ssnerf_method.properties import PropertySpec


def display_image(image: torch.Tensor) -> np.ndarray:
    """A display image (`PropertySpec.display`: colours in [0, 1]) as 8-bit RGB."""
    return (image.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)


def shown(spec: PropertySpec, prediction: torch.Tensor, palette: torch.Tensor) -> np.ndarray:
    """A prediction (the model's layout) as the viewer shows it, 8-bit RGB."""
    return display_image(spec.display(prediction.detach().cpu(), palette.cpu()))


def shown_label(
    spec: PropertySpec, item: Dict[str, torch.Tensor], num_classes: int, palette: torch.Tensor
) -> np.ndarray:
    """A dataset item's label of `spec` (ground truth, or a weak or rendered label) as the viewer shows it."""
    return shown(spec, spec.kind.label_as_prediction(spec.label(item, num_classes), num_classes), palette)


def property_grid(
    path: Path,
    specs: Sequence[PropertySpec],
    rows: Dict[str, Dict[str, Optional[np.ndarray]]],
    title: str,
) -> None:
    """Save a grid: one row per method (name -> property name -> 8-bit RGB image, None = not predicted), one column
    per property, titled with the paper's abbreviations."""
    image_grid(path, [(spec.name, spec.short) for spec in specs], rows, title)


def image_grid(
    path: Path,
    columns: Sequence[Tuple[str, str]],
    rows: Dict[str, Dict[str, Optional[np.ndarray]]],
    title: str,
) -> None:
    """Save a grid of 8-bit RGB images: `columns` are (key, title) pairs, `rows` map a row title to key -> image
    (missing or None: drawn as "n/a")."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names: List[str] = list(rows)
    height, width = next(image for row in rows.values() for image in row.values() if image is not None).shape[:2]
    scale = 2.2 / max(width, height) * max(width, 1)
    figure, axes = plt.subplots(
        len(names), len(columns), figsize=(scale * len(columns), scale * height / width * len(names) + 0.6),
        squeeze=False,
    )
    for row, name in enumerate(names):
        for column, (key, heading) in enumerate(columns):
            axis = axes[row][column]
            image = rows[name].get(key)
            axis.imshow(image if image is not None else np.full((height, width, 3), 235, dtype=np.uint8))
            if image is None:
                axis.text(width / 2, height / 2, "n/a", ha="center", va="center", color="grey")
            axis.set_xticks([])
            axis.set_yticks([])
            if row == 0:
                axis.set_title(heading, fontsize=10)
            if column == 0:
                axis.set_ylabel(name, fontsize=9)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=150)
    plt.close(figure)
