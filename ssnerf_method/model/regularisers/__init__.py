"""The optional training terms (regularisers), one module each; importing this package registers every module of
the folder, so adding a term is adding a file and removing one is deleting it."""

from __future__ import annotations

import importlib
import pkgutil
from typing import Dict

from ssnerf_method.model.regularisers.base import REGULARISERS, PatchRequest, Regulariser, RegulariserConfig


def discover() -> None:
    """Import every module of this folder (each registers its term); run on import."""
    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")


discover()


def default_regularisers() -> Dict[str, RegulariserConfig]:
    """Every registered term at its defaults (the model config's `regularisers`)."""
    return {name: config() for name, config in REGULARISERS.items()}


__all__ = ["REGULARISERS", "PatchRequest", "Regulariser", "RegulariserConfig", "default_regularisers", "discover"]
