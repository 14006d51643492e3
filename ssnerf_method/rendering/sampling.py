"""Where along each ray the field is evaluated: one interface, two strategies.

`HierarchicalSampling` is the paper's (NeRF's): uniform coarse samples through a coarse field, then importance
samples drawn from the coarse weights through the fine field; both levels are rendered and supervised.
`ProposalSampling` is `ssnerf-lite`'s: nerfstudio's proposal sampler with small density-only grids finds the
surfaces, and only the field's own samples are rendered; the proposals learn through nerfstudio's interlevel loss.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Tuple, Union

import numpy as np
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.fields.base_field import Field
from nerfstudio.model_components.ray_samplers import PDFSampler, ProposalNetworkSampler, UniformSampler

from ssnerf_method.fields.compiled import CompiledOrEager
from ssnerf_method.fields.ssnerf_field import SSNeRFField
from ssnerf_method.rendering.weights import volume_weights


@dataclass
class SampleLevel:
    """Samples of one level, the field's outputs at them and their rendering weights."""

    ray_samples: RaySamples
    field_outputs: Dict[Union[FieldHeadNames, str], Float[Tensor, "*bs num_samples channels"]]
    """Per sample: density (`FieldHeadNames.DENSITY`) and each property's activated head output, by name."""
    weights: Float[Tensor, "*bs num_samples 1"]


@dataclass
class SamplingResult:
    """The supervised levels (last = final prediction) and, for proposal sampling, the proposal levels."""

    levels: List[SampleLevel]
    weights_list: List[Tensor] = field(default_factory=list)
    ray_samples_list: List[RaySamples] = field(default_factory=list)


def evaluate(field_module: Field, ray_samples: RaySamples) -> SampleLevel:
    """Run a field on samples and compute their weights."""
    outputs = field_module(ray_samples)
    return SampleLevel(ray_samples, outputs, volume_weights(ray_samples, outputs[FieldHeadNames.DENSITY]))


def flat_density(density_fn: Callable[[Tensor], Tensor]) -> Callable[[Tensor], Tensor]:
    """`density_fn` evaluated on the positions as one flat batch (what a compiled network runs fastest on)."""

    def density(positions: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 1"]:
        return density_fn(positions.reshape(-1, 3)).view(*positions.shape[:-1], 1)

    return density


class RaySampling(nn.Module):
    """Interface: a ray bundle in, the evaluated and weighted sample levels out."""

    num_levels: int = 1
    """Number of supervised levels `forward` returns."""

    def forward(self, ray_bundle: RayBundle) -> SamplingResult:
        raise NotImplementedError

    @property
    def final_field(self) -> Field:
        """The field whose outputs make the final level (the rendered prediction)."""
        raise NotImplementedError

    def before_training_step(self, step: int) -> None:
        """Called before each training step (schedules)."""

    def after_training_step(self, step: int) -> None:
        """Called after each training step (schedules)."""

    def param_groups(self) -> Dict[str, List[nn.Parameter]]:
        """Parameters by optimizer group name (the method config names an optimizer per group)."""
        return {"fields": list(self.parameters())}

    def compile_for_training(self, bfloat16_matmuls: bool = False) -> None:
        """Run the networks' training forwards (and backwards) through `torch.compile` (`fields/compiled.py`), with
        their matrix multiplications in bfloat16 if asked."""
        for module in self.modules():
            if isinstance(module, SSNeRFField):
                module.compile_for_training(bfloat16_matmuls)


class HierarchicalSampling(RaySampling):
    """Coarse (uniform, stratified) then fine (PDF of the coarse weights, coarse samples kept) samples."""

    num_levels = 2

    def __init__(self, coarse_field: Field, fine_field: Field, num_coarse: int, num_fine: int) -> None:
        super().__init__()
        self.coarse_field = coarse_field
        self.fine_field = fine_field
        self.uniform_sampler = UniformSampler(num_samples=num_coarse)
        self.pdf_sampler = PDFSampler(num_samples=num_fine, include_original=True)

    @property
    def final_field(self) -> Field:
        return self.fine_field

    def forward(self, ray_bundle: RayBundle) -> SamplingResult:
        coarse = evaluate(self.coarse_field, self.uniform_sampler(ray_bundle))
        fine_samples = self.pdf_sampler(ray_bundle, coarse.ray_samples, coarse.weights.detach())
        return SamplingResult(levels=[coarse, evaluate(self.fine_field, fine_samples)])


class ProposalSampling(RaySampling):
    """nerfstudio's proposal sampler in front of one field (as in nerfacto)."""

    def __init__(
        self,
        field_module: Field,
        proposal_networks: nn.ModuleList,
        num_proposal_samples: Tuple[int, ...],
        num_field_samples: int,
        update_every: int = 5,
        warmup_steps: int = 5000,
        anneal_steps: int = 1000,
    ) -> None:
        super().__init__()
        self.field_module = field_module
        self.proposal_networks = proposal_networks
        self.anneal_steps = anneal_steps

        def update_schedule(step: int) -> int:
            return int(np.clip(np.interp(step, [0, warmup_steps], [0, update_every]), 1, update_every))

        self.density_fns: List[Callable[[Tensor], Tensor]] = [network.density_fn for network in proposal_networks]
        """What the sampler calls for each proposal network's density while training (`compile_for_training`)."""
        self.sampler = ProposalNetworkSampler(
            num_nerf_samples_per_ray=num_field_samples,
            num_proposal_samples_per_ray=num_proposal_samples,
            num_proposal_network_iterations=len(num_proposal_samples),
            single_jitter=True,
            update_sched=update_schedule,
        )

    @property
    def final_field(self) -> Field:
        return self.field_module

    def forward(self, ray_bundle: RayBundle) -> SamplingResult:
        density_fns = self.density_fns if self.training else [network.density_fn for network in self.proposal_networks]
        ray_samples, weights_list, ray_samples_list = self.sampler(ray_bundle, density_fns=density_fns)
        level = evaluate(self.field_module, ray_samples)
        return SamplingResult(
            levels=[level],
            weights_list=[*weights_list, level.weights],
            ray_samples_list=[*ray_samples_list, ray_samples],
        )

    def before_training_step(self, step: int) -> None:
        """Anneal the proposal weights before resampling (mip-NeRF 360 Eq. 18, slope 10), as nerfacto does."""
        fraction = float(np.clip(step / self.anneal_steps, 0, 1))
        self.sampler.set_anneal(10.0 * fraction / (9.0 * fraction + 1.0))

    def after_training_step(self, step: int) -> None:
        self.sampler.step_cb(step)

    def compile_for_training(self, bfloat16_matmuls: bool = False) -> None:
        """The field's and each proposal network's training forwards through `torch.compile`."""
        super().compile_for_training(bfloat16_matmuls)
        self.density_fns = [
            flat_density(CompiledOrEager(network.density_fn, f"proposal network {index}", bfloat16_matmuls))
            for index, network in enumerate(self.proposal_networks)
        ]

    def param_groups(self) -> Dict[str, List[nn.Parameter]]:
        return {
            "fields": list(self.field_module.parameters()),
            "proposal_networks": list(self.proposal_networks.parameters()),
        }
