"""Normals that shape the density (`normals_density_mult`): the density's own normals by finite differences, and a
loss that moves the density, not the normals head, towards the predicted normals."""

from __future__ import annotations

import pytest
import torch
from test_properties import make_bundle

from nerfstudio.data.scene_box import SceneBox

from ssnerf_method.fields.encoders import PositionEncoder
from ssnerf_method.fields.ssnerf_field import SSNeRFField
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig


def small_model(properties=("normals",), **overrides):
    settings = dict(encoder="hashgrid", grid_levels=4, grid_max_res=32, grid_log2_hashmap_size=10, grid_hidden_dim=16,
                    grid_feature_dim=8, decoder_width=16, num_coarse_samples=16, num_fine_samples=8,
                    density_noise=0.0, density_activation="trunc_exp", normals_density_mult=1.0)
    config = SSNeRFModelConfig(properties=properties, **{**settings, **overrides})  # type: ignore[arg-type]
    return config.setup(scene_box=SceneBox(aabb=torch.tensor([[-2.0] * 3, [2.0] * 3])), num_train_data=1,
                        metadata={"semantic_classes": ["a", "b"],
                                  "available_properties": ("semantics", "normals", "shading")})


class Slab(PositionEncoder):
    """Raw density rising along `axis` (a wall whose outside faces minus `axis`)."""

    feature_dim = 8

    def __init__(self, axis: torch.Tensor) -> None:
        super().__init__()
        self.axis = torch.nn.Parameter(axis.clone())

    def forward(self, positions):
        return 4.0 * (positions * self.axis).sum(-1, keepdim=True), torch.zeros(*positions.shape[:-1], 8)


def test_the_density_normals_point_out_of_the_density_and_are_differentiable() -> None:
    model = small_model()
    field = next(module for module in model.modules() if isinstance(module, SSNeRFField))
    axis = torch.tensor([0.3, -0.8, 0.5])
    field.encoder = Slab(axis)
    positions = torch.rand(5, 7, 3) - 0.5  # inside the contraction's identity region
    normals = field.density_normals(positions, 0.01)
    assert normals.shape == (5, 7, 3)
    torch.testing.assert_close(normals, -torch.nn.functional.normalize(axis, dim=0).expand(5, 7, 3))
    normals[..., 0].sum().backward()
    assert field.encoder.axis.grad is not None and field.encoder.axis.grad.abs().max() > 0


def test_the_loss_exists_only_while_training_world_normals_and_reaches_the_density_not_the_head() -> None:
    torch.manual_seed(0)
    bundle = make_bundle(num_rays=32)
    batch = {"image": torch.full((32, 3), 0.5), "normals": torch.full((32, 3), 0.5),
             "shading": torch.full((32, 1), 0.5)}
    for properties, overrides, expected in ((("normals",), {}, True), (("normals",), {"normals_density_mult": 0.0},
                                            False), (("shading",), {}, False),
                                            (("normals",), {"normals_mode": "pose"}, False)):
        model = small_model(properties, **overrides)
        model.train()
        outputs = model(bundle)
        assert ("normals_density_loss" in model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
                ) == expected, (properties, overrides)
    model = small_model()
    model.eval()
    assert "normals_density" not in model(bundle)
    model.train()
    outputs = model(bundle)
    loss = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))["normals_density_loss"]
    loss.backward()
    field = model.sampling.final_field
    assert any(p.grad is not None and p.grad.abs().max() > 0 for p in field.encoder.parameters())
    heads = [p for decoder in field.decoders.values() for p in decoder.parameters()]
    assert heads and all(p.grad is None or p.grad.abs().max() == 0 for p in heads)  # the predicted normals: detached


@pytest.mark.filterwarnings("ignore")
def test_trained_on_the_loss_alone_the_density_turns_to_the_predicted_normals() -> None:
    torch.manual_seed(0)
    model = small_model()
    model.train()
    bundle = make_bundle(num_rays=64)
    batch = {"image": torch.full((64, 3), 0.5), "normals": torch.full((64, 3), 0.5)}
    field = model.sampling.final_field
    optimizer = torch.optim.Adam(field.encoder.parameters(), lr=1e-2)

    def loss() -> torch.Tensor:
        outputs = model(bundle)
        return model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))["normals_density_loss"]

    before = float(loss())
    for _ in range(60):
        optimizer.zero_grad()
        loss().backward()
        optimizer.step()
    after = float(loss())
    assert after < 0.5 * before, (before, after)
