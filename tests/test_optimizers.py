"""The methods' Adam (`engine/optimizers.py`): torch's fused kernel, nerfstudio's update, checkpoints either way."""

from __future__ import annotations

import copy
from typing import List

import pytest
import torch

from nerfstudio.engine.optimizers import AdamOptimizerConfig

from ssnerf_method.engine.optimizers import FusedAdamOptimizerConfig
from ssnerf_method.method_configs import ssnerf_config, ssnerf_lite_config


def parameters(seed: int = 0) -> List[torch.nn.Parameter]:
    generator = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(shape, generator=generator)) for shape in ((4096, 2), (64, 64), (64,))]


def train(optimizer: torch.optim.Optimizer, params: List[torch.nn.Parameter], steps: int, seed: int = 1) -> None:
    generator = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        for param in params:
            param.grad = torch.randn(param.shape, generator=generator)
        optimizer.step()


@pytest.mark.parametrize("method", [ssnerf_config, ssnerf_lite_config], ids=["ssnerf", "ssnerf-lite"])
def test_the_methods_adam_is_fused_on_a_cpu(method) -> None:
    for group in method.optimizers.values():
        optimizer = group["optimizer"].setup(parameters())
        assert isinstance(optimizer, torch.optim.Adam) and optimizer.defaults["fused"] is True
        assert optimizer.defaults["eps"] == group["optimizer"].eps and optimizer.defaults["lr"] == group["optimizer"].lr


def test_fused_adam_makes_nerfstudios_update() -> None:
    config = dict(lr=1e-2, eps=1e-15, weight_decay=1e-3)
    plain_params, fused_params = parameters(), parameters()
    train(AdamOptimizerConfig(**config).setup(plain_params), plain_params, steps=20)
    train(FusedAdamOptimizerConfig(**config).setup(fused_params), fused_params, steps=20)
    moved = max(float((param - start).abs().max()) for param, start in zip(fused_params, parameters()))
    assert moved > 0.1  # 20 steps of lr 1e-2 move every weight
    for plain, fused in zip(plain_params, fused_params):
        torch.testing.assert_close(fused, plain, rtol=1e-5, atol=1e-6)


def test_an_unfused_checkpoint_resumes_in_the_fused_optimizer() -> None:
    """A checkpoint written before the methods used the fused kernel goes on training as it would have."""
    config = dict(lr=1e-2, eps=1e-15)
    old_params = parameters()
    old = AdamOptimizerConfig(**config).setup(old_params)
    train(old, old_params, steps=5)
    state = copy.deepcopy(old.state_dict())  # (as torch.save and torch.load would copy it)
    resumed_params = [torch.nn.Parameter(param.detach().clone()) for param in old_params]
    resumed = FusedAdamOptimizerConfig(**config).setup(resumed_params)
    resumed.load_state_dict(state)
    train(old, old_params, steps=5, seed=2)
    train(resumed, resumed_params, steps=5, seed=2)
    for expected, got in zip(old_params, resumed_params):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)


def test_parameters_the_fused_kernel_cannot_take_use_the_default_adam() -> None:
    optimizer = FusedAdamOptimizerConfig().setup([torch.nn.Parameter(torch.zeros(3, device="meta"))])
    assert optimizer.defaults["fused"] is None
