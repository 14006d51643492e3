"""Keypoint labels, two definitions.

- `response` (default): the dense response map of SURF's blob detector, as Taskonomy's keypoint2d images are: the
  positive determinant of the box-filter Hessian, largest over the first octave's filter sizes, mapped into [0, 1)
  by one fixed curve, so that the same blob gives the same value in every view. Its local maxima above 0.5 are blobs
  whose response exceeds `RESPONSE_AT_HALF` (roughly SURF's detections at that threshold). A field learns it like
  any dense map (keypoint F1 0.57-0.63 after 1000 `ssnerf-lite` steps on the default scenes).
- `blobs`: detector keypoints (SURF, SIFT or ORB) splatted as Gaussian blobs whose peak is the response over the
  image's strongest; sparse, and the blobs differ from view to view: fields trained on it render an empty map.
"""

from __future__ import annotations

from typing import Literal, Tuple

import cv2
import numpy as np

from ssnerf_method.label_makers.edges import to_gray_uint8
from ssnerf_method.label_makers.surf import detect_surf, hessian_response, integral_image, octave_sizes

KeypointLabel = Literal["response", "blobs"]
"""Definition of the keypoint label (module docstring)."""

RESPONSE_AT_HALF = 0.002
"""Hessian-determinant response (of the [0, 1] grey image) that maps to 0.5 in the `response` label."""

Detector = Literal["surf", "sift", "orb"]
"""`surf`: our Fast-Hessian detector (`labels/surf.py`); `sift`, `orb`: OpenCV's, with OpenCV's defaults."""


def detect_keypoints(image: np.ndarray, detector: Detector = "surf") -> Tuple[np.ndarray, np.ndarray]:
    """Keypoints of an RGB or grey image.

    Returns their (N, 2) positions (x, y) in OpenCV pixel coordinates (pixel (row i, column j) is centred at
    (j, i)) and their (N,) detector responses.
    """
    gray = to_gray_uint8(image)
    if detector == "surf":
        # detect_surf reports positions with pixel centres at +0.5; shift them to OpenCV's convention.
        found = detect_surf(gray)
        return found.positions - 0.5, found.responses
    if detector not in ("sift", "orb"):
        raise ValueError(f"unknown keypoint detector {detector!r}; use surf, sift or orb")
    keypoints = (cv2.SIFT_create() if detector == "sift" else cv2.ORB_create()).detect(gray, None)
    positions = np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
    responses = np.array([kp.response for kp in keypoints], dtype=np.float64)
    return positions, responses


def splat_keypoints(
    positions: np.ndarray, weights: np.ndarray, height: int, width: int, sigma: float = 1.5
) -> np.ndarray:
    """(H, W) float32 heatmap: the max over keypoints of `weight * exp(-d^2 / (2 sigma^2))`, cut off at 4 sigma.

    `positions` are (x, y) in OpenCV pixel coordinates, `d` the distance from a keypoint to a pixel centre.
    """
    heatmap = np.zeros((height, width), dtype=np.float32)
    radius = int(np.ceil(4 * sigma))
    for (x, y), weight in zip(positions, weights):
        c0, c1 = max(int(round(x)) - radius, 0), min(int(round(x)) + radius + 1, width)
        r0, r1 = max(int(round(y)) - radius, 0), min(int(round(y)) + radius + 1, height)
        if c0 >= c1 or r0 >= r1:
            continue
        dy, dx = np.meshgrid(np.arange(r0, r1) - y, np.arange(c0, c1) - x, indexing="ij")
        blob = weight * np.exp(-(dx * dx + dy * dy) / (2 * sigma * sigma))
        heatmap[r0:r1, c0:c1] = np.maximum(heatmap[r0:r1, c0:c1], blob)
    return heatmap


def keypoint_heatmap(image: np.ndarray, sigma: float = 1.5, detector: Detector = "surf") -> np.ndarray:
    """(H, W) float32 keypoint heatmap in [0, 1] of an RGB or grey image.

    Each keypoint of `detector` becomes a Gaussian blob of standard deviation `sigma` pixels whose peak is its response
    divided by the image's largest response (so the strongest keypoint peaks at 1); overlapping blobs combine by
    max. An image without keypoints gives all zeros.
    """
    positions, responses = detect_keypoints(image, detector)
    height, width = image.shape[:2]
    if len(responses) == 0 or responses.max() <= 0:
        return np.zeros((height, width), dtype=np.float32)
    return splat_keypoints(positions, responses / responses.max(), height, width, sigma)


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


def keypoint_label(
    image: np.ndarray, definition: KeypointLabel = "response", sigma: float = 1.5, detector: Detector = "surf"
) -> np.ndarray:
    """The keypoint label of an image by `definition`: the dense response map, or `detector`'s blobs of `sigma`."""
    if definition == "response":
        return keypoint_response_map(image)
    if definition == "blobs":
        return keypoint_heatmap(image, sigma=sigma, detector=detector)
    raise ValueError(f"unknown keypoint label {definition!r}; use response or blobs")


def describe_keypoint_label(definition: KeypointLabel, sigma: float = 1.5, detector: Detector = "surf") -> str:
    """How a keypoint label was made, for a dataset's provenance record."""
    if definition == "response":
        return f"SURF blob-response map 1 - 2^(-r / {RESPONSE_AT_HALF:g}), largest over box filters {octave_sizes(0)}"
    return f"{detector.upper()} keypoints, Gaussian blobs of sigma {sigma:g} px, peak response / max"
