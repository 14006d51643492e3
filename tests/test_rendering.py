"""Volume rendering, per-kind renderers, losses and metrics against hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.field_components.field_heads import FieldHeadNames

from ssnerf_method.data.pose_metadata import POSE_METADATA_KEY
from ssnerf_method.model.losses import LOSSES, cross_entropy_loss, l1_loss, mse_loss
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig
from ssnerf_method.properties import (
    SEMANTIC_IGNORE,
    UNNAMED_LOGIT,
    ClassKind,
    NormalKind,
    RenderContext,
    ScalarKind,
    class_uncertainty,
)
from ssnerf_method.rendering.sampling import RaySampling, SampleLevel, SamplingResult
from ssnerf_method.rendering.weights import nerfacc_weights, volume_weights

STARTS = [0.0, 0.5, 1.5]
ENDS = [0.5, 1.5, 1.75]
SIGMAS = [1.0, 2.0, 4.0]


def hand_weights() -> torch.Tensor:
    """w_m = T_m (1 - exp(-sigma_m delta_m)), T_m = exp(-sum_{k<m} sigma_k delta_k), written out."""
    d0, d1, d2 = 0.5, 1.0, 0.25
    s0, s1, s2 = SIGMAS
    w0 = 1.0 * (1 - math.exp(-s0 * d0))
    w1 = math.exp(-s0 * d0) * (1 - math.exp(-s1 * d1))
    w2 = math.exp(-s0 * d0 - s1 * d1) * (1 - math.exp(-s2 * d2))
    return torch.tensor([w0, w1, w2])


def make_ray_samples(num_rays: int = 1, starts=STARTS, ends=ENDS, c2w: torch.Tensor | None = None) -> RaySamples:
    metadata = {}
    if c2w is not None:
        metadata[POSE_METADATA_KEY] = c2w.reshape(1, 12).expand(num_rays, 12).clone()
    bundle = RayBundle(
        origins=torch.zeros(num_rays, 3),
        directions=torch.tensor([[-1.0, 0.0, 0.0]]).expand(num_rays, 3).clone(),
        pixel_area=torch.ones(num_rays, 1),
        camera_indices=torch.zeros(num_rays, 1, dtype=torch.long),
        metadata=metadata,
    )
    bin_starts = torch.tensor(starts).view(1, -1, 1).expand(num_rays, -1, 1).clone()
    bin_ends = torch.tensor(ends).view(1, -1, 1).expand(num_rays, -1, 1).clone()
    return bundle.get_ray_samples(bin_starts, bin_ends)


def densities(num_rays: int = 1) -> torch.Tensor:
    return torch.tensor(SIGMAS).view(1, -1, 1).expand(num_rays, -1, 1).clone()


# ---------------------------------------------------------------------------------------------------- weights


def test_volume_weights_hand_computed() -> None:
    weights = volume_weights(make_ray_samples(), densities())
    assert weights.shape == (1, 3, 1)
    assert torch.allclose(weights[0, :, 0], hand_weights(), atol=1e-6)
    # total opacity = 1 - exp(-sum sigma delta)
    assert torch.isclose(weights.sum(), torch.tensor(1 - math.exp(-(0.5 + 2.0 + 1.0))), atol=1e-6)


def test_volume_weights_zero_density_and_opaque_first_sample() -> None:
    zero = volume_weights(make_ray_samples(), torch.zeros(1, 3, 1))
    assert torch.equal(zero, torch.zeros(1, 3, 1))
    opaque = volume_weights(make_ray_samples(), torch.tensor([[[1e4], [1.0], [1.0]]]))
    assert torch.allclose(opaque[0, :, 0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)


def test_nerfacc_weights_agree_with_torch_path() -> None:
    torch.manual_seed(0)
    num_rays, num_samples = 4, 7
    edges = torch.sort(torch.rand(num_rays, num_samples + 1) * 3, dim=-1).values
    bundle = RayBundle(
        origins=torch.zeros(num_rays, 3), directions=torch.tensor([[0.0, 0.0, 1.0]]).expand(num_rays, 3).clone(),
        pixel_area=torch.ones(num_rays, 1),
    )
    samples = bundle.get_ray_samples(edges[:, :-1, None], edges[:, 1:, None])
    sigmas = torch.rand(num_rays, num_samples, 1) * 5
    expected = volume_weights(samples, sigmas)
    got = nerfacc_weights(samples, sigmas)
    assert got.shape == expected.shape
    assert torch.allclose(got, expected, atol=1e-5)
    # and the hand case
    assert torch.allclose(nerfacc_weights(make_ray_samples(), densities())[0, :, 0], hand_weights(), atol=1e-6)


# ---------------------------------------------------------------------------------------------------- kinds


def test_scalar_and_semantic_rendering_is_weighted_sum() -> None:
    weights = hand_weights().view(1, 3, 1)
    values = torch.tensor([[[0.2], [0.9], [0.4]]])
    expected = (hand_weights() * torch.tensor([0.2, 0.9, 0.4])).sum()
    for activation in ("sigmoid", "relu"):
        rendered = ScalarKind(activation).render(values, weights, RenderContext())
        assert rendered.shape == (1, 1)
        assert torch.isclose(rendered[0, 0], expected)
    logits = torch.tensor([[[1.0, -2.0, 0.5], [0.0, 3.0, 1.0], [2.0, 2.0, -1.0]]])
    rendered = ClassKind().render(logits, weights, RenderContext())
    assert torch.allclose(rendered[0], (hand_weights()[:, None] * logits[0]).sum(0))


def test_scalar_activations() -> None:
    raw = torch.tensor([-2.0, 0.0, 3.0])
    assert torch.allclose(ScalarKind("sigmoid").activation(raw), torch.sigmoid(raw))
    assert torch.equal(ScalarKind("relu").activation(raw), torch.tensor([0.0, 0.0, 3.0]))
    assert torch.equal(ClassKind().activation(raw), raw)  # logits stay logits per sample


LOGITS = torch.tensor([[[10.0, 0.0], [0.0, 1.0]]])  # one ray, two samples, two classes
HALF = torch.tensor([[[0.5], [0.5]]])


def test_softmax_after_rendering_differs_from_rendering_probabilities() -> None:
    rendered_logits = ClassKind().render(LOGITS, HALF, RenderContext())
    assert torch.allclose(rendered_logits, torch.tensor([[5.0, 0.5]]))
    after = torch.softmax(rendered_logits, dim=-1)
    before = (HALF * torch.softmax(LOGITS, dim=-1)).sum(-2)
    assert not torch.allclose(after, before, atol=1e-2)
    assert after[0, 0] > 0.98 and 0.6 < before[0, 0] < 0.7


class FixedSampling(RaySampling):
    """A sampling strategy returning fixed samples, field outputs and weights (to test the model's rendering)."""

    def __init__(self, result: SamplingResult) -> None:
        super().__init__()
        self.result = result

    def forward(self, ray_bundle: RayBundle) -> SamplingResult:
        return self.result


def tiny_model(properties=("semantics", "normals", "shading"), **overrides):
    settings = dict(
        encoder="hashgrid", grid_levels=2, grid_max_res=16, grid_log2_hashmap_size=8, grid_hidden_dim=16,
        grid_feature_dim=8, decoder_width=16, num_coarse_samples=4, num_fine_samples=4, density_noise=0.0,
    )
    config = SSNeRFModelConfig(properties=properties, **{**settings, **overrides})  # type: ignore[arg-type]
    model = config.setup(
        scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])),
        num_train_data=1,
        metadata={"semantic_classes": ["a", "b"], "available_properties": ("semantics", "normals", "shading")},
    )
    return model


# camera looking along world -x (OpenGL: camera -z = world -x), camera up = world +z
LOOK_MINUS_X = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns: x_c, y_c, z_c in world
C2W = torch.cat([LOOK_MINUS_X, torch.tensor([[3.0], [0.0], [0.0]])], dim=-1)


def test_model_renders_semantic_logits_then_softmax_and_cross_entropy() -> None:
    model = tiny_model()
    model.eval()
    samples = make_ray_samples(1, starts=[0.0, 0.5], ends=[0.5, 1.0], c2w=C2W)
    # rendered logits favour class 1, rendered probabilities would favour class 0
    logits = torch.tensor([[[0.0, 10.0], [1.0, 0.0]]])
    weights = torch.tensor([[[0.3], [0.7]]])
    prob_render = (weights * torch.softmax(logits, -1)).sum(-2)[0]
    assert prob_render.argmax() == 0
    outputs = {
        "rgb": torch.full((1, 2, 3), 0.5),
        "semantics": logits,
        "normals": torch.tensor([[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]]),
        "shading": torch.tensor([[[0.2], [0.6]]]),
        FieldHeadNames.DENSITY: torch.ones(1, 2, 1),
    }
    model.sampling = FixedSampling(SamplingResult(levels=[SampleLevel(samples, outputs, weights)]))
    bundle = RayBundle(
        origins=torch.tensor([[3.0, 0.0, 0.0]]), directions=torch.tensor([[-1.0, 0.0, 0.0]]),
        pixel_area=torch.ones(1, 1), camera_indices=torch.zeros(1, 1, dtype=torch.long),
        metadata={POSE_METADATA_KEY: C2W.reshape(1, 12)},
    )
    rendered = model.get_outputs(bundle)
    assert torch.allclose(rendered["semantics_logits"], torch.tensor([[0.7, 3.0]]))
    # display: palette colour of the argmax of the rendered logits (class 1), not of rendered probabilities (0)
    assert not torch.allclose(model.palette[0], model.palette[1])
    assert torch.allclose(rendered["semantics"], model.palette[1][None])
    probabilities = torch.softmax(torch.tensor([0.7, 3.0]), dim=-1)  # uncertainty from the rendered logits too
    entropy = -(probabilities * probabilities.log()).sum()
    assert torch.allclose(rendered["semantics_uncertainty"], (entropy / math.log(2.0)).reshape(1, 1), atol=1e-6)
    model.train()  # the exporters' outputs are for eval-mode renders: a training step does not compute them
    assert "semantics_uncertainty" not in model.get_outputs(bundle) and "semantics_logits" in model.get_outputs(bundle)
    model.eval()
    assert torch.allclose(rendered["shading_value"], torch.tensor([[0.48]]))
    assert torch.allclose(rendered["shading"], torch.tensor([[0.48, 0.48, 0.48]]))  # grey, range fixed to [0, 1]
    # world normal +x faces this camera: camera frame (0, 0, 1) -> encoding (0.5, 0.5, 1)
    assert torch.allclose(rendered["normals"], torch.tensor([[0.5, 0.5, 1.0]]), atol=1e-6)

    batch = {
        "image": torch.full((1, 3), 0.5),
        "semantics": torch.tensor([[1.0]]),
        "normals": torch.tensor([[0.5, 0.5, 1.0]]),
        "shading": torch.tensor([[0.48]]),
    }
    losses = model.get_loss_dict(rendered, batch, model.get_metrics_dict(rendered, batch))
    expected_ce = -torch.log_softmax(torch.tensor([0.7, 3.0]), dim=-1)[1]
    assert torch.isclose(losses["semantics_loss"], 0.04 * expected_ce, atol=1e-5)
    assert torch.isclose(cross_entropy_loss(rendered["semantics_logits"], batch["semantics"], torch.tensor([True])),
                         expected_ce, atol=1e-5)
    # a pure softmax-then-render model would give a different loss: the test above discriminates
    assert not torch.isclose(expected_ce, -torch.log(prob_render[1]), atol=1e-2)
    assert torch.isclose(losses["normals_loss"], torch.tensor(0.0), atol=1e-10)
    assert torch.isclose(losses["shading_loss"], torch.tensor(0.0), atol=1e-7)
    assert set(losses) == {"rgb_loss", "semantics_loss", "normals_loss", "shading_loss"}


def test_class_uncertainty_is_entropy_over_the_named_classes() -> None:
    """0 for one certain class, 1 for the named classes equally likely, whatever spare slots the model holds; the
    point cloud gets it beside the class id."""
    named = torch.tensor([[30.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 1.0, 0.0]])
    spare = torch.cat([named, torch.full((3, 2), UNNAMED_LOGIT)], dim=-1)
    for logits in (named, spare):
        uncertainty = class_uncertainty(logits)
        assert uncertainty.shape == (3, 1)
        assert uncertainty[0, 0] < 1e-9 and torch.isclose(uncertainty[1, 0], torch.tensor(1.0))
        assert 0.5 < uncertainty[2, 0] < 0.9
    assert torch.allclose(class_uncertainty(spare), class_uncertainty(named))
    exported = ClassKind().export_outputs("semantics", spare, RenderContext())
    assert set(exported) == {"semantics_uncertainty"} and ClassKind().display_extras("semantics") == list(exported)
    values = ClassKind().point_values("semantics", {"semantics_logits": spare, **exported})
    assert values["semantics"].tolist() == [0, 0, 0] and values["semantics_uncertainty"].shape == (3,)


# ---------------------------------------------------------------------------------------------------- normals


def render_world_normals(world_normals: torch.Tensor, c2w_rotation: torch.Tensor) -> torch.Tensor:
    num = world_normals.shape[0]
    values = world_normals[:, None, :].expand(num, 2, 3) * 2.0  # not unit length: the renderer normalises
    weights = torch.tensor([[[0.3], [0.5]]]).expand(num, 2, 1)
    context = RenderContext(world_to_camera=c2w_rotation.T.expand(num, 3, 3))
    return NormalKind("world").render(values, weights, context)


def test_world_normals_rotated_into_camera_frame() -> None:
    world = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    rendered = render_world_normals(world, LOOK_MINUS_X)
    expected = torch.tensor([
        [0.5, 0.5, 1.0],  # facing the camera
        [0.5, 1.0, 0.5],  # world up -> camera up
        [1.0, 0.5, 0.5],  # world +y -> camera right
        [0.5, 0.5, 0.0],  # facing away
    ])
    assert torch.allclose(rendered, expected, atol=1e-6)


def test_world_normals_with_conftest_look_at() -> None:
    """The same with a camera built like the tiny dataset's: at (2, 0, 0) looking at the origin."""

    from conftest import look_at

    c2w = torch.tensor(look_at(np.array([2.0, 0.0, 0.0]), np.zeros(3)), dtype=torch.float32)
    rendered = render_world_normals(torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), c2w[:3, :3])
    assert torch.allclose(rendered, torch.tensor([[0.5, 0.5, 1.0], [0.5, 1.0, 0.5]]), atol=1e-6)


def test_rays_without_a_camera_keep_world_normals() -> None:
    """nerfstudio's exporters probe the model with rays that carry no camera: normals stay in world axes."""
    world = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    rendered = NormalKind("world").render(world[:, None, :] * 3.0, torch.ones(2, 1, 1), RenderContext())
    assert torch.allclose(rendered, (world + 1.0) / 2.0)


@pytest.mark.parametrize("mode", ["world", "pose"])
def test_export_normals_are_world_frame(mode: str) -> None:
    """`normals_world` undoes the camera rotation of the camera-frame prediction, in both normal modes."""
    world = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    context = RenderContext(world_to_camera=LOOK_MINUS_X.T.expand(3, 3, 3))
    camera_frame = render_world_normals(world, LOOK_MINUS_X)
    exported = NormalKind(mode).export_outputs("normals", camera_frame, context)
    assert set(exported) == {"normals_world"}
    assert torch.allclose(exported["normals_world"], (world + 1.0) / 2.0, atol=1e-6)
    values = NormalKind(mode).point_values("normals", exported)
    assert torch.allclose(torch.stack([values[axis] for axis in ("nx", "ny", "nz")], -1), world, atol=1e-6)


def test_pose_normals_pass_encoding_through() -> None:
    kind = NormalKind("pose")
    values = torch.tensor([[[0.2, 0.4, 0.9], [0.6, 0.8, 0.1]]])
    weights = torch.tensor([[[0.25], [0.75]]])
    # no rotation even when a camera rotation is given
    rendered = kind.render(values, weights, RenderContext(world_to_camera=LOOK_MINUS_X.T[None]))
    assert torch.allclose(rendered, (weights * values).sum(-2))
    assert torch.allclose(kind.activation(torch.tensor([0.0, 100.0])), torch.tensor([0.5, 1.0]))
    assert torch.equal(NormalKind("world").activation(torch.tensor([-3.0])), torch.tensor([-3.0]))


# ---------------------------------------------------------------------------------------------------- losses


def test_losses_mask_invalid_rays() -> None:
    prediction = torch.tensor([[0.2, 0.4, 0.6], [0.1, 0.1, 0.1], [0.9, 0.9, 0.9]], requires_grad=True)
    label = torch.tensor([[0.3, 0.4, 0.4], [float("nan")] * 3, [1.0, 1.0, 0.6]])
    valid = NormalKind().valid(label)
    assert valid.tolist() == [True, False, True]
    mse = mse_loss(prediction, label, valid)
    expected_mse = ((0.1**2 + 0 + 0.2**2) + (0.1**2 + 0.1**2 + 0.3**2)) / 6
    assert torch.isclose(mse, torch.tensor(expected_mse))
    l1 = l1_loss(prediction, label, valid)
    assert torch.isclose(l1, torch.tensor((0.1 + 0 + 0.2 + 0.1 + 0.1 + 0.3) / 6))
    (mse + l1).backward()
    assert torch.isfinite(prediction.grad).all()
    assert torch.equal(prediction.grad[1], torch.zeros(3))  # the unlabelled ray gets no gradient


def test_cross_entropy_ignores_unlabelled_pixels() -> None:
    logits = torch.tensor([[2.0, 0.0, -1.0], [0.0, 5.0, 0.0], [1.0, 1.0, 1.0]])
    label = torch.tensor([[0.0], [float(SEMANTIC_IGNORE)], [2.0]])
    valid = ClassKind().valid(label)
    assert valid.tolist() == [True, False, True]
    loss = cross_entropy_loss(logits, label, valid)
    log_probs = torch.log_softmax(logits, dim=-1)
    assert torch.isclose(loss, -(log_probs[0, 0] + log_probs[2, 2]) / 2)


@pytest.mark.parametrize("name", ["mse", "l1", "cross_entropy"])
def test_all_invalid_gives_zero_with_gradient_path(name: str) -> None:
    prediction = torch.randn(4, 3, requires_grad=True)
    if name == "cross_entropy":
        label = torch.full((4, 1), float(SEMANTIC_IGNORE))
        valid = ClassKind().valid(label)
    else:
        label = torch.full((4, 3), float("nan"))
        valid = NormalKind().valid(label)
    assert not valid.any()
    loss = LOSSES[name](prediction, label, valid)
    assert loss.item() == 0.0
    assert loss.requires_grad
    loss.backward()
    assert torch.equal(prediction.grad, torch.zeros(4, 3))
