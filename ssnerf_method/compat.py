"""Living with nerfstudio 1.1.5 on today's torch: its checkpoints, and its deprecation warnings.

torch now unpickles checkpoints with `weights_only=True`, which refuses the numpy scalars nerfstudio stores
(`ns-eval`, `ns-render`, `ns-viewer --load-config`). The few numpy globals involved are allow-listed (no arbitrary code
is allowed to load); nerfstudio imports this package through the config's `_target` before it reads the checkpoint.

nerfstudio 1.1.5 also makes torch warn: `Cameras` indexes with a list on every ray batch, and importing it decorates
functions with `torch.jit.script` and `torch.cuda.amp.custom_fwd/bwd`. Exactly those warnings, from exactly those
places, are silenced; nothing else is. (`ns-train` imports nerfstudio before it discovers this plugin, so its
import-time warnings come first; the per-batch one is silenced from the plugin's import on.)
"""

from __future__ import annotations

import warnings

import numpy as np

KNOWN_WARNINGS = (
    (FutureWarning, r"`torch\.jit\.script` is deprecated", r"torch\.jit\._script"),
    (FutureWarning, r"`torch\.cuda\.amp\.custom_(fwd|bwd)\(args\.\.\.\)` is deprecated",
     r"nerfstudio\.field_components\.activations"),
    (UserWarning, r"Using a non-tuple sequence for multidimensional indexing is deprecated", r"nerfstudio\.cameras\."),
)
"""(category, message, module) of each third-party warning silenced: the message's start and the module it is
attributed to, both regular expressions as `warnings.filterwarnings` takes them."""


def quiet_known_warnings() -> None:
    """Ignore exactly `KNOWN_WARNINGS`."""
    for category, message, module in KNOWN_WARNINGS:
        warnings.filterwarnings("ignore", message=message, category=category, module=module)


def allow_nerfstudio_checkpoints() -> None:
    """Allow-list the numpy types found in nerfstudio checkpoints for `torch.load(weights_only=True)`."""
    import torch  # (here, so that `quiet_known_warnings` can run before torch is first imported)

    add_safe_globals = getattr(torch.serialization, "add_safe_globals", None)
    if add_safe_globals is None:  # torch < 2.4 loads them anyway
        return
    scalar = np.core.multiarray.scalar
    dtypes = [type(np.dtype(name)) for name in ("float64", "float32", "int64", "int32", "bool")]
    add_safe_globals([scalar, np.dtype, *dtypes])
