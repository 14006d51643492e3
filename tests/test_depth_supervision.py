"""Depth supervision (the `depth` regulariser): nerfstudio's depth loss on the frames' depth maps, off by default."""

from __future__ import annotations

import torch
from test_properties import make_bundle
from test_regularisers import small_model as regularised_model
from test_regularisers import terms

from ssnerf_method.data.dataset import DEPTH_KEY

NUM_RAYS = 64


def small_model(depth_loss_mult: float, scale: float = 1.0):
    return regularised_model((), regularisers=terms(depth={"mult": depth_loss_mult, "sigma": 0.01}),
                             num_coarse_samples=32, num_fine_samples=16,
                             metadata={"semantic_classes": [], "available_properties": (), "dataparser_scale": scale})


def bundle_and_batch(metres: float):
    bundle = make_bundle(num_rays=NUM_RAYS, pose=False)
    bundle.metadata["directions_norm"] = torch.ones(NUM_RAYS, 1)  # z-depth = distance along these rays
    return bundle, {"image": torch.full((NUM_RAYS, 3), 0.5), DEPTH_KEY: torch.full((NUM_RAYS, 1), metres)}


def test_depth_loss_only_when_asked_for_and_when_the_frames_have_depth() -> None:
    torch.manual_seed(0)
    bundle, batch = bundle_and_batch(1.0)
    for mult, with_depth, expected in ((0.0, True, False), (0.1, False, False), (0.1, True, True)):
        model = small_model(mult)
        model.train()
        outputs = model(bundle)
        given = batch if with_depth else {"image": batch["image"]}
        losses = model.get_loss_dict(outputs, given, model.get_metrics_dict(outputs, given))
        assert ("depth_loss" in losses) == expected, (mult, with_depth)
    model.eval()
    assert "depth_weights_list" not in model(bundle)  # nothing kept for the loss outside training


def test_depth_loss_pulls_the_rendered_depth_to_the_label_in_scene_units() -> None:
    """Trained on the depth loss alone, the median depth moves to the label: 0.8 m at a dataparser scale of 1.5 is
    1.2 scene units along these unit-length rays."""
    torch.manual_seed(0)
    model = small_model(1.0, scale=1.5)
    model.train()
    bundle, batch = bundle_and_batch(0.8)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)

    def depth_error() -> float:
        model.eval()
        with torch.no_grad():
            error = float((model(bundle)["depth"] - 1.2).abs().mean())
        model.train()
        return error

    before = depth_error()
    for _ in range(80):
        outputs = model(bundle)
        loss = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))["depth_loss"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after = depth_error()
    assert before > 0.2
    assert after < 0.25 * before, (before, after)
