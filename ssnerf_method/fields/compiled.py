"""`torch.compile` of the per-sample networks (the field, the proposal networks), with an eager fallback.

A training step on a CPU is paced by many small elementwise ops and their autograd bookkeeping (the hash grid's
hashing and interpolation, activations, concatenations), not by arithmetic; inductor fuses them into a few loops.
The compiled function computes the same numbers as the eager one (tests compare outputs and gradients). Compiling
costs tens of seconds at the first training step; when it fails (no C++ compiler, an unsupported op), one console
line says so and the function runs eagerly from then on.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Callable, Generic, Optional, TypeVar

import torch
import torch._functorch.config
from torch import Tensor
from torch.utils._pytree import tree_map

from nerfstudio.utils.rich_utils import CONSOLE

Output = TypeVar("Output")


def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 matrices in hardware (AMX or AVX512-BF16). Elsewhere oneDNN emulates
    bfloat16, which is slower than float32. (torch's probes are private: a torch without them counts as no.)"""
    probes = (getattr(torch.cpu, name, None) for name in ("_is_amx_tile_supported", "_is_avx512_bf16_supported"))
    return any(probe is not None and probe() for probe in probes)


def with_bfloat16_matmuls(function: Callable[..., Output]) -> Callable[..., Output]:
    """`function` under CPU autocast: its matrix multiplications (and what follows them up to its return) in
    bfloat16, as tiny-cuda-nn runs nerfstudio's MLPs in half precision on a GPU. Parameters stay float32 (autocast
    casts copies) and so do the outputs: every floating tensor it returns is cast back to float32."""

    @functools.wraps(function)
    def run(*args, **kwargs) -> Output:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            outputs = function(*args, **kwargs)
        return tree_map(lambda value: value.float() if isinstance(value, Tensor) and value.is_floating_point()
                        else value, outputs)

    return run


class CompiledOrEager(Generic[Output]):
    """`function` through `torch.compile` (inductor), or eagerly once compiling it has failed.

    Not an `nn.Module`: held as a plain attribute, it adds nothing to a state dict (checkpoints stay the same).

    Args:
        function: the tensor function to compile (its modules' parameters are inputs of the compiled graph).
        label: what it is, for the fallback's console line.
        bfloat16_matmuls: run it with its matrix multiplications in bfloat16 (`with_bfloat16_matmuls`), compiled or
            eager.
    """

    def __init__(self, function: Callable[..., Output], label: str, bfloat16_matmuls: bool = False) -> None:
        self.function = with_bfloat16_matmuls(function) if bfloat16_matmuls else function
        self.label = label
        self.bfloat16_matmuls = bfloat16_matmuls
        # No donated buffers (a memory saving of AOTAutograd, read when a backward is compiled, lazily): the loss
        # balancer differentiates one step's losses more than once (`retain_graph`), which they forbid.
        torch._functorch.config.donated_buffer = False
        self.compiled: Optional[Callable[..., Output]] = None
        """None after a failure: eager from then on."""
        try:  # one graph per input shape (a training run's shapes are fixed)
            self.compiled = torch.compile(self.function, dynamic=False)
        except Exception as err:  # noqa: BLE001 - e.g. a Python version dynamo does not support
            self._fall_back(err)

    def __call__(self, *args, **kwargs) -> Output:
        if self.compiled is not None:
            try:
                return self.compiled(*args, **kwargs)
            except Exception as err:  # noqa: BLE001 - any compile failure falls back; a real error recurs below
                self._fall_back(err)
        return self.function(*args, **kwargs)

    def _fall_back(self, err: Exception) -> None:
        reason = (str(err).strip().splitlines() or [""])[0]
        CONSOLE.print(f"[yellow]torch.compile of {self.label} failed ({type(err).__name__}: {reason[:160]}); it runs "
                      "eagerly from now on (same results, slower steps).", soft_wrap=True)
        self.compiled = None


@dataclass
class CompileConfig:
    """When a CPU training run compiles the field's and the proposal networks' forwards and backwards (the same
    outputs from a cheaper step, after a compile at the first step). Evaluation, the viewer and CUDA stay eager."""

    enabled: bool = True
    """Compile CPU training runs of at least `min_steps` steps."""
    bfloat16_matmuls: bool = True
    """On a CPU that multiplies bfloat16 in hardware (AMX or AVX512-BF16; elsewhere it is ignored): the compiled
    networks' matrix multiplications in bfloat16 (`torch.autocast`), as tiny-cuda-nn runs nerfstudio's MLPs in half
    precision on a GPU. Parameters, hash tables, rendering and losses stay float32."""
    min_steps: int = 300
    """Runs of fewer training steps (the trainer's `max_num_iterations`) stay eager: the compile would not pay off."""

    def apply(self, sampling: Any, device: torch.device, run_steps: int) -> None:
        """Compile `sampling`'s networks for training (its `compile_for_training`) when this run should be."""
        if self.enabled and device.type == "cpu" and run_steps >= self.min_steps:
            sampling.compile_for_training(self.bfloat16_matmuls and native_bfloat16())
