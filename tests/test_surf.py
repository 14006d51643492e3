"""SURF's Fast-Hessian detector on synthetic Gaussian blobs of known position and size."""

from __future__ import annotations

import numpy as np

from ssnerf_method.label_makers.surf import box_sum, integral_image, octave_sizes

BLOBS = [(60.0, 50.0, 3.0), (150.0, 60.0, 5.0), (110.0, 150.0, 8.0)]  # x, y, sigma


def blob_image(height: int = 220, width: int = 220) -> np.ndarray:
    rows, cols = np.mgrid[0:height, 0:width] + 0.5
    image = np.full((height, width), 0.2)
    for x, y, sigma in BLOBS:
        image += 0.7 * np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * sigma**2))
    return image


def test_box_sums_match_direct_sums() -> None:
    rng = np.random.default_rng(0)
    image = rng.random((12, 15))
    table = integral_image(image, pad=4)
    sums = box_sum(table, 4, image.shape, -1, -2, 2, 1)  # rows y-1..y+1, columns x-2..x
    padded = np.pad(image, 4, mode="edge")
    assert np.isclose(sums[5, 7], padded[4 + 4 : 4 + 7, 4 + 5 : 4 + 8].sum())
    assert np.isclose(sums[0, 0], padded[3:6, 2:5].sum())


def test_octave_filter_sizes_follow_bay() -> None:
    assert octave_sizes(0) == [9, 15, 21, 27]
    assert octave_sizes(1) == [15, 27, 39, 51]
    assert octave_sizes(2) == [27, 51, 75, 99]


def explicit_kernels(size: int):
    """Bay et al.'s box filters written out cell by cell: Dyy (3 lobes of `size/3` rows, 2*lobe-1 wide), Dxx, Dxy."""
    lobe, half = size // 3, size // 2
    dyy = np.zeros((size, size))
    columns = slice(half - (lobe - 1), half + lobe)
    dyy[:lobe, columns] = 1.0
    dyy[lobe : 2 * lobe, columns] = -2.0
    dyy[2 * lobe :, columns] = 1.0
    dxy = np.zeros((size, size))
    dxy[half - lobe : half, half - lobe : half] = 1.0
    dxy[half + 1 : half + 1 + lobe, half + 1 : half + 1 + lobe] = 1.0
    dxy[half - lobe : half, half + 1 : half + 1 + lobe] = -1.0
    dxy[half + 1 : half + 1 + lobe, half - lobe : half] = -1.0
    return dyy.T, dyy, dxy


def test_hessian_response_equals_explicit_box_filters() -> None:
    from ssnerf_method.label_makers.surf import hessian_response

    rng = np.random.default_rng(1)
    image = rng.random((40, 40))
    for size in (9, 15):
        pad = size
        response = hessian_response(integral_image(image, pad), pad, image.shape, size)
        dxx, dyy, dxy = (kernel / size**2 for kernel in explicit_kernels(size))
        half = size // 2
        for y, x in ((20, 20), (17, 23)):
            patch = image[y - half : y + half + 1, x - half : x + half + 1]
            expected = (patch * dxx).sum() * (patch * dyy).sum() - (0.9 * (patch * dxy).sum()) ** 2
            assert np.isclose(response[y, x], expected)
