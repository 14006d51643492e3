"""The depth smoothness of a model whose depth makes normals: 3x3 pixel patches in the batch, a loss that only bends
pay."""

from __future__ import annotations

import pytest
import torch

from ssnerf_method.data.pixel_sampler import PATCH_RAYS, SMOOTHNESS_PATCHES_KEY, LabelledPixelSamplerConfig
from ssnerf_method.model.losses import planar_smoothness_loss


def image_batch() -> dict:
    """Three 20x24 images whose colour is (image, row, column), so a sampled ray tells where it came from."""
    grid = torch.stack(torch.meshgrid(torch.arange(3), torch.arange(20), torch.arange(24), indexing="ij"), -1)
    return {"image": grid.float(), "image_idx": torch.tensor([4, 5, 6])}


def test_patches_open_the_batch_as_strided_3x3_grids_of_one_image() -> None:
    sampler = LabelledPixelSamplerConfig(num_rays_per_batch=100, smoothness_patches=5,
                                         smoothness_patch_stride=3).setup()
    batch = sampler.sample(image_batch())
    assert batch["image"].shape == (100, 3) and batch["indices"].shape == (100, 3)
    assert int(batch[SMOOTHNESS_PATCHES_KEY]) == 5
    patches = batch["image"][: 5 * PATCH_RAYS].view(5, 3, 3, 3)
    assert (patches[..., 0] == patches[:, :1, :1, 0]).all(), "a patch lies in one image"
    assert (patches[:, 1:, :, 1] - patches[:, :-1, :, 1] == 3).all(), "rows 3 pixels apart"
    assert (patches[:, :, 1:, 2] - patches[:, :, :-1, 2] == 3).all(), "columns 3 pixels apart"
    # every row is one whole pixel: camera index and place agree with its colour
    assert torch.equal(batch["indices"][:, 0], batch["image"][:, 0].long() + 4)
    assert torch.equal(batch["indices"][:, 1:], batch["image"][:, 1:].long())
    assert sampler.num_rays_per_batch == 100, "the uniform share is restored after each batch"


def test_without_patches_the_batch_is_as_before() -> None:
    torch.manual_seed(1)
    ours = LabelledPixelSamplerConfig(num_rays_per_batch=64).setup().sample(image_batch())
    assert SMOOTHNESS_PATCHES_KEY not in ours and ours["image"].shape == (64, 3)


def plane_inverse_depth(patches: int) -> torch.Tensor:
    """Inverse z-depth of random planes at 3x3 pixels: affine in the pixel."""
    rows, columns = torch.meshgrid(torch.arange(3.0), torch.arange(3.0), indexing="ij")
    a, b = torch.rand(patches, 1, 1) * 0.05, torch.rand(patches, 1, 1) * 0.05
    return 0.5 + a * rows + b * columns


def test_planes_cost_nothing_bends_do_and_edges_soften_them() -> None:
    flat_colours = torch.full((8, PATCH_RAYS, 3), 0.5)
    plane = plane_inverse_depth(8)
    assert float(planar_smoothness_loss(plane, flat_colours, edge=10.0)) == pytest.approx(0.0, abs=1e-6)
    bent = plane.clone()
    bent[:, 1, 1] += 0.05
    bent.requires_grad_(True)
    loss = planar_smoothness_loss(bent, flat_colours, edge=10.0)
    assert float(loss.detach()) > 0.1
    loss.backward()
    assert (bent.grad[:, 1, 1] > 0).all(), "the gradient pulls the bulge back towards the plane"
    edged = flat_colours.clone()
    edged[:, 0] = 1.0  # one pixel of each patch across a colour edge
    assert float(planar_smoothness_loss(bent.detach(), edged, edge=10.0)) < 0.01 * float(loss)


def test_the_model_loss_needs_the_patches_and_reaches_the_density() -> None:
    from test_properties import make_bundle
    from test_regularisers import small_model, terms

    torch.manual_seed(0)
    patches = 2
    bundle = make_bundle(num_rays=32)
    batch = {"image": torch.rand(32, 3)}
    patched = {**batch, SMOOTHNESS_PATCHES_KEY: torch.tensor(patches)}
    for mult, given, expected in ((0.1, patched, True), (0.0, patched, False), (0.1, batch, False)):
        model = small_model((), regularisers=terms(depth_smoothness={"mult": mult}))
        model.train()
        outputs = model(bundle)
        losses = model.get_loss_dict(outputs, given, model.get_metrics_dict(outputs, given))
        assert ("depth_smoothness_loss" in losses) == expected, (mult, given.keys())
    model.zero_grad()
    outputs = model(bundle)  # the last model: smoothness on
    loss = model.get_loss_dict(outputs, patched, model.get_metrics_dict(outputs, patched))["depth_smoothness_loss"]
    assert torch.isfinite(loss) and float(loss.detach()) > 0
    loss.backward()
    assert any(p.grad is not None and p.grad.abs().max() > 0 for p in model.sampling.final_field.encoder.parameters())


def test_patches_keep_off_the_pixels_a_mask_excludes() -> None:
    masked = image_batch()
    masked["mask"] = torch.ones(3, 20, 24, 1, dtype=torch.bool)
    masked["mask"][:, :, 12:] = False  # the right half of every image is excluded
    sampler = LabelledPixelSamplerConfig(num_rays_per_batch=200, smoothness_patches=10,
                                         smoothness_patch_stride=2).setup()
    batch = sampler.sample(masked)
    patches = int(batch[SMOOTHNESS_PATCHES_KEY])
    assert 0 < patches <= 10
    assert (batch["image"][: patches * PATCH_RAYS, 2] < 12).all()
