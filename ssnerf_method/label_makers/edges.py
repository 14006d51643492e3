"""Edge label: Canny edges of an RGB image as a {0, 1} float map."""

from __future__ import annotations

import cv2
import numpy as np


def to_gray_uint8(image: np.ndarray) -> np.ndarray:
    """8-bit grey image of an RGB (H, W, 3) or grey (H, W) image; float input is taken to be in [0, 1]."""
    if image.dtype != np.uint8:
        image = np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image


def canny_edges(image: np.ndarray, low_threshold: float = 100.0, high_threshold: float = 200.0) -> np.ndarray:
    """(H, W) float32 edge map in {0, 1}: OpenCV Canny (3x3 Sobel, L1 gradient) on the 8-bit grey image.

    The thresholds are the hysteresis thresholds on the gradient magnitude of the 0-255 grey image: pixels above
    `high_threshold` start an edge, neighbours above `low_threshold` continue it. No blur is applied first.
    """
    return (cv2.Canny(to_gray_uint8(image), low_threshold, high_threshold) > 0).astype(np.float32)
