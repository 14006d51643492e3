"""Shared position encoders F_enc: position -> (raw density, feature e_x).

`PositionalMLPEncoder` is the paper's (NeRF positional encoding + 8x256 MLP with a skip); `HashGridEncoder` is the
`ssnerf-lite` one (nerfstudio's multi-resolution `HashEncoding` + a small MLP), which learns far faster on a CPU.
Both take positions already contracted into [-2, 2] by the field.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Literal, Optional, Tuple

import torch
from jaxtyping import Float, Int
from torch import Tensor, nn

from nerfstudio.field_components.encodings import HashEncoding, NeRFEncoding
from nerfstudio.field_components.mlp import MLP, MLPWithHashEncoding


def unit_cube(contracted: Float[Tensor, "*bs 3"]) -> Float[Tensor, "*bs 3"]:
    """Positions contracted into [-2, 2] (`SceneContraction`) mapped to [0, 1], where hash grids expect them."""
    return (contracted + 2.0) / 4.0


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
        out = self.mlp(unit_cube(positions).reshape(-1, 3)).view(*positions.shape[:-1], -1)
        return torch.split(out, [1, self.feature_dim], dim=-1)  # type: ignore[return-value]


_HASH_PRIMES = (1, 2654435761, 805459861)
"""Instant-NGP's spatial hash primes, as `HashEncoding.hash_fn` multiplies the three axes by them."""


_column_worker: Optional[ThreadPoolExecutor] = None
"""One thread that sums `add_rows`' second column while the calling thread sums the first (made on first use)."""


def _sum_columns_in_parallel(columns: int) -> bool:
    """Whether `add_rows` sums the columns on two threads: only where torch may use more than one, so that a run
    told to use one thread (one of several training side by side) keeps to one core."""
    return columns > 1 and torch.get_num_threads() > 1


@torch.library.custom_op("ssnerf::add_rows", mutates_args=())
def add_rows(index: Tensor, values: Tensor, rows: int) -> Tensor:
    """`rows` zero rows with each row of `values` added at its `index` (the backward of a row gather).

    On a CPU the sum runs serially per column (`torch.bincount`), which is also deterministic; where torch has more
    than one thread, the first column on this thread and the rest on one worker thread (a hash grid's two features
    per level, measured on 2026-12-05: about 5% of a compiled step at 2 threads). As a custom op
    it is opaque to inductor, which would compile the scatter into a parallel loop of atomic adds: on a hash grid's
    table those contend for the coarse levels' few cells, which every sample reads (an inductor kernel profile of
    the compiled step put almost half of a step there)."""
    if values.device.type != "cpu":
        return values.new_zeros(rows, values.shape[-1]).index_add_(0, index, values)
    summed = values.new_empty(rows, values.shape[-1])

    def add_column(column: int) -> None:  # (bincount gives int64 zeros for an empty index: copy_ casts)
        summed[:, column].copy_(torch.bincount(index, weights=values[:, column], minlength=rows))

    global _column_worker
    if _sum_columns_in_parallel(values.shape[-1]):
        if _column_worker is None:
            _column_worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ssnerf-add-rows")
        rest = [_column_worker.submit(add_column, column) for column in range(1, values.shape[-1])]
        add_column(0)
        for future in rest:
            future.result()
    else:
        for column in range(values.shape[-1]):
            add_column(column)
    return summed


@add_rows.register_fake
def _(index: Tensor, values: Tensor, rows: int) -> Tensor:
    return values.new_empty(rows, values.shape[-1])


class GatherRows(torch.autograd.Function):
    """`table[index]` (an `index_select`, which inductor fuses into what follows) whose backward is `add_rows`."""

    @staticmethod
    def forward(ctx, table: Float[Tensor, "rows feature"], index: Int[Tensor, " n"]) -> Float[Tensor, "n feature"]:
        ctx.save_for_backward(index)
        ctx.rows = table.shape[0]
        return torch.index_select(table, 0, index)

    @staticmethod
    def backward(ctx, grad: Float[Tensor, "n feature"]) -> Tuple[Tensor, None]:
        (index,) = ctx.saved_tensors
        return add_rows(index, grad.contiguous(), ctx.rows), None


class GatheredHashEncoding(HashEncoding):
    """nerfstudio's `HashEncoding` whose torch path hashes and reads the eight cell corners in one batch.

    The features are the same numbers as nerfstudio's (same hash, same interpolation, same order of operations: a
    test compares them bit for bit). nerfstudio indexes the table eight times with `table[indices]`, whose backward on
    a CPU is a serial `index_put_(accumulate=True)` into eight zero-filled table-sized gradients, and hashes each
    corner from scratch; here one `index_select` reads all corners (`GatherRows`: its backward is one serial sum,
    also when compiled), and the per-axis products of the hash are computed once and combined by XOR. The tcnn path is
    untouched."""

    def pytorch_fwd(self, in_tensor: Float[Tensor, "*bs input_dim"]) -> Float[Tensor, "*bs output_dim"]:
        assert in_tensor.shape[-1] == 3
        scaled = in_tensor[..., None, :] * self.scalings.view(-1, 1).to(in_tensor.device)  # [..., L, 3]
        floor = torch.floor(scaled)
        offset = scaled - floor
        primes = torch.tensor(_HASH_PRIMES, device=in_tensor.device)
        # per axis, [ceiling, floor] times its prime: [2, ..., L] each
        x, y, z = (torch.stack([torch.ceil(scaled[..., axis]), floor[..., axis]]).long() * primes[axis]
                   for axis in range(3))
        hashed = (x[:, None, None] ^ y[None, :, None]) ^ z[None, None, :]  # [2 (x), 2 (y), 2 (z), ..., L]
        hashed = hashed % self.hash_table_size + self.hash_offset.to(hashed.device)
        corners = GatherRows.apply(self.hash_table, hashed.reshape(-1))
        corners = corners.view(*hashed.shape, self.features_per_level)  # [2, 2, 2, ..., L, F]
        # nerfstudio's interpolation, x first, then y, then z; index 0 is the ceiling corner, weighted by the offset
        # (unbind, not indexing: its backward stacks the halves' gradients instead of zero-filling one per half)
        ceiling, below = corners.unbind(0)
        along_x = ceiling * offset[..., 0:1] + below * (1 - offset[..., 0:1])  # [2 (y), 2 (z), ..., L, F]
        ceiling, below = along_x.unbind(0)
        along_y = ceiling * offset[..., 1:2] + below * (1 - offset[..., 1:2])  # [2 (z), ..., L, F]
        ceiling, below = along_y.unbind(0)
        encoded = ceiling * offset[..., 2:3] + below * (1 - offset[..., 2:3])  # [..., L, F]
        return torch.flatten(encoded, start_dim=-2, end_dim=-1)


def gather_hash_lookups(module: nn.Module) -> int:
    """Switch every torch-path `HashEncoding` inside `module` (the field's F_enc, the proposal networks) to
    `GatheredHashEncoding` in place: same parameters and state-dict keys, so checkpoints load either way. Returns how
    many were switched."""
    switched = 0
    for child in module.modules():
        if type(child) is HashEncoding and child.tcnn_encoding is None:
            child.__class__ = GatheredHashEncoding
            switched += 1
    return switched
