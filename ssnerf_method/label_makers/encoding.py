"""How labels are stored: 8-bit values of [0, 1], unit normals n as (n + 1) / 2 in [0, 1] (numpy or torch), and
class ids with one id for "unlabelled"."""

from __future__ import annotations

from typing import TypeVar

import numpy as np

Values = TypeVar("Values")

SEMANTIC_IGNORE = 255
"""Class id of an unlabelled pixel in a semantic label file; its rays carry no semantic loss."""


def to_uint8(values: np.ndarray) -> np.ndarray:
    """Values in [0, 1] as 0-255 (rounded, clipped; NaN as 0): how every 8-bit label and image is written."""
    return np.round(np.clip(np.nan_to_num(values), 0.0, 1.0) * 255.0).astype(np.uint8)


def encode_normals(normals: Values) -> Values:
    """Unit normals (components in [-1, 1]) as the stored encoding (n + 1) / 2 in [0, 1]."""
    return (normals + 1.0) / 2.0  # type: ignore[operator]


def decode_normals(encoded: Values) -> Values:
    """The stored encoding back to normals in [-1, 1] (not renormalised)."""
    return encoded * 2.0 - 1.0  # type: ignore[operator]
