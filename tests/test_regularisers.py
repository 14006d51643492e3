"""The optional training terms (`model/regularisers/`): a new one is one new file, the model trains every active one
and no inactive one, and a config.yml saved in the flat layout before them loads into them."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Dict

import pytest
import torch
import yaml
from test_properties import make_bundle

from nerfstudio.data.scene_box import SceneBox

from ssnerf_method.model import regularisers
from ssnerf_method.model.ssnerf_model import SSNeRFModelConfig

TINY = dict(encoder="hashgrid", grid_levels=4, grid_max_res=32, grid_log2_hashmap_size=10, grid_hidden_dim=16,
            grid_feature_dim=8, decoder_width=16, num_coarse_samples=16, num_fine_samples=8, density_noise=0.0,
            density_activation="trunc_exp")


def terms(**settings: Dict[str, float]) -> Dict[str, regularisers.RegulariserConfig]:
    """Every registered term at its defaults, `mult` 0 (so that a test turns on only what it names), then
    `settings` per term name, e.g. terms(depth={"mult": 0.1})."""
    configs = regularisers.default_regularisers()
    for config in configs.values():
        config.mult = 0.0
    for name, values in settings.items():
        for key, value in values.items():
            setattr(configs[name], key, value)
    return configs


def small_model(properties=("normals",), regularisers=None, metadata=None, **overrides):
    """A tiny hierarchical SS-NeRF on a 4-unit box, with only the terms `regularisers` turns on."""
    config = SSNeRFModelConfig(properties=properties, regularisers=regularisers or terms(),  # type: ignore[arg-type]
                               **{**TINY, **overrides})
    return config.setup(scene_box=SceneBox(aabb=torch.tensor([[-2.0] * 3, [2.0] * 3])), num_train_data=1,
                        metadata=metadata or {"semantic_classes": ["a", "b"],
                                              "available_properties": ("semantics", "normals", "shading")})


TOY = '''
from dataclasses import dataclass, field
from typing import Type

from ssnerf_method.model.regularisers.base import Regulariser, RegulariserConfig


class Toy(Regulariser):
    """The mean rendered accumulation, pulled towards 0."""

    def loss(self, model, outputs, batch):
        return self.config.mult * outputs["accumulation"].mean()


@dataclass
class ToyConfig(RegulariserConfig):
    _target: Type = field(default_factory=lambda: Toy)
    name = "toy"
'''


def test_a_new_regulariser_is_one_new_file(tmp_path: Path, monkeypatch) -> None:
    """A file in the regularisers' folder is found, is in every new config (off), and once on, the model logs its
    loss and its gradient reaches the field; no other file changes."""
    (tmp_path / "toy.py").write_text(textwrap.dedent(TOY))
    monkeypatch.setattr(regularisers, "__path__", [*regularisers.__path__, str(tmp_path)])
    monkeypatch.setattr(regularisers.base, "REGULARISERS", dict(regularisers.REGULARISERS))
    monkeypatch.setattr(regularisers, "REGULARISERS", regularisers.base.REGULARISERS)
    regularisers.discover()
    assert "toy" in SSNeRFModelConfig().regularisers and SSNeRFModelConfig().regularisers["toy"].mult == 0.0
    bundle, batch = make_bundle(num_rays=16), {"image": torch.rand(16, 3)}
    for mult, expected in ((0.0, False), (0.5, True)):
        torch.manual_seed(0)
        model = small_model((), regularisers=terms(toy={"mult": mult}))
        model.train()
        outputs = model(bundle)
        losses = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
        assert ("toy_loss" in losses) == expected
    model.zero_grad()
    losses["toy_loss"].backward()
    assert torch.isfinite(losses["toy_loss"]) and float(losses["toy_loss"].detach()) > 0
    assert any(p.grad is not None and p.grad.abs().max() > 0 for p in model.sampling.final_field.encoder.parameters())


def test_every_term_is_registered_and_only_the_affinity_is_on_by_default() -> None:
    defaults = SSNeRFModelConfig().regularisers
    assert set(defaults) >= {"depth", "depth_smoothness", "semantic_affinity"}
    assert {name for name, config in defaults.items() if config.mult > 0} == {"semantic_affinity"}


FLAT = """!!python/object:ssnerf_method.model.ssnerf_model.SSNeRFModelConfig
properties: !!python/tuple [semantics]
grid_feature_dim: 32
balance_ratio: 0.1
balance_every: 50
compile_fields: false
depth_loss_mult: 0.2
depth_sigma: 0.05
depth_smoothness_mult: 0.1
semantic_affinity_mult: 0.5
semantic_affinity_stride: 3
pixel_patches: 7
normals_density_mult: 0.0
hash_lookup: gathered
"""


def test_a_config_saved_in_the_flat_layout_loads_into_the_nested_one() -> None:
    """A run's config.yml from before the terms had modules (`config_upgrade.py`): moved fields land in their nested
    config, removed options are dropped, and what the file lacks takes its default."""
    config = yaml.load(FLAT, Loader=yaml.Loader)
    assert config.grid_feature_dim == 32 and config.properties == ("semantics",)
    assert (config.balancing.ratio, config.balancing.every, config.compile.enabled) == (0.1, 50, False)
    assert config.compile.min_steps == 300 and config.compile.bfloat16_matmuls
    depth, smooth, affinity = (config.regularisers[name] for name in ("depth", "depth_smoothness", "semantic_affinity"))
    assert (depth.mult, depth.sigma, smooth.mult, smooth.patches) == (0.2, 0.05, 0.1, 7)
    assert (affinity.mult, affinity.stride, affinity.patches, affinity.edge) == (0.5, 3, 7, 10.0)
    for removed in ("normals_density_mult", "hash_lookup", "balance_ratio", "pixel_patches"):
        assert not hasattr(config, removed)
    again = yaml.load(yaml.dump(config), Loader=yaml.Loader)  # and a config saved now loads as saved
    assert again.regularisers["depth"].mult == 0.2 and again.balancing.ratio == 0.1


@pytest.mark.parametrize("settings, patches, always, stride", [
    ({}, 32, False, 2),  # the affinity alone (on by default): while class labels are sparse, at its stride
    ({"semantic_affinity": {"mult": 0.0}}, 0, False, 4),  # nothing asks: batches as before
    ({"depth_smoothness": {"mult": 0.1, "patches": 7}}, 32, True, 4),  # the smoothness wants them on every batch
    ({"semantic_affinity": {"mult": 0.0}, "depth_smoothness": {"mult": 0.1, "patches": 7}}, 7, True, 4),
])
def test_the_terms_patch_requests_reach_the_sampler(settings, patches: int, always: bool, stride: int) -> None:
    from copy import deepcopy

    from ssnerf_method.method_configs import ssnerf_lite_config
    from ssnerf_method.pipelines.ssnerf_pipeline import hand_patches_to_sampler

    config = deepcopy(ssnerf_lite_config.pipeline)
    configured = config.model.regularisers
    for name, values in settings.items():
        for key, value in values.items():
            setattr(configured[name], key, value)
    hand_patches_to_sampler(config)
    sampler = config.datamanager.pixel_sampler
    assert sampler.smoothness_patches == patches
    if patches:
        assert sampler.patches_while_class_sparse != always and sampler.smoothness_patch_stride == stride
