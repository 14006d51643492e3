"""Knowledge transfer (paper Sec. 4.4, Table 5): start a model's shared encoder F_enc from another trained model's.

Only the `PositionEncoder` modules (F_enc of the field, or of the coarse and fine fields) are copied; decoders, heads
and nerfstudio's proposal networks keep their fresh initialisation. The source must have the same architecture
(method and encoder sizes); its properties may differ, which is the point.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import torch
from torch import Tensor, nn

from ssnerf_method.fields.encoders import PositionEncoder

MODEL_PREFIX = "_model."
"""Prefix of the model's entries in a nerfstudio checkpoint's pipeline state dict."""


class EncoderTransferError(ValueError):
    """The source checkpoint cannot initialise this model's F_enc."""


def encoder_modules(model: nn.Module) -> Dict[str, PositionEncoder]:
    """Every F_enc of `model`, by module path (e.g. `sampling.field_module.encoder`)."""
    return {name: module for name, module in model.named_modules() if isinstance(module, PositionEncoder)}


def load_encoders(model: nn.Module, checkpoint: Path) -> List[str]:
    """Copy each F_enc's weights from a nerfstudio checkpoint of a model with the same architecture, in place (the
    optimiser keeps its parameters). Returns the module paths loaded."""
    if not checkpoint.is_file():
        raise EncoderTransferError(f"{checkpoint}: no such checkpoint. Pass the .ckpt of a trained SS-NeRF "
                                   "(<run>/nerfstudio_models/step-*.ckpt) as --pipeline.model.encoder-init.")
    state: Dict[str, Tensor] = torch.load(checkpoint, map_location="cpu")["pipeline"]
    loaded = []
    for name, module in encoder_modules(model).items():
        prefix = f"{MODEL_PREFIX}{name}."
        weights = {key[len(prefix):]: value for key, value in state.items() if key.startswith(prefix)}
        mine = module.state_dict()
        if set(weights) != set(mine) or any(weights[key].shape != mine[key].shape for key in mine):
            raise EncoderTransferError(
                f"{checkpoint}: its F_enc `{name}` does not match this model's (different method or encoder sizes). "
                "Transfer between models of the same method (ssnerf-lite -> ssnerf-lite) and encoder settings."
            )
        module.load_state_dict(weights)
        loaded.append(name)
    if not loaded:
        raise EncoderTransferError(f"{checkpoint}: this model has no F_enc to initialise.")
    return loaded
