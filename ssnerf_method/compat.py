"""Let torch >= 2.6 load nerfstudio 1.1.5 checkpoints (`ns-eval`, `ns-render`, `ns-viewer --load-config`).

torch now unpickles checkpoints with `weights_only=True`, which refuses the numpy scalars nerfstudio stores. The few
numpy globals involved are allow-listed (no arbitrary code is allowed to load); nerfstudio imports this package
through the config's `_target` before it reads the checkpoint.
"""

from __future__ import annotations

import numpy as np
import torch


def allow_nerfstudio_checkpoints() -> None:
    """Allow-list the numpy types found in nerfstudio checkpoints for `torch.load(weights_only=True)`."""
    add_safe_globals = getattr(torch.serialization, "add_safe_globals", None)
    if add_safe_globals is None:  # torch < 2.4 loads them anyway
        return
    scalar = np.core.multiarray.scalar
    dtypes = [type(np.dtype(name)) for name in ("float64", "float32", "int64", "int32", "bool")]
    add_safe_globals([scalar, np.dtype, *dtypes])
