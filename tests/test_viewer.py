"""What people see: each property's display colours (a known class map gives its palette colours, a normal facing the
camera is (0.5, 0.5, 1.0), scalar maps keep the fixed range [0, 1]), the semantics panel's legend and class picker,
and a model whose viewer outputs are the display images only."""

from __future__ import annotations

import torch

from ssnerf_method.properties import REGISTRY
from ssnerf_method.rendering.palette import default_palette, semantic_palette
from ssnerf_method.viewer.semantic_panel import ALL_CLASSES, SemanticViewerPanel, highlight_class

COLORS = [[0, 0, 0], [255, 0, 0], [0, 128, 255]]


def test_a_known_class_map_gives_the_dataset_colours() -> None:
    palette = semantic_palette(3, COLORS)
    classes = torch.tensor([[0, 1], [2, 1]])
    logits = torch.nn.functional.one_hot(classes, 3).float() * 5.0
    shown = REGISTRY["semantics"].display(logits, palette)
    expected = torch.tensor(COLORS, dtype=torch.float32)[classes] / 255.0
    assert torch.equal(shown, expected)


def test_without_dataset_colours_the_palette_is_fixed_and_distinct() -> None:
    palette = semantic_palette(13)
    assert torch.equal(palette, default_palette(13))  # the same colours on every run
    assert torch.cdist(palette, palette).add(torch.eye(13)).min() > 0.1  # no two classes look alike


def test_a_normal_facing_the_camera_is_light_blue() -> None:
    facing = torch.tensor([[[0.0, 0.0, 1.0]]])  # camera frame, OpenGL: towards the camera
    shown = REGISTRY["normals"].display((facing + 1.0) / 2.0)
    assert torch.allclose(shown, torch.tensor([[[0.5, 0.5, 1.0]]]))


def test_scalar_maps_keep_the_fixed_range() -> None:
    """A dim frame stays dim (no per-frame normalisation), values outside [0, 1] clip, NaN (unlabelled) is black."""
    values = torch.tensor([[[0.1], [0.2]], [[1.7], [float("nan")]]])
    for name in [spec.name for spec in REGISTRY.values() if spec.kind.head_channels(4) == 1]:  # one-channel maps
        shown = REGISTRY[name].display(values)
        assert shown.shape == (2, 2, 3)
        expected = torch.tensor([[0.1, 0.2], [1.0, 0.0]])[..., None].expand(2, 2, 3)
        assert torch.allclose(shown, expected), name
    rays = REGISTRY["shading"].display(torch.tensor([[0.25], [0.5]]))  # per-ray (N, 1) values, as in get_outputs
    assert torch.allclose(rays, torch.tensor([[0.25] * 3, [0.5] * 3]))


def test_legend_and_class_picker() -> None:
    palette = semantic_palette(3, COLORS)
    panel = SemanticViewerPanel(["void", "wall", "sky"], palette)
    assert panel.highlighted_class is None and panel.class_shown.value == ALL_CLASSES
    legend = [panel.legend_000, panel.legend_001, panel.legend_002]  # type: ignore[attr-defined]
    assert [entry.name for entry in legend] == ["0: void", "1: wall", "2: sky"]
    assert [entry.default_value for entry in legend] == [tuple(colour) for colour in COLORS]
    assert all(entry.disabled for entry in legend)
    assert not list(panel.parameters())  # nothing of the panel enters a checkpoint
    panel.class_shown.value = "2: sky"
    assert panel.highlighted_class == 2


def test_highlight_tints_the_chosen_class_over_grey_rgb() -> None:
    palette = semantic_palette(3, COLORS)
    logits = torch.tensor([[0.0, 3.0, 0.0], [0.0, 0.0, 3.0]])
    rgb = torch.tensor([[0.2, 0.4, 0.6], [0.2, 0.4, 0.6]])
    shown = highlight_class(logits, rgb, palette, class_id=2)
    grey = 0.299 * 0.2 + 0.587 * 0.4 + 0.114 * 0.6
    assert torch.allclose(shown[0], torch.full((3,), 0.4 * grey))  # another class: dimmed grey
    assert torch.allclose(shown[1], 0.35 * rgb[1] + 0.65 * palette[2])  # the chosen class: its colour over RGB
