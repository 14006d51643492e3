"""Keypoint label: SIFT detections splatted as Gaussian blobs into a heatmap in [0, 1]."""

from __future__ import annotations

from typing import Tuple

import cv2
import numpy as np

from ssnerf_method.labels.edges import to_gray_uint8


def detect_keypoints(image: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints (OpenCV defaults) of an RGB or grey image.

    Returns their (N, 2) positions (x, y) in OpenCV pixel coordinates (pixel (row i, column j) is centred at
    (j, i)) and their (N,) detector responses.
    """
    keypoints = cv2.SIFT_create().detect(to_gray_uint8(image), None)
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


def keypoint_heatmap(image: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """(H, W) float32 keypoint heatmap in [0, 1] of an RGB or grey image.

    Each SIFT keypoint becomes a Gaussian blob of standard deviation `sigma` pixels whose peak is its response
    divided by the image's largest response (so the strongest keypoint peaks at 1); overlapping blobs combine by
    max. An image without keypoints gives all zeros.
    """
    positions, responses = detect_keypoints(image)
    height, width = image.shape[:2]
    if len(responses) == 0 or responses.max() <= 0:
        return np.zeros((height, width), dtype=np.float32)
    return splat_keypoints(positions, responses / responses.max(), height, width, sigma)
