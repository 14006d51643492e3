"""SURF's Fast-Hessian blob response (Bay et al., ECCV 2006), in numpy: the keypoint label (`keypoints.py`).

OpenCV's pip wheels leave SURF out (patented), and the paper's keypoint labels come from SURF, so it is written
here: box-filter approximations of the second derivatives of Gaussians, evaluated in constant time per pixel on an
integral image, and the determinant of the approximate Hessian as the blob response.
"""

from __future__ import annotations

from typing import List, Tuple

import numpy as np

HESSIAN_XY_WEIGHT = 0.9
"""Bay et al.'s correction of the Dxy box filter's weight relative to the Gaussian derivative it approximates."""


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
