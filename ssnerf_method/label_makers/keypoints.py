"""The keypoint label: the dense response map of SURF's blob detector, as Taskonomy's keypoint2d images are (the
paper's data): the positive determinant of the box-filter Hessian, largest over the first octave's filter sizes,
mapped into [0, 1) by one fixed curve, so that the same blob gives the same value in every view. Its local maxima
above 0.5 are blobs whose response exceeds `RESPONSE_AT_HALF` (roughly SURF's detections at that threshold). A field
learns it like any dense map. (Detected keypoints splatted as blobs, the label before 2026-12, differ from view to
view, and fields rendered them as an empty map; it was removed.)
"""

from __future__ import annotations

import numpy as np

from ssnerf_method.label_makers.edges import to_gray_uint8
from ssnerf_method.label_makers.surf import hessian_response, integral_image, octave_sizes

RESPONSE_AT_HALF = 0.002
"""Hessian-determinant response (of the [0, 1] grey image) that maps to 0.5 in the label."""


def keypoint_response_map(image: np.ndarray, response_at_half: float = RESPONSE_AT_HALF) -> np.ndarray:
    """(H, W) float32 map in [0, 1): 1 - 2^(-r / `response_at_half`) of r, the positive SURF blob response (largest
    over the first octave's box filters, 9 to 27 px) of an RGB or grey image. Flat regions give 0; the curve is fixed,
    not scaled per image, so a blob seen from two views gets the same value."""
    gray = to_gray_uint8(image).astype(np.float64) / 255.0
    sizes = octave_sizes(0)
    pad = max(sizes) // 2 + 1
    table = integral_image(gray, pad)
    response = np.max([hessian_response(table, pad, gray.shape, size) for size in sizes], axis=0).clip(min=0.0)
    return (1.0 - np.exp2(-response / response_at_half)).astype(np.float32)


def describe_keypoint_label() -> str:
    """How the keypoint label is made, for a dataset's provenance record."""
    return f"SURF blob-response map 1 - 2^(-r / {RESPONSE_AT_HALF:g}), largest over box filters {octave_sizes(0)}"
