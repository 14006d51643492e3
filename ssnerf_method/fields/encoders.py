"""Shared position encoders F_enc: position -> (raw density, feature e_x).

`PositionalMLPEncoder` is the paper's (NeRF positional encoding + 8x256 MLP with a skip); `HashGridEncoder` is the
`ssnerf-lite` one (nerfstudio's multi-resolution `HashEncoding` + a small MLP), which learns far faster on a CPU.
Both take positions already contracted into [-2, 2] by the field.
"""

from __future__ import annotations

from typing import Literal, Tuple

import torch
from jaxtyping import Float
from torch import Tensor, nn

from nerfstudio.field_components.encodings import NeRFEncoding
from nerfstudio.field_components.mlp import MLP, MLPWithHashEncoding


class PositionEncoder(nn.Module):
    """Interface of F_enc: contracted positions in [-2, 2] -> raw density and a feature vector."""

    feature_dim: int

    def forward(self, positions: Float[Tensor, "*bs 3"]) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        raise NotImplementedError


class PositionalMLPEncoder(PositionEncoder):
    """NeRF's F_enc: sinusoidal encoding (10 frequencies) and an MLP with the input concatenated again mid-way."""

    def __init__(self, num_layers: int = 8, width: int = 256, num_frequencies: int = 10, skip_at: int = 4) -> None:
        super().__init__()
        self.encoding = NeRFEncoding(
            in_dim=3, num_frequencies=num_frequencies, min_freq_exp=0.0, max_freq_exp=num_frequencies - 1.0,
            include_input=True,
        )
        self.trunk = MLP(
            in_dim=self.encoding.get_out_dim(), num_layers=num_layers, layer_width=width, out_dim=width,
            skip_connections=(skip_at,), activation=nn.ReLU(), out_activation=nn.ReLU(),
        )
        self.density_head = nn.Linear(width, 1)
        self.feature_layer = nn.Linear(width, width)
        self.feature_dim = width

    def forward(self, positions: Float[Tensor, "*bs 3"]) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        hidden = self.trunk(self.encoding(positions))
        return self.density_head(hidden), self.feature_layer(hidden)


class HashGridEncoder(PositionEncoder):
    """Multi-resolution hash grid (nerfstudio's `HashEncoding`, torch path on CPU) followed by a small MLP."""

    def __init__(
        self,
        num_levels: int = 12,
        base_res: int = 16,
        max_res: int = 512,
        log2_hashmap_size: int = 17,
        features_per_level: int = 2,
        hidden_dim: int = 64,
        feature_dim: int = 15,
        implementation: Literal["tcnn", "torch"] = "torch",
    ) -> None:
        super().__init__()
        self.mlp = MLPWithHashEncoding(
            num_levels=num_levels, min_res=base_res, max_res=max_res, log2_hashmap_size=log2_hashmap_size,
            features_per_level=features_per_level, num_layers=2, layer_width=hidden_dim, out_dim=1 + feature_dim,
            activation=nn.ReLU(), out_activation=None, implementation=implementation,
        )
        self.feature_dim = feature_dim

    def forward(self, positions: Float[Tensor, "*bs 3"]) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs feature"]]:
        unit = (positions + 2.0) / 4.0  # the grid expects [0, 1]
        out = self.mlp(unit.reshape(-1, 3)).view(*positions.shape[:-1], -1)
        return torch.split(out, [1, self.feature_dim], dim=-1)  # type: ignore[return-value]
