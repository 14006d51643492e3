"""Multi-task balancing: each property's loss is scaled so that its gradient into F_enc is at most the configured
multiple of RGB's."""

from __future__ import annotations

import pytest
import torch
from test_properties import make_bundle

from nerfstudio.data.scene_box import SceneBox

from ssnerf_method.model.loss_balancing import LossBalancer, LossBalancerConfig
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig


def test_balancer_caps_each_property_at_the_ratio_of_rgbs_gradient() -> None:
    """Hand-made losses on one shared parameter: RGB's gradient norm 2, a property's 8 and another's 0.1. With ratio
    0.5 the first is scaled to 0.5 * 2 / 8 and the second (already below 0.5 * 2) keeps its weight."""
    shared = torch.nn.Parameter(torch.tensor([1.0, 1.0]))
    balancer = LossBalancer(["loud", "quiet"], ratio=0.5, momentum=0.0)
    rgb = (shared * torch.tensor([2.0, 0.0])).sum()
    losses = {"loud": (shared * torch.tensor([0.0, 8.0])).sum(), "quiet": (shared * torch.tensor([0.1, 0.0])).sum()}
    assert float(balancer.multiplier("loud")) == 1.0  # before any measurement
    balancer.update(rgb, losses, [shared])
    assert float(balancer.multiplier("loud")) == pytest.approx(0.5 * 2.0 / 8.0)
    assert float(balancer.multiplier("quiet")) == 1.0
    scaled = losses["loud"] * balancer.multiplier("loud")
    assert LossBalancer.gradient_norm(scaled, [shared]) == pytest.approx(0.5 * 2.0)


def test_balancer_smooths_and_leaves_properties_alone_without_rgb() -> None:
    shared = torch.nn.Parameter(torch.tensor([1.0]))
    balancer = LossBalancer(["p"], ratio=1.0, momentum=0.5)
    balancer.update((shared * 1.0).sum(), {"p": (shared * 4.0).sum()}, [shared])
    assert float(balancer.multiplier("p")) == pytest.approx(0.25)
    balancer.update((shared * 1.0).sum(), {"p": (shared * 2.0).sum()}, [shared])  # smoothed norm (4 + 2) / 2 = 3
    assert float(balancer.multiplier("p")) == pytest.approx(1.0 / 3.0)
    without_rgb = LossBalancer(["p"], ratio=1.0)
    without_rgb.update((shared * 0.0).sum().detach(), {"p": (shared * 4.0).sum()}, [shared])  # RGB weight 0
    assert float(without_rgb.multiplier("p")) == 1.0


def small_model(ratio=None):
    config = SSNeRFModelConfig(
        properties=("semantics", "edges"), encoder="hashgrid", grid_levels=2, grid_max_res=16,
        grid_log2_hashmap_size=8, grid_hidden_dim=16, grid_feature_dim=8, decoder_width=16, num_coarse_samples=4,
        num_fine_samples=4, balancing=LossBalancerConfig(ratio, every=3),
    )
    return config.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=1,
                        metadata={"semantic_classes": ["a", "b", "c"], "available_properties": ("semantics", "edges")})


def test_model_scales_every_level_of_a_property_loss_by_its_multiplier() -> None:
    """The model's losses with balancing are the paper's weighted losses times each property's multiplier, on both
    levels; RGB's are untouched; the multipliers are re-measured only on the scheduled steps and logged."""
    torch.manual_seed(0)
    plain, balanced = small_model(), small_model(0.01)
    balanced.load_state_dict(plain.state_dict(), strict=False)
    for model in (plain, balanced):
        model.train()
    bundle = make_bundle(num_rays=8)
    batch = {"image": torch.rand(8, 3), "semantics": torch.randint(0, 3, (8, 1)).float(), "edges": torch.rand(8, 1)}
    callbacks = balanced.get_training_callbacks(None)  # type: ignore[arg-type]
    for callback in callbacks:
        callback.run_callback_at_location(0, callback.where_to_run[0])
    assert balanced.balance_now
    torch.manual_seed(1)
    plain_losses = plain.get_loss_dict(outputs := plain(bundle), batch, plain.get_metrics_dict(outputs, batch))
    torch.manual_seed(1)
    outputs = balanced(bundle)
    losses = balanced.get_loss_dict(outputs, batch, balanced.get_metrics_dict(outputs, batch))
    assert not balanced.balance_now  # measured once, then off until the next scheduled step
    for name in ("semantics", "edges"):
        factor = balanced.balancer.multiplier(name)
        assert float(factor) < 1.0  # a ratio of 0.01 caps any property whose gradient is more than 1% of RGB's
        for prefix in ("", "level0_"):
            assert float(losses[f"{prefix}{name}_loss"]) == pytest.approx(float(plain_losses[f"{prefix}{name}_loss"]
                                                                                * factor), rel=1e-5)
    assert float(losses["rgb_loss"]) == pytest.approx(float(plain_losses["rgb_loss"]), rel=1e-5)
    assert "edges_loss_multiplier" in balanced.get_metrics_dict(outputs, batch)
    for callback in callbacks:
        callback.run_callback_at_location(1, callback.where_to_run[0])
    assert not balanced.balance_now  # step 1 is not a multiple of balancing.every = 3


def small_field(names, sharing: str, **options):
    """A field with a tiny hash grid and 16-wide decoders (unless `options` says otherwise) for the decoder tests."""
    from test_properties import NUM_CLASSES

    from ssnerf_method.fields.encoders import HashGridEncoder
    from ssnerf_method.fields.ssnerf_field import SSNeRFField
    from ssnerf_method.properties import resolve_properties

    torch.manual_seed(0)
    encoder = HashGridEncoder(num_levels=2, base_res=4, max_res=16, log2_hashmap_size=8, hidden_dim=16, feature_dim=8)
    return SSNeRFField(resolve_properties(names), NUM_CLASSES, encoder, **{"decoder_width": 16, **options},
                       decoder_sharing=sharing)


def test_property_decoders_share_nothing_between_properties() -> None:
    """`decoder_sharing=property`: each property has its own MLP on its branch's inputs, so RGB's output has no
    gradient in edges' decoder; with the paper's branch sharing the two share the F_dec^v MLP."""
    from test_properties import NUM_CLASSES, make_samples

    samples = make_samples(make_bundle())
    for sharing, shared in (("property", False), ("branch", True)):
        field = small_field(["semantics", "edges"], sharing)
        outputs = field(samples)
        assert outputs["rgb"].shape[-1] == 3 and outputs["edges"].shape[-1] == 1
        assert outputs["semantics"].shape[-1] == NUM_CLASSES
        v = field.decoders["v"]
        edges_mlp = v.decoders["edges"].mlp if sharing == "property" else v.mlp
        edges_parameters = list(edges_mlp.parameters())
        gradients = torch.autograd.grad(outputs["rgb"].sum(), edges_parameters, allow_unused=True)
        reached = any(g is not None and g.abs().sum() > 0 for g in gradients)
        assert reached == shared


