"""CUDA-only checks (skipped without a GPU; `scripts/gpu_check.sh` runs them on a lent one): nerfacc's fused weights
against the pure-torch path on CUDA tensors, and one training step of each method on the GPU."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from nerfstudio.cameras.rays import RayBundle

from ssnerf_method.rendering.weights import nerfacc_weights, volume_weights

from conftest import write_tiny_dataset

pytestmark = [pytest.mark.cuda, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")]


def test_nerfacc_weights_on_cuda_match_the_torch_path() -> None:
    torch.manual_seed(0)
    num_rays, num_samples = 256, 48
    edges = torch.sort(torch.rand(num_rays, num_samples + 1) * 4, dim=-1).values.cuda()
    bundle = RayBundle(
        origins=torch.zeros(num_rays, 3, device="cuda"),
        directions=torch.tensor([[0.0, 0.0, 1.0]], device="cuda").expand(num_rays, 3).clone(),
        pixel_area=torch.ones(num_rays, 1, device="cuda"),
    )
    samples = bundle.get_ray_samples(edges[:, :-1, None], edges[:, 1:, None])
    sigmas = torch.rand(num_rays, num_samples, 1, device="cuda") * 5
    fused = volume_weights(samples, sigmas)  # nerfacc on CUDA
    assert fused.is_cuda
    assert torch.allclose(fused, samples.get_weights(sigmas), atol=1e-5)
    assert torch.allclose(nerfacc_weights(samples, sigmas).cpu(), samples.get_weights(sigmas).cpu(), atol=1e-5)


@pytest.mark.parametrize("method", ["ssnerf-lite", "ssnerf"])
def test_one_training_step_on_cuda(method: str, tmp_path: Path) -> None:
    from test_training import lite_config, train

    write_tiny_dataset(tmp_path / "data")
    config = lite_config(tmp_path / "data", tmp_path / "outputs", iterations=3)
    if method == "ssnerf":
        import copy

        from ssnerf_method.method_configs import ssnerf_config

        config.pipeline.model = copy.deepcopy(ssnerf_config.pipeline.model)
        config.pipeline.model.num_coarse_samples = config.pipeline.model.num_fine_samples = 16
        config.optimizers = copy.deepcopy(ssnerf_config.optimizers)
        config.method_name = "ssnerf"
    config.machine.device_type = "cuda"
    trainer, totals, _ = train(config)
    assert len(totals) == 3 and all(torch.isfinite(torch.tensor(totals)))
    assert next(trainer.pipeline.model.parameters()).is_cuda
