"""SURF's Fast-Hessian keypoint detector (Bay et al., ECCV 2006), in numpy.

OpenCV's pip wheels leave SURF out (patented), and the paper's keypoint labels come from SURF, so the detector is
written here: box-filter approximations of the second derivatives of Gaussians, evaluated in constant time per pixel
on an integral image, the determinant of the approximate Hessian as the blob response, and non-maximum suppression
over 3x3x3 neighbourhoods in (scale, y, x) within each octave.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Tuple

import numpy as np

HESSIAN_XY_WEIGHT = 0.9
"""Bay et al.'s correction of the Dxy box filter's weight relative to the Gaussian derivative it approximates."""


@dataclass(frozen=True)
class SurfKeypoints:
    """Detected blobs: pixel positions (x, y), scale (Gaussian sigma in pixels) and Hessian-determinant response."""

    positions: np.ndarray
    scales: np.ndarray
    responses: np.ndarray


def integral_image(gray: np.ndarray, pad: int) -> np.ndarray:
    """Summed-area table of `gray` padded by `pad` pixels of edge values, with a leading zero row and column."""
    padded = np.pad(gray.astype(np.float64), pad, mode="edge")
    table = np.zeros((padded.shape[0] + 1, padded.shape[1] + 1))
    table[1:, 1:] = padded.cumsum(0).cumsum(1)
    return table


def box_sum(
    table: np.ndarray, pad: int, shape: Tuple[int, int], top: int, left: int, bottom: int, right: int
) -> np.ndarray:
    """Per pixel (y, x) of an image of `shape`: sum of rows [y+top, y+bottom) and columns [x+left, x+right)."""
    height, width = shape
    r0, r1 = pad + top, pad + bottom
    c0, c1 = pad + left, pad + right
    return (
        table[r1 : r1 + height, c1 : c1 + width]
        - table[r0 : r0 + height, c1 : c1 + width]
        - table[r1 : r1 + height, c0 : c0 + width]
        + table[r0 : r0 + height, c0 : c0 + width]
    )


def hessian_response(table: np.ndarray, pad: int, shape: Tuple[int, int], size: int) -> np.ndarray:
    """Normalised det of the box-filter Hessian at filter size `size` (9, 15, 21, ...: lobe = size / 3)."""
    lobe = size // 3
    half = size // 2
    band = lobe - 1  # half-width of the (2 * lobe - 1)-wide band across the lobes

    def lobes_along_y() -> np.ndarray:
        whole = box_sum(table, pad, shape, -half, -band, half + 1, band + 1)
        middle = box_sum(table, pad, shape, -(lobe // 2), -band, lobe // 2 + 1, band + 1)
        return whole - 3.0 * middle

    def lobes_along_x() -> np.ndarray:
        whole = box_sum(table, pad, shape, -band, -half, band + 1, half + 1)
        middle = box_sum(table, pad, shape, -band, -(lobe // 2), band + 1, lobe // 2 + 1)
        return whole - 3.0 * middle

    dyy, dxx = lobes_along_y(), lobes_along_x()
    dxy = (
        box_sum(table, pad, shape, -lobe, -lobe, 0, 0)
        + box_sum(table, pad, shape, 1, 1, lobe + 1, lobe + 1)
        - box_sum(table, pad, shape, -lobe, 1, 0, lobe + 1)
        - box_sum(table, pad, shape, 1, -lobe, lobe + 1, 0)
    )
    area = float(size * size)
    return (dxx / area) * (dyy / area) - (HESSIAN_XY_WEIGHT * dxy / area) ** 2


def octave_sizes(octave: int, layers: int = 4) -> List[int]:
    """Filter sizes of one octave: 9, 15, 21, 27; then 15, 27, 39, 51; then 27, 51, 75, 99; ..."""
    step = 6 * 2**octave
    first = 3 * (2 ** (octave + 1) + 1)
    return [first + step * index for index in range(layers)]


def local_max_3x3x3(neighbourhood: np.ndarray) -> np.ndarray:
    """(H, W) maximum over each pixel's 3x3 window in all three (3, H, W) layers; outside the image counts as 0.

    Separable (layers, then rows, then columns), which is an order of magnitude faster than a windowed view.
    """
    across = neighbourhood.max(axis=0)
    rows = np.pad(across, ((1, 1), (0, 0)))
    across = np.maximum(np.maximum(rows[:-2], rows[1:-1]), rows[2:])
    cols = np.pad(across, ((0, 0), (1, 1)))
    return np.maximum(np.maximum(cols[:, :-2], cols[:, 1:-1]), cols[:, 2:])


def detect_surf(
    image: np.ndarray, threshold: float = 1e-4, num_octaves: int = 3, max_keypoints: int = 1000
) -> SurfKeypoints:
    """Fast-Hessian blobs of an image (H, W) or (H, W, 3), values in [0, 1] (float) or 0-255 (uint8).

    `threshold` is on the normalised Hessian determinant of the [0, 1] grey image; the strongest `max_keypoints`
    are kept. A blob's scale is sigma = 1.2 * size / 9, the Gaussian its box filter stands for.
    """
    gray = image.astype(np.float64)
    if image.dtype == np.uint8:
        gray = gray / 255.0
    if gray.ndim == 3:
        gray = gray @ np.array([0.299, 0.587, 0.114])
    shape = gray.shape[:2]
    sizes = sorted({size for octave in range(num_octaves) for size in octave_sizes(octave)})
    pad = max(sizes) // 2 + 1
    table = integral_image(gray, pad)
    responses = {size: hessian_response(table, pad, shape, size) for size in sizes}

    positions, scales, values = [], [], []
    for octave in range(num_octaves):
        stack = np.stack([responses[size] for size in octave_sizes(octave)])
        border = octave_sizes(octave)[-1] // 2
        for layer in range(1, stack.shape[0] - 1):
            centre = stack[layer]
            keep = (centre >= local_max_3x3x3(stack[layer - 1 : layer + 2])) & (centre > threshold)
            keep[:border] = keep[-border:] = False
            keep[:, :border] = keep[:, -border:] = False
            ys, xs = np.nonzero(keep)
            positions.append(np.stack([xs + 0.5, ys + 0.5], axis=-1))
            scales.append(np.full(len(xs), 1.2 * octave_sizes(octave)[layer] / 9.0))
            values.append(centre[ys, xs])
    positions_all = np.concatenate(positions) if positions else np.zeros((0, 2))
    scales_all, values_all = np.concatenate(scales), np.concatenate(values)
    order = np.argsort(-values_all)[:max_keypoints]
    return SurfKeypoints(positions_all[order], scales_all[order], values_all[order])
