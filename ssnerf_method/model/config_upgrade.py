"""A model config.yml saved in an older layout loads into the current one (PyYAML hands the saved fields to
`SSNeRFModelConfig.__setstate__`): moved fields go to their nested config, removed options are dropped, and fields
saved before they existed take their defaults."""

from __future__ import annotations

from typing import Any, Dict, Tuple

from ssnerf_method.fields.compiled import CompileConfig
from ssnerf_method.model.loss_balancing import LossBalancerConfig
from ssnerf_method.model.regularisers import default_regularisers

MOVED: Dict[str, Tuple[str, ...]] = {
    "compile_fields": ("compile", "enabled"),
    "bfloat16_matmuls": ("compile", "bfloat16_matmuls"),
    "compile_min_steps": ("compile", "min_steps"),
    "balance_ratio": ("balancing", "ratio"),
    "balance_every": ("balancing", "every"),
    "depth_loss_mult": ("regularisers", "depth", "mult"),
    "depth_loss_type": ("regularisers", "depth", "loss_type"),
    "depth_sigma": ("regularisers", "depth", "sigma"),
    "depth_smoothness_mult": ("regularisers", "depth_smoothness", "mult"),
    "depth_smoothness_edge": ("regularisers", "depth_smoothness", "edge"),
    "semantic_affinity_mult": ("regularisers", "semantic_affinity", "mult"),
    "semantic_affinity_edge": ("regularisers", "semantic_affinity", "edge"),
    "semantic_affinity_stride": ("regularisers", "semantic_affinity", "stride"),
}
"""Where a field of the flat layout (before 2026-12-07) lives now."""
SHARED_PATCHES = ("pixel_patches", ("depth_smoothness", "semantic_affinity"))
"""The one patch count both patch terms shared then; each has its own now."""
REMOVED = ("normals_density_mult", "normals_density_samples", "normals_density_step", "hash_lookup",
           "property_decoder_width")
"""Options measurement left off, removed on 2026-12-07 (runs trained with them at their defaults load unchanged)."""


def upgrade_model_state(state: Dict[str, Any]) -> Dict[str, Any]:
    """`state` (a saved config's fields) in the current layout, nested configs at their defaults where not saved."""
    state = dict(state)
    state.setdefault("compile", CompileConfig())
    state.setdefault("balancing", LossBalancerConfig())
    state["regularisers"] = {**default_regularisers(), **state.get("regularisers", {})}  # terms added since: defaults
    for old, path in MOVED.items():
        if old in state:
            *where, last = path
            target = state[where[0]]
            for key in where[1:]:
                target = target[key]
            setattr(target, last, state.pop(old))
    if SHARED_PATCHES[0] in state:
        patches = state.pop(SHARED_PATCHES[0])
        for term in SHARED_PATCHES[1]:
            state["regularisers"][term].patches = patches
    for old in REMOVED:
        state.pop(old, None)
    return state
