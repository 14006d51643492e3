"""Multi-task balancing: property losses reach the rendering weights scaled by `property_geometry_gradient` (RGB's
in full), and the keypoint heatmap loss weights the responses as documented."""

from __future__ import annotations

import pytest
import torch

from nerfstudio.data.scene_box import SceneBox

from ssnerf_method.model.gradient_scaling import scale_gradient
from ssnerf_method.model.losses import HEATMAP_POSITIVE_WEIGHT, LOSSES
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig
from ssnerf_method.properties import RenderContext
from ssnerf_method.rendering.sampling import SampleLevel


@pytest.mark.parametrize("scale", [0.0, 0.25, 1.0])
def test_scale_gradient_keeps_the_value_and_scales_the_gradient(scale: float) -> None:
    leaf = torch.tensor([1.0, -2.0, 3.0], requires_grad=True)
    scaled = scale_gradient(leaf, scale)
    assert torch.equal(scaled, leaf.detach())
    if scale == 0.0:
        assert not scaled.requires_grad  # detached: no gradient at all
        return
    (scaled * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert torch.allclose(leaf.grad, scale * torch.tensor([1.0, 2.0, 3.0]))


def small_model(geometry_gradient: float):
    config = SSNeRFModelConfig(
        properties=("semantics", "edges"), encoder="hashgrid", grid_levels=2, grid_max_res=16,
        grid_log2_hashmap_size=8, grid_hidden_dim=16, grid_feature_dim=8, decoder_width=16, num_coarse_samples=4,
        num_fine_samples=4, property_geometry_gradient=geometry_gradient,
    )
    return config.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=1,
                        metadata={"semantic_classes": ["a", "b", "c"], "available_properties": ("semantics", "edges")})


def weight_gradients(geometry_gradient: float):
    """Gradient of each rendered output's sum with respect to a level's weights."""
    model = small_model(geometry_gradient)
    generator = torch.Generator().manual_seed(0)
    outputs = {"rgb": torch.rand(3, 5, 3, generator=generator), "semantics": torch.randn(3, 5, 3, generator=generator),
               "edges": torch.rand(3, 5, 1, generator=generator)}
    outputs = {name: values.requires_grad_() for name, values in outputs.items()}  # the field's outputs train too
    gradients = {}
    for name, key in (("rgb", "rgb"), ("semantics", "semantics_logits"), ("edges", "edges_value")):
        weights = torch.rand(3, 5, 1, generator=torch.Generator().manual_seed(1)).requires_grad_()
        level = SampleLevel(None, outputs, weights)  # type: ignore[arg-type]
        rendered = model._render_level(level, RenderContext(background_color=torch.zeros(3)), "")
        rendered[key].sum().backward()
        gradients[name] = torch.zeros_like(weights) if weights.grad is None else weights.grad.clone()
    return gradients


def test_property_losses_reach_the_weights_scaled_and_rgb_in_full() -> None:
    full, quarter, none = weight_gradients(1.0), weight_gradients(0.25), weight_gradients(0.0)
    assert full["edges"].abs().sum() > 0 and full["semantics"].abs().sum() > 0
    for name in ("semantics", "edges"):
        assert torch.allclose(quarter[name], 0.25 * full[name])
        assert torch.equal(none[name], torch.zeros_like(full[name]))
    assert torch.allclose(none["rgb"], full["rgb"]) and full["rgb"].abs().sum() > 0


def test_heatmap_l1_weights_responses() -> None:
    label = torch.tensor([[0.0], [1.0], [0.5], [0.0]])
    prediction = torch.tensor([[0.2], [0.8], [0.5], [0.0]], requires_grad=True)
    valid = torch.tensor([True, True, True, False])
    loss = LOSSES["heatmap_l1"](prediction, label, valid)
    expected = torch.tensor([1.0, 1.0 + HEATMAP_POSITIVE_WEIGHT, 1.0 + HEATMAP_POSITIVE_WEIGHT * 0.5])
    assert float(loss) == pytest.approx(float((expected * torch.tensor([0.2, 0.2, 0.0])).sum() / expected.sum()))
    loss.backward()
    # the same error costs 1 + 9 = 10 times more on a response of 1 than on background; the unlabelled ray nothing
    assert float(prediction.grad[1, 0]) == pytest.approx(-10.0 * float(prediction.grad[0, 0]))
    assert float(prediction.grad[3, 0]) == 0.0
