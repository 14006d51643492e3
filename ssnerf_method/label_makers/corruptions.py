"""Weak labels: view-inconsistent corruptions of clean labels, for measuring how far SS-NeRF cleans them (the paper's
auto-labelling use, Fig. 4, where a pre-trained annotator's labels stand in for these).

Each function corrupts one frame's label in its on-disk encoding and draws its randomness from the generator it is
given, so every frame gets its own corruption (view-inconsistent, as an annotator's mistakes are). The documented
rate is what the tests check:

- `corrupt_semantics`, "pixels" (Semantic-NeRF's pixel-wise noise): exactly `rate` of the labelled pixels take
  another class, drawn uniformly.
- `corrupt_semantics`, "regions" (region swaps): whole connected regions of one class take another class, in random
  order, until at least `rate` of the labelled pixels changed (at most one region beyond it).
- `corrupt_dense` (normals, shading): a smooth per-view bias field plus `num_blotches` Gaussian blotches, scaled to a
  mean absolute value of `strength` per channel, added to the value or (n+1)/2 encoding; normals are renormalised,
  then everything is clipped to [0, 1] (so a map away from 0 and 1 changes by exactly `strength` on average).
- `corrupt_sparse` (edges, keypoints): `drop_rate` of the responses (connected regions above `threshold`) removed,
  and spurious Gaussian responses added, as many as `spurious_rate` x the clean responses.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
from jaxtyping import Float, UInt8
from scipy import ndimage

from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE, decode_normals, encode_normals


def corrupt_semantics(
    ids: UInt8[np.ndarray, "h w"], num_classes: int, rate: float, rng: np.random.Generator,
    mode: Literal["pixels", "regions"] = "pixels",
) -> UInt8[np.ndarray, "h w"]:
    """Class ids with `rate` of the labelled pixels relabelled (unlabelled pixels, 255, stay)."""
    if not 0.0 <= rate <= 1.0 or num_classes < 2:
        raise ValueError(f"rate must be in [0, 1] and there must be two classes or more (rate {rate}, "
                         f"{num_classes} classes)")
    result = ids.copy()
    labelled = np.flatnonzero(ids.reshape(-1) != SEMANTIC_IGNORE)
    target = int(round(rate * labelled.size))
    if mode == "pixels":
        chosen = rng.choice(labelled, size=target, replace=False)
        flat = result.reshape(-1)
        flat[chosen] = _other_class(flat[chosen], num_classes, rng)
        return result
    changed = 0
    regions = []
    for class_id in np.unique(ids[ids != SEMANTIC_IGNORE]):
        components, count = ndimage.label(ids == class_id)
        regions += [(components == number) for number in range(1, count + 1)]
    for index in rng.permutation(len(regions)):
        if changed >= target:
            break
        region = regions[index]
        result[region] = _other_class(ids[region][:1], num_classes, rng)[0]
        changed += int(region.sum())
    return result


def _other_class(current: np.ndarray, num_classes: int, rng: np.random.Generator) -> np.ndarray:
    """A class different from each of `current`, uniformly among the others."""
    offset = rng.integers(1, num_classes, size=current.shape)
    return ((current.astype(np.int64) + offset) % num_classes).astype(np.uint8)


def smooth_field(height: int, width: int, rng: np.random.Generator, cells: int = 4) -> Float[np.ndarray, "h w"]:
    """A smooth random field: standard normal values on a `cells` x `cells` grid, bicubically upsampled."""
    grid = rng.standard_normal((cells, cells)).astype(np.float32)
    return cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC).astype(np.float64)


def corrupt_dense(
    values: Float[np.ndarray, "h w *c"], strength: float, rng: np.random.Generator, num_blotches: int = 3,
) -> Float[np.ndarray, "h w *c"]:
    """A map in [0, 1] ((H, W) shading or (H, W, 3) normals in the (n+1)/2 encoding) plus a per-view bias field and
    blotches of mean absolute value `strength`; normals renormalised, then clipped to [0, 1]."""
    height, width = values.shape[:2]
    channels = 1 if values.ndim == 2 else values.shape[2]
    noise = np.stack([smooth_field(height, width, rng) for _ in range(channels)], axis=-1)
    rows, cols = np.mgrid[0:height, 0:width]
    for _ in range(num_blotches):
        centre, sigma = rng.uniform([0, 0], [height, width]), rng.uniform(0.05, 0.15) * max(height, width)
        blob = np.exp(-((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2) / (2 * sigma**2))
        noise += 3.0 * blob[..., None] * rng.choice([-1.0, 1.0], size=channels)
    noise *= strength / max(float(np.abs(noise).mean()), 1e-12)
    shifted = values.reshape(height, width, channels) + noise
    if channels == 3:  # a direction again: renormalise in [-1, 1], back to the encoding
        vectors = decode_normals(shifted)
        vectors /= np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-9)
        shifted = encode_normals(vectors)
    return np.clip(shifted, 0.0, 1.0).reshape(values.shape)


def corrupt_sparse(
    values: Float[np.ndarray, "h w"], drop_rate: float, spurious_rate: float, rng: np.random.Generator,
    threshold: float = 0.1, sigma: float = 1.5,
) -> Float[np.ndarray, "h w"]:
    """A sparse map in [0, 1] (edges, keypoint heatmap) with `drop_rate` of its responses removed and
    `spurious_rate` x as many Gaussian responses of peak 1 added at random places."""
    components, count = ndimage.label(values > threshold, structure=np.ones((3, 3)))
    result = values.copy()
    dropped = rng.choice(np.arange(1, count + 1), size=int(round(drop_rate * count)), replace=False)
    result[np.isin(components, dropped)] = 0.0
    height, width = values.shape
    rows, cols = np.mgrid[0:height, 0:width]
    for _ in range(int(round(spurious_rate * count))):
        centre = rng.uniform([0, 0], [height, width])
        blob = np.exp(-((rows - centre[0]) ** 2 + (cols - centre[1]) ** 2) / (2 * sigma**2))
        result = np.maximum(result, blob)
    return result


DEFAULT_RATES = {"classes": (0.1, 0.3, 0.5), "dense": (0.02, 0.05, 0.1), "sparse": (0.2, 0.4, 0.6)}
"""Corruption rates of the auto-labelling study: share of pixels relabelled (classes), mean absolute change (dense),
share of responses dropped and added (sparse)."""


def corrupt_label_file(
    image: np.ndarray, corruption: str, rate: float, num_classes: int, rng: np.random.Generator,
    mode: Literal["pixels", "regions"] = "pixels",
) -> np.ndarray:
    """One label file's 8-bit content (as read, an alpha channel of unlabelled pixels kept) corrupted at `rate`."""
    channels = 1 if image.ndim == 2 else image.shape[2]
    has_alpha = channels in (2, 4)
    values = image[..., :-1] if has_alpha else image
    values = values[..., 0] if values.ndim == 3 and values.shape[2] == 1 else values
    if corruption == "classes":
        weak = corrupt_semantics(values, num_classes, rate, rng, mode)
    elif corruption == "dense":
        weak = np.round(corrupt_dense(values.astype(np.float64) / 255.0, rate, rng) * 255.0).astype(np.uint8)
    elif corruption == "sparse":
        weak = np.round(corrupt_sparse(values.astype(np.float64) / 255.0, rate, rate, rng) * 255.0).astype(np.uint8)
    else:
        raise ValueError(f"no corruption {corruption!r}: use classes, dense or sparse")
    if not has_alpha:
        return weak
    return np.concatenate([weak.reshape(*weak.shape[:2], -1), image[..., -1:]], axis=-1)
