"""The viewer's semantics panel: a legend (class name and colour) and a choice of one class to show over RGB.

nerfstudio's viewer installs every `ViewerElement` it finds on the model's sub-modules under "Custom Elements" and
re-renders when one changes, so this panel is a plain `nn.Module` holding elements; the model reads
`highlighted_class` while rendering.
"""

from __future__ import annotations

from typing import Optional, Sequence

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.viewer.viewer_elements import ViewerDropdown, ViewerRGB

ALL_CLASSES = "all classes"
"""Dropdown entry that shows every class in its colour."""


class SemanticViewerPanel(nn.Module):
    """Legend and class picker for the `semantics` output (no parameters: nothing enters the checkpoint)."""

    def __init__(self, class_names: Sequence[str], palette: Float[Tensor, "classes 3"]) -> None:
        super().__init__()
        self.class_names = list(class_names)
        self.entries = [f"{index}: {name}" for index, name in enumerate(self.class_names)]
        self.class_shown = ViewerDropdown(
            "Show class", ALL_CLASSES, [ALL_CLASSES, *self.entries],
            hint="The semantics output: every class in its colour, or one class highlighted over RGB",
        )
        # the viewer installs elements in attribute-name order: the dropdown first, then the legend by class id
        for index, entry in enumerate(self.entries):
            colour = tuple(int(round(float(value) * 255)) for value in palette[index])
            setattr(self, f"legend_{index:03d}", ViewerRGB(entry, colour, disabled=True, hint="Legend: class colour"))

    def set_classes(self, class_names: Sequence[str]) -> None:
        """Offer `class_names` in "Show class" (a class added in the Label panel; the legend keeps its entries)."""
        self.class_names = list(class_names)
        self.entries = [f"{index}: {name}" for index, name in enumerate(self.class_names)]
        self.class_shown.set_options([ALL_CLASSES, *self.entries])

    @property
    def highlighted_class(self) -> Optional[int]:
        """The class picked in the viewer, or None for all classes."""
        value = self.class_shown.value
        return self.entries.index(value) if value in self.entries else None


def highlight_class(
    logits: Float[Tensor, "*bs classes"], rgb: Float[Tensor, "*bs 3"], palette: Float[Tensor, "classes 3"],
    class_id: int,
) -> Float[Tensor, "*bs 3"]:
    """RGB dimmed to grey, with the pixels whose most likely class is `class_id` tinted in that class's colour."""
    grey = (0.299 * rgb[..., 0:1] + 0.587 * rgb[..., 1:2] + 0.114 * rgb[..., 2:3]).expand_as(rgb)
    chosen = (logits.argmax(dim=-1, keepdim=True) == class_id).to(rgb.dtype)
    tinted = 0.35 * rgb + 0.65 * palette[class_id].to(rgb)
    return torch.lerp(0.4 * grey, tinted, chosen)
