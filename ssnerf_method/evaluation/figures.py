"""Property images for people: display images as 8-bit RGB, and the paper's Fig. 3 grid (rows of methods,
columns of properties) for one test view."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch

from ssnerf_method.properties import PropertySpec


def display_image(image: torch.Tensor) -> np.ndarray:
    """A display image (`PropertySpec.display`: colours in [0, 1]) as 8-bit RGB."""
    return (image.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)


def property_grid(
    path: Path,
    specs: Sequence[PropertySpec],
    rows: Dict[str, Dict[str, Optional[np.ndarray]]],
    title: str,
) -> None:
    """Save a grid: one row per method (name -> property name -> 8-bit RGB image, None = not predicted), one column
    per property, titled with the paper's abbreviations."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names: List[str] = list(rows)
    height, width = next(image for row in rows.values() for image in row.values() if image is not None).shape[:2]
    scale = 2.2 / max(width, height) * max(width, 1)
    figure, axes = plt.subplots(
        len(names), len(specs), figsize=(scale * len(specs), scale * height / width * len(names) + 0.6), squeeze=False
    )
    for row, name in enumerate(names):
        for column, spec in enumerate(specs):
            axis = axes[row][column]
            image = rows[name].get(spec.name)
            axis.imshow(image if image is not None else np.full((height, width, 3), 235, dtype=np.uint8))
            if image is None:
                axis.text(width / 2, height / 2, "n/a", ha="center", va="center", color="grey")
            axis.set_xticks([])
            axis.set_yticks([])
            if row == 0:
                axis.set_title(spec.short, fontsize=10)
            if column == 0:
                axis.set_ylabel(name, fontsize=9)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=150)
    plt.close(figure)
