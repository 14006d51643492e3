"""Living with nerfstudio 1.1.5 on today's torch: its checkpoints, and its deprecation warnings.

torch now unpickles checkpoints with `weights_only=True`, which refuses the numpy scalars nerfstudio stores
(`ns-eval`, `ns-render`, `ns-viewer --load-config`). The few numpy globals involved are allow-listed (no arbitrary code
is allowed to load); nerfstudio imports this package through the config's `_target` before it reads the checkpoint.

nerfstudio 1.1.5 also makes torch and torchmetrics warn: importing it decorates functions with `torch.jit.script` and
`torch.cuda.amp.custom_fwd/bwd`, its trainer builds a `torch.cuda.amp.GradScaler`, its metrics import a name
torchmetrics has moved, and `Cameras` indexes with a list on every ray batch. Exactly those warnings, from exactly
those places, are silenced; nothing else is. nerfstudio's commands (`ns-train`, `ns-eval`, `ns-render`, `ns-viewer`)
import nerfstudio before they find this plugin, so the filters are installed at interpreter start by
`ssnerf_method_warnings.pth`, which the build backend puts into site-packages with every install
(`build_hooks/ssnerf_build.py`); importing the package installs them again, for an interpreter started without
site-packages' hooks.

This module imports nothing but the standard library at load time: the `.pth` hook runs it on every start of Python.
"""

from __future__ import annotations

import warnings

KNOWN_WARNINGS = (
    (FutureWarning, r"`torch\.jit\.script` is deprecated", r"torch\.jit\._script"),
    (FutureWarning, r"`torch\.cuda\.amp\.custom_(fwd|bwd)\(args\.\.\.\)` is deprecated",
     r"nerfstudio\.field_components\.activations"),
    (UserWarning, r"Using a non-tuple sequence for multidimensional indexing is deprecated", r"nerfstudio\.cameras\."),
    (FutureWarning, r"`torch\.cuda\.amp\.GradScaler\(args\.\.\.\)` is deprecated", r"nerfstudio\.engine\.trainer"),
    (FutureWarning, r"Importing `spectral_angle_mapper` from `torchmetrics\.functional` was deprecated",
     r"torchmetrics\.utilities\.prints"),
)
"""(category, message, module) of each third-party warning silenced: the message's start and the module it is
attributed to, both regular expressions as `warnings.filterwarnings` takes them."""


def quiet_known_warnings() -> None:
    """Ignore exactly `KNOWN_WARNINGS` (idempotent: `warnings` keeps one copy of a filter added twice)."""
    for category, message, module in KNOWN_WARNINGS:
        warnings.filterwarnings("ignore", message=message, category=category, module=module)


def allow_nerfstudio_checkpoints() -> None:
    """Allow-list the numpy types found in nerfstudio checkpoints for `torch.load(weights_only=True)`."""
    import numpy as np
    import torch

    add_safe_globals = getattr(torch.serialization, "add_safe_globals", None)
    if add_safe_globals is None:  # torch < 2.4 loads them anyway
        return
    scalar = np.core.multiarray.scalar
    dtypes = [type(np.dtype(name)) for name in ("float64", "float32", "int64", "int32", "bool")]
    add_safe_globals([scalar, np.dtype, *dtypes])
