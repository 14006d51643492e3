"""Adam as nerfstudio configures it, run by torch's fused kernel.

nerfstudio's `AdamOptimizerConfig` builds `torch.optim.Adam` with torch's default implementation, which on a CPU is
the per-tensor loop: about a dozen elementwise ops per parameter tensor, each a pass over memory. The fused kernel
makes one pass per tensor (on 2 CPU cores, about a third of the time per `ssnerf-lite` step, 2026-12-05) and
computes the same update up to float rounding. Its state dict has the same keys, so checkpoints load either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import torch

from nerfstudio.engine.optimizers import AdamOptimizerConfig

FUSED_DEVICES = ("cpu", "cuda")
"""Devices whose parameters torch's fused Adam takes (elsewhere the default implementation runs)."""


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """nerfstudio's Adam config whose optimizer uses torch's fused kernel where the parameters allow it."""

    fused: bool = True
    """Use the fused kernel when every parameter is a floating-point tensor on a CPU or a CUDA GPU."""

    def setup(self, params: Iterable[torch.nn.Parameter]) -> torch.optim.Optimizer:
        params = list(params)
        kwargs = {name: value for name, value in vars(self).items() if name not in ("_target", "max_norm", "fused")}
        fused = self.fused and all(param.device.type in FUSED_DEVICES and param.is_floating_point()
                                   for param in params)
        return self._target(params, **kwargs, fused=True if fused else None)
