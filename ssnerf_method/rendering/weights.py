"""Volume-rendering weights w_m = T_m * (1 - exp(-sigma_m * delta_m)) (paper Eq. 1-2), chosen by device.

On CUDA nerfacc's fused kernel computes them; elsewhere nerfstudio's pure-torch `RaySamples.get_weights` does, so
the CPU path never touches a CUDA extension.
"""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from nerfstudio.cameras.rays import RaySamples


def nerfacc_weights(ray_samples: RaySamples, densities: Float[Tensor, "*bs num_samples 1"]) -> Tensor:
    """nerfacc's batched (non-packed) weights; same values as `RaySamples.get_weights`."""
    import nerfacc

    weights, _, _ = nerfacc.render_weight_from_density(
        t_starts=ray_samples.frustums.starts[..., 0],
        t_ends=ray_samples.frustums.ends[..., 0],
        sigmas=densities[..., 0],
    )
    return weights[..., None]


def volume_weights(ray_samples: RaySamples, densities: Float[Tensor, "*bs num_samples 1"]) -> Tensor:
    """Per-sample weights, through nerfacc on CUDA and plain torch on every other device."""
    if densities.is_cuda:
        return nerfacc_weights(ray_samples, densities)
    return ray_samples.get_weights(densities)
