"""The semantic affinity that spreads sparse class labels over the image: a loss on 3x3 pixel patches that pays for
unlike classes on like colours, leaves labelled pairs to their labels, and patches drawn only while labels are
sparse."""

from __future__ import annotations

import pytest
import torch

from ssnerf_method.data.pixel_sampler import PATCH_RAYS, SMOOTHNESS_PATCHES_KEY, LabelledPixelSamplerConfig
from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE
from ssnerf_method.model.losses import colour_affinity_loss
from ssnerf_method.properties import class_property

CLASS_KEY = class_property().name


def test_unlike_classes_on_like_colours_cost_and_an_edge_or_two_labels_excuse_them() -> None:
    patches, classes = 6, 4
    colours = torch.full((patches, PATCH_RAYS, 3), 0.4)
    nobody = torch.zeros(patches, PATCH_RAYS, dtype=torch.bool)
    agreeing = torch.softmax(torch.randn(patches, 1, classes).expand(patches, PATCH_RAYS, classes), dim=-1)
    assert float(colour_affinity_loss(agreeing, colours, nobody, edge=10.0)) == pytest.approx(0.0, abs=1e-7)

    logits = torch.randn(patches, PATCH_RAYS, classes, requires_grad=True)
    loss = colour_affinity_loss(torch.softmax(logits, dim=-1), colours, nobody, edge=10.0)
    assert float(loss.detach()) > 0.05
    loss.backward()
    assert logits.grad is not None and logits.grad.abs().max() > 0

    probabilities = torch.softmax(logits.detach(), dim=-1)
    edged = colours.clone()
    edged[:, :4] = 1.0  # the first row and the left pixel of the middle row lie across a colour edge
    edged_loss = colour_affinity_loss(probabilities, edged, nobody, edge=10.0)
    assert float(edged_loss) < float(loss.detach()) * 0.7  # 4 of the 8 neighbours hardly count
    everybody = torch.ones_like(nobody)
    assert float(colour_affinity_loss(probabilities, colours, everybody, edge=10.0)) == 0.0  # labels decide
    centre_only = nobody.clone()
    centre_only[:, 4] = True  # a click at the centre: its unlabelled neighbours are pulled towards it
    assert float(colour_affinity_loss(probabilities, colours, centre_only, edge=10.0)) == pytest.approx(
        float(loss.detach()))


def labelled_images(labelled_share: float, count: int = 4) -> dict:
    """`count` 20x24 images whose colour's first channel is the image's index; class ids cover `labelled_share` of
    the pixels of the first three (the rest, and all of the others, `SEMANTIC_IGNORE`)."""
    generator = torch.Generator().manual_seed(0)
    labels = torch.randint(0, 3, (count, 20, 24, 1), generator=generator).float()
    labels[torch.rand(count, 20, 24, generator=generator) >= labelled_share] = SEMANTIC_IGNORE
    labels[3:] = SEMANTIC_IGNORE
    image = torch.rand(count, 20, 24, 3, generator=generator)
    image[..., 0] = torch.arange(float(count))[:, None, None]
    return {"image": image, "image_idx": torch.arange(count), CLASS_KEY: labels}


@pytest.mark.parametrize("share, expected", [(0.05, True), (1.0, False)])
def test_affinity_patches_are_drawn_only_while_the_class_labels_are_sparse(share: float, expected: bool) -> None:
    sampler = LabelledPixelSamplerConfig(num_rays_per_batch=256, smoothness_patches=8,
                                         patches_while_class_sparse=True).setup()
    batch = sampler.sample(labelled_images(share))
    assert (SMOOTHNESS_PATCHES_KEY in batch) == expected
    assert batch["image"].shape == (256, 3) and batch[CLASS_KEY].shape == (256, 1)
    if expected:  # and only in the images that hold labels
        assert (batch["image"][: 8 * PATCH_RAYS, 0] < 3).all()
    some_frames = labelled_images(share, count=40)  # three labelled frames of 40: sparse however labelled
    drawn = sampler.sample(some_frames)
    assert (SMOOTHNESS_PATCHES_KEY in drawn) == expected  # frames labelled all over have nothing to spread onto
    always = LabelledPixelSamplerConfig(num_rays_per_batch=256, smoothness_patches=8).setup()
    patched = always.sample(labelled_images(share))  # the depth smoothness's: every batch, every image
    assert int(patched[SMOOTHNESS_PATCHES_KEY]) == 8


def test_the_model_loss_follows_the_class_loss_and_reaches_the_field() -> None:
    from test_properties import make_bundle
    from test_regularisers import small_model, terms

    torch.manual_seed(0)
    patches = 2
    bundle = make_bundle(num_rays=32)
    labels = torch.full((32, 1), float(SEMANTIC_IGNORE))
    labels[4] = 1.0  # one click, at the first patch's centre
    batch = {"image": torch.rand(32, 3), CLASS_KEY: labels, SMOOTHNESS_PATCHES_KEY: torch.tensor(patches)}
    batch["image"][: patches * PATCH_RAYS] = 0.3  # the patches are of one colour
    losses = {}
    for mult in (0.0, 1.0, 2.0):
        torch.manual_seed(0)
        model = small_model((CLASS_KEY,), regularisers=terms(semantic_affinity={"mult": mult}))
        model.train()
        outputs = model(bundle)
        losses[mult] = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
    assert "semantic_affinity_loss" not in losses[0.0]
    affinity = losses[2.0]["semantic_affinity_loss"]
    assert float(affinity.detach()) > 0
    assert float(affinity.detach()) == pytest.approx(2 * float(losses[1.0]["semantic_affinity_loss"].detach()))
    affinity.backward()
    assert any(p.grad is not None and p.grad.abs().max() > 0 for p in model.sampling.final_field.parameters())
