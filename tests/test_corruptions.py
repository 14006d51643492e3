"""Weak-label corruptions produce the documented error rates, per view and differently for each view."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from ssnerf_method.label_makers.corruptions import corrupt_dense, corrupt_semantics, corrupt_sparse
from ssnerf_method.properties import SEMANTIC_IGNORE


def class_map() -> np.ndarray:
    ids = np.zeros((40, 60), dtype=np.uint8)
    ids[:, 20:40], ids[:, 40:] = 1, 2
    ids[10:20, 45:55] = 3
    ids[:5, :10] = SEMANTIC_IGNORE
    return ids


@pytest.mark.parametrize("rate", [0.0, 0.1, 0.35])
def test_pixel_noise_changes_exactly_the_rate_of_labelled_pixels(rate: float) -> None:
    ids = class_map()
    weak = corrupt_semantics(ids, 4, rate, np.random.default_rng(0), mode="pixels")
    labelled = ids != SEMANTIC_IGNORE
    assert (weak[~labelled] == SEMANTIC_IGNORE).all()
    assert int((weak != ids).sum()) == round(rate * labelled.sum())
    assert weak[labelled].max() < 4  # only real classes
    other = corrupt_semantics(ids, 4, rate, np.random.default_rng(1), mode="pixels")
    assert rate == 0.0 or not np.array_equal(weak, other)  # each view its own noise


def test_region_swaps_relabel_whole_regions_up_to_the_rate() -> None:
    ids = class_map()
    labelled = int((ids != SEMANTIC_IGNORE).sum())
    weak = corrupt_semantics(ids, 4, 0.2, np.random.default_rng(3), mode="regions")
    changed = weak != ids
    largest = max(int((ids == c).sum()) for c in range(4))
    assert 0.2 * labelled <= changed.sum() <= 0.2 * labelled + largest
    for class_id in range(4):  # a region changes as a whole, into one other class
        components, count = ndimage.label(ids == class_id)
        for number in range(1, count + 1):
            region = components == number
            assert changed[region].all() or not changed[region].any()
            assert len(np.unique(weak[region])) == 1


def test_dense_bias_has_the_documented_mean_change() -> None:
    shading = np.full((48, 64), 0.5)
    weak = corrupt_dense(shading, 0.04, np.random.default_rng(0))
    assert np.abs(weak - shading).mean() == pytest.approx(0.04, rel=1e-6)  # nothing clipped at 0.5 +- 0.2
    assert np.abs(weak - shading).std() > 0.005  # a field, not a constant offset
    normals = np.zeros((48, 64, 3))
    normals[..., 2] = 1.0
    weak_normals = corrupt_dense((normals + 1) / 2, 0.05, np.random.default_rng(0))
    vectors = weak_normals * 2 - 1
    assert np.allclose(np.linalg.norm(vectors, axis=-1), 1.0, atol=1e-6)
    angles = np.degrees(np.arccos(np.clip(vectors[..., 2], -1, 1)))
    assert 1.0 < angles.mean() < 20.0


def test_sparse_maps_lose_and_gain_the_documented_responses() -> None:
    edges = np.zeros((50, 50))
    for row in range(5, 50, 5):
        edges[row, 5:45] = 1.0  # nine separate lines
    weak = corrupt_sparse(edges, drop_rate=1 / 3, spurious_rate=2 / 3, rng=np.random.default_rng(0))
    kept = [row for row in range(5, 50, 5) if weak[row, 20] == 1.0 and weak[row, 5:45].min() > 0.99]
    assert len(kept) == 6  # 3 of the 9 lines dropped
    spurious = weak * (edges == 0)
    _, blobs = ndimage.label(spurious > 0.5)
    assert 1 <= blobs <= 6 and spurious.max() > 0.9  # 6 added responses (two may overlap or touch a line)
