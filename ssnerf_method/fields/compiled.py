"""`torch.compile` of the per-sample networks (the field, the proposal networks), with an eager fallback.

A training step on a CPU is paced by many small elementwise ops and their autograd bookkeeping (the hash grid's
hashing and interpolation, activations, concatenations), not by arithmetic; inductor fuses them into a few loops.
The compiled function computes the same numbers as the eager one (tests compare outputs and gradients). Compiling
costs tens of seconds at the first training step; when it fails (no C++ compiler, an unsupported op), one console
line says so and the function runs eagerly from then on.
"""

from __future__ import annotations

from typing import Callable, Generic, Optional, TypeVar

import torch
import torch._functorch.config

from nerfstudio.utils.rich_utils import CONSOLE

Output = TypeVar("Output")


class CompiledOrEager(Generic[Output]):
    """`function` through `torch.compile` (inductor), or eagerly once compiling it has failed.

    Not an `nn.Module`: held as a plain attribute, it adds nothing to a state dict (checkpoints stay the same).

    Args:
        function: the tensor function to compile (its modules' parameters are inputs of the compiled graph).
        label: what it is, for the fallback's console line.
    """

    def __init__(self, function: Callable[..., Output], label: str) -> None:
        self.function = function
        self.label = label
        # No donated buffers (a memory saving of AOTAutograd, read when a backward is compiled, lazily): the loss
        # balancer differentiates one step's losses more than once (`retain_graph`), which they forbid.
        torch._functorch.config.donated_buffer = False
        self.compiled: Optional[Callable[..., Output]] = None
        """None after a failure: eager from then on."""
        try:  # one graph per input shape (a training run's shapes are fixed)
            self.compiled = torch.compile(function, dynamic=False)
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
